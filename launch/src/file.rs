//! The launch file: read once into each process's typed settings, checked, and written to the
//! run directory for the children.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tes_bridge::config::{BridgeSettings, TransportKind};

use crate::world::WorldSettings;
use tes_controller::config::{ControllerConfig, default_data_dir};
use tes_perception_sim::process::PerceptionConfig;
use tes_runtime::channel::WaitStrategy;
use tes_runtime::lock::{Lock, LockError};
use tes_runtime::settings::{self, Origin, SettingError};
use tes_topics::Role;

use crate::children::ChildSpec;
use crate::run_folder;

/// What to do when a child dies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Restart {
    /// Stop the others and exit non-zero.
    #[default]
    Never,
    /// Respawn it (up to `max_restarts` times).
    OnFailure,
}

impl std::fmt::Display for Restart {
    /// As the launch file spells it: `never`, `on-failure`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Restart::Never => "never",
            Restart::OnFailure => "on-failure",
        })
    }
}

/// The `[launch]` table. Each field's doc is its key's entry in the launch file's reference
/// ([`super::reference`], generated from these docs by build.rs): what it does, then its unit
/// or values on a `Values:` line; the defaults are this struct's `Default`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LaunchSection {
    /// Episodes perception runs before the group stops (`--episodes` overrides it).
    ///
    /// Values: count, at least 1.
    pub episodes: u32,
    /// The arena perception simulates; 3 is the paper's test arena.
    ///
    /// Values: `1` | `2` | `3`.
    pub arena: u8,
    /// The pace: 1.0 = physical time (the paper's 200 ms settle after each motion), 0 = as
    /// fast as possible. It sets perception's settle time and the simulated brick's time
    /// scale (1 / factor; [`FASTEST_TIME_SCALE`] at 0).
    ///
    /// Values: factor, finite, at least 0.
    pub real_time_factor: f64,
    /// How every process waits for its next input: `auto` anticipates where the input is
    /// announced and blocks where it is not — at a real-time factor above 0 (with a settle
    /// time) the controller and the bridge `anticipate` (perception announces each
    /// observation as the robot starts to settle) and perception blocks; at the fastest pace,
    /// where nothing is announced, every process blocks; the launch says at start what it
    /// chose. `block` sleeps until notified (no CPU while idle); `spin` busy-polls (lowest
    /// latency, a core per process); `spin-then-block` busy-polls for 200 µs (or the µs
    /// given), then sleeps; `anticipate` sleeps until shortly before the next message is due
    /// (announced, or learned from the gaps between messages), polls for at most 2 ms then,
    /// and blocks if it is late. What each costs, decision p50 / p99 and the controller's
    /// share of a core, by machine and pace: docs/performance.md.
    ///
    /// Values: `auto` | `block` | `spin` | `spin-then-block` | `spin-then-block:<µs>` |
    /// `anticipate`.
    pub wait: WaitStrategy,
    /// What to do when a child dies: `never` stops the others and exits non-zero;
    /// `on-failure` respawns it, at most `max_restarts` times.
    ///
    /// Values: `never` | `on-failure`.
    pub restart: Restart,
    /// Respawns allowed per child with `restart = "on-failure"`.
    ///
    /// Values: count.
    pub max_restarts: u32,
    /// Grace period of each shutdown step: SIGINT, then SIGTERM after this long, then
    /// SIGKILL after as long again.
    ///
    /// Values: ms.
    pub grace_ms: u64,
    /// Prefix of every iceoryx2 service name. Empty: each launch gets one of its own,
    /// `tes-PID-XXXXXXXX/`, so any number of launches run side by side; a prefix already
    /// used by a running group is refused.
    ///
    /// Values: text, at most [`SERVICE_PREFIX_MAX`](tes_runtime::settings::SERVICE_PREFIX_MAX)
    /// bytes.
    pub service_prefix: String,
    /// This launch's run folder, used as it is: no folder of its own per launch, never
    /// pruned (it holds the lock that keeps a second launch out). Unset: each launch gets a
    /// run folder of its own in `runs_dir`.
    ///
    /// Values: path.
    ///
    /// Example: `"/path/to/run"`.
    pub run_dir: Option<PathBuf>,
    /// Where each launch makes its run folder, named by its UTC start time
    /// (`2026-12-02T19-05-33Z`): the resolved launch file, the children's settings, output
    /// and logs, `episodes.csv`, `trajectory.csv`, the latency reports and, at the end,
    /// `rewards.svg`, `latency.svg` and `arena.svg`; `latest` links to the newest. Unset:
    /// `runs` in the data directory (`$TES_DATA_DIR`, else `$XDG_DATA_HOME/tes`, else
    /// `~/.local/share/tes`).
    ///
    /// Values: path.
    ///
    /// Example: `"/path/to/runs"`.
    pub runs_dir: Option<PathBuf>,
    /// How many run folders `runs_dir` keeps: when a launch starts, the oldest beyond this
    /// are removed.
    ///
    /// Values: count; 0 = keep every one.
    pub keep_runs: u32,
    /// Seed of the world, the agent and the simulated brick.
    ///
    /// Values: integer, 0 to 2^63 - 1.
    pub seed: u64,
    /// A group whose controller sends no command for this long is stalled: the launcher
    /// names the process holding it up and stops the group (`restart = "never"`) or
    /// restarts that process (`on-failure`).
    ///
    /// Values: ms of wall time, at least [`MIN_STALL_TIMEOUT_MS`].
    pub stall_timeout_ms: u64,
    /// Record the run to this file (`tes launch --record` overrides it): the world map and
    /// every observation, command, keep-alive and motor state, with the run's settings, seed
    /// and starting library; `tes replay` reads it (docs/recording.md). A relative path is
    /// taken from the directory `tes launch` runs in. Unset: no recording.
    ///
    /// Values: path of an MCAP file.
    ///
    /// Example: `"run.mcap"`.
    pub record: Option<PathBuf>,
    /// Serve the run live over Foxglove's WebSocket protocol on this address (`tes launch
    /// --foxglove` sets it): the arena, the robot moving on it, its decisions, episode rewards
    /// and the processes' logs, the same channels a recording holds (docs/recording.md).
    /// Loopback unless another address is given, which is then said at start. Unset: not
    /// served.
    ///
    /// Values: HOST:PORT; port 0 picks a free one.
    ///
    /// Example: `"127.0.0.1:8765"`.
    pub foxglove: Option<String>,
    /// Publish the run on ROS 2 (`tes launch --ros2` sets it): the robot's pose on `/tf`, the
    /// arena as markers, the episode's path, each decision, latency, reward and episode's end,
    /// and the processes' logs on `/rosout`, in the domain of `ROS_DOMAIN_ID` (docs/ros2.md).
    /// Where peers can reach it is said at start. Needs a `tes` built with `--features ros2`.
    ///
    /// Values: `true` | `false`.
    pub ros2: bool,
    /// Write the run's ROS 2 topics (those `ros2` publishes) to a rosbag2 bag in this new
    /// directory (`tes launch --rosbag` overrides it): MCAP storage, CDR messages, as `ros2
    /// bag` reads it; no DDS node is needed for it. A relative path is taken from the
    /// directory `tes launch` runs in. Unset: no bag. Needs a `tes` built with `--features
    /// ros2`.
    ///
    /// Values: path of a directory that does not exist yet.
    ///
    /// Example: `"run-bag"`.
    pub rosbag: Option<PathBuf>,
    /// The processes this launch starts (`tes launch --roles` overrides it); the others run
    /// on other hosts, reached through the link (`[launch.link]`, docs/multi-host.md).
    /// Empty: all three on this host, over shared memory only, and no link.
    ///
    /// Values: list of `perception-sim`, `controller`, `bridge`.
    pub roles: Vec<Role>,
    /// How a launch with roles reaches the other hosts (the `[launch.link]` table).
    pub link: tes_link::LinkSection,
}

impl LaunchSection {
    /// The address of `foxglove`, resolved (`localhost:8765` as well as `127.0.0.1:8765`).
    pub fn foxglove_addr(&self) -> Result<Option<std::net::SocketAddr>, SettingError> {
        use std::net::ToSocketAddrs;
        let Some(text) = &self.foxglove else {
            return Ok(None);
        };
        let bad = |why: String| {
            SettingError::new(
                LAUNCH,
                "foxglove",
                format!(
                    "{text:?} is not an address to serve on ({why}); write HOST:PORT, e.g. \"127.0.0.1:8765\""
                ),
            )
        };
        let mut addrs = text.to_socket_addrs().map_err(|e| bad(e.to_string()))?;
        addrs
            .next()
            .map(Some)
            .ok_or_else(|| bad("it resolves to no address".into()))
    }
}

/// How `[launch] wait` comes out for each process of a launch, and why: said at start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChosenWait {
    /// `[launch] wait` as set.
    pub setting: WaitStrategy,
    /// Whether perception announces each observation to this launch's processes (a
    /// real-time factor above 0, a settle time, and perception on this host: its heads-ups
    /// do not cross the link): what `auto` goes by.
    pub announced: bool,
}

impl ChosenWait {
    /// The choice of a launch whose perception settles for `settle_ms` at `real_time_factor`,
    /// on this host (`perception_here`) or on another.
    pub fn new(
        setting: WaitStrategy,
        real_time_factor: f64,
        settle_ms: u64,
        perception_here: bool,
    ) -> Self {
        Self {
            setting,
            announced: real_time_factor > 0.0 && settle_ms > 0 && perception_here,
        }
    }

    /// How the controller and the bridge wait: their inputs (an observation, the command that
    /// follows it) are what perception announces.
    pub fn acting(&self) -> WaitStrategy {
        self.setting.resolve(self.announced)
    }

    /// How perception waits: its input, the brick's motion report, is never announced.
    pub fn perception(&self) -> WaitStrategy {
        self.setting.resolve(false)
    }
}

impl std::fmt::Display for ChosenWait {
    /// The setting, and with `auto` what it chose and why.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (self.setting, self.announced) {
            (WaitStrategy::Auto, true) => f.write_str(
                "auto: anticipate for the controller and the bridge (perception announces \
                 each observation as the robot settles), block for perception",
            ),
            (WaitStrategy::Auto, false) => f.write_str(
                "auto: block (nothing is announced here to anticipate: no settle time, or \
                 perception on another host)",
            ),
            (other, _) => write!(f, "{other}"),
        }
    }
}

/// The least `[launch] stall_timeout_ms`: a stall is longer than any healthy pause.
pub const MIN_STALL_TIMEOUT_MS: u64 = 500;

impl Default for LaunchSection {
    fn default() -> Self {
        Self {
            episodes: 20,
            arena: 3,
            real_time_factor: 0.0,
            wait: WaitStrategy::Auto,
            restart: Restart::Never,
            max_restarts: 3,
            grace_ms: 3000,
            service_prefix: String::new(),
            run_dir: None,
            runs_dir: None,
            keep_runs: 20,
            seed: 1,
            stall_timeout_ms: 10_000,
            record: None,
            foxglove: None,
            ros2: false,
            rosbag: None,
            roles: Vec::new(),
            link: tes_link::LinkSection::default(),
        }
    }
}

/// The process name of errors about the `[launch]` table (and about the file as a whole).
pub const LAUNCH: &str = "launch";

/// Which process a table of a launch file is for.
pub fn process_of(table: &str) -> Option<&'static str> {
    match table {
        "launch" => Some(LAUNCH),
        "perception" => Some(tes_perception_sim::process::config::PROCESS),
        "controller" => Some(tes_controller::config::PROCESS),
        "bridge" => Some(tes_bridge::config::PROCESS),
        "ros2_world" => Some(crate::world::WORLD),
        _ => None,
    }
}

/// A key of a child's table that the launcher fills in from `[launch]` unless the table sets
/// it itself.
#[derive(Debug, Clone, Copy)]
pub struct Inherited {
    /// The child's table (`perception`, `controller`, `bridge`).
    pub table: &'static str,
    /// The key, dotted within the table (`ipc.wait`).
    pub key: &'static str,
    /// The value it gets, as the reference says it.
    pub value: &'static str,
    /// Sets it in the children's settings from the `[launch]` table.
    pub apply: fn(&LaunchSection, &mut Children),
}

impl Inherited {
    /// Its dotted name from the top of the file (`bridge.ipc.wait`).
    pub fn path(&self) -> String {
        format!("{}.{}", self.table, self.key)
    }
}

/// What the reference says a child's `service_prefix` gets.
const PREFIX_VALUE: &str = "`[launch] service_prefix` (the launch's own prefix when that is empty)";

/// The launch-wide values the launcher sets in the children's tables: each is set unless the
/// table sets the key itself. The one list of them: [`LaunchFile::children`] applies it, the
/// reference marks its keys inherited with their `value`.
pub const INHERITED: &[Inherited] = &[
    Inherited {
        table: "perception",
        key: "arena",
        value: "`[launch] arena`",
        apply: |l, c| c.perception.arena = u32::from(l.arena),
    },
    Inherited {
        table: "perception",
        key: "episodes",
        value: "`[launch] episodes` (or `--episodes`)",
        apply: |l, c| c.perception.episodes = l.episodes,
    },
    Inherited {
        table: "perception",
        key: "real_time_factor",
        value: "`[launch] real_time_factor`",
        apply: |l, c| c.perception.real_time_factor = l.real_time_factor,
    },
    Inherited {
        table: "perception",
        key: "wait",
        value: "`[launch] wait` (`auto`: `block`)",
        apply: |l, c| c.perception.wait = chosen_wait(l, c).perception(),
    },
    Inherited {
        table: "perception",
        key: "service_prefix",
        value: PREFIX_VALUE,
        apply: |l, c| c.perception.service_prefix.clone_from(&l.service_prefix),
    },
    Inherited {
        table: "perception",
        key: "seed",
        value: "`[launch] seed`",
        apply: |l, c| c.perception.seed = launch_seed(l),
    },
    Inherited {
        table: "controller",
        key: "wait",
        value: AUTO_ACTING,
        apply: |l, c| c.controller.wait = chosen_wait(l, c).acting(),
    },
    Inherited {
        table: "controller",
        key: "service_prefix",
        value: PREFIX_VALUE,
        apply: |l, c| c.controller.service_prefix.clone_from(&l.service_prefix),
    },
    Inherited {
        table: "controller",
        key: "seed",
        value: "`[launch] seed`",
        apply: |l, c| c.controller.seed = launch_seed(l),
    },
    Inherited {
        table: "bridge",
        key: "seed",
        value: "`[launch] seed`",
        apply: |l, c| c.bridge.seed = launch_seed(l),
    },
    Inherited {
        table: "bridge",
        key: "use_command_degrees",
        value: "`true`",
        apply: |_, c| c.bridge.use_command_degrees = true,
    },
    Inherited {
        table: "bridge",
        key: "ipc.service_prefix",
        value: PREFIX_VALUE,
        apply: |l, c| c.bridge.ipc.service_prefix.clone_from(&l.service_prefix),
    },
    Inherited {
        table: "bridge",
        key: "ipc.wait",
        value: AUTO_ACTING,
        apply: |l, c| c.bridge.ipc.wait = chosen_wait(l, c).acting(),
    },
    Inherited {
        table: "bridge",
        key: "brick.time_scale",
        value: "1 / `[launch] real_time_factor`, or 200 at real-time factor 0",
        apply: |l, c| c.bridge.brick.time_scale = brick_time_scale(l),
    },
    Inherited {
        table: "bridge",
        key: "watchdog.deadline_ms",
        value: "1000 × `[bridge.brick] time_scale` (at least × 1) with the simulated brick, one \
                second of wall time; 1000 with a serial transport",
        apply: |l, c| c.bridge.watchdog.deadline_ms = watchdog_deadline_ms(l, &c.bridge),
    },
];

/// What the reference says the controller's and the bridge's `wait` get.
const AUTO_ACTING: &str = "`[launch] wait` (`auto`: `anticipate` when perception announces its \
                           observations, at a real-time factor above 0 with a settle time, \
                           on this host; else `block`)";

/// How the launch's `wait` comes out for the children `c` (perception's settle time as its
/// table sets it).
fn chosen_wait(l: &LaunchSection, c: &Children) -> ChosenWait {
    ChosenWait::new(
        l.wait,
        l.real_time_factor,
        c.perception.settle_ms,
        announces(l, c.ros2_world.is_some()),
    )
}

/// Whether perception-sim runs here and announces its observations: a ROS 2 robot's world
/// does not (its steps come when the robot sends them).
fn announces(l: &LaunchSection, ros2_world: bool) -> bool {
    plays_perception(l) && !ros2_world
}

/// Whether the launch runs perception itself (no roles: all three).
fn plays_perception(l: &LaunchSection) -> bool {
    l.roles.is_empty() || l.roles.contains(&Role::Perception)
}

/// The seed the children get: `[launch] seed`, at most `i64::MAX` (TOML integers end there;
/// a larger seed set in code is written as that).
fn launch_seed(l: &LaunchSection) -> u64 {
    l.seed.min(i64::MAX.unsigned_abs())
}

/// The simulated brick's time scale at the launch's pace: 1 / `real_time_factor`, or
/// [`FASTEST_TIME_SCALE`] as fast as possible.
fn brick_time_scale(l: &LaunchSection) -> f64 {
    if l.real_time_factor == 0.0 {
        FASTEST_TIME_SCALE
    } else {
        1.0 / l.real_time_factor
    }
}

/// The bridge's watchdog deadline in a launch, ms of brick time. The deadline is in brick
/// time: at a speed-up, it gives the wall clock the usual second, so a descheduled bridge on
/// a busy machine does not brake a healthy run. A real brick (serial transport) runs in
/// physical time whatever the scale.
fn watchdog_deadline_ms(l: &LaunchSection, bridge: &BridgeSettings) -> u64 {
    let scale = if bridge.transport == TransportKind::Sim {
        brick_time_scale(l).max(1.0)
    } else {
        1.0
    };
    // Saturating: a deadline beyond i64::MAX ms is no deadline at all.
    ((1000.0 * scale).round() as i64).unsigned_abs()
}

/// The tables of a launch file, as the parser reads them.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Tables {
    launch: LaunchSection,
    perception: PerceptionConfig,
    controller: ControllerConfig,
    bridge: BridgeSettings,
    ros2_world: Option<WorldSettings>,
}

/// A whole launch file: each table typed as its process reads it, and where it came from.
#[derive(Debug, Clone)]
pub struct LaunchFile {
    /// `[launch]`: the launch-wide settings.
    pub launch: LaunchSection,
    /// `[perception]`: perception-sim's settings, before the launch-wide values go in.
    pub perception: PerceptionConfig,
    /// `[controller]`: the controller's settings, before the launch-wide values go in.
    pub controller: ControllerConfig,
    /// `[bridge]`: the bridge's settings, before the launch-wide values go in.
    pub bridge: BridgeSettings,
    /// `[ros2_world]`: a ROS 2 robot as the world, in place of perception-sim and the bridge
    /// (docs/ros2.md; its keys are `tes_ros2::world::WorldSettings`, checked by a `tes` built
    /// with ROS 2).
    pub ros2_world: Option<WorldSettings>,
    /// The [`INHERITED`] keys the children's tables set themselves, as `table.key`
    /// (`perception.wait`): the launch-wide values do not replace them.
    pub own: BTreeSet<String>,
    /// Where the file came from (errors name it).
    pub origin: Origin,
    /// The file as the user wrote it (errors give the line of their key in it).
    pub text: Option<String>,
}

impl Default for LaunchFile {
    fn default() -> Self {
        let Tables {
            launch,
            perception,
            controller,
            bridge,
            ros2_world,
        } = Tables::default();
        Self {
            launch,
            perception,
            controller,
            bridge,
            ros2_world,
            own: BTreeSet::new(),
            origin: Origin::Defaults,
            text: None,
        }
    }
}

/// The children's settings as they are written to the run directory: the launch file's
/// tables with the launch-wide values set, each checked.
#[derive(Debug, Clone, PartialEq)]
pub struct Children {
    /// The bridge's.
    pub bridge: BridgeSettings,
    /// The controller's.
    pub controller: ControllerConfig,
    /// perception-sim's.
    pub perception: PerceptionConfig,
    /// The ROS 2 world's, when the launch's world is a ROS 2 robot.
    pub ros2_world: Option<WorldSettings>,
}

/// The trajectory perception writes in the run folder, unless its table names a file.
pub const TRAJECTORY: &str = "trajectory.csv";

/// The latency report the bridge writes in the run folder, unless its table names a file.
pub const BRIDGE_REPORT: &str = "bridge-report.json";

impl Children {
    /// Has the children write their records into the run folder `run_dir` where their tables
    /// name no file of their own: perception's trajectory, the bridge's latency report.
    pub fn write_into(&mut self, run_dir: &Path) {
        self.perception
            .trajectory
            .get_or_insert_with(|| run_dir.join(TRAJECTORY));
        self.bridge
            .ipc
            .latency_report
            .get_or_insert_with(|| run_dir.join(BRIDGE_REPORT));
    }
}

impl LaunchFile {
    /// Parses a launch file's text, once, into the typed tables; a key that is unknown, of
    /// the wrong type or repeated is reported with `origin`, its line and its table and key.
    pub fn from_toml(text: &str, origin: Origin) -> Result<Self, SettingError> {
        let t: Tables = settings::parse_tables(LAUNCH, text, origin.clone(), process_of)?;
        let own = INHERITED
            .iter()
            .filter(|i| settings::is_set(text, Some(i.table), i.key))
            .map(Inherited::path)
            .collect();
        Ok(Self {
            launch: t.launch,
            perception: t.perception,
            controller: t.controller,
            bridge: t.bridge,
            ros2_world: t.ros2_world,
            own,
            origin,
            text: Some(text.to_owned()),
        })
    }

    /// Keeps `[table] key` as the table sets it: the launch-wide value does not replace it
    /// (what writing the key in the table does in a file).
    pub fn keep(&mut self, table: &str, key: &str) {
        self.own.insert(format!("{table}.{key}"));
    }

    /// The roles this launch plays, in [`Role::ALL`] order; `None` when it plays all three on
    /// one host (no link).
    pub fn roles(&self) -> Option<Vec<Role>> {
        let roles: Vec<Role> = Role::ALL
            .into_iter()
            .filter(|r| self.launch.roles.contains(r))
            .collect();
        (!roles.is_empty() && roles.len() < Role::ALL.len()).then_some(roles)
    }

    /// The arena perception runs: its own `arena` if its table sets one, else `[launch] arena`;
    /// 0 when the world is a ROS 2 robot's.
    pub fn arena(&self) -> u32 {
        if self.ros2_world.is_some() {
            0
        } else if self.inherits("perception", "arena") {
            u32::from(self.launch.arena)
        } else {
            self.perception.arena
        }
    }

    /// Whether the launch-wide value goes into `[table] key`.
    fn inherits(&self, table: &str, key: &str) -> bool {
        !self.own.contains(&format!("{table}.{key}"))
    }

    /// `error`, about a key of `table`, placed at its line in the file.
    fn place(&self, error: SettingError, table: &str) -> SettingError {
        error.in_file(self.origin.clone(), Some(table), self.text.as_deref())
    }

    /// The world, as the start of a launch says it: `arena Env 3`, or a ROS 2 robot's.
    pub fn world_name(&self) -> String {
        match self.arena() {
            0 => "the world of a ROS 2 robot ([ros2_world])".to_owned(),
            n => format!("arena Env {n}"),
        }
    }

    /// How `[launch] wait` comes out for each process (said at start).
    pub fn chosen_wait(&self) -> ChosenWait {
        ChosenWait::new(
            self.launch.wait,
            self.launch.real_time_factor,
            self.perception.settle_ms,
            announces(&self.launch, self.ros2_world.is_some()),
        )
    }

    /// The children's settings: the tables with the launch-wide values set where a table
    /// does not set its own, every one checked (the first bad key is reported, placed in the
    /// file).
    pub fn children(&self) -> Result<Children, SettingError> {
        check_launch(&self.launch).map_err(|e| self.place(e, "launch"))?;
        let ros2_world = match &self.ros2_world {
            Some(table) => {
                if !self.launch.roles.is_empty() {
                    return Err(self.place(
                        SettingError::new(
                            LAUNCH,
                            "roles",
                            "a ROS 2 robot's world ([ros2_world]) runs with the controller on \
                             one host; the robot's own node is the other side",
                        ),
                        "launch",
                    ));
                }
                crate::world::check_world(table).map_err(|e| self.place(e, "ros2_world"))?;
                Some(table.clone())
            }
            None => None,
        };
        let mut children = Children {
            bridge: self.bridge.clone(),
            controller: self.controller.clone(),
            perception: self.perception.clone(),
            ros2_world,
        };
        for inherited in INHERITED {
            if self.inherits(inherited.table, inherited.key) {
                (inherited.apply)(&self.launch, &mut children);
            }
        }
        self.check_children(&children)?;
        Ok(children)
    }

    /// Checks every child's settings, so that a bad key stops the launch before any process
    /// starts, and that the controller's keep-alives come well within the bridge's watchdog
    /// deadline.
    fn check_children(&self, children: &Children) -> Result<(), SettingError> {
        let Children {
            bridge,
            controller,
            perception,
            // Checked as it was taken in (`children`).
            ros2_world: _,
        } = children;
        let bridge_cfg = bridge.check().map_err(|e| self.place(e, "bridge"))?;
        controller
            .check()
            .map_err(|e| self.place(e, "controller"))?;
        // The watchdog's deadline is brick time; the keep-alives are wall time.
        let wall_scale = if bridge.transport == TransportKind::Sim {
            bridge_cfg.brick.time_scale
        } else {
            1.0
        };
        let deadline_wall_ms = bridge_cfg.watchdog_deadline.as_secs_f64() * 1000.0 / wall_scale;
        if controller.keepalive_ms as f64 * 2.0 > deadline_wall_ms {
            let reason = format!(
                "{} must be at most half the bridge's watchdog deadline ({deadline_wall_ms:.0} \
                 ms of wall time: watchdog.deadline_ms / brick.time_scale), or the watchdog \
                 brakes moves of a live controller",
                controller.keepalive_ms
            );
            let error = SettingError::new(tes_controller::config::PROCESS, "keepalive_ms", reason);
            return Err(self.place(error, "controller"));
        }
        perception
            .check()
            .map_err(|e| self.place(e, "perception"))?;
        Ok(())
    }
}

/// Checks the `[launch]` table's own keys.
pub fn check_launch(l: &LaunchSection) -> Result<(), SettingError> {
    let bad = |key, reason: String| Err(SettingError::new(LAUNCH, key, reason));
    if !(1..=3).contains(&l.arena) {
        return bad("arena", format!("must be 1, 2 or 3, got {}", l.arena));
    }
    if !(l.real_time_factor.is_finite() && l.real_time_factor >= 0.0) {
        return bad("real_time_factor", "must be a finite number >= 0".into());
    }
    if l.episodes == 0 {
        return bad("episodes", "must be at least 1".into());
    }
    if l.stall_timeout_ms < MIN_STALL_TIMEOUT_MS {
        return bad(
            "stall_timeout_ms",
            format!(
                "must be at least {MIN_STALL_TIMEOUT_MS}, got {}",
                l.stall_timeout_ms
            ),
        );
    }
    settings::service_prefix(LAUNCH, "service_prefix", &l.service_prefix)?;
    l.foxglove_addr()?;
    let mut seen = BTreeSet::new();
    for role in &l.roles {
        if !seen.insert(*role) {
            return bad("roles", format!("{:?} is listed twice", role.name()));
        }
    }
    if !l.roles.is_empty() {
        l.link.check_for(&l.roles)?;
    }
    Ok(())
}

/// The simulated brick's speed-up at real-time factor 0 ("as fast as possible"): motor
/// motion runs this many times faster than physical time.
pub const FASTEST_TIME_SCALE: f64 = 200.0;

/// A launch file that cannot be used; when one is refused, nothing is started.
#[derive(Debug)]
pub enum LaunchFileError {
    /// It cannot be read: missing, unreadable, not UTF-8 text, not a regular file (a FIFO, a
    /// device, a directory: refused without reading from it) or larger than
    /// [`MAX_LAUNCH_FILE_BYTES`].
    Read {
        /// The file.
        path: PathBuf,
        /// Why (boxed: it is rare, and keeps the error small).
        error: Box<tes_files::FileProblem>,
    },
    /// A key is unknown, of the wrong type, repeated or out of range, the settings contradict
    /// each other, or the text is not TOML: placed in the file (its origin, line, table and
    /// key).
    Setting(SettingError),
    /// The children's settings cannot be serialised (a bug).
    Write {
        /// The launch file (or the embedded defaults).
        origin: Origin,
        /// What could not be written.
        what: String,
        /// Why.
        error: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The run directory cannot be created or written (disk full, read-only, permissions).
    RunDir {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// Another group owns the run directory.
    Busy(LockError),
    /// Another launch plays this role from the same data directory.
    RoleBusy {
        /// The role.
        role: Role,
        /// Its lock, held by the other launch.
        error: LockError,
    },
}

impl std::fmt::Display for LaunchFileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let what = |origin: &Origin| match origin {
            Origin::File(_) => "launch file",
            Origin::Text | Origin::Defaults => "launch settings",
        };
        match self {
            LaunchFileError::Read { path, error } => {
                write!(f, "cannot read the launch file {}: {error}", path.display())?
            }
            LaunchFileError::Setting(error) => {
                let origin = error
                    .location
                    .as_ref()
                    .map_or(&Origin::Defaults, |l| &l.origin);
                write!(f, "{} {error}", what(origin))?;
            }
            LaunchFileError::Write {
                origin,
                what: written,
                error,
            } => {
                write!(f, "{} {origin}: {written}: {error}", what(origin))?;
            }
            LaunchFileError::RunDir { path, error } => write!(
                f,
                "cannot write the run directory: {}: {}",
                path.display(),
                tes_runtime::cause::explain(error)
            )?,
            LaunchFileError::Busy(LockError::Held { path, pid, .. }) => write!(
                f,
                "the run directory {} is in use by another tes launch{}; stop that one first, \
                 or give this launch a data directory of its own (TES_DATA_DIR) or another \
                 [launch] run_dir",
                path.parent().unwrap_or(path).display(),
                pid.map(|p| format!(" (pid {p})")).unwrap_or_default()
            )?,
            LaunchFileError::Busy(LockError::Io { path, error, .. })
            | LaunchFileError::RoleBusy {
                error: LockError::Io { path, error, .. },
                ..
            } => write!(
                f,
                "cannot lock the run directory: {}: {}",
                path.display(),
                tes_runtime::cause::explain(error)
            )?,
            LaunchFileError::RoleBusy {
                role,
                error: LockError::Held { path, pid, .. },
            } => write!(
                f,
                "the {role} of the runs in {} is in use by another tes launch{}; stop that \
                 one first, or give this launch other roles (--roles), a data directory of its \
                 own (TES_DATA_DIR) or another [launch] runs_dir",
                path.parent().unwrap_or(path).display(),
                pid.map(|p| format!(" (pid {p})")).unwrap_or_default()
            )?,
        }
        f.write_str("; nothing was started")
    }
}

impl std::error::Error for LaunchFileError {}

/// The largest launch file read, in bytes: every key of every table, commented, is some
/// 20 KiB.
pub const MAX_LAUNCH_FILE_BYTES: u64 = 1 << 20;

/// Reads and parses a launch file; a problem is reported with the file, the line and the key.
/// The file is read as every TES file is ([`tes_files::read_text`]): a FIFO, a device or a
/// directory is refused without blocking or reading from it, and a file over
/// [`MAX_LAUNCH_FILE_BYTES`] without reading it.
pub fn read_launch_file(path: &Path) -> Result<LaunchFile, LaunchFileError> {
    let text = tes_files::read_text(path, MAX_LAUNCH_FILE_BYTES).map_err(|error| {
        LaunchFileError::Read {
            path: path.to_owned(),
            error: Box::new(error),
        }
    })?;
    LaunchFile::from_toml(&text, Origin::File(path.to_owned())).map_err(LaunchFileError::Setting)
}

/// A launch ready to start: its children's settings written, its run directory owned.
#[derive(Debug)]
pub struct Prepared {
    /// The children, in start order.
    pub specs: Vec<ChildSpec>,
    /// This launch's run folder: the children's settings, output and logs, the resolved launch
    /// file, the episode table, the trajectories and, at the end, the pictures.
    pub run_dir: PathBuf,
    /// A new run folder's parent (`runs/`) and `[launch] keep_runs`, until
    /// [`commit`](Prepared::commit): a launch refused before then removes its run folder and
    /// leaves `runs/` and `runs/latest` as they were. `None` for a `run_dir` of the file's own.
    fresh: Option<(PathBuf, u32)>,
    /// The group's service prefix (its own unless the file sets one).
    pub service_prefix: String,
    /// Where the bridge writes its report at exit (latency, the link's round trips), when
    /// this launch plays the bridge.
    pub bridge_report: Option<PathBuf>,
    /// The run directory's locks, held for the group's life.
    pub _locks: RunLocks,
}

/// The locks a launch holds while it runs: its roles' in the data directory's `runs/` (or
/// a `run_dir` of its own whole), and its run folder's, which keeps other launches' pruning
/// off it. Each file is removed as its lock is let go.
#[derive(Debug)]
pub struct RunLocks {
    _roles: Vec<Lock>,
    _folder: Option<Lock>,
}

/// Takes `runs/ROLE.lock` for each role a launch plays (every role when `roles` is empty),
/// or says which role another launch holds, naming its pid.
fn lock_roles(runs: &Path, roles: &[Role]) -> Result<Vec<Lock>, LaunchFileError> {
    Role::ALL
        .into_iter()
        .filter(|r| roles.is_empty() || roles.contains(r))
        .map(|role| {
            Lock::acquire(&runs.join(format!("{}.lock", role.name())), role.name())
                .map_err(|error| LaunchFileError::RoleBusy { role, error })
        })
        .collect()
}

impl Prepared {
    /// The group has started: the new run folder becomes `runs/latest` and the oldest are
    /// pruned to `keep_runs`. Returns the folders removed.
    pub fn commit(&mut self) -> Vec<PathBuf> {
        match self.fresh.take() {
            Some((runs, keep)) => {
                let pruned = run_folder::prune(&runs, keep, &self.run_dir);
                run_folder::point_latest_at(&runs, &self.run_dir);
                pruned
            }
            None => Vec::new(),
        }
    }
}

impl Drop for Prepared {
    /// A launch refused before its group started leaves no run folder behind.
    fn drop(&mut self) {
        if self.fresh.is_some() {
            let _ = std::fs::remove_dir_all(&self.run_dir);
        }
    }
}

/// The order the children start in: the bridge first (the brick is there before any command
/// comes), perception last (its first observation finds the controller listening).
pub const START_ORDER: [Role; 3] = [Role::Bridge, Role::Controller, Role::Perception];

/// A service prefix no other launch has: this process's id and the clock's low bits.
pub fn unique_service_prefix() -> String {
    let ns = tes_runtime::clock::monotonic_ns();
    format!("tes-{}-{:08x}/", std::process::id(), ns & 0xffff_ffff)
}

/// The resolved launch file a run folder keeps.
pub const RESOLVED_LAUNCH_FILE: &str = "launch.toml";

/// Checks every child's settings, takes the run directory for this launch and writes their
/// settings there. A launch without a service prefix gets one of its own. The resolved launch
/// file beside them is [`reference::write_resolved`](crate::reference::write_resolved)'s.
pub fn prepare(file: &LaunchFile) -> Result<Prepared, LaunchFileError> {
    let mut file = file.clone();
    if file.launch.service_prefix.is_empty() {
        file.launch.service_prefix = unique_service_prefix();
    }
    let mut children = file.children().map_err(LaunchFileError::Setting)?;
    let unwritable = |what: String| {
        let origin = file.origin.clone();
        move |error: Box<dyn std::error::Error + Send + Sync>| LaunchFileError::Write {
            origin,
            what,
            error,
        }
    };
    let run_dir_error = |path: &Path| {
        let path = path.to_owned();
        move |error| LaunchFileError::RunDir { path, error }
    };
    let (run_dir, fresh, lock) = match &file.launch.run_dir {
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(run_dir_error(dir))?;
            // A run directory of the file's own holds one group's files: one launch at a time.
            let lock = Lock::acquire(&dir.join("launch.lock"), "run directory")
                .map_err(LaunchFileError::Busy)?;
            let locks = RunLocks {
                _roles: vec![lock],
                _folder: None,
            };
            (dir.clone(), None, locks)
        }
        None => {
            let runs = file
                .launch
                .runs_dir
                .clone()
                .unwrap_or_else(|| default_data_dir().join(run_folder::RUNS));
            std::fs::create_dir_all(&runs).map_err(run_dir_error(&runs))?;
            // One launch per role and data directory: the two sides of a split group share
            // one (each in a run folder of its own), a second controller is refused.
            let role_locks = lock_roles(&runs, &file.launch.roles)?;
            let dir = run_folder::create(&runs, std::time::SystemTime::now())
                .map_err(run_dir_error(&runs))?;
            // Held for the run: another launch's pruning keeps a folder in use.
            let in_use = Lock::acquire(&dir.join(run_folder::IN_USE), "run folder")
                .map_err(LaunchFileError::Busy)?;
            let locks = RunLocks {
                _roles: role_locks,
                _folder: Some(in_use),
            };
            (dir, Some((runs, file.launch.keep_runs)), locks)
        }
    };
    // From here on a refusal removes the new run folder (the guard's drop).
    let mut prepared = Prepared {
        specs: Vec::new(),
        run_dir,
        fresh,
        service_prefix: file.launch.service_prefix.clone(),
        bridge_report: None,
        _locks: lock,
    };
    let run_dir = prepared.run_dir.clone();
    children.write_into(&run_dir);
    // A ROS 2 robot's world plays perception and the bridge both (its node is the robot).
    let world = children.ros2_world.clone();
    let plays = |role: &Role| {
        (file.launch.roles.is_empty() || file.launch.roles.contains(role))
            && !(world.is_some() && *role == Role::Bridge)
    };
    for role in START_ORDER.iter().filter(|r| plays(r)) {
        let text = match (role, &world) {
            (Role::Bridge, _) => toml::to_string(&children.bridge),
            (Role::Controller, _) => toml::to_string(&children.controller),
            (Role::Perception, None) => toml::to_string(&children.perception),
            (Role::Perception, Some(world)) => {
                let (episodes, prefix) = (file.launch.episodes, &file.launch.service_prefix);
                crate::world::world_file(world, episodes, prefix, &run_dir)
            }
        }
        .map_err(|e| {
            unwritable(format!("cannot write the {}'s settings", role.name()))(e.into())
        })?;
        let path = run_dir.join(format!("{}.toml", role.name()));
        std::fs::write(&path, text).map_err(|error| LaunchFileError::RunDir {
            path: path.clone(),
            error,
        })?;
        prepared.specs.push(ChildSpec {
            role: *role,
            config: path,
        });
    }
    if plays(&Role::Bridge) {
        prepared
            .bridge_report
            .clone_from(&children.bridge.ipc.latency_report);
    }
    Ok(prepared)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;
    use tes_bridge::config::BridgeConfig;
    use tes_controller::config::PlanningMode;

    /// A launch file `launch.toml` in a fresh directory, with `[launch] run_dir` in that
    /// directory followed by `extra`; the directory and the file, read.
    fn launch_file(
        extra: &str,
    ) -> (
        tempfile::TempDir,
        PathBuf,
        Result<LaunchFile, LaunchFileError>,
    ) {
        let dir = tempfile::tempdir().expect("temp dir");
        let text = format!(
            "[launch]\nrun_dir = \"{}\"\n{extra}",
            dir.path().join("run").display()
        );
        let path = dir.path().join("launch.toml");
        std::fs::write(&path, text).expect("launch file");
        let file = read_launch_file(&path);
        (dir, path, file)
    }

    /// Prepares the children of a launch file with `extra` after its `[launch]` table; the
    /// directory's `run` holds the children's settings files.
    fn prepared(extra: &str) -> (tempfile::TempDir, Result<Prepared, LaunchFileError>) {
        let (dir, _, file) = launch_file(extra);
        let specs = prepare(&file.expect("a launch file"));
        (dir, specs)
    }

    fn bridge_settings(dir: &tempfile::TempDir) -> BridgeConfig {
        let path = dir.path().join("run/bridge.toml");
        let text = std::fs::read_to_string(path).expect("bridge.toml");
        BridgeConfig::from_toml_str(&text).expect("valid bridge settings")
    }

    /// The setting error a launch file's problem is.
    fn setting(err: &LaunchFileError) -> &SettingError {
        match err {
            LaunchFileError::Setting(e) => e,
            other => panic!("not a setting error: {other}"),
        }
    }

    /// A run directory that cannot be written is named with its cause — never reported as
    /// invalid settings.
    #[test]
    fn an_unwritable_run_directory_is_named_with_its_cause() {
        for (code, cause) in [
            (28, "the disk is full"),
            (30, "the file system is read-only"),
        ] {
            let err = LaunchFileError::RunDir {
                path: PathBuf::from("/data/run"),
                error: std::io::Error::from_raw_os_error(code),
            };
            let shown = err.to_string();
            assert!(
                shown.starts_with("cannot write the run directory: /data/run: ")
                    && shown.contains(cause)
                    && shown.ends_with("; nothing was started"),
                "{shown}"
            );
        }
    }

    /// `roles` starts only the named children; an unknown or repeated role, and link settings
    /// that cannot work, are refused naming their key.
    #[test]
    fn roles_name_the_children_and_bad_roles_or_link_settings_are_refused() {
        let (_, ok) = prepared("roles = [\"controller\"]\n");
        let specs = ok.expect("prepared").specs.clone();
        assert_eq!(
            specs.iter().map(|s| s.role).collect::<Vec<_>>(),
            [Role::Controller]
        );
        let (_, ok) = prepared("roles = [\"bridge\", \"perception-sim\"]\n");
        let specs = ok.expect("prepared").specs.clone();
        assert_eq!(
            specs.iter().map(|s| s.role).collect::<Vec<_>>(),
            [Role::Bridge, Role::Perception]
        );
        for (extra, key, reason) in [
            ("roles = [\"brige\"]\n", "roles", "unknown role \"brige\""),
            (
                "roles = [\"bridge\", \"bridge\"]\n",
                "roles",
                "\"bridge\" is listed twice",
            ),
            (
                "roles = [\"bridge\"]\n[launch.link]\ngroup = \"a*b\"\n",
                "link.group",
                "is not a group name",
            ),
            (
                "roles = [\"bridge\"]\n[launch.link]\nconnect = [\"udp/10.0.0.1:7447\"]\n",
                "link.connect",
                "is not a QUIC, TCP or Unix socket endpoint",
            ),
            (
                "roles = [\"bridge\"]\n[launch.link]\nlisten = [\"tcp/10.0.0.1:7447\"]\n",
                "link.listen",
                "is plain TCP, with no authentication: it is reachable from other hosts",
            ),
            (
                "roles = [\"bridge\"]\n[launch.link]\npeer_timeout_ms = 5\n",
                "link.peer_timeout_ms",
                "at least 100",
            ),
        ] {
            // An unknown role is refused as the file is read, the others when it is prepared.
            let (_dir, _, read) = launch_file(extra);
            let err = match read {
                Ok(file) => prepare(&file).expect_err(extra),
                Err(e) => e,
            };
            let e = setting(&err);
            assert_eq!((e.process, e.key.as_str()), ("launch", key), "{extra}");
            assert!(e.reason.contains(reason), "{extra}: {}", e.reason);
        }
        // Link settings are not checked without roles: nothing uses them.
        let (_, ok) = prepared("[launch.link]\npeer_timeout_ms = 5\n");
        assert!(ok.is_ok());
    }

    #[test]
    fn keep_alives_must_come_well_within_the_watchdog_deadline() {
        let (_, ok) = prepared("");
        assert!(ok.is_ok());
        let (_, off) = prepared("[controller]\nkeepalive_ms = 0\n");
        assert!(off.is_ok());
        let (_, bad) = prepared("[controller]\nkeepalive_ms = 600\n");
        let err = bad.expect_err("refused");
        let e = setting(&err);
        assert_eq!((e.process, e.key.as_str()), ("controller", "keepalive_ms"));
        assert_eq!(e.line(), Some(4));
        let err = err.to_string();
        assert!(
            err.contains("[controller] keepalive_ms: 600 must be at most half")
                && err.contains("1000 ms of wall time"),
            "{err}"
        );
    }

    #[test]
    fn the_watchdog_deadline_follows_the_simulated_brick_but_not_a_real_one() {
        // As fast as possible: the simulated brick runs 200x, so its deadline is 200 s of brick
        // time, one second of wall time.
        let (dir, specs) = prepared("");
        assert!(specs.is_ok());
        let sim = bridge_settings(&dir);
        assert_eq!(sim.watchdog_deadline, Duration::from_secs(200));
        // A real NXT lives in physical time whatever the real-time factor.
        let (dir, specs) = prepared("[bridge]\ntransport = \"serial:/dev/rfcomm0\"\n");
        assert!(specs.is_ok());
        let real = bridge_settings(&dir);
        assert_eq!(real.watchdog_deadline, Duration::from_secs(1));
    }

    /// A key the parser refuses in any table — unknown, of the wrong type, an enum's unknown
    /// word — is reported against the user's own file, at its line, with its table and key.
    #[test]
    fn a_bad_key_in_a_child_table_names_the_users_file_line_and_key() {
        // (text after the two-line [launch] table, process, key, line)
        let cases = [
            (
                "episodes = 2\n\n[bridge]\nseed = 3\n[bridge.watchdog]\ndeadline_ms = \"soon\"\n",
                "bridge",
                "watchdog.deadline_ms",
                8,
            ),
            ("[bridge]\nwatchdogg = 1\n", "bridge", "watchdogg", 4),
            ("[bridge]\ntransport = \"usb:\"\n", "bridge", "transport", 4),
            (
                "[bridge.ipc]\nservice_prefix = \"x/\"\nwait = \"nap\"\n",
                "bridge",
                "ipc.wait",
                5,
            ),
            (
                "[[bridge.actions]]\nid = 0\nleft_deg = 1\nright_deg = 1\nspeed = 3\n",
                "bridge",
                "actions[0].speed",
                7,
            ),
            (
                "[controller]\nepsilon = 0.1\nbudjet_us = 5\n",
                "controller",
                "budjet_us",
                5,
            ),
            ("[controller]\nwait = \"nap\"\n", "controller", "wait", 4),
            (
                "[controller]\nplanning = \"later\"\n",
                "controller",
                "planning",
                4,
            ),
            (
                "[controller]\nacting_cpu = \"fast\"\n",
                "controller",
                "acting_cpu",
                4,
            ),
            (
                "[perception]\narena = \"three\"\n",
                "perception",
                "arena",
                4,
            ),
            ("[perception]\nwait = \"doze\"\n", "perception", "wait", 4),
            ("wait = \"nap\"\n", "launch", "wait", 3),
            ("restart = \"always\"\n", "launch", "restart", 3),
        ];
        for (extra, process, key, line) in cases {
            let (_, path, file) = launch_file(extra);
            let err = file.expect_err(extra);
            let e = setting(&err);
            assert_eq!(
                (e.process, e.key.as_str(), e.line()),
                (process, key, Some(line)),
                "{extra}"
            );
            let location = e.location.as_ref().expect("placed");
            assert_eq!(location.origin, Origin::File(path.clone()));
            let table = if process == "launch" {
                "launch"
            } else {
                process
            };
            let shown = err.to_string();
            let start = format!("launch file {}:{line}:", path.display());
            assert!(shown.starts_with(&start), "{shown}");
            assert!(shown.contains(&format!(": [{table}] {key}: ")), "{shown}");
            assert!(shown.ends_with("; nothing was started"), "{shown}");
        }
    }

    /// A value a child's `check` refuses is placed at its key's line in the user's file; a
    /// refused value the file does not set is said to be a default or a launch-wide value.
    /// Nothing is written to the run directory.
    #[test]
    fn a_range_error_of_a_child_names_the_users_file_line_and_key() {
        let cases = [
            (
                "seed = 2\n[bridge]\nuse_command_degrees = false\n\
                 [bridge.poll]\nsettle_polls = 0\n",
                "bridge",
                "poll.settle_polls",
                Some(7),
            ),
            (
                "[bridge.watchdog]\ndeadline_ms = 100\n[bridge.poll]\nmoving_period_ms = 100\n",
                "bridge",
                "poll.moving_period_ms",
                Some(6),
            ),
            (
                "[[bridge.actions]]\nid = 1\nleft_deg = 1\nright_deg = 1\n\
                 [[bridge.actions]]\nid = 1\nleft_deg = 2\nright_deg = 2\n",
                "bridge",
                "actions[1].id",
                Some(8),
            ),
            (
                "[controller]\n# the budget\nbudget_us = 0\n",
                "controller",
                "budget_us",
                Some(5),
            ),
            (
                "[controller]\nplanning = \"between-polls\"\n",
                "controller",
                "planning",
                Some(4),
            ),
            (
                "[perception]\nstep_cap = 0\n",
                "perception",
                "step_cap",
                Some(4),
            ),
            ("arena = 4\n", "launch", "arena", Some(3)),
            (
                &format!("service_prefix = \"{}\"\n", "x".repeat(65)),
                "launch",
                "service_prefix",
                Some(3),
            ),
            // The launch-wide real-time factor makes the brick 100 000 times faster.
            (
                "real_time_factor = 0.00001\n",
                "bridge",
                "brick.time_scale",
                None,
            ),
        ];
        for (extra, process, key, line) in cases {
            let (dir, path, file) = launch_file(extra);
            let err = prepare(&file.expect(extra)).expect_err(extra);
            let e = setting(&err);
            assert_eq!(
                (e.process, e.key.as_str(), e.line()),
                (process, key, line),
                "{extra}"
            );
            let shown = err.to_string();
            let table = format!("[{process}] {key}");
            match line {
                Some(line) => {
                    let start = format!("launch file {}:{line}:1: {table}: ", path.display());
                    assert!(shown.starts_with(&start), "{shown}");
                }
                None => {
                    let start = format!(
                        "launch file {}: {table} (not in the file: a default or a launch-wide \
                         value): ",
                        path.display()
                    );
                    assert!(shown.starts_with(&start), "{shown}");
                }
            }
            for role in Role::ALL {
                let written = dir.path().join(format!("run/{}.toml", role.name()));
                assert!(!written.exists(), "{extra}: {role} was written");
            }
        }
    }

    /// The launch-wide values go into the typed tables unless a table sets the key itself
    /// (in the file, or in code with `keep`).
    #[test]
    fn launch_wide_values_go_where_a_table_does_not_set_its_own() {
        let (_, _, file) = launch_file(
            "arena = 1\nepisodes = 3\nreal_time_factor = 0.5\nwait = \"spin-then-block\"\n\
             seed = 5\nservice_prefix = \"g/\"\n\
             [perception]\nwait = \"block\"\nseed = 9\n\
             [controller]\nservice_prefix = \"c/\"\n\
             [bridge]\nuse_command_degrees = false\n[bridge.ipc]\nwait = \"spin\"\n",
        );
        let c = file.expect("valid").children().expect("valid");
        let stb = WaitStrategy::SpinThenBlock(WaitStrategy::DEFAULT_SPIN);
        let p = &c.perception;
        assert_eq!((p.arena, p.episodes, p.real_time_factor), (1, 3, 0.5));
        assert_eq!(
            (p.wait, p.seed, p.service_prefix.as_str()),
            (WaitStrategy::Block, 9, "g/")
        );
        let k = &c.controller;
        assert_eq!((k.wait, k.seed, k.service_prefix.as_str()), (stb, 5, "c/"));
        let b = &c.bridge;
        assert_eq!((b.seed, b.use_command_degrees), (5, false));
        assert_eq!(
            (b.ipc.wait, b.ipc.service_prefix.as_str()),
            (WaitStrategy::Spin, "g/")
        );
        // Twice as fast as physical time: the brick at 2x, its deadline 2 s of brick time.
        assert_eq!((b.brick.time_scale, b.watchdog.deadline_ms), (2.0, 2000));

        let mut file = LaunchFile::default();
        file.launch.wait = WaitStrategy::Spin;
        file.perception.wait = WaitStrategy::Block;
        file.keep("perception", "wait");
        let c = file.children().expect("valid");
        assert_eq!(c.perception.wait, WaitStrategy::Block);
        assert_eq!(c.controller.wait, WaitStrategy::Spin);
        assert_eq!(c.controller.planning, PlanningMode::Auto);
        assert_eq!(c.bridge.ipc.wait, WaitStrategy::Spin);
        assert!(c.bridge.use_command_degrees);
        // Without a file, an error names the embedded defaults.
        file.launch.episodes = 0;
        let err = LaunchFileError::Setting(file.children().expect_err("no episodes"));
        assert_eq!(
            err.to_string(),
            "launch settings (embedded defaults): [launch] episodes: must be at least 1; \
             nothing was started"
        );
    }

    /// What a child reads from the run directory is exactly the typed settings the launcher
    /// checked: typed → TOML → typed is the identity for each child.
    /// With no `wait` set, the controller and the bridge anticipate where perception announces
    /// its observations (a real-time factor above 0 and a settle time) and every process
    /// blocks at the fastest pace; the launch says which, and why.
    #[test]
    fn the_default_wait_anticipates_at_the_robots_pace_and_blocks_at_the_fastest() {
        let mut file = LaunchFile::default();
        assert_eq!(file.launch.wait, WaitStrategy::Auto);
        let c = file.children().expect("valid");
        for wait in [c.perception.wait, c.controller.wait, c.bridge.ipc.wait] {
            assert_eq!(wait, WaitStrategy::Block);
        }
        assert!(file.chosen_wait().to_string().starts_with("auto: block"));

        file.launch.real_time_factor = 1.0;
        let c = file.children().expect("valid");
        assert_eq!(c.perception.wait, WaitStrategy::Block);
        assert_eq!(c.controller.wait, WaitStrategy::Anticipate);
        assert_eq!(c.bridge.ipc.wait, WaitStrategy::Anticipate);
        let said = file.chosen_wait().to_string();
        assert!(
            said.starts_with("auto: anticipate for the controller and the bridge"),
            "{said}"
        );

        // Perception on another host: its heads-ups stay there.
        file.launch.roles = vec![Role::Controller];
        let c = file.children().expect("valid");
        assert_eq!(c.controller.wait, WaitStrategy::Block);
        file.launch.roles = Vec::new();
        // No settle time: nothing is announced, whatever the pace.
        file.perception.settle_ms = 0;
        let c = file.children().expect("valid");
        assert_eq!(c.controller.wait, WaitStrategy::Block);
        // A strategy set is used as it is.
        file.launch.wait = WaitStrategy::Anticipate;
        let c = file.children().expect("valid");
        assert_eq!(c.perception.wait, WaitStrategy::Anticipate);
        assert_eq!(file.chosen_wait().to_string(), "anticipate");
    }

    #[test]
    fn the_children_read_back_exactly_what_the_launcher_checked() {
        for extra in [
            "",
            "wait = \"spin\"\nseed = 77\nreal_time_factor = 1.0\narena = 2\n\
             [perception]\nsettle_ms = 150\nmotor_timeout_ms = 900\n\
             [controller]\nlibrary = \"/tmp/tes-lib.tesl\"\nreport = \"/tmp/r.json\"\n\
             planning = \"thread\"\nacting_cpu = \"none\"\nepsilon = 0.2\n\
             [bridge]\nseed = 3\n[bridge.link_delay]\nenabled = true\n[bridge.motors]\npower = 60\n\
             [[bridge.actions]]\nid = 0\nname = \"only\"\nleft_deg = 10\nright_deg = -10\n",
        ] {
            let (dir, _, file) = launch_file(extra);
            let mut file = file.expect("valid");
            let prepared = prepare(&file).expect("prepared");
            // Without a prefix of its own, the launch got a unique one.
            assert!(prepared.service_prefix.starts_with("tes-"), "{prepared:?}");
            file.launch
                .service_prefix
                .clone_from(&prepared.service_prefix);
            let mut children = file.children().expect("valid");
            children.write_into(&dir.path().join("run"));
            assert_eq!(
                prepared.specs.iter().map(|s| s.role).collect::<Vec<_>>(),
                START_ORDER
            );
            let read = |role: &str| {
                let path = dir.path().join(format!("run/{role}.toml"));
                (
                    std::fs::read_to_string(&path).expect("written"),
                    Origin::File(path),
                )
            };
            let (text, origin) = read("bridge");
            let bridge = BridgeSettings::from_toml_in(&text, origin.clone()).expect("bridge");
            assert_eq!(bridge, children.bridge, "{text}");
            assert_eq!(
                BridgeConfig::from_toml_in(&text, origin).ok(),
                children.bridge.check().ok()
            );
            let (text, origin) = read("controller");
            let controller = ControllerConfig::from_toml_in(&text, origin).expect("controller");
            assert_eq!(controller, children.controller, "{text}");
            let (text, origin) = read("perception-sim");
            let perception = PerceptionConfig::from_toml_in(&text, origin).expect("perception");
            assert_eq!(perception, children.perception, "{text}");
        }
    }

    /// A launch file that is a FIFO, a device or a huge file is refused with its reason,
    /// without blocking or reading it.
    #[test]
    fn launch_files_that_are_not_regular_files_are_refused_without_reading() {
        let dir = tempfile::tempdir().expect("temp dir");
        let fifo = dir.path().join("fifo.toml");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
        let huge = dir.path().join("huge.toml");
        std::fs::File::create(&huge)
            .and_then(|f| f.set_len(2 << 30))
            .expect("a sparse file");
        for (path, reason) in [
            (fifo.as_path(), "is a FIFO, not a regular file"),
            (
                Path::new("/dev/zero"),
                "is a character device, not a regular file",
            ),
            (dir.path(), "is a directory, not a regular file"),
            (huge.as_path(), "more than the 1048576 bytes"),
        ] {
            let e = read_launch_file(path).expect_err("refused");
            let text = e.to_string();
            assert!(text.contains(reason), "{text}");
            assert!(text.starts_with("cannot read the launch file"), "{text}");
            assert!(text.ends_with("nothing was started"), "{text}");
        }
    }

    /// The launch file docs/ros2.md shows for a ROS 2 robot's world.
    fn documented_world() -> LaunchFile {
        let doc = include_str!("../../docs/ros2.md");
        let block = doc
            .split_once("<!-- launch file: ros2 world -->\n```toml\n")
            .and_then(|(_, rest)| rest.split_once("```"))
            .expect("docs/ros2.md shows the launch file")
            .0;
        LaunchFile::from_toml(block, Origin::Defaults).expect("the documented launch file parses")
    }

    /// docs/ros2.md's launch file is taken as written by a `tes` with ROS 2, and it runs the
    /// ROS 2 world in perception's place with no bridge; without ROS 2 it is refused saying
    /// how to build it in.
    #[test]
    fn the_documented_ros2_world_is_taken_or_refused_by_how_tes_was_built() {
        let file = documented_world();
        let children = file.children();
        #[cfg(feature = "ros2")]
        {
            let children = children.expect("the documented world checks");
            let world = children.ros2_world.expect("a ROS 2 world");
            assert_eq!(world.cells, [20, 20]);
            assert_eq!(world.twist[0].seconds, 1.5);
            assert_eq!(
                file.world_name(),
                "the world of a ROS 2 robot ([ros2_world])"
            );
            let dir = tempfile::tempdir().expect("temp dir");
            let mut file = file;
            file.launch.run_dir = Some(dir.path().to_owned());
            let prepared = prepare(&file).expect("prepared");
            let roles: Vec<_> = prepared.specs.iter().map(|s| s.role).collect();
            assert_eq!(roles, [Role::Controller, Role::Perception]);
            let text = std::fs::read_to_string(&prepared.specs[1].config).expect("its settings");
            assert!(crate::world::is_world_file(&text), "{text}");
            let back: tes_ros2::world::WorldFile = toml::from_str(&text).expect("its file");
            assert_eq!(back.run.episodes, 50);
            assert_eq!(
                back.run.report.as_deref(),
                Some(dir.path().join(crate::world::WORLD_REPORT).as_path())
            );
        }
        #[cfg(not(feature = "ros2"))]
        {
            let e = children.unwrap_err().to_string();
            assert!(
                e.contains("built without ROS 2") && e.contains("--features ros2"),
                "{e}"
            );
        }
    }
}
