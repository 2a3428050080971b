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
//! Ports of `ipc::Service` are not `Send`: keep each channel on the thread that made it.

use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;

/// How a process waits for its next input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum WaitStrategy {
    /// Sleep on the event until notified (no CPU while idle).
    #[default]
    Block,
    /// Busy-poll the subscriber (for a dedicated core).
    Spin,
    /// Busy-poll for up to the given time, then sleep on the event.
    SpinThenBlock(Duration),
}

impl WaitStrategy {
    /// The spin time of `spin-then-block` when none is given: 200 µs.
    pub const DEFAULT_SPIN: Duration = Duration::from_micros(200);
}

impl fmt::Display for WaitStrategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WaitStrategy::Block => f.write_str("block"),
            WaitStrategy::Spin => f.write_str("spin"),
            WaitStrategy::SpinThenBlock(d) if *d == Self::DEFAULT_SPIN => {
                f.write_str("spin-then-block")
            }
            WaitStrategy::SpinThenBlock(d) => write!(f, "spin-then-block:{}", d.as_micros()),
        }
    }
}

/// A wait strategy that is not `block`, `spin`, `spin-then-block` or `spin-then-block:<µs>`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown wait strategy {0:?}: expected block, spin, spin-then-block or spin-then-block:<microseconds>"
)]
pub struct BadWaitStrategy(pub String);

impl FromStr for WaitStrategy {
    type Err = BadWaitStrategy;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "block" => Ok(Self::Block),
            "spin" => Ok(Self::Spin),
            "spin-then-block" => Ok(Self::SpinThenBlock(Self::DEFAULT_SPIN)),
            other => other
                .strip_prefix("spin-then-block:")
                .and_then(|us| us.parse::<u64>().ok())
                .filter(|&us| us > 0)
                .map(|us| Self::SpinThenBlock(Duration::from_micros(us)))
                .ok_or_else(|| BadWaitStrategy(s.to_owned())),
        }
    }
}

/// An iceoryx2 failure; `context` says which step.
#[derive(Debug, thiserror::Error)]
#[error("iceoryx2: cannot {context}: {message}")]
pub struct IpcError {
    /// The step that failed.
    pub context: &'static str,
    /// iceoryx2's error.
    pub message: String,
}

/// Maps an iceoryx2 error to an [`IpcError`] naming the step.
pub fn ipc_err<E: fmt::Debug>(context: &'static str) -> impl FnOnce(E) -> IpcError {
    move |e| IpcError {
        context,
        message: format!("{e:?}"),
    }
}

/// `CLOCK_MONOTONIC` in ns: the stamp every TES process uses, comparable across processes.
pub fn monotonic_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map(|t| {
            (t.tv_sec() as u64)
                .saturating_mul(1_000_000_000)
                .saturating_add(t.tv_nsec() as u64)
        })
        .unwrap_or(0)
}

/// Raises the returned flag on SIGINT or SIGTERM: every TES process stops its loop cleanly on
/// either (saving what it must) instead of dying mid-write.
pub fn stop_on_signals() -> std::io::Result<std::sync::Arc<AtomicBool>> {
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone())?;
    }
    Ok(stop)
}

/// Creates a process's iceoryx2 node with an explicit default config (no "no config file"
/// warning); `handle_signals` lets iceoryx2 turn SIGINT/SIGTERM into a termination request
/// (a launcher that handles signals itself passes `false`).
pub fn node(handle_signals: bool) -> Result<Node<ipc::Service>, IpcError> {
    let mode = if handle_signals {
        SignalHandlingMode::HandleTerminationRequests
    } else {
        SignalHandlingMode::Disabled
    };
    NodeBuilder::new()
        .config(&Config::default())
        .signal_handling_mode(mode)
        .create::<ipc::Service>()
        .map_err(ipc_err("create the node"))
}

/// Removes the iceoryx2 resources (shared memory, event and service files) left behind by
/// nodes whose process died without cleaning up; returns how many dead nodes were cleaned.
pub fn clean_stale_resources() -> Result<usize, IpcError> {
    let mut cleaned = 0;
    let mut failures = Vec::new();
    Node::<ipc::Service>::list(&Config::default(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(()) => cleaned += 1,
                Err(e) => failures.push(format!("{e:?}")),
            }
        }
        CallbackProgression::Continue
    })
    .map_err(ipc_err("list the nodes"))?;
    if let Some(first) = failures.first() {
        return Err(IpcError {
            context: "remove a dead node's stale resources",
            message: format!("{first} ({} failures)", failures.len()),
        });
    }
    Ok(cleaned)
}

/// Opens (or creates) a publish–subscribe service with the settings every TES process uses
/// (subscriber buffer [`BUFFER`], `history` samples for late subscribers). Every opener of a
/// service must use these, since iceoryx2 refuses to open a service with other settings.
pub fn pubsub<T: ZeroCopySend + Copy + fmt::Debug + 'static>(
    node: &Node<ipc::Service>,
    name: &str,
    history: usize,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>,
    IpcError,
> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .history_size(history)
        .subscriber_max_buffer_size(history.max(BUFFER))
        .open_or_create()
        .map_err(ipc_err("open a publish-subscribe service"))
}

/// The names of the iceoryx2 services that exist now and start with `prefix` (to check that a
/// stopped group left nothing behind).
pub fn services_with_prefix(prefix: &str) -> Result<Vec<String>, IpcError> {
    use iceoryx2::service::Service as _;
    let mut names = Vec::new();
    ipc::Service::list(&Config::default(), |service| {
        let name = service.static_details.name().to_string();
        if name.starts_with(prefix) {
            names.push(name);
        }
        CallbackProgression::Continue
    })
    .map_err(ipc_err("list the services"))?;
    Ok(names)
}

/// A notifier on the event service `event` (opened or created).
fn notifier(
    node: &Node<ipc::Service>,
    event: &str,
) -> Result<iceoryx2::port::notifier::Notifier<ipc::Service>, IpcError> {
    node.service_builder(&service_name(event)?)
        .event()
        .open_or_create()
        .map_err(ipc_err("open an event service"))?
        .notifier_builder()
        .create()
        .map_err(ipc_err("create a notifier"))
}

/// A listener on the event service `event` (opened or created).
fn listener(node: &Node<ipc::Service>, event: &str) -> Result<Listener, IpcError> {
    node.service_builder(&service_name(event)?)
        .event()
        .open_or_create()
        .map_err(ipc_err("open an event service"))?
        .listener_builder()
        .create()
        .map_err(ipc_err("create a listener"))
}

fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).map_err(ipc_err("use the service name"))
}

/// The sending end: a publisher and a notifier.
pub struct Outbox<T: ZeroCopySend + Copy + fmt::Debug + 'static> {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, T, ()>,
    notifier: iceoryx2::port::notifier::Notifier<ipc::Service>,
}

impl<T: ZeroCopySend + Copy + fmt::Debug + 'static> Outbox<T> {
    /// Opens (or creates) the payload service `name` and its event service `event`.
    /// `history` samples are kept for subscribers that join later (0 for none).
    pub fn open(
        node: &Node<ipc::Service>,
        name: &str,
        event: &str,
        history: usize,
    ) -> Result<Self, IpcError> {
        let service = pubsub::<T>(node, name, history)?;
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
    /// `topics/tests/allocations.rs` and docs/performance.md).
    pub fn send(&self, value: T) -> Result<(), IpcError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(ipc_err("loan a sample"))?;
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

/// Why [`Inbox::next`] returned without a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Idle {
    /// The timeout passed.
    Timeout,
    /// The stop flag was raised.
    Stopped,
}

/// The receiving end: a subscriber, a listener, and the strategy to wait by.
pub struct Inbox<T: ZeroCopySend + Copy + fmt::Debug + 'static> {
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, T, ()>,
    listener: Listener,
    strategy: WaitStrategy,
}

/// Samples a subscriber can hold before the oldest is dropped. The control loop has one sample
/// in flight; the slack absorbs a receiver descheduled on a loaded machine, and receivers
/// detect any loss by the payloads' sequence numbers.
pub const BUFFER: usize = 16;

/// How often a blocking wait looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(50);

impl<T: ZeroCopySend + Copy + fmt::Debug + 'static> Inbox<T> {
    /// Opens (or creates) the payload service `name` and its event service `event`.
    pub fn open(
        node: &Node<ipc::Service>,
        name: &str,
        event: &str,
        history: usize,
        strategy: WaitStrategy,
    ) -> Result<Self, IpcError> {
        let service = pubsub::<T>(node, name, history)?;
        let subscriber = service
            .subscriber_builder()
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
        })
    }

    /// The strategy it waits by.
    pub fn strategy(&self) -> WaitStrategy {
        self.strategy
    }

    /// The next payload if one is waiting, without waiting.
    pub fn try_next(&self) -> Result<Option<T>, IpcError> {
        Ok(self
            .subscriber
            .receive()
            .map_err(ipc_err("receive a sample"))?
            .map(|sample| *sample))
    }

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
            timeout,
            stop,
            || self.try_next(),
            work,
        )
    }

    /// Connects publishers that appeared since the last call.
    pub fn update_connections(&self) -> Result<(), IpcError> {
        self.subscriber
            .update_connections()
            .map_err(ipc_err("connect a subscriber"))
    }
}

type Listener = iceoryx2::port::listener::Listener<ipc::Service>;

/// Polls `try_next` and waits between polls by `strategy` on `listener`, at most `timeout`,
/// calling `work` between polls while spinning; returns early when `stop` is raised. Allocation-free in `spin`; `block` sleeps in the kernel.
fn wait_next<T>(
    listener: &Listener,
    strategy: WaitStrategy,
    timeout: Duration,
    stop: &AtomicBool,
    mut try_next: impl FnMut() -> Result<Option<T>, IpcError>,
    mut work: impl FnMut() -> bool,
) -> Result<Result<T, Idle>, IpcError> {
    let start = Instant::now();
    let spin_for = match strategy {
        WaitStrategy::Block => Duration::ZERO,
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
        listener
            .try_wait(|_| {})
            .map_err(ipc_err("drain the listener"))?;
        if let Some(v) = try_next()? {
            return Ok(Ok(v));
        }
    }
}

/// Blocks until the listener's socket is readable or `timeout` passes, by `ppoll(2)`:
/// timer-precise, unlike iceoryx2 0.10's `Listener::timed_wait` (a socket receive
/// timeout, which the kernel rounds up to its tick — measured 8 ms here for any timeout
/// from 20 µs to 3 ms). A signal ends the wait early (the caller looks at its stop flag).
fn wait_readable(listener: &Listener, timeout: Duration) -> Result<(), IpcError> {
    use iceoryx2::prelude::FileDescriptorBased;
    use nix::poll::{PollFd, PollFlags, ppoll};
    use std::os::fd::BorrowedFd;
    // SAFETY: the descriptor belongs to `listener`, which outlives this call.
    let fd = unsafe { BorrowedFd::borrow_raw(listener.file_descriptor().native_handle()) };
    let mut fds = [PollFd::new(fd, PollFlags::POLLIN)];
    match ppoll(
        &mut fds,
        Some(nix::sys::time::TimeSpec::from_duration(timeout)),
        None,
    ) {
        Ok(_) | Err(nix::errno::Errno::EINTR) => Ok(()),
        Err(e) => Err(ipc_err("wait on the listener")(e)),
    }
}

/// The one key of every latest-value board.
const BOARD_KEY: u64 = 0;

type Board = iceoryx2::service::port_factory::blackboard::PortFactory<ipc::Service, u64>;

/// Opens the blackboard service `name` holding one `T` under [`BOARD_KEY`], creating it (with
/// `T::default()`) if no process has yet; retried while another process is creating it.
fn board<T: ZeroCopySend + Copy + Default + fmt::Debug + 'static>(
    node: &Node<ipc::Service>,
    name: &str,
) -> Result<Board, IpcError> {
    let name = service_name(name)?;
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let opened = node
            .service_builder(&name)
            .blackboard_opener::<u64>()
            .open();
        let open_error = match opened {
            Ok(board) => return Ok(board),
            Err(e) => e,
        };
        match node
            .service_builder(&name)
            .blackboard_creator::<u64>()
            .add::<T>(BOARD_KEY, T::default())
            .create()
        {
            Ok(board) => return Ok(board),
            Err(create_error) if Instant::now() > deadline => {
                return Err(ipc_err("open or create a blackboard")(format!(
                    "open: {open_error:?}; create: {create_error:?}"
                )));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(2)),
        }
    }
}

/// The sending end of a latest-value channel: an iceoryx2 blackboard entry holding one `T`,
/// overwritten in place by each [`send`](Self::send), and an event to wake the reader.
///
/// Unlike [`Outbox`], sending allocates nothing at all (iceoryx2 0.10's publisher allocates
/// one shared-state object per loaned sample; a blackboard entry is a lock-free store into
/// shared memory). The reader sees only the latest value: use it where the sender waits for
/// the receiver's answer before sending again (the controller's commands), so nothing is
/// overwritten unread; a value overwritten anyway is detected by its sequence number.
pub struct LatestOutbox<T: ZeroCopySend + Copy + fmt::Debug + 'static> {
    entry: iceoryx2::port::writer::EntryHandleMut<ipc::Service, u64, T>,
    notifier: iceoryx2::port::notifier::Notifier<ipc::Service>,
    _writer: iceoryx2::port::writer::Writer<ipc::Service, u64>,
    _board: Board,
}

impl<T: ZeroCopySend + Copy + Default + fmt::Debug + 'static> LatestOutbox<T> {
    /// Opens (or creates) the board `name` and its event service `event`. One writer per
    /// board.
    ///
    /// A writer killed without dropping its ports leaves the entry marked as written by it
    /// (iceoryx2 0.10 cannot release that mark), so a respawned writer waits, up to 30 s, for
    /// the readers to drop the abandoned board ([`LatestInbox::renew_if_abandoned`]) and then
    /// opens a fresh one.
    pub fn open(node: &Node<ipc::Service>, name: &str, event: &str) -> Result<Self, IpcError> {
        let deadline = Instant::now() + Duration::from_secs(30);
        let (board, writer, entry) = loop {
            let board = board::<T>(node, name)?;
            let writer = board
                .writer_builder()
                .create()
                .map_err(ipc_err("create a blackboard writer"))?;
            match writer.entry::<T>(&BOARD_KEY) {
                Ok(entry) => break (board, writer, entry),
                Err(iceoryx2::port::writer::EntryHandleMutError::HandleAlreadyExists)
                    if Instant::now() < deadline =>
                {
                    drop(writer);
                    drop(board);
                    std::thread::sleep(Duration::from_millis(20));
                }
                Err(e) => return Err(ipc_err("open the blackboard entry for writing")(e)),
            }
        };
        let notifier = notifier(node, event)?;
        Ok(Self {
            entry,
            notifier,
            _writer: writer,
            _board: board,
        })
    }

    /// Stores `value` as the board's latest and wakes the reader. Allocation-free.
    pub fn send(&self, value: T) -> Result<(), IpcError> {
        self.entry.update_with_copy(value);
        self.notifier.notify().map_err(ipc_err("notify"))?;
        Ok(())
    }
}

/// The receiving end of a latest-value channel ([`LatestOutbox`]): yields each new value of
/// the board once, waiting by its [`WaitStrategy`] like [`Inbox`].
pub struct LatestInbox<T: ZeroCopySend + Copy + PartialEq + fmt::Debug + 'static> {
    /// `None` only between letting an abandoned board go and opening the next.
    reading: Option<BoardReader<T>>,
    /// The last value read, to tell a new one from it.
    last: std::cell::Cell<Option<iceoryx2::port::reader::BlackboardValue<T>>>,
    listener: Listener,
    strategy: WaitStrategy,
    name: String,
    /// Whether a writer has been seen on the current board.
    had_writer: bool,
    /// Since when the current board has had no writer (as last checked).
    writerless_since: Option<Instant>,
}

/// How long a board that never had a writer is kept before [`LatestInbox::renew_if_abandoned`]
/// renews it anyway.
const RENEW_AFTER: Duration = Duration::from_secs(2);

/// A reader's hold on a board (dropped together, so the board can be renewed).
struct BoardReader<T: ZeroCopySend + Copy + fmt::Debug + 'static> {
    entry: iceoryx2::port::reader::EntryHandle<ipc::Service, u64, T>,
    _reader: iceoryx2::port::reader::Reader<ipc::Service, u64>,
    board: Board,
}

impl<T: ZeroCopySend + Copy + Default + fmt::Debug + 'static> BoardReader<T> {
    fn open(node: &Node<ipc::Service>, name: &str) -> Result<Self, IpcError> {
        let board = board::<T>(node, name)?;
        let reader = board
            .reader_builder()
            .create()
            .map_err(ipc_err("create a blackboard reader"))?;
        let entry = reader
            .entry::<T>(&BOARD_KEY)
            .map_err(ipc_err("open the blackboard entry for reading"))?;
        Ok(Self {
            entry,
            _reader: reader,
            board,
        })
    }
}

impl<T: ZeroCopySend + Copy + Default + PartialEq + fmt::Debug + 'static> LatestInbox<T> {
    /// Opens (or creates) the board `name` and its event service `event`. What the board holds
    /// at opening counts as already read.
    pub fn open(
        node: &Node<ipc::Service>,
        name: &str,
        event: &str,
        strategy: WaitStrategy,
    ) -> Result<Self, IpcError> {
        let reading = BoardReader::open(node, name)?;
        let listener = listener(node, event)?;
        let last = std::cell::Cell::new(Some(reading.entry.get()));
        Ok(Self {
            reading: Some(reading),
            last,
            listener,
            strategy,
            name: name.to_owned(),
            had_writer: false,
            writerless_since: None,
        })
    }

    /// When the board's writer has left (or none has come for 2 s), lets go of it and opens
    /// it afresh; returns whether it did. Call it while idle: a writer killed without dropping its ports leaves the board's
    /// entry marked as its own, and a respawned writer can only write to a board created
    /// after every holder of the old one let go ([`LatestOutbox::open`]).
    pub fn renew_if_abandoned(&mut self, node: &Node<ipc::Service>) -> Result<bool, IpcError> {
        use iceoryx2::service::port_factory::PortFactory as _;
        if let Some(r) = &self.reading {
            if r.board.dynamic_config().number_of_writers() > 0 {
                self.had_writer = true;
                self.writerless_since = None;
                return Ok(false);
            }
            // Renew a board its writer left, or one no writer has used for a while (a
            // respawned writer may be waiting for it); not one a writer may be about to join.
            let since = *self.writerless_since.get_or_insert_with(Instant::now);
            if !self.had_writer && since.elapsed() < RENEW_AFTER {
                return Ok(false);
            }
        }
        self.had_writer = false;
        self.writerless_since = None;
        // Let the old board go first, so that, abandoned, it can be removed.
        self.last.set(None);
        self.reading = None;
        let fresh = BoardReader::open(node, &self.name)?;
        self.last.set(Some(fresh.entry.get()));
        self.reading = Some(fresh);
        Ok(true)
    }

    /// The strategy it waits by.
    pub fn strategy(&self) -> WaitStrategy {
        self.strategy
    }

    /// The board's value if it changed since the last read, without waiting.
    pub fn try_next(&self) -> Result<Option<T>, IpcError> {
        let Some(reading) = &self.reading else {
            return Ok(None);
        };
        let last = self.last.take();
        if let Some(l) = &last
            && reading.entry.is_up_to_date(l)
        {
            self.last.set(last);
            return Ok(None);
        }
        let now = reading.entry.get();
        let value = *now;
        // A write racing the read can make the same value look new once more.
        let same = last.as_ref().is_some_and(|l| **l == value);
        self.last.set(Some(now));
        Ok((!same).then_some(value))
    }

    /// Waits, by the inbox's strategy, for the board's next value, at most `timeout`, and
    /// returns early when `stop` is raised. Allocation-free.
    pub fn next(&self, timeout: Duration, stop: &AtomicBool) -> Result<Result<T, Idle>, IpcError> {
        wait_next(
            &self.listener,
            self.strategy,
            timeout,
            stop,
            || self.try_next(),
            || false,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wait_strategies_parse_and_print() {
        for (text, strategy) in [
            ("block", WaitStrategy::Block),
            ("spin", WaitStrategy::Spin),
            (
                "spin-then-block",
                WaitStrategy::SpinThenBlock(WaitStrategy::DEFAULT_SPIN),
            ),
            (
                "spin-then-block:50",
                WaitStrategy::SpinThenBlock(Duration::from_micros(50)),
            ),
        ] {
            assert_eq!(text.parse::<WaitStrategy>(), Ok(strategy));
            assert_eq!(strategy.to_string(), text);
        }
        for bad in [
            "",
            "Block",
            "spin-then-block:",
            "spin-then-block:0",
            "sleep",
        ] {
            let err = bad.parse::<WaitStrategy>().unwrap_err();
            assert!(err.to_string().contains("expected block, spin"), "{err}");
        }
    }
}
