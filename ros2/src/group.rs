//! The group on ROS 2: a thread of its own (the launcher's, never the controller's) that
//! reads the group's iceoryx2 services as the recorder does and hands what it reads, as ROS 2
//! messages ([`RosScene`]), to a ROS 2 node ([`RosNode`]), a rosbag2 bag ([`BagWriter`]), or
//! both.
//!
//! The thread runs off the acting thread's CPU, and so do the DDS threads RustDDS starts from
//! it (a thread inherits its creator's placement and scheduling). Those DDS threads run at
//! nice +19 under the normal policy, not `SCHED_IDLE`: a caution — DDS discovery already
//! takes seconds (docs/ros2.md), though a run with them at `SCHED_IDLE` matched its peer as
//! soon. The thread itself then reads the group at `SCHED_IDLE`: publishing takes only time
//! the group does not want; a watcher at normal priority ([`tes_runtime::background::Watcher`])
//! raises it back, for the rest of the run, once it has not drained for
//! [`tes_runtime::background::LAG_LIMIT`] (a busy machine), as it does the recorder. No process of the group notifies it or waits for it: it looks
//! every half millisecond whether a new command is out (one entry of the command log read)
//! and then takes everything queued, at least every 20 ms. The node gets the robot's motion
//! (`/tf`, `/tes/path`) at a screen's pace (`tes_viewer::live::MotionPace`, 30 a second per
//! topic), the rest whole; the bag gets everything.

use std::path::PathBuf;
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
use tes_topics::{Command, MotorState, Observation, ServiceNames, WorldMap};
use tes_viewer::live::MotionPace;

use crate::bag::{BagError, BagSummary, BagWriter};
use crate::dds::{DdsError, DiscoveryRange, Reach, RosNode};
use crate::scene::{Delivery, RosMessage, RosScene, SceneSettings, Sink};

/// How often the thread looks whether a new command is out.
const LOOK_EVERY: Duration = Duration::from_micros(500);
/// The longest it leaves the services undrained (well within their buffers).
const DRAIN_AT_LEAST: Duration = Duration::from_millis(20);

/// Why the group's ROS 2 side stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum GroupError {
    /// An iceoryx2 failure.
    #[error("ROS 2 publisher: {0}")]
    Ipc(#[from] IpcError),
    /// The ROS 2 node cannot start.
    #[error(transparent)]
    Dds(#[from] DdsError),
    /// The bag cannot be written.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// The thread could not start or died.
    #[error("the ROS 2 thread {0}")]
    Thread(&'static str),
}

/// What the group's ROS 2 side does.
#[derive(Debug, Clone, Default)]
pub struct Outputs {
    /// Publish on ROS 2 in this domain (`None`: no node, no socket).
    pub domain: Option<u16>,
    /// How far ROS 2's environment lets the node reach (checked before it starts).
    pub range: DiscoveryRange,
    /// Write a rosbag2 bag to this new directory.
    pub bag: Option<PathBuf>,
    /// Times and wheels.
    pub scene: SceneSettings,
}

/// What the ROS 2 side did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Published {
    /// Messages handed to the DDS node.
    pub published: u64,
    /// Messages the node could not hand over (a reliable reader that kept it waiting).
    pub not_published: u64,
    /// The bag, when one was written.
    pub bag: Option<BagSummary>,
}

/// Hands the processes' log lines to the ROS 2 side, for `/rosout`.
#[derive(Debug, Clone)]
pub struct LogLines(mpsc::Sender<(&'static str, String, u64)>);

impl LogLines {
    /// Hands over a log line of the process `role`.
    pub fn send(&self, role: &'static str, text: &str) {
        // A side that already stopped needs no more lines.
        let _ = self
            .0
            .send((role, text.to_owned(), tes_runtime::clock::monotonic_ns()));
    }
}

/// The group's ROS 2 side, running; [`stop`](Self::stop) finishes it.
#[derive(Debug)]
pub struct GroupOnRos2 {
    stop: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<Result<Published, GroupError>>>,
    watcher: Option<Watcher>,
    reach: Option<Reach>,
    lines: mpsc::Sender<(&'static str, String, u64)>,
}

impl GroupOnRos2 {
    /// Starts reading the group of `service_prefix` into `outputs`; returns once it is
    /// subscribed to every service and its node (if any) is up (start the group after).
    pub fn start(service_prefix: &str, outputs: Outputs) -> Result<Self, GroupError> {
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready) = mpsc::channel::<Result<Option<Reach>, GroupError>>();
        let (lines, line_rx) = mpsc::channel();
        let (prefix, flag) = (service_prefix.to_owned(), stop.clone());
        let background = Arc::new(Background::new());
        let lowered = background.clone();
        let handle = std::thread::Builder::new()
            .name("ros2".into())
            .spawn(move || run(&prefix, outputs, &flag, &line_rx, ready_tx, &lowered))
            .map_err(|_| GroupError::Thread("could not start"))?;
        match ready.recv() {
            Ok(Ok(reach)) => {
                let mut group = Self {
                    stop,
                    handle: Some(handle),
                    watcher: None,
                    reach,
                    lines,
                };
                // Without its watcher the side is stopped (by the drop) and refused.
                group.watcher = Some(
                    Watcher::start(background, LAG_LIMIT, "the ROS 2 side")
                        .map_err(|_| GroupError::Thread("could not start its watcher"))?,
                );
                Ok(group)
            }
            Ok(Err(e)) => {
                let _ = handle.join();
                Err(e)
            }
            Err(_) => match handle.join() {
                Ok(Err(e)) => Err(e),
                _ => Err(GroupError::Thread("died while starting")),
            },
        }
    }

    /// Where the node is reachable, when there is one.
    pub fn reach(&self) -> Option<&Reach> {
        self.reach.as_ref()
    }

    /// Where the processes' log lines go for `/rosout`.
    pub fn log_lines(&self) -> LogLines {
        LogLines(self.lines.clone())
    }

    /// Takes what is still queued, finishes the bag and stops the node.
    pub fn stop(mut self) -> Result<Published, GroupError> {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(watcher) = self.watcher.take() {
            watcher.stop();
        }
        match self.handle.take().map(std::thread::JoinHandle::join) {
            Some(Ok(result)) => result,
            _ => Err(GroupError::Thread("panicked")),
        }
    }
}

impl Drop for GroupOnRos2 {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
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
    mut each: impl FnMut(T) -> Result<(), GroupError>,
) -> Result<(), GroupError> {
    while let Some(sample) = subscriber
        .receive()
        .map_err(channel::ipc_err("receive a sample"))?
    {
        each(*sample)?;
    }
    Ok(())
}

/// The group's services, subscribed.
struct Ports {
    _node: Node<ipc::Service>,
    maps: Sub<WorldMap>,
    observations: Sub<Observation>,
    motor_states: Sub<MotorState>,
    commands: RingReader<Command>,
}

fn open_ports(prefix: &str) -> Result<Ports, GroupError> {
    let names = ServiceNames::with_prefix(prefix);
    let node = channel::node(false)?;
    Ok(Ports {
        maps: subscriber::<WorldMap>(&node, &names.world_map, 1, 1)?,
        observations: subscriber::<Observation>(&node, &names.observation, 0, RECORDER_BUFFER)?,
        motor_states: subscriber::<MotorState>(&node, &names.motor_state, 0, RECORDER_BUFFER)?,
        commands: RingReader::<Command>::open(&node, &names.command_log)?,
        _node: node,
    })
}

/// The node (at a screen's pace for motion) and the bag, as one sink.
struct Outlets {
    node: Option<RosNode>,
    pace: MotionPace,
    bag: Option<BagWriter>,
    published: Published,
}

impl Sink for Outlets {
    type Error = BagError;
    fn put(&mut self, m: &RosMessage, wall_ns: u64, d: Delivery) -> Result<(), BagError> {
        if let Some(node) = &mut self.node
            && (d == Delivery::Always || self.pace.admits(m.topic().name(), wall_ns))
        {
            match node.put(m, wall_ns, d) {
                Ok(()) => self.published.published += 1,
                Err(_) => self.published.not_published += 1,
            }
        }
        match &mut self.bag {
            Some(bag) => bag.put(m, wall_ns, d),
            None => Ok(()),
        }
    }
}

/// The side's state between two drains.
struct Tap {
    scene: RosScene,
    outlets: Outlets,
    have_map: bool,
}

impl Tap {
    /// Takes everything queued, in the loop's order: observations, the commands answering
    /// them, the motion; then the log lines.
    fn drain(
        &mut self,
        ports: &mut Ports,
        lines: &mpsc::Receiver<(&'static str, String, u64)>,
        stopping: bool,
    ) -> Result<(), GroupError> {
        if !self.have_map {
            drain(&ports.maps, |m| {
                self.have_map = true;
                let now = tes_runtime::clock::monotonic_ns();
                Ok(self.scene.world_map(&m, now, &mut self.outlets)?)
            })?;
        }
        drain(&ports.observations, |o| {
            Ok(self.scene.observation(&o, &mut self.outlets)?)
        })?;
        let commands = if stopping {
            ports.commands.take_new_scanning()
        } else {
            ports.commands.take_new()
        };
        for c in commands {
            self.scene.command(c, &mut self.outlets)?;
        }
        drain(&ports.motor_states, |m| {
            Ok(self.scene.motor_state(&m, &mut self.outlets)?)
        })?;
        while let Ok((role, text, stamp_ns)) = lines.try_recv() {
            self.scene
                .log_line(role, &text, stamp_ns, &mut self.outlets)?;
        }
        Ok(())
    }
}

/// Opens the ports, the node and the bag (in this thread, so RustDDS's threads inherit its
/// placement and nice value).
fn open(prefix: &str, outputs: &Outputs) -> Result<(Ports, Outlets), GroupError> {
    let ports = open_ports(prefix)?;
    let node = match outputs.domain {
        Some(domain) => Some(RosNode::start(domain, &outputs.range, "group")?),
        None => None,
    };
    let bag = match &outputs.bag {
        Some(dir) => Some(BagWriter::create(dir)?),
        None => None,
    };
    let outlets = Outlets {
        node,
        pace: MotionPace::default(),
        bag,
        published: Published::default(),
    };
    Ok((ports, outlets))
}

/// Pins the calling thread off the acting thread's CPU and sets its nice value to +19 (under
/// the normal policy), for the threads it starts to inherit. Best effort, as
/// `make_this_a_background_thread`: a refusal is logged and the thread runs anyway.
fn keep_off_the_acting_cpu_at_nice_19() {
    if let Err(e) = tes_runtime::affinity::pin_off_the_acting_cpu() {
        tracing::debug!("the ROS 2 side stays unpinned: {e}");
    }
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain syscalls on the calling thread's own id; no memory is shared.
        let nice = unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, 19)
        };
        if nice != 0 {
            tracing::debug!(
                error = %std::io::Error::last_os_error(),
                "the ROS 2 side could not lower its nice value"
            );
        }
    }
}

/// The thread.
fn run(
    prefix: &str,
    outputs: Outputs,
    stop: &AtomicBool,
    lines: &mpsc::Receiver<(&'static str, String, u64)>,
    ready: mpsc::Sender<Result<Option<Reach>, GroupError>>,
    background: &Background,
) -> Result<Published, GroupError> {
    keep_off_the_acting_cpu_at_nice_19();
    let opened = open(prefix, &outputs);
    let (mut ports, outlets) = match opened {
        Ok(opened) => opened,
        Err(e) => {
            let _ = ready.send(Err(e));
            return Err(GroupError::Thread("could not start"));
        }
    };
    let _ = ready.send(Ok(outlets.node.as_ref().map(|n| n.reach().clone())));
    // Lowered once its services and node are open (the group starts after that), and only
    // where the watcher can raise it back: a side left starved would lose what it reads.
    background.lower_if_restorable();
    let mut tap = Tap {
        scene: RosScene::new(outputs.scene),
        outlets,
        have_map: false,
    };
    let mut last_drain = Instant::now();
    loop {
        // Read after the stop too: what the group sent last is still queued.
        let stopping = stop.load(Ordering::SeqCst);
        if !(stopping || ports.commands.has_new() || last_drain.elapsed() >= DRAIN_AT_LEAST) {
            std::thread::sleep(LOOK_EVERY);
            continue;
        }
        last_drain = Instant::now();
        tap.drain(&mut ports, lines, stopping)?;
        background.beat();
        if stopping {
            break;
        }
    }
    let mut published = std::mem::take(&mut tap.outlets.published);
    if let Some(bag) = tap.outlets.bag.take() {
        published.bag = Some(bag.finish()?);
    }
    Ok(published)
}
