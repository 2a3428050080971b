//! One-way channels between the TES processes: an iceoryx2 publish–subscribe service for the
//! payload plus an event service to wake the receiver, and the [`WaitStrategy`] the receiver
//! waits by.
//!
//! * [`Outbox`] — publishes a payload (written straight into shared memory) and notifies.
//! * [`Inbox`] — receives the next payload, waiting by its strategy:
//!   * `block` (default) — sleep on the event listener until notified: no CPU burnt while idle;
//!   * `spin` — busy-poll the subscriber: lowest latency, one core fully used;
//!   * `spin-then-block` — busy-poll for a bounded time, then sleep.
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
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::Service;

pub use crate::anticipate::Catches;
use crate::anticipate::{Anticipation, Step};
pub use crate::board::{LatestInbox, LatestOutbox};
use crate::clock::monotonic_ns;
pub use crate::ipc::{
    Cleanup, DOMAIN_VAR, IpcError, Member, NODE_NAME_MAX, NodeEntry, NodeLiveness,
    clean_every_stale_domain, clean_every_stale_resource, clean_stale_domains,
    clean_stale_resources, config, group_node, group_node_name, ipc_err, list_nodes, node,
    node_named, parse_group_node_name, prefix_of, pubsub, remove_domain, services_with_prefix,
    shared_node,
};
use crate::ipc::{listener, notifier};
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

/// Why [`Inbox::next`] returned without a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Idle {
    /// The timeout passed.
    Timeout,
    /// The stop flag was raised.
    Stopped,
}

/// The receiving end: a subscriber, a listener, and the strategy to wait by.
pub struct Inbox<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service = ipc::Service> {
    subscriber: iceoryx2::port::subscriber::Subscriber<S, T, ()>,
    listener: Listener<S>,
    strategy: WaitStrategy,
    /// With `anticipate`: what it learned of the sender's timing.
    anticipation: Option<Box<Anticipation<S>>>,
}

/// Samples a subscriber can hold before the oldest is dropped. The control loop has one sample
/// in flight; the slack absorbs a receiver descheduled on a loaded machine, and receivers
/// detect any loss by the payloads' sequence numbers.
pub const BUFFER: usize = 16;

/// How often a blocking wait looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(50);

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

pub(crate) type Listener<S = ipc::Service> = iceoryx2::port::listener::Listener<S>;

/// Polls `try_next` and waits between polls by `strategy` on `listener`, at most `timeout`,
/// calling `work` between polls while spinning; returns early when `stop` is raised.
/// Allocation-free in `spin`; `block` sleeps in the kernel; `anticipate` (with its
/// `anticipation`) sleeps until shortly before the next message is due.
pub(crate) fn wait_next<T, S: Service>(
    listener: &Listener<S>,
    strategy: WaitStrategy,
    anticipation: Option<&Anticipation<S>>,
    timeout: Duration,
    stop: &AtomicBool,
    mut try_next: impl FnMut() -> Result<Option<T>, IpcError>,
    mut work: impl FnMut() -> bool,
) -> Result<Result<T, Idle>, IpcError>
where
    Listener<S>: FileDescriptorBased,
{
    if let Some(a) = anticipation {
        return wait_anticipating(listener, a, timeout, stop, try_next, work);
    }
    let start = Instant::now();
    let spin_for = match strategy {
        WaitStrategy::Block | WaitStrategy::Anticipate => Duration::ZERO,
        WaitStrategy::Spin => timeout,
        WaitStrategy::SpinThenBlock(d) => d.min(timeout),
    };
    let mut polls: u32 = 0;
    loop {
        if let Some(v) = try_next()? {
            return Ok(Ok(v));
        }
        let waited = start.elapsed();
        if waited >= spin_for {
            break;
        }
        polls = polls.wrapping_add(1);
        if polls.is_multiple_of(1024) && stop.load(Ordering::Relaxed) {
            return Ok(Err(Idle::Stopped));
        }
        if !work() {
            std::hint::spin_loop();
        }
    }
    loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(Err(Idle::Stopped));
        }
        let left = timeout.saturating_sub(start.elapsed());
        if left.is_zero() {
            return Ok(Err(Idle::Timeout));
        }
        // Sleep until the listener's socket is readable or the time is up, then drain
        // every pending notification and look again: a value sent between the last look
        // and the wait still wakes us, because its notification is pending.
        wait_readable(listener, left.min(STOP_POLL))?;
        drain(listener)?;
        if let Some(v) = try_next()? {
            return Ok(Ok(v));
        }
    }
}

/// How close to its poll window an anticipating receiver stops watching for messages and
/// sleeps by the timer alone: a message early by more than this still wakes it at once.
const FINAL_APPROACH: Duration = Duration::from_millis(2);

/// The `anticipate` wait ([`crate::anticipate`]): sleeps until the model's poll window (a
/// message or a heads-up wakes it earlier), polls through the window calling `work`, and
/// blocks once the window has passed.
fn wait_anticipating<T, S: Service>(
    listener: &Listener<S>,
    anticipation: &Anticipation<S>,
    timeout: Duration,
    stop: &AtomicBool,
    mut try_next: impl FnMut() -> Result<Option<T>, IpcError>,
    mut work: impl FnMut() -> bool,
) -> Result<Result<T, Idle>, IpcError>
where
    Listener<S>: FileDescriptorBased,
{
    let start = Instant::now();
    let heads_up = anticipation.heads_up_listener();
    let model = &anticipation.model;
    loop {
        if let Some(v) = try_next()? {
            model.borrow_mut().arrived(monotonic_ns(), false);
            return Ok(Ok(v));
        }
        if stop.load(Ordering::Relaxed) {
            return Ok(Err(Idle::Stopped));
        }
        let left = timeout.saturating_sub(start.elapsed());
        if left.is_zero() {
            return Ok(Err(Idle::Timeout));
        }
        anticipation.take_heads_ups()?;
        let now = monotonic_ns();
        let step = model.borrow_mut().step(now);
        match step {
            Step::SleepUntil(until) => {
                let nap = Duration::from_nanos(until - now);
                if nap <= FINAL_APPROACH && nap <= left {
                    // The last stretch by the timer alone: a wait on the listeners comes back
                    // hundreds of µs late here, when the message itself wakes it.
                    std::thread::sleep(nap);
                    model.borrow_mut().woke(until, monotonic_ns());
                } else {
                    let nap = nap.saturating_sub(FINAL_APPROACH);
                    wait_readable_any(listener, heads_up, nap.min(left).min(STOP_POLL))?;
                    drain(listener)?;
                }
            }
            Step::PollUntil(until) => {
                loop {
                    if let Some(v) = try_next()? {
                        model.borrow_mut().arrived(monotonic_ns(), true);
                        return Ok(Ok(v));
                    }
                    // Every look: a yield may give the CPU away for a while.
                    if monotonic_ns() >= until || stop.load(Ordering::Relaxed) {
                        break;
                    }
                    if work() {
                        continue;
                    }
                    if anticipation.alone {
                        std::hint::spin_loop();
                    } else {
                        // The window is shared with the sender, which must run to send: on
                        // a machine with fewer CPUs than busy threads, a poll that keeps
                        // its CPU would hold the message up.
                        std::thread::yield_now();
                    }
                }
            }
            Step::Block => {
                wait_readable_any(listener, heads_up, left.min(STOP_POLL))?;
                drain(listener)?;
            }
        }
    }
}

/// Takes every pending notification of `listener`.
fn drain<S: Service>(listener: &Listener<S>) -> Result<(), IpcError> {
    listener
        .try_wait(|_| {})
        .map(|_| ())
        .map_err(ipc_err("drain the listener"))
}

/// Blocks until the listener's socket is readable or `timeout` passes, by `ppoll(2)`:
/// timer-precise, unlike iceoryx2 0.10's `Listener::timed_wait` (a socket receive
/// timeout, which the kernel rounds up to its scheduler tick, milliseconds for any shorter
/// timeout). A signal ends the wait early (the caller looks at its stop flag).
pub(crate) fn wait_readable<S: Service>(
    listener: &Listener<S>,
    timeout: Duration,
) -> Result<(), IpcError>
where
    Listener<S>: FileDescriptorBased,
{
    wait_readable_any(listener, None, timeout).map(|_| ())
}

/// [`wait_readable`] on `listener` and, if given, a second listener (an anticipating
/// receiver's heads-up); returns whether either became readable.
fn wait_readable_any<S: Service>(
    listener: &Listener<S>,
    other: Option<&Listener<S>>,
    timeout: Duration,
) -> Result<bool, IpcError>
where
    Listener<S>: FileDescriptorBased,
{
    use nix::poll::{PollFd, PollFlags, ppoll};
    use std::os::fd::BorrowedFd;
    // SAFETY: the descriptors belong to the listeners, which outlive this call.
    let fd =
        |l: &Listener<S>| unsafe { BorrowedFd::borrow_raw(l.file_descriptor().native_handle()) };
    let mut fds = [
        PollFd::new(fd(listener), PollFlags::POLLIN),
        PollFd::new(fd(other.unwrap_or(listener)), PollFlags::POLLIN),
    ];
    let n = if other.is_some() { 2 } else { 1 };
    match ppoll(
        &mut fds[..n],
        Some(nix::sys::time::TimeSpec::from_duration(timeout)),
        None,
    ) {
        Ok(ready) => Ok(ready > 0),
        Err(nix::errno::Errno::EINTR) => Ok(true),
        Err(e) => Err(ipc_err("wait on the listener")(e)),
    }
}
