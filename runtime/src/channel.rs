//! One-way channels between the TES processes: an iceoryx2 publish–subscribe service for the
//! payload plus an event service to wake the receiver, and the [`WaitStrategy`] the receiver
//! waits by.
//!
//! * [`Outbox`] — publishes a payload (written straight into shared memory) and notifies.
//! * [`Inbox`] — receives the next payload, waiting by its strategy ([`crate::wait`]):
//!   * `auto` (default) — `anticipate` for announced messages, else `block`;
//!   * `block` — sleep on the event listener until notified: no CPU burnt while idle;
//!   * `spin` — busy-poll the subscriber: lowest latency, one core fully used;
//!   * `spin-then-block` — busy-poll for a bounded time, then sleep;
//!   * `anticipate` — sleep until shortly before the next message is due, then poll.
//! * [`LatestOutbox`] / [`LatestInbox`] — the same over a one-entry iceoryx2 blackboard: the
//!   receiver sees the latest value, each once. Sending allocates nothing (the publisher of
//!   0.10 allocates one small object per sample), so the controller sends its commands this
//!   way.
//!
//! Ports of `ipc::Service` (the default) are not `Send`: keep each channel on the thread that
//! made it. A channel opened on an [`ipc_threadsafe`] node
//! ([`shared_node`]) is `Send` and `Sync` (its ports lock a mutex) and reaches the same services:
//! the link publishes from Zenoh's callbacks that way.

use std::fmt;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::Service;

pub use crate::anticipate::Catches;
use crate::anticipate::{Anticipation, sleep_until};
pub use crate::board::{LatestInbox, LatestOutbox};
pub use crate::ipc::{
    BUFFER, Cleanup, DOMAIN_VAR, IpcError, Member, NODE_NAME_MAX, NodeEntry, NodeLiveness,
    ProcessNode, clean_every_stale_domain, clean_every_stale_resource, clean_stale_domains,
    clean_stale_resources, config, group_node, group_node_name, ipc_err, list_nodes, node,
    node_named, parse_group_node_name, prefix_of, pubsub, remove_domain, services_with_prefix,
    shared_node,
};
use crate::ipc::{Listener, listener, notifier};
pub use crate::receive::Idle;
use crate::receive::wait_next;
pub use crate::wait::{BadWaitStrategy, WaitStrategy};

/// The sending end: a publisher and a notifier.
pub struct Outbox<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service = ipc::Service> {
    publisher: iceoryx2::port::publisher::Publisher<S, T, ()>,
    notifier: iceoryx2::port::notifier::Notifier<S>,
}

impl<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service> Outbox<T, S> {
    /// Opens (or creates) the payload service `name` and its event service `event`.
    /// `history` samples are kept for subscribers that join later (0 for none).
    pub fn open(node: &Node<S>, name: &str, event: &str, history: usize) -> Result<Self, IpcError> {
        let service = pubsub::<T, S>(node, name, history)?;
        let publisher = service
            .publisher_builder()
            .create()
            .map_err(ipc_err("create a publisher"))?;
        let notifier = notifier(node, event)?;
        publisher
            .update_connections()
            .map_err(ipc_err("connect a publisher"))?;
        Ok(Self {
            publisher,
            notifier,
        })
    }

    /// Publishes `value` and wakes the receivers. Nothing of ours allocates; iceoryx2 0.10's
    /// `loan_uninit` allocates one small shared-state object per sample (see
    /// `runtime/tests/allocations.rs` and docs/performance.md).
    pub fn send(&self, value: T) -> Result<(), IpcError> {
        self.send_in(None, value)
    }

    /// Loans the next message's sample now, for [`send_in`](Self::send_in): a sender that
    /// knows when its next message is due loans it shortly before, so that the send itself
    /// only writes and publishes memory its CPU has just touched.
    pub fn loan(&self) -> Result<Loan<T, S>, IpcError> {
        self.publisher
            .loan_uninit()
            .map(Loan)
            .map_err(ipc_err("loan a sample"))
    }

    /// [`send`](Self::send) into `loan`, if given (from [`loan`](Self::loan)), else into a
    /// sample loaned now.
    pub fn send_in(&self, loan: Option<Loan<T, S>>, value: T) -> Result<(), IpcError> {
        let Loan(sample) = match loan {
            Some(loan) => loan,
            None => self.loan()?,
        };
        sample
            .write_payload(value)
            .send()
            .map_err(ipc_err("publish a sample"))?;
        self.notifier.notify().map_err(ipc_err("notify"))?;
        Ok(())
    }

    /// Connects subscribers that appeared since the last call (call after peers start).
    pub fn update_connections(&self) -> Result<(), IpcError> {
        self.publisher
            .update_connections()
            .map_err(ipc_err("connect a publisher"))
    }
}

/// A sample loaned ahead of the message that will fill it ([`Outbox::loan`]). Dropped
/// unsent, it goes back to the publisher.
pub struct Loan<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service = ipc::Service>(
    iceoryx2::sample_mut_uninit::SampleMutUninit<S, std::mem::MaybeUninit<T>, ()>,
);

impl<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service> fmt::Debug for Loan<T, S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Loan")
    }
}

/// The receiving end: a subscriber, a listener, and the strategy to wait by.
pub struct Inbox<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service = ipc::Service> {
    subscriber: iceoryx2::port::subscriber::Subscriber<S, T, ()>,
    listener: Listener<S>,
    strategy: WaitStrategy,
    /// With `anticipate`: what it learned of the sender's timing.
    anticipation: Option<Box<Anticipation<S>>>,
}

impl<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service> Inbox<T, S> {
    /// Opens (or creates) the payload service `name` and its event service `event`.
    pub fn open(
        node: &Node<S>,
        name: &str,
        event: &str,
        history: usize,
        strategy: WaitStrategy,
    ) -> Result<Self, IpcError> {
        let service = pubsub::<T, S>(node, name, history)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(history.max(BUFFER))
            .create()
            .map_err(ipc_err("create a subscriber"))?;
        let listener = listener(node, event)?;
        subscriber
            .update_connections()
            .map_err(ipc_err("connect a subscriber"))?;
        Ok(Self {
            subscriber,
            listener,
            strategy,
            anticipation: Anticipation::for_strategy(strategy),
        })
    }

    /// The strategy it waits by.
    pub fn strategy(&self) -> WaitStrategy {
        self.strategy
    }

    /// Waiting by `anticipate`, also takes its sender's [`HeadsUp`](tes_topics::HeadsUp)s
    /// from the service `name` and its event `event` (with any other strategy, nothing).
    pub fn with_heads_up(
        mut self,
        node: &Node<S>,
        name: &str,
        event: &str,
    ) -> Result<Self, IpcError> {
        if let Some(a) = &mut self.anticipation {
            a.listen(node, name, event)?;
        }
        Ok(self)
    }

    /// Waiting by `anticipate`, whether the receiving thread has its CPU to itself (pinned
    /// there, with the other processes kept off it): if so its poll window spins without
    /// yielding the CPU. With any other strategy, nothing.
    pub fn poll_alone(&mut self, alone: bool) {
        if let Some(a) = &mut self.anticipation {
            a.alone = alone;
        }
    }

    /// Waiting by `anticipate`, how its messages came against their poll windows.
    pub fn catches(&self) -> Option<Catches> {
        self.anticipation
            .as_ref()
            .map(|a| a.model.borrow().catches())
    }

    /// The next payload if one is waiting, without waiting.
    pub fn try_next(&self) -> Result<Option<T>, IpcError> {
        Ok(self
            .subscriber
            .receive()
            .map_err(ipc_err("receive a sample"))?
            .map(|sample| *sample))
    }

    /// Connects publishers that appeared since the last call.
    pub fn update_connections(&self) -> Result<(), IpcError> {
        self.subscriber
            .update_connections()
            .map_err(ipc_err("connect a subscriber"))
    }
}

impl<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service> Inbox<T, S>
where
    iceoryx2::port::listener::Listener<S>: FileDescriptorBased,
{
    /// Waits, by the inbox's strategy, for the next payload, at most `timeout`, and returns
    /// early when `stop` is raised. Allocation-free in `spin`; `block` sleeps in the kernel.
    pub fn next(&self, timeout: Duration, stop: &AtomicBool) -> Result<Result<T, Idle>, IpcError> {
        self.next_or_work(timeout, stop, || false)
    }

    /// [`next`](Self::next), calling `work` between polls while it spins (`spin`, and the
    /// spinning part of `spin-then-block`): a waiting acting loop can do bounded pieces of
    /// background work (a slice of planning) instead of only spinning. `work` returns
    /// whether it has more to do; while it has, polls follow each other without a pause.
    /// How long one call takes is what an arriving payload may wait.
    pub fn next_or_work(
        &self,
        timeout: Duration,
        stop: &AtomicBool,
        work: impl FnMut() -> bool,
    ) -> Result<Result<T, Idle>, IpcError> {
        wait_next(
            &self.listener,
            self.strategy,
            self.anticipation.as_deref(),
            timeout,
            stop,
            || self.try_next(),
            work,
        )
    }
}

/// How long before a message is due its sender loans its sample
/// ([`sleep_until_with_loan`]), ns: inside [`sleep_until`]'s final poll of the clock.
const LOAN_AHEAD_NS: u64 = 100_000;

/// [`sleep_until`] for a sender whose message, sent by `outbox`, is due at `due_ns`: returns
/// then with the message's sample loaned shortly before, so that the send at the due time
/// only writes and publishes memory this CPU has just touched (a loan after an idle settle
/// finds the publisher's memory cold).
pub fn sleep_until_with_loan<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service>(
    due_ns: u64,
    outbox: &Outbox<T, S>,
) -> Result<Loan<T, S>, IpcError> {
    sleep_until(due_ns.saturating_sub(LOAN_AHEAD_NS));
    let loan = outbox.loan()?;
    sleep_until(due_ns);
    Ok(loan)
}
