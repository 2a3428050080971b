//! What the tests share: a stand-in group publishing on iceoryx2 as perception, the
//! controller and the bridge do, and the Python peers.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command as Process, Stdio};

use iceoryx2::prelude::*;
use tes_perception_sim::arena::{Arena, ArenaId};
use tes_runtime::channel::{self, Outbox};
use tes_runtime::ring::RingOutbox;
use tes_topics::{
    Command, MotorState, Observation, ServiceNames, StateAttributes, WorldMap, observation_flags,
};

/// A service prefix and a DDS domain of this test process's own, so parallel tests (and
/// other processes' tests) never meet.
pub fn own_prefix_and_domain(test: &str) -> (String, u16) {
    let pid = std::process::id();
    (format!("tes-ros2-it-{pid}-{test}/"), 1 + (pid % 200) as u16)
}

/// The Python the peers run on: the one `build.rs` probed.
pub fn python() -> &'static str {
    env!("TES_ROS2_PYTHON")
}

/// A Python peer from `tests/peers/`, killed when dropped.
pub struct Peer {
    child: Child,
    pub out: BufReader<ChildStdout>,
}

impl Peer {
    /// Runs `tests/peers/SCRIPT ARGS`. Cyclone DDS uses the interface it picks: RustDDS
    /// speaks only on interfaces with multicast (not loopback), so a peer held to loopback
    /// would never hear it; the test's own domain keeps other runs apart.
    pub fn start(script: &str, args: &[String]) -> Self {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/peers");
        let mut child = Process::new(python())
            .arg(dir.join(script))
            .args(args)
            .current_dir(&dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("the Python peer starts");
        let out = BufReader::new(child.stdout.take().expect("its output"));
        Self { child, out }
    }

    /// The next line it prints (empty at its end).
    pub fn line(&mut self) -> String {
        let mut line = String::new();
        self.out
            .read_line(&mut line)
            .expect("the peer's output reads");
        line.trim().to_owned()
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A stand-in for the group: publishes a world map, observations, commands and motor states
/// on the services of `prefix` as the processes do.
pub struct StandIn {
    maps: Outbox<WorldMap>,
    observations: Outbox<Observation>,
    motors: Outbox<MotorState>,
    commands: RingOutbox<Command>,
    seq: u64,
    pub episode: u32,
    step: u32,
    // Dropped last.
    _node: Node<ipc::Service>,
}

/// Actions per episode of the stand-in.
pub const STEPS: u32 = 4;

impl StandIn {
    /// Opens the group's services of `prefix`.
    pub fn open(prefix: &str) -> Self {
        let names = ServiceNames::with_prefix(prefix);
        let node = channel::node(false).expect("an iceoryx2 node");
        Self {
            maps: Outbox::open(&node, &names.world_map, &names.world_map_event, 1).expect("maps"),
            observations: Outbox::open(&node, &names.observation, &names.observation_event, 0)
                .expect("observations"),
            motors: Outbox::open(&node, &names.motor_state, &names.motor_state_event, 0)
                .expect("motor states"),
            commands: RingOutbox::open(&node, &names.command_log).expect("the command log"),
            seq: 0,
            episode: 0,
            step: 0,
            _node: node,
        }
    }

    /// Publishes Env 3's world map.
    pub fn world_map(&self) {
        let map = tes_perception_sim::process::world_map(&Arena::new(ArenaId::Env3))
            .expect("Env 3's map");
        self.maps.send(*map).expect("the map goes out");
    }

    /// One action: an observation, the command answering it, a motor report; every
    /// [`STEPS`] actions an episode ends.
    pub fn act(&mut self) {
        self.seq += 1;
        let now = tes_runtime::clock::monotonic_ns();
        let last = self.step + 1 == STEPS;
        let flags = match (self.step, last) {
            (0, _) => observation_flags::EPISODE_START,
            (_, true) => observation_flags::TRUNCATED,
            _ => 0,
        };
        let o = Observation {
            seq: self.seq,
            stamp_ns: now,
            episode: self.episode,
            step: self.step,
            state: StateAttributes {
                x: 2 + self.step as u16,
                y: 3,
                orientation: 0,
                reserved: 0,
            },
            reward: -0.05,
            flags,
            ..Observation::default()
        };
        self.observations.send(o).expect("an observation goes out");
        if last {
            self.episode += 1;
            self.step = 0;
            return;
        }
        self.step += 1;
        self.commands.put(Command {
            seq: self.seq,
            answers: self.seq,
            stamp_ns: now + 40_000,
            observed_ns: now,
            action: self.step % 3,
            ..Command::default()
        });
        let m = MotorState {
            seq: self.seq,
            stamp_ns: now + 50_000,
            tacho_count: [0, 90 * self.seq as i32, 90 * self.seq as i32],
            ..MotorState::default()
        };
        self.motors.send(m).expect("a motor state goes out");
    }
}
