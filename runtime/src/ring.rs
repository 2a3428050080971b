//! A ring of the last [`RING`] values over an iceoryx2 blackboard: value `seq` is stored in
//! entry `seq % RING`, so a reader that looks at least once every `RING` values sees every
//! one. Writing is a lock-free store into shared memory that allocates nothing (like
//! [`LatestOutbox`](crate::board::LatestOutbox)), and nobody is notified: a reader polls at
//! its own pace. The controller keeps its commands here for the recorder.

use std::fmt;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;

use crate::ipc::{IpcError, ipc_err, service_name};

/// Entries of a ring.
pub const RING: usize = 1024;

type Board = iceoryx2::service::port_factory::blackboard::PortFactory<ipc::Service, u64>;

/// A value a ring can keep: its sequence number decides its entry.
pub trait Sequenced: ZeroCopySend + Copy + Default + fmt::Debug + 'static {
    /// Its sequence number (0: an empty entry).
    fn seq(&self) -> u64;
}

impl Sequenced for tes_topics::Command {
    fn seq(&self) -> u64 {
        self.seq
    }
}

fn ring_board<T: Sequenced>(node: &Node<ipc::Service>, name: &str) -> Result<Board, IpcError> {
    let name = service_name(name)?;
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let open_error = match node
            .service_builder(&name)
            .blackboard_opener::<u64>()
            .open()
        {
            Ok(board) => return Ok(board),
            Err(e) => e,
        };
        let mut creator = node.service_builder(&name).blackboard_creator::<u64>();
        for key in 0..RING as u64 {
            creator = creator.add::<T>(key, T::default());
        }
        match creator.create() {
            Ok(board) => return Ok(board),
            Err(create_error) if Instant::now() > deadline => {
                return Err(ipc_err("open or create a ring")(format!(
                    "open: {open_error:?}; create: {create_error:?}"
                )));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(2)),
        }
    }
}

/// The writing end of a ring.
pub struct RingOutbox<T: Sequenced> {
    entries: Vec<iceoryx2::port::writer::EntryHandleMut<ipc::Service, u64, T>>,
    _writer: iceoryx2::port::writer::Writer<ipc::Service, u64>,
    _board: Board,
}

impl<T: Sequenced> RingOutbox<T> {
    /// Opens (or creates) the ring `name`. One writer per ring: a writer killed without
    /// dropping its ports leaves the entries marked as its own until every reader lets the
    /// ring go, so a successor may be refused (the caller decides whether to go on without).
    pub fn open(node: &Node<ipc::Service>, name: &str) -> Result<Self, IpcError> {
        let board = ring_board::<T>(node, name)?;
        let writer = board
            .writer_builder()
            .create()
            .map_err(ipc_err("create a ring writer"))?;
        let mut entries = Vec::with_capacity(RING);
        for key in 0..RING as u64 {
            entries.push(
                writer
                    .entry::<T>(&key)
                    .map_err(ipc_err("open a ring entry for writing"))?,
            );
        }
        Ok(Self {
            entries,
            _writer: writer,
            _board: board,
        })
    }

    /// Stores `value` in its entry. Allocation-free.
    pub fn put(&self, value: T) {
        if let Some(entry) = self.entries.get(value.seq() as usize % RING) {
            entry.update_with_copy(value);
        }
    }
}

/// The reading end of a ring: yields the values newer than the last it yielded.
pub struct RingReader<T: Sequenced> {
    entries: Vec<iceoryx2::port::reader::EntryHandle<ipc::Service, u64, T>>,
    _reader: iceoryx2::port::reader::Reader<ipc::Service, u64>,
    _board: Board,
    last: u64,
    scratch: Vec<T>,
}

impl<T: Sequenced> RingReader<T> {
    /// Opens (or creates) the ring `name`; what it holds at opening counts as read.
    pub fn open(node: &Node<ipc::Service>, name: &str) -> Result<Self, IpcError> {
        let board = ring_board::<T>(node, name)?;
        let reader = board
            .reader_builder()
            .create()
            .map_err(ipc_err("create a ring reader"))?;
        let mut entries = Vec::with_capacity(RING);
        for key in 0..RING as u64 {
            entries.push(
                reader
                    .entry::<T>(&key)
                    .map_err(ipc_err("open a ring entry for reading"))?,
            );
        }
        let last = entries.iter().map(|e| e.get().seq()).max().unwrap_or(0);
        Ok(Self {
            entries,
            _reader: reader,
            _board: board,
            last,
            scratch: Vec::with_capacity(RING),
        })
    }

    /// Whether the value after the last one taken has been written: one entry read, so a
    /// reader can look often at little cost to the cache it shares with the writer. False
    /// also when that value was overwritten (the reader fell a whole ring behind) or the
    /// numbering jumped; [`take_new`](Self::take_new) finds those by a scan.
    pub fn has_new(&self) -> bool {
        self.entry_after(1).is_some()
    }

    /// The value `k` after the last taken, if it is in its entry.
    fn entry_after(&self, k: u64) -> Option<T> {
        let seq = self.last.wrapping_add(k);
        let v = *self.entries.get(seq as usize % RING)?.get();
        (v.seq() == seq).then_some(v)
    }

    /// The values written since the last call, oldest first, read forward from the entry
    /// after the last taken (only the entries written since). A value overwritten before
    /// this call (more than [`RING`] writes since) is lost; so is a jump in the numbering (a
    /// new writer numbering from elsewhere) until [`take_new_scanning`](Self::take_new_scanning).
    pub fn take_new(&mut self) -> &[T] {
        self.scratch.clear();
        for k in 1..=RING as u64 {
            match self.entry_after(k) {
                Some(v) => self.scratch.push(v),
                None => break,
            }
        }
        if let Some(v) = self.scratch.last() {
            self.last = v.seq();
        }
        if self.scratch.is_empty() {
            // The next value was overwritten unread, or lost: find the newest by a scan.
            return self.take_new_scanning();
        }
        &self.scratch
    }

    /// [`take_new`](Self::take_new) by reading every entry: also finds values after a gap
    /// or a jump in the numbering (the caller sees the gap in the sequence numbers).
    pub fn take_new_scanning(&mut self) -> &[T] {
        self.scratch.clear();
        for entry in &self.entries {
            let v = *entry.get();
            if v.seq() > self.last {
                self.scratch.push(v);
            }
        }
        self.scratch.sort_by_key(|v| v.seq());
        if let Some(v) = self.scratch.last() {
            self.last = v.seq();
        }
        &self.scratch
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_topics::Command;

    #[test]
    fn a_reader_sees_every_value_written_since_it_last_looked() {
        let node = crate::ipc::node(false).unwrap();
        let name = format!("tes-test/ring/{}/commands", std::process::id());
        let mut reader = RingReader::<Command>::open(&node, &name).unwrap();
        let writer = RingOutbox::<Command>::open(&node, &name).unwrap();
        assert!(reader.take_new().is_empty());
        let command = |seq| Command {
            seq,
            action: (seq % 3) as u32,
            ..Command::default()
        };
        for seq in 1..=700 {
            writer.put(command(seq));
        }
        let seen: Vec<u64> = reader.take_new().iter().map(|c| c.seq).collect();
        assert_eq!(seen, (1..=700).collect::<Vec<_>>());
        // More than a ring's worth: the oldest are gone, the newest RING are there.
        for seq in 701..=700 + RING as u64 + 10 {
            writer.put(command(seq));
        }
        // The entry after the last taken was overwritten: only a scan finds the rest.
        assert!(!reader.has_new());
        let seen = reader.take_new();
        assert_eq!(seen.len(), RING);
        assert_eq!(seen[0].seq, 711);
        assert!(!reader.has_new());
        assert!(reader.take_new().is_empty());
        // A new writer numbering from elsewhere (a respawned controller): found by a scan.
        writer.put(command(1_000_000));
        writer.put(command(1_000_001));
        assert!(!reader.has_new());
        let seen: Vec<u64> = reader.take_new().iter().map(|c| c.seq).collect();
        assert_eq!(seen, [1_000_000, 1_000_001]);
        writer.put(command(1_000_002));
        assert!(reader.has_new());
        assert_eq!(reader.take_new()[0].seq, 1_000_002);
    }
}
