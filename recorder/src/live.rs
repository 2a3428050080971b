//! The recorder: a thread of its own (in the launcher, never in the controller) reading the
//! group's services and writing what it finds to a [`RunWriter`].
//!
//! It is woken by nothing, so no process of the group notifies it, and it never waits on the
//! loop: every half millisecond it reads one entry of the command log, and when a new
//! command is out (the robot is moving, the next decision is a motion away) it takes
//! everything queued and writes it; at least every 20 ms in any case. What each service guarantees decides how it
//! is read:
//!
//! * observations and motor states are publish–subscribe: the recorder's subscribers (no
//!   listener) queue up to `tes_runtime::ipc::RECORDER_BUFFER` samples each;
//! * the controller's commands go to the bridge over a one-entry blackboard, which a passive
//!   reader could miss; the controller also stores each one, once it is out, in a ring of the
//!   last `tes_runtime::ring::RING` commands (`tes/command/log`, a lock-free store into shared
//!   memory that allocates nothing and notifies nobody), which the recorder reads;
//! * the world map is published with history, so it reaches the recorder whenever it joins.
//!
//! The thread runs under `SCHED_IDLE` (else nice +19): formatting and writing take only time
//! the group's processes do not want, and a waking process preempts it at once, so the
//! recorder costs the acting path no wake-up delay. Nothing is formatted or written on the
//! controller's side. A sample the recorder could not
//! take in time (a machine that kept it from running for a whole buffer's worth of actions)
//! is counted from the gaps in the sequence numbers and written in the file's end record.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use tes_runtime::channel::{self, IpcError};
use tes_runtime::ipc::RECORDER_BUFFER;
use tes_runtime::ring::RingReader;
use tes_topics::{Command, MotorState, Observation, ServiceNames, WorldMap};

use crate::writer::{RecordCounts, RunInfo, RunWriter, WriteError};

/// Why the recorder stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The file could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// An iceoryx2 failure.
    #[error("recorder: {0}")]
    Ipc(#[from] IpcError),
    /// The recorder thread could not start or died.
    #[error("the recorder thread {0}")]
    Thread(&'static str),
}

/// How often the file is flushed (the open chunk closed and written out).
const FLUSH_EVERY: Duration = Duration::from_millis(500);

/// How often the recorder looks whether a new command is out: one entry of the command log
/// read, nothing else.
const LOOK_EVERY: Duration = Duration::from_micros(500);

/// The longest the recorder leaves the services undrained while no command comes (between
/// runs, or a controller that stopped deciding): well within what their buffers hold at the
/// fastest real-time factor (`RECORDER_BUFFER` samples; about 17 motor states per action).
const DRAIN_AT_LEAST: Duration = Duration::from_millis(20);

/// A running recorder; [`stop`](Self::stop) finishes the file.
#[derive(Debug)]
pub struct Recorder {
    stop: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<Result<RecordCounts, RecordError>>>,
    path: PathBuf,
}

/// Counts gaps in a sequence of numbers.
#[derive(Debug, Default, Clone, Copy)]
struct Gaps {
    last: Option<u64>,
    missed: u64,
}

impl Gaps {
    /// A jump this large is a respawned publisher starting from the clock, not a loss.
    const RESTART: u64 = 1_000_000;

    fn see(&mut self, seq: u64) {
        if let Some(last) = self.last
            && seq > last + 1
            && seq - last < Self::RESTART
        {
            self.missed += seq - last - 1;
        }
        self.last = Some(seq);
    }
}

type Sub<T> = iceoryx2::port::subscriber::Subscriber<ipc::Service, T, ()>;

fn subscriber<T: ZeroCopySend + Copy + std::fmt::Debug + 'static>(
    node: &Node<ipc::Service>,
    name: &str,
    history: usize,
    buffer: usize,
) -> Result<Sub<T>, IpcError> {
    let service = channel::pubsub::<T, _>(node, name, history)?;
    let subscriber = service
        .subscriber_builder()
        .buffer_size(buffer)
        .create()
        .map_err(channel::ipc_err("create a subscriber"))?;
    subscriber
        .update_connections()
        .map_err(channel::ipc_err("connect a subscriber"))?;
    Ok(subscriber)
}

fn drain<T: ZeroCopySend + Copy + std::fmt::Debug + 'static>(
    subscriber: &Sub<T>,
    mut each: impl FnMut(T) -> Result<(), RecordError>,
) -> Result<(), RecordError> {
    while let Some(sample) = subscriber
        .receive()
        .map_err(channel::ipc_err("receive a sample"))?
    {
        each(*sample)?;
    }
    Ok(())
}

impl Recorder {
    /// Creates the recording at `path` and starts recording the group of `service_prefix`;
    /// returns once the recorder is subscribed to every service (start the group after).
    pub fn start(path: &Path, service_prefix: &str, info: RunInfo) -> Result<Self, RecordError> {
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready) = std::sync::mpsc::channel::<Result<(), RecordError>>();
        let (file, prefix, flag) = (path.to_owned(), service_prefix.to_owned(), stop.clone());
        let handle = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || record(&file, &prefix, &info, &flag, ready_tx))
            .map_err(|_| RecordError::Thread("could not start"))?;
        match ready.recv() {
            Ok(Ok(())) => Ok(Self {
                stop,
                handle: Some(handle),
                path: path.to_owned(),
            }),
            Ok(Err(e)) => {
                let _ = handle.join();
                Err(e)
            }
            Err(_) => match handle.join() {
                Ok(Err(e)) => Err(e),
                _ => Err(RecordError::Thread("died while starting")),
            },
        }
    }

    /// The file it writes.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Takes what is still queued, finishes the file and returns what was written and missed.
    pub fn stop(mut self) -> Result<RecordCounts, RecordError> {
        self.stop.store(true, Ordering::SeqCst);
        match self.handle.take().map(|h| h.join()) {
            Some(Ok(result)) => result,
            _ => Err(RecordError::Thread("panicked")),
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// The recorder thread.
fn record(
    path: &Path,
    prefix: &str,
    info: &RunInfo,
    stop: &AtomicBool,
    ready: std::sync::mpsc::Sender<Result<(), RecordError>>,
) -> Result<RecordCounts, RecordError> {
    // Best effort: recording works at any priority, at some cost to the group's latency.
    if !tes_runtime::affinity::lower_this_threads_priority() {
        tracing::warn!("the recorder runs at nice +19 or normal priority, not SCHED_IDLE");
    }
    // Off the CPU the controller's acting thread is pinned to by default, so the recorder's
    // wake-ups and writes never sit between that thread and its next observation.
    if let Some((_, helper_cpu)) = tes_runtime::affinity::auto_pair()
        && let Err(e) = tes_runtime::affinity::pin_this_thread(helper_cpu)
    {
        tracing::debug!("the recorder thread stays unpinned: {e}");
    }
    let opened = (|| -> Result<_, RecordError> {
        let names = ServiceNames::with_prefix(prefix);
        let node = channel::node(false)?;
        let maps = subscriber::<WorldMap>(&node, &names.world_map, 1, 1)?;
        let observations =
            subscriber::<Observation>(&node, &names.observation, 0, RECORDER_BUFFER)?;
        let motor_states = subscriber::<MotorState>(&node, &names.motor_state, 0, RECORDER_BUFFER)?;
        let commands = RingReader::<Command>::open(&node, &names.command_log)?;
        let writer = RunWriter::create(path, info)?;
        Ok((node, maps, observations, motor_states, commands, writer))
    })();
    let (_node, maps, observations, motor_states, mut commands, mut writer) = match opened {
        Ok(ports) => {
            let _ = ready.send(Ok(()));
            ports
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return Err(RecordError::Thread("could not start"));
        }
    };
    let (mut seen_obs, mut seen_cmd, mut seen_motor) =
        (Gaps::default(), Gaps::default(), Gaps::default());
    let mut have_map = false;
    let (mut last_flush, mut last_drain) = (Instant::now(), Instant::now());
    loop {
        // Read after the stop too: what the group sent last is still queued.
        let stopping = stop.load(Ordering::SeqCst);
        // The work waits for a command: then the observation has been answered and the robot
        // moves, so the formatting and writing fall between decisions, not across one.
        if !(stopping || commands.has_new() || last_drain.elapsed() >= DRAIN_AT_LEAST) {
            std::thread::sleep(LOOK_EVERY);
            continue;
        }
        last_drain = Instant::now();
        if !have_map {
            drain(&maps, |m| {
                if !have_map {
                    have_map = true;
                    writer.world_map(&m, tes_runtime::clock::monotonic_ns())?;
                }
                Ok(())
            })?;
        }
        // In the order of the loop: observations, the commands answering them, the motion.
        drain(&observations, |o| {
            seen_obs.see(o.seq);
            Ok(writer.observation(&o)?)
        })?;
        let new_commands = if stopping {
            commands.take_new_scanning()
        } else {
            commands.take_new()
        };
        for c in new_commands {
            seen_cmd.see(c.seq);
            writer.command(c)?;
        }
        drain(&motor_states, |m| {
            seen_motor.see(m.seq);
            Ok(writer.motor_state(&m)?)
        })?;
        if stopping {
            break;
        }
        if last_flush.elapsed() >= FLUSH_EVERY {
            writer.flush()?;
            last_flush = Instant::now();
        }
    }
    let missed = RecordCounts {
        missed_observations: seen_obs.missed,
        missed_commands: seen_cmd.missed,
        missed_motor_states: seen_motor.missed,
        ..RecordCounts::default()
    };
    Ok(writer.finish(missed)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_count_losses_not_restarts() {
        let mut g = Gaps::default();
        for s in [1, 2, 5, 6, 7_000_000, 7_000_001] {
            g.see(s);
        }
        assert_eq!(g.missed, 2);
    }
}
