//! Latest-value channels over a one-entry iceoryx2 blackboard: the receiver sees the latest
//! value, each once, and sending allocates nothing.

use std::fmt;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use iceoryx2::service::Service;

use crate::anticipate::Anticipation;
use crate::ipc::{IpcError, Listener, ipc_err, listener, notifier, service_name};
use crate::receive::{Idle, wait_next};
use crate::wait::WaitStrategy;

/// The one key of every latest-value board.
const BOARD_KEY: u64 = 0;

type Board<S = ipc::Service> = iceoryx2::service::port_factory::blackboard::PortFactory<S, u64>;

/// Opens the blackboard service `name` holding one `T` under [`BOARD_KEY`], creating it (with
/// `T::default()`) if no process has yet; retried while another process is creating it.
fn board<T: ZeroCopySend + Copy + Default + fmt::Debug + 'static, S: Service>(
    node: &Node<S>,
    name: &str,
) -> Result<Board<S>, IpcError> {
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
/// Unlike [`Outbox`](crate::channel::Outbox), sending allocates nothing at all (iceoryx2 0.10's publisher allocates
/// one shared-state object per loaned sample; a blackboard entry is a lock-free store into
/// shared memory). The reader sees only the latest value: use it where the sender waits for
/// the receiver's answer before sending again (the controller's commands), so nothing is
/// overwritten unread; a value overwritten anyway is detected by its sequence number.
pub struct LatestOutbox<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service = ipc::Service> {
    entry: iceoryx2::port::writer::EntryHandleMut<S, u64, T>,
    notifier: iceoryx2::port::notifier::Notifier<S>,
    _writer: iceoryx2::port::writer::Writer<S, u64>,
    _board: Board<S>,
}

impl<T: ZeroCopySend + Copy + Default + fmt::Debug + 'static, S: Service> LatestOutbox<T, S> {
    /// Opens (or creates) the board `name` and its event service `event`. One writer per
    /// board.
    ///
    /// A writer killed without dropping its ports leaves the entry marked as written by it
    /// (iceoryx2 0.10 cannot release that mark), so a respawned writer waits, up to 30 s, for
    /// the readers to drop the abandoned board ([`LatestInbox::renew_if_abandoned`]) and then
    /// opens a fresh one.
    pub fn open(node: &Node<S>, name: &str, event: &str) -> Result<Self, IpcError> {
        let deadline = Instant::now() + Duration::from_secs(30);
        let (board, writer, entry) = loop {
            let board = board::<T, S>(node, name)?;
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
/// the board once, waiting by its [`WaitStrategy`] like [`Inbox`](crate::channel::Inbox).
pub struct LatestInbox<T: ZeroCopySend + Copy + PartialEq + fmt::Debug + 'static> {
    /// `None` only between letting an abandoned board go and opening the next.
    reading: Option<BoardReader<T>>,
    /// The last value read, to tell a new one from it.
    last: std::cell::Cell<Option<iceoryx2::port::reader::BlackboardValue<T>>>,
    listener: Listener,
    strategy: WaitStrategy,
    /// With `anticipate`: what it learned of the writer's timing.
    anticipation: Option<Box<Anticipation>>,
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
        let board = board::<T, ipc::Service>(node, name)?;
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
            anticipation: Anticipation::for_strategy(strategy),
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

    /// Waiting by `anticipate`, also takes [`HeadsUp`](tes_topics::HeadsUp)s from the
    /// service `name` and its event `event`: the bridge takes perception's, as a command
    /// follows its observation by the controller's decision (with any other strategy,
    /// nothing).
    pub fn with_heads_up(
        mut self,
        node: &Node<ipc::Service>,
        name: &str,
        event: &str,
    ) -> Result<Self, IpcError> {
        if let Some(a) = &mut self.anticipation {
            a.listen(node, name, event)?;
        }
        Ok(self)
    }

    /// Waiting by `anticipate`, how its values came against their poll windows.
    pub fn catches(&self) -> Option<crate::anticipate::Catches> {
        self.anticipation
            .as_ref()
            .map(|a| a.model.borrow().catches())
    }

    /// What the board holds now, read or not (for a receiver deciding, at its start, what to
    /// make of the value it found there).
    pub fn current(&self) -> Result<Option<T>, IpcError> {
        Ok(self.reading.as_ref().map(|r| *r.entry.get()))
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
            self.anticipation.as_deref(),
            timeout,
            stop,
            || self.try_next(),
            || false,
        )
    }
}
