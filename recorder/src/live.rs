//! The recorder: a thread of its own (in the launcher, never in the controller) reading the
//! group's services and writing what it finds to a [`RunWriter`], and drawing the run's scene
//! ([`tes_viewer::scene::Scene`]) into the same file and to a live Foxglove server
//! ([`Outputs`]); the processes' log lines reach it from the launcher ([`LogLines`]).
//!
//! It is woken by nothing, so no process of the group notifies it, and it never waits on the
//! loop: every half millisecond it reads one entry of the command log, and when a new
//! command is out (the robot is moving, the next decision is a motion away) it takes
//! everything queued; at least every 20 ms in any case. It writes and draws what it took in
//! the order of the samples' stamps, not stream by stream (`merge`): a sample
//! published while another stream is read would otherwise be drawn before older ones. What
//! each service guarantees decides how it is read:
//!
//! * observations, motor states and the world's poses are publish–subscribe: the recorder's
//!   subscribers (no listener) queue up to `tes_runtime::ipc::RECORDER_BUFFER` samples each;
//! * the controller's commands go to the bridge over a one-entry blackboard, which a passive
//!   reader could miss; the controller also stores each one, once it is out, in a ring of the
//!   last `tes_runtime::ring::RING` commands (`tes/command/log`, a lock-free store into shared
//!   memory that allocates nothing and notifies nobody), which the recorder reads;
//! * the world map is published with history, so it reaches the recorder whenever it joins.
//!
//! The thread runs under `SCHED_IDLE`: formatting and writing take only time the group's
//! processes do not want, and a waking process preempts it at once, so the recorder costs
//! the acting path no wake-up delay. On a machine whose cores are all busy at normal priority
//! such a thread gets almost no CPU, and a recorder that does not drain the services while
//! the group runs loses what they held: a subscriber's queued samples go with their publisher
//! when it exits (perception at the end of its episodes), so a run recorded under full load
//! came out with no observation and no world map. A watcher at normal priority
//! ([`tes_runtime::background::Watcher`], [`LAG_LIMIT`]: 100 ms) raises the recorder back to
//! normal scheduling, for the rest of the run, once it has not drained for that long; where
//! this process cannot undo `SCHED_IDLE` (no `CAP_SYS_NICE`), the recorder keeps normal
//! priority from the start. It lowers itself only once its services are open: the group
//! starts after that, and on a machine whose cores are busy a lowered recorder takes minutes
//! to open them. Nothing is formatted or
//! written on the controller's side. A sample the recorder could not
//! take in time (a machine that kept it from running for a whole buffer's worth of actions)
//! is counted from the gaps in the sequence numbers and written in the file's end record.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use tes_runtime::background::{Background, LAG_LIMIT, Watcher};
use tes_runtime::channel::{self, IpcError};
use tes_runtime::ipc::RECORDER_BUFFER;
use tes_runtime::ring::RingReader;
use tes_topics::{Command, MotorState, Observation, ServiceNames, WorldMap, WorldPose};
use tes_viewer::canvas::{Canvas, Drawing};
use tes_viewer::live::{LiveError, LiveServer};
use tes_viewer::scene::{Scene, SceneSettings};

use crate::merge::{Merge, Sample};
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
    /// The live Foxglove server cannot start.
    #[error(transparent)]
    Live(#[from] LiveError),
    /// The recorder thread could not start or died.
    #[error("the recorder thread {0}")]
    Thread(&'static str),
}

/// Where the recorder's thread puts what it reads of the group.
#[derive(Debug, Clone, Default)]
pub struct Outputs {
    /// The recording: its file and what it says of the run (`None`: no file).
    pub file: Option<(PathBuf, RunInfo)>,
    /// Serve the run live over Foxglove's WebSocket protocol on this address.
    pub foxglove: Option<SocketAddr>,
    /// How the run's scene is drawn (in the file beside the `tes.*` channels, and live).
    pub scene: SceneSettings,
}

/// Hands the processes' log lines to a recorder, for the scene's `/log`.
#[derive(Debug, Clone)]
pub struct LogLines(mpsc::Sender<LogLine>);

impl LogLines {
    /// Hands over a log line of the process `role`.
    pub fn send(&self, role: &'static str, text: &str) {
        let line = LogLine {
            role,
            text: text.to_owned(),
            stamp_ns: tes_runtime::clock::monotonic_ns(),
        };
        // A recorder that already stopped needs no more lines.
        let _ = self.0.send(line);
    }
}

/// A process's log line, for the scene's `/log`.
#[derive(Debug)]
struct LogLine {
    role: &'static str,
    text: String,
    stamp_ns: u64,
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

/// A running recorder (a file, a live Foxglove server, or both); [`stop`](Self::stop)
/// finishes the file.
#[derive(Debug)]
pub struct Recorder {
    stop: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<Result<RecordCounts, RecordError>>>,
    watcher: Option<Watcher>,
    path: Option<PathBuf>,
    foxglove: Option<SocketAddr>,
    lines: mpsc::Sender<LogLine>,
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
        let scene = SceneSettings {
            wall_offset_ns: info.wall_offset_ns,
            ..SceneSettings::default()
        };
        let outputs = Outputs {
            file: Some((path.to_owned(), info)),
            foxglove: None,
            scene,
        };
        Self::start_with(service_prefix, outputs)
    }

    /// Starts reading the group of `service_prefix` into `outputs`; returns once the
    /// recorder is subscribed to every service and the live server (if any) listens.
    pub fn start_with(service_prefix: &str, outputs: Outputs) -> Result<Self, RecordError> {
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready) = mpsc::channel::<Result<Option<SocketAddr>, RecordError>>();
        let (lines, line_rx) = mpsc::channel();
        let path = outputs.file.as_ref().map(|(p, _)| p.clone());
        let (prefix, flag) = (service_prefix.to_owned(), stop.clone());
        let background = Arc::new(Background::new());
        let lowered = background.clone();
        let handle = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || record(&prefix, outputs, &flag, &line_rx, ready_tx, &lowered))
            .map_err(|_| RecordError::Thread("could not start"))?;
        match ready.recv() {
            Ok(Ok(foxglove)) => {
                let mut recorder = Self {
                    stop,
                    handle: Some(handle),
                    watcher: None,
                    path,
                    foxglove,
                    lines,
                };
                // A recorder without its watcher is stopped (by the drop) and refused.
                let watcher = Watcher::start(background, LAG_LIMIT, "the recorder")
                    .map_err(|_| RecordError::Thread("could not start its watcher"))?;
                recorder.watcher = Some(watcher);
                Ok(recorder)
            }
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

    /// The file it writes, if any.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// The address the live Foxglove server listens on, if it serves.
    pub fn foxglove_addr(&self) -> Option<SocketAddr> {
        self.foxglove
    }

    /// Where the processes' log lines go for the scene's `/log`.
    pub fn log_lines(&self) -> LogLines {
        LogLines(self.lines.clone())
    }

    /// Takes what is still queued, finishes the file and returns what was written and missed.
    pub fn stop(mut self) -> Result<RecordCounts, RecordError> {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(watcher) = self.watcher.take() {
            watcher.stop();
        }
        match self.handle.take().map(|h| h.join()) {
            Some(Ok(result)) => result,
            _ => Err(RecordError::Thread("panicked")),
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(watcher) = self.watcher.take() {
            watcher.stop();
        }
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// The recorder's outputs as one canvas: the live server (never failing, never blocking) and
/// the file.
struct Fanout<'a> {
    file: Option<&'a mut RunWriter>,
    live: Option<&'a mut LiveServer>,
}

impl Canvas for Fanout<'_> {
    type Error = WriteError;
    fn draw(&mut self, d: Drawing<'_>) -> Result<(), WriteError> {
        if let Some(live) = self.live.as_deref_mut() {
            let Ok(()) = live.draw(d);
        }
        match self.file.as_deref_mut() {
            Some(file) => file.draw(d),
            None => Ok(()),
        }
    }
}

/// The group's services, subscribed.
struct Ports {
    _node: Node<ipc::Service>,
    maps: Sub<WorldMap>,
    observations: Sub<Observation>,
    motor_states: Sub<MotorState>,
    world_poses: Sub<WorldPose>,
    commands: RingReader<Command>,
}

fn open_ports(prefix: &str) -> Result<Ports, RecordError> {
    let names = ServiceNames::with_prefix(prefix);
    let node = channel::node(false)?;
    Ok(Ports {
        maps: subscriber::<WorldMap>(&node, &names.world_map, 1, 1)?,
        observations: subscriber::<Observation>(&node, &names.observation, 0, RECORDER_BUFFER)?,
        motor_states: subscriber::<MotorState>(&node, &names.motor_state, 0, RECORDER_BUFFER)?,
        world_poses: subscriber::<WorldPose>(&node, &names.world_pose, 0, RECORDER_BUFFER)?,
        commands: RingReader::<Command>::open(&node, &names.command_log)?,
        _node: node,
    })
}

/// The recorder's state between two drains.
struct Tap {
    file: Option<RunWriter>,
    live: Option<LiveServer>,
    scene: Scene,
    seen: [Gaps; 3],
    have_map: bool,
    /// The samples taken, handed on in the order of their stamps.
    merge: Merge,
}

impl Tap {
    fn canvas(&mut self) -> (&mut Scene, Fanout<'_>) {
        (
            &mut self.scene,
            Fanout {
                file: self.file.as_mut(),
                live: self.live.as_mut(),
            },
        )
    }

    /// Takes everything queued and hands on, in the order of their stamps, every sample no
    /// stream can still bring an older one than ([`Merge`]); then the log lines.
    fn drain(
        &mut self,
        ports: &mut Ports,
        lines: &mpsc::Receiver<LogLine>,
        stopping: bool,
    ) -> Result<(), RecordError> {
        // Before any stream is read: a sample stamped well before this is queued by now.
        let read_ns = tes_runtime::clock::monotonic_ns();
        self.take(ports, stopping)?;
        // What is drawn once is drawn no later than the oldest sample still to draw, so
        // every channel stays in time order.
        let drawn_ns = self.merge.oldest_ns().map_or(read_ns, |o| o.min(read_ns));
        if !self.have_map {
            drain(&ports.maps, |m| self.world_map(&m, drawn_ns))?;
        }
        if self.live.as_ref().is_some_and(LiveServer::take_joined) {
            let (scene, mut canvas) = self.canvas();
            scene.redraw(drawn_ns, &mut canvas)?;
        }
        while let Some(sample) = self.merge.next_ready(read_ns, stopping) {
            self.sample(sample)?;
        }
        while let Ok(line) = lines.try_recv() {
            let (scene, mut canvas) = self.canvas();
            scene.log_line(line.role, &line.text, line.stamp_ns, &mut canvas)?;
        }
        Ok(())
    }

    /// Reads every stream into the merge: what each queued since the last drain and the
    /// commands logged since (at the stop, the whole command log scanned once more).
    fn take(&mut self, ports: &mut Ports, stopping: bool) -> Result<(), RecordError> {
        let merge = &mut self.merge;
        drain(&ports.observations, |o| {
            merge.push(Sample::Observation(o));
            Ok(())
        })?;
        let commands = if stopping {
            ports.commands.take_new_scanning()
        } else {
            ports.commands.take_new()
        };
        for c in commands {
            merge.push(Sample::Command(*c));
        }
        drain(&ports.world_poses, |w| {
            merge.push(Sample::WorldPose(w));
            Ok(())
        })?;
        drain(&ports.motor_states, |m| {
            merge.push(Sample::MotorState(m));
            Ok(())
        })
    }

    /// Writes and draws one sample.
    fn sample(&mut self, sample: Sample) -> Result<(), RecordError> {
        match sample {
            Sample::Observation(o) => self.observation(&o),
            Sample::Command(c) => self.command(&c),
            Sample::MotorState(m) => self.motor_state(&m),
            Sample::WorldPose(w) => {
                let (scene, mut canvas) = self.canvas();
                Ok(scene.world_pose(&w, &mut canvas)?)
            }
        }
    }

    fn motor_state(&mut self, m: &MotorState) -> Result<(), RecordError> {
        self.seen[2].see(m.seq);
        if let Some(file) = &mut self.file {
            file.motor_state(m)?;
        }
        let (scene, mut canvas) = self.canvas();
        Ok(scene.motor_state(m, &mut canvas)?)
    }

    fn observation(&mut self, o: &Observation) -> Result<(), RecordError> {
        self.seen[0].see(o.seq);
        if let Some(file) = &mut self.file {
            file.observation(o)?;
        }
        let (scene, mut canvas) = self.canvas();
        Ok(scene.observation(o, &mut canvas)?)
    }

    fn command(&mut self, c: &Command) -> Result<(), RecordError> {
        self.seen[1].see(c.seq);
        if let Some(file) = &mut self.file {
            file.command(c)?;
        }
        let (scene, mut canvas) = self.canvas();
        Ok(scene.command(c, &mut canvas)?)
    }

    fn world_map(&mut self, map: &WorldMap, now: u64) -> Result<(), RecordError> {
        if self.have_map {
            return Ok(());
        }
        self.have_map = true;
        if let Some(file) = &mut self.file {
            file.world_map(map, now)?;
        }
        let (scene, mut canvas) = self.canvas();
        Ok(scene.world_map(map, now, &mut canvas)?)
    }
}

/// The recorder thread.
fn record(
    prefix: &str,
    outputs: Outputs,
    stop: &AtomicBool,
    lines: &mpsc::Receiver<LogLine>,
    ready: mpsc::Sender<Result<Option<SocketAddr>, RecordError>>,
    background: &Background,
) -> Result<RecordCounts, RecordError> {
    if let Err(e) = tes_runtime::affinity::pin_off_the_acting_cpu() {
        tracing::debug!("the recorder stays unpinned: {e}");
    }
    let scene = Scene::new(outputs.scene);
    let opened = (|| -> Result<_, RecordError> {
        let ports = open_ports(prefix)?;
        let file = match &outputs.file {
            Some((path, info)) => Some(RunWriter::create(path, info)?),
            None => None,
        };
        let live = match outputs.foxglove {
            Some(addr) => Some(LiveServer::start(addr, scene.channels())?),
            None => None,
        };
        Ok((ports, file, live))
    })();
    let (mut ports, file, live) = match opened {
        Ok(opened) => opened,
        Err(e) => {
            let _ = ready.send(Err(e));
            return Err(RecordError::Thread("could not start"));
        }
    };
    let _ = ready.send(Ok(live.as_ref().map(LiveServer::addr)));
    // Lowered only now: opening the services is not on the acting path (the group starts
    // once the recorder is ready), and under SCHED_IDLE on a busy machine it takes minutes.
    // Recording works at any priority, at some cost to the group's latency; a lowering the
    // watcher could not undo would lose the run on a busy machine.
    background.lower_if_restorable();
    let mut tap = Tap {
        file,
        live,
        scene,
        seen: [Gaps::default(); 3],
        have_map: false,
        merge: Merge::with_capacity(RECORDER_BUFFER),
    };
    let (mut last_flush, mut last_drain) = (Instant::now(), Instant::now());
    loop {
        // Read after the stop too: what the group sent last is still queued.
        let stopping = stop.load(Ordering::SeqCst);
        // The work waits for a command: then the observation has been answered and the robot
        // moves, so the formatting and writing fall between decisions, not across one.
        if !(stopping || ports.commands.has_new() || last_drain.elapsed() >= DRAIN_AT_LEAST) {
            std::thread::sleep(LOOK_EVERY);
            continue;
        }
        last_drain = Instant::now();
        tap.drain(&mut ports, lines, stopping)?;
        background.beat();
        if stopping {
            let (scene, mut canvas) = tap.canvas();
            scene.finish(&mut canvas)?;
            break;
        }
        if last_flush.elapsed() >= FLUSH_EVERY
            && let Some(file) = &mut tap.file
        {
            file.flush()?;
            last_flush = Instant::now();
        }
    }
    if let Some(live) = tap.live.take() {
        live.stop();
    }
    let missed = RecordCounts {
        missed_observations: tap.seen[0].missed,
        missed_commands: tap.seen[1].missed,
        missed_motor_states: tap.seen[2].missed,
        ..RecordCounts::default()
    };
    match tap.file {
        Some(file) => Ok(file.finish(missed)?),
        None => Ok(missed),
    }
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
