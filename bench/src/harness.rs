//! What the latency run and its parts share: the settings ([`LatencySettings`], checked into
//! [`CheckedLatency`]), the [`Harness`] the caller lends (its programs, stop flag and
//! observers), the [`Note`]s said on the way, and the results ([`LatencyResult`], the
//! floor's, the observers' costs). Kept below [`crate::latency`], [`crate::floor`] and
//! [`crate::recorder_cost`], which all read them, so that none of those names another back.

use serde::Serialize;
use std::fmt;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use tes_controller::config::{ControllerConfig, Order, PlanningMode, ThreadPlacement};
use tes_controller::process::ControllerSummary;
use tes_launch::ChildCommand;
use tes_launch::event::Observer;
use tes_launch::file::ChosenWait;
use tes_perception_sim::process::PerceptionConfig;
use tes_runtime::affinity::Placement;
use tes_runtime::channel::Catches;
use tes_runtime::channel::WaitStrategy;
use tes_runtime::cpu::CpuUse;
use tes_runtime::latency::LatencyReport;

use crate::error::{BenchError, Result};

/// How the group's processes reach each other.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Via {
    /// One host, shared memory (iceoryx2 only); the floor a raw iceoryx2 relay.
    #[default]
    Shm,
    /// Two launches, each in an iceoryx2 domain of its own, linked by Zenoh over loopback
    /// TCP; the floor the same two hops over a Zenoh link with no work.
    Zenoh,
    /// As [`Via::Zenoh`], over QUIC with keys of the run's own authority (TLS 1.3, both
    /// sides' certificates checked, access control by role): what a split group across hosts
    /// runs on. The floor the same, with no work.
    #[serde(rename = "zenoh-tls")]
    ZenohTls,
}

impl Via {
    /// Whether the group is split in two launches linked by Zenoh.
    pub fn is_split(self) -> bool {
        matches!(self, Via::Zenoh | Via::ZenohTls)
    }
}

/// The pace the group runs at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Pace {
    /// Actions back to back: real-time factor 0, the simulated brick 200× faster than a
    /// real one, no settle time.
    #[default]
    Fastest,
    /// The robot's own: real-time factor 1 (the paper's 200 ms settle after each motion, the
    /// simulated brick in real time) and a Bluetooth link's delay on every reply (30 ± 10
    /// ms), about 0.8 s per action, in which every CPU goes idle.
    Real,
}

impl Pace {
    /// Actions measured by default: at the robot's pace ~14 minutes a side.
    pub fn default_actions(self) -> u64 {
        match self {
            Self::Fastest => 10_000,
            Self::Real => 1_000,
        }
    }

    /// Actions run first and left out, by default.
    pub fn default_warmup(self) -> u64 {
        match self {
            Self::Fastest => 1_000,
            Self::Real => 50,
        }
    }
}

impl fmt::Display for Pace {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Fastest => "fastest",
            Self::Real => "real",
        })
    }
}

/// The link delay of the robot's pace: a real NXT's Bluetooth, per reply.
pub const REAL_LINK_DELAY_MS: (u64, u64) = (30, 10);

/// The settings of a latency run: `tes bench latency`'s flags, each defined here once (its
/// help from its doc, its default from [`LatencySettings::default`]).
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct LatencySettings {
    /// Actions measured (after the warm-up); `None`: the pace's
    /// ([`Pace::default_actions`]).
    #[arg(long, help = pace_default("Actions measured (after the warm-up)", Pace::default_actions))]
    pub actions: Option<u64>,
    /// The per-action budget, µs.
    #[arg(long, default_value_t = LatencySettings::default().budget_us)]
    pub budget_us: u64,
    /// How every process waits: auto (the controller and the bridge anticipate at the
    /// robot's pace, where perception announces each observation, and block at the fastest),
    /// block, spin, spin-then-block, spin-then-block:<µs> or anticipate. The floor's hop and
    /// sink wait as the controller and the bridge do.
    #[arg(long, default_value_t = LatencySettings::default().wait)]
    pub wait: WaitStrategy,
    /// Views in the controller's library (trained in Env 1 and Env 2).
    #[arg(long, default_value_t = LatencySettings::default().views)]
    pub views: usize,
    /// Actions run first and left out of every figure; `None`: the pace's
    /// ([`Pace::default_warmup`]).
    #[arg(long, help = pace_default("Actions run first and left out of every figure", Pace::default_warmup))]
    pub warmup: Option<u64>,
    /// Seed of the library's training, the world and the controller.
    #[arg(long, default_value_t = LatencySettings::default().seed)]
    pub seed: u64,
    /// Keep the run's files (library, settings, raw reports) here instead of a temporary
    /// directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The controller's acting thread's CPU — a number, auto or none — and the floor's hop
    /// (its place in the relay) is pinned the same way, so both paths run with the same
    /// placement. auto: with --wait block, the last allowed CPU (the controller's default)
    #[arg(long, default_value_t = LatencySettings::default().acting_cpu)]
    pub acting_cpu: Placement,
    /// The controller's planner thread's CPU — a number, auto or none. auto: the first
    /// allowed CPU other than the acting thread's, where that is pinned
    #[arg(long, default_value_t = LatencySettings::default().planner_cpu)]
    pub planner_cpu: Placement,
    /// Who plans in the controller: thread, between-polls (the acting thread, in slices,
    /// while it spins) or auto (between-polls with --wait spin, else thread).
    #[arg(long, default_value_t = LatencySettings::default().planning)]
    pub planning: PlanningMode,
    /// When the controller learns from an observation: decide-first (after publishing the
    /// command) or learn-first (before deciding, the older order, for a before/after
    /// comparison in one build).
    #[arg(long, default_value_t = LatencySettings::default().order)]
    pub order: Order,
    /// How long the controller's planner thread polls for its next job after a plan, µs
    /// (the floor's helper thread polls as long) [default: the controller's, 5000 with a
    /// spinning wait, else 0].
    #[arg(long)]
    pub planner_idle_spin_us: Option<u64>,
    /// Also compare the group with and without the recorder (`tes launch --record`): after
    /// the main run and the floor, blocks of each kind alternate (without, with, with,
    /// without, …), each from the same library, and the medians over the blocks are compared.
    #[arg(long)]
    pub record: bool,
    /// Also compare the group with and without the live Foxglove server (`tes launch
    /// --foxglove`) and a viewer subscribed to every channel, in alternating blocks as
    /// `--record`'s.
    #[arg(long)]
    pub foxglove: bool,
    /// Also compare the group with and without the live Foxglove server followed by Rerun's
    /// own viewer (`python3 SCRIPT --live ADDR -o FILE.rrd`, SCRIPT being
    /// `python/tes/rerun_view.py`; needs rerun-sdk, mcap and websockets), in alternating
    /// blocks as `--record`'s.
    #[arg(long, value_name = "SCRIPT")]
    pub rerun: Option<PathBuf>,
    /// Also compare the group with and without its ROS 2 side (`tes launch --ros2`: a DDS
    /// node publishing the run, in the domain of `ROS_DOMAIN_ID`), in alternating blocks as
    /// `--record`'s. Needs a tes built with `--features ros2`.
    #[arg(long)]
    pub ros2: bool,
    /// With `--record`, `--foxglove`, `--rerun` or `--ros2`: blocks of each kind; each measures
    /// `--actions / N` actions after the warm-up.
    #[arg(long, default_value_t = LatencySettings::default().record_blocks, value_name = "N")]
    pub record_blocks: u64,
    /// How the processes reach each other: shm (one host, iceoryx2 only; the floor a raw
    /// iceoryx2 relay) or zenoh (the group split in two launches, perception-sim and bridge
    /// in one, the controller in the other, each in an iceoryx2 domain of its own, linked by
    /// Zenoh over loopback TCP; the floor the same two hops over a Zenoh link with no work).
    #[arg(long, value_enum, default_value_t = LatencySettings::default().via)]
    pub via: Via,
    /// The pace the group runs at: fastest (actions back to back) or real (the robot's own:
    /// the paper's 200 ms settle after each motion, the simulated brick in real time, and a
    /// Bluetooth-like 30 ± 10 ms delay on each of its replies — about 0.8 s per action, so
    /// the default 1000 actions take some 14 minutes, and as long again for the floor). The
    /// floor runs at the group's measured cadence either way.
    #[arg(long, value_enum, default_value_t = LatencySettings::default().pace)]
    pub pace: Pace,
}

/// A pace-dependent flag's help: `what`, and its default at each pace, from `default`.
fn pace_default(what: &str, default: fn(Pace) -> u64) -> String {
    format!(
        "{what} [default: {} at the fastest pace, {} at the robot's]",
        default(Pace::Fastest),
        default(Pace::Real)
    )
}

impl Default for LatencySettings {
    /// `tes bench latency`'s defaults.
    fn default() -> Self {
        Self {
            actions: None,
            budget_us: tes_runtime::settings::DEFAULT_BUDGET_US,
            wait: WaitStrategy::Auto,
            views: 9,
            warmup: None,
            seed: 1,
            out: None,
            acting_cpu: Placement::Auto,
            planner_cpu: Placement::Auto,
            planning: PlanningMode::Auto,
            order: Order::DecideFirst,
            planner_idle_spin_us: None,
            record: false,
            foxglove: false,
            rerun: None,
            ros2: false,
            record_blocks: 4,
            via: Via::Shm,
            pace: Pace::Fastest,
        }
    }
}

impl LatencySettings {
    /// Actions measured (after the warm-up): the given number, or the pace's.
    pub fn actions(&self) -> u64 {
        self.actions.unwrap_or(self.pace.default_actions())
    }

    /// Actions run first and left out: the given number, or the pace's.
    pub fn warmup(&self) -> u64 {
        self.warmup.unwrap_or(self.pace.default_warmup())
    }

    /// How `wait` comes out for the controller at this pace: the launch's own choice
    /// ([`ChosenWait`]), with perception's default settle time.
    pub fn chosen_wait(&self) -> ChosenWait {
        let real_time_factor = match self.pace {
            Pace::Fastest => 0.0,
            Pace::Real => 1.0,
        };
        // Split, the controller's launch runs without perception, whose heads-ups stay on
        // the robot's side.
        ChosenWait::new(
            self.wait,
            real_time_factor,
            PerceptionConfig::default().settle_ms,
            !self.via.is_split(),
        )
    }

    /// How the measured receivers wait (the controller and the bridge, the floor's hop and
    /// sink): `wait`, with `auto` resolved.
    pub fn acting_wait(&self) -> WaitStrategy {
        self.chosen_wait().acting()
    }

    /// Checks the settings once, and resolves where the controller's threads (and so the
    /// floor's hop) run on this machine. Errors name the flag.
    pub fn check(self) -> Result<CheckedLatency> {
        if self.actions() == 0 || self.budget_us == 0 || self.views == 0 {
            return Err(BenchError::Settings(
                "--actions, --budget-us and --views must be at least 1".into(),
            ));
        }
        let wait = self.acting_wait();
        let controller = ControllerConfig {
            wait,
            acting_cpu: self.acting_cpu,
            planner_cpu: self.planner_cpu,
            planning: self.planning,
            ..ControllerConfig::default()
        };
        let planning = controller
            .planning_for(wait)
            .map_err(|e| BenchError::Settings(format!("--planning: {}", e.reason)))?;
        // Resolved here, so that the floor's hop gets the acting thread's very CPU.
        let placement = controller.placement(wait, planning).map_err(|e| {
            BenchError::Settings(format!("--{}: {}", e.key.replace('_', "-"), e.reason))
        })?;
        if (self.record || self.foxglove || self.rerun.is_some() || self.ros2)
            && self.record_blocks == 0
        {
            return Err(BenchError::Settings(
                "--record-blocks must be at least 1".into(),
            ));
        }
        Ok(CheckedLatency {
            settings: self,
            placement,
        })
    }
}

/// [`LatencySettings`] that passed [`LatencySettings::check`], with the threads' placement.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedLatency {
    pub(crate) settings: LatencySettings,
    pub(crate) placement: ThreadPlacement,
}

impl CheckedLatency {
    /// The settings.
    pub fn settings(&self) -> &LatencySettings {
        &self.settings
    }

    /// Where the controller's threads run (CPUs or unpinned), the floor's hop with the
    /// acting thread.
    pub fn placement(&self) -> ThreadPlacement {
        self.placement
    }

    /// Actions in all, warm-up included.
    pub fn total(&self) -> u64 {
        self.settings.actions() + self.settings.warmup()
    }

    /// How long the controller's planner thread polls after a plan, µs: the floor's helper
    /// polls as long.
    pub fn planner_idle_spin_us(&self) -> u64 {
        let s = &self.settings;
        let config = ControllerConfig {
            planner_idle_spin_us: s.planner_idle_spin_us,
            ..ControllerConfig::default()
        };
        config.planner_idle_spin(s.acting_wait()).as_micros() as u64
    }
}

/// The programs the harness starts: the command line's own executable in each role.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Programs {
    /// The group's children; the supervisor adds `ROLE --config FILE` (`tes child`).
    pub child: ChildCommand,
    /// A launch of its own, the split run's second; `--config FILE` is added (`tes launch`).
    pub launch: ChildCommand,
    /// The floor relay's processes; `ROLE --config FILE` is added (`tes bench relay`).
    pub relay: ChildCommand,
    /// The Zenoh floor's controller side; [`crate::floor::HopSettings::args`] are added (`tes
    /// bench zenoh-floor-hop`).
    pub floor_hop: ChildCommand,
}

/// What the harness needs from its caller: the programs it starts, the stop flag, and where
/// it tells what happens.
pub struct Harness<'a> {
    /// The programs.
    pub programs: Programs,
    /// Raised (by a signal handler), a running group stops.
    pub stop: Arc<AtomicBool>,
    /// Takes every event of every launch of the group.
    pub observer: &'a mut dyn Observer,
    /// Takes the harness's progress.
    pub notes: &'a mut dyn FnMut(&Note),
}

/// The harness's progress, said as a line by its [`fmt::Display`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Note {
    /// The controller's starting library is being trained.
    Training {
        /// Its views.
        views: usize,
    },
    /// Our group runs.
    Ours {
        /// Actions, warm-up included.
        total: u64,
        /// At which pace.
        pace: Pace,
        /// How its processes wait, and why.
        wait: ChosenWait,
    },
    /// The floor runs.
    Floor {
        /// Which floor.
        via: Via,
        /// Round trips, warm-up included.
        total: u64,
        /// How its receivers wait.
        wait: WaitStrategy,
        /// One round trip every this many µs.
        cycle_us: u64,
        /// Whether every CPU is kept awake while it runs ([`crate::keep_awake`]).
        awake: bool,
    },
    /// A block of an observer's comparison runs.
    RecorderBlock {
        /// Its number, from 1.
        block: u64,
        /// Blocks in all.
        of: u64,
        /// Whether the observer runs.
        recorded: bool,
        /// Which observer.
        watcher: Watcher,
        /// Actions measured.
        measured: u64,
    },
}

impl fmt::Display for Note {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Training { views } => write!(
                f,
                "bench: training a {views}-view library in Env 1 and Env 2"
            ),
            Self::Ours {
                total,
                pace: Pace::Fastest,
                wait,
            } => write!(
                f,
                "bench: ours — perception-sim → controller → bridge on Env 3, {total} actions, \
                 wait {wait}"
            ),
            Self::Ours {
                total,
                pace: Pace::Real,
                wait,
            } => write!(
                f,
                "bench: ours — perception-sim → controller → bridge on Env 3, {total} actions \
                 at the robot's pace (200 ms settle, Bluetooth-like link delay), wait {wait}: \
                 about {} minutes, and as long again for the floor",
                (total * 800).div_ceil(60_000)
            ),
            Self::Floor {
                via,
                total,
                wait,
                cycle_us,
                awake,
            } => {
                let kind = match via {
                    Via::Shm => "a raw iceoryx2 two-hop relay",
                    Via::Zenoh => {
                        "the same two hops through the split launch's own Zenoh link on \
                         loopback TCP, with no work"
                    }
                    Via::ZenohTls => {
                        "the same two hops through the split launch's own Zenoh link over \
                         QUIC with the run's keys, on loopback, with no work"
                    }
                };
                write!(
                    f,
                    "bench: the floor — {kind}, {total} round trips, wait {wait}, one every \
                     {cycle_us} us{}",
                    if *awake {
                        ", every CPU kept awake by a SCHED_IDLE spinner"
                    } else {
                        ""
                    }
                )
            }
            Self::RecorderBlock {
                block,
                of,
                recorded,
                watcher,
                measured,
            } => write!(
                f,
                "bench: {} comparison, block {block} of {of}: {} the {}, {measured} actions",
                watcher.name(),
                if *recorded { "with" } else { "without" },
                match watcher {
                    Watcher::Recorder => "recorder",
                    Watcher::Foxglove => "Foxglove server and a viewer",
                    Watcher::Rerun => "Foxglove server and Rerun's viewer",
                    Watcher::Ros2 => "ROS 2 node",
                }
            ),
        }
    }
}

/// What a latency run measured (`tes bench latency --json` prints it).
#[derive(Debug, Clone, Serialize)]
pub struct LatencyResult {
    /// How the processes reached each other: `shm` or `zenoh`.
    pub via: Via,
    /// `--wait` as given (`auto` by default).
    pub wait: String,
    /// How the measured receivers waited (the controller and the bridge, the floor's hop and
    /// sink): `wait`, with `auto` resolved.
    pub wait_chosen: String,
    /// Actions measured.
    pub actions: u64,
    /// The per-action budget, µs.
    pub budget_us: u64,
    /// Views in the starting library.
    pub views: usize,
    /// Observation → bridge, median, µs.
    pub p50_us: u64,
    /// Observation → bridge, 90th percentile, µs.
    pub p90_us: u64,
    /// Observation → bridge, 99th percentile, µs.
    pub p99_us: u64,
    /// Observation → bridge, 99.9th percentile, µs.
    pub p999_us: u64,
    /// Observation → bridge, the most, µs.
    pub max_us: u64,
    /// Actions over the budget.
    pub misses: u64,
    /// Heap allocations on the controller's acting path (null if not counted).
    pub allocations: Option<u64>,
    /// Of those, the ones inside iceoryx2 sending the command.
    pub ipc_allocations: Option<u64>,
    /// The controller's own decision latency (observation stamped → command published).
    pub decision: LatencyReport,
    /// Its first part: observation stamped → received by the controller's acting loop.
    pub wake: LatencyReport,
    /// Its second part: observation received → command published (the acting path's work).
    pub compute: LatencyReport,
    /// When the controller learned: `decide-first` or `learn-first`.
    pub order: String,
    /// Deciding first, the learning after each command (command published → views scored and
    /// updated, the planner handed the model).
    pub learn: LatencyReport,
    /// Observations published before the previous learning had finished (they waited for it).
    pub learning_overran: u64,
    /// The floor's round trip, median, µs.
    pub floor_p50_us: u64,
    /// The floor's round trip, 90th percentile, µs.
    pub floor_p90_us: u64,
    /// The floor's round trip, 99th percentile, µs.
    pub floor_p99_us: u64,
    /// The floor's round trip, 99.9th percentile, µs.
    pub floor_p999_us: u64,
    /// The floor's round trip, the most, µs.
    pub floor_max_us: u64,
    /// The floor's round trips over the budget.
    pub floor_misses: u64,
    /// The floor's first hop alone (observation stamped → the hop's command published): the
    /// counterpart of `decision` with no work.
    pub floor_decision: LatencyReport,
    /// Ours' second hop: the command published → received by the bridge (its wake-up).
    pub command_hop: LatencyReport,
    /// The floor's second hop: the hop's command published → received at the sink (empty
    /// over Zenoh).
    pub floor_second_hop: LatencyReport,
    /// Ours over the floor's, at the median.
    pub ratio_p50: f64,
    /// Ours over the floor's, at the 99th percentile.
    pub ratio_p99: f64,
    /// Whether the floor can be compared with: a ratio below [`COMPARABLE_RATIO`] means the
    /// group had a help the floor lacked, not that it beat its transport.
    pub floor_comparable: bool,
    /// At the fastest pace, the floor again with every CPU kept out of its idle state
    /// ([`crate::keep_awake`]): the help a group's busy processes give each other, given to
    /// the floor (null at the robot's pace, where both sides wake from the same idleness).
    pub floor_awake: Option<AwakeFloor>,
    /// The pace the group ran at: `fastest` or `real`.
    pub pace: Pace,
    /// Each process's CPU over the measured actions, by name (`perception-sim`,
    /// `controller`, `bridge`), and the controller's acting thread alone
    /// (`controller/acting`).
    pub cpu: std::collections::BTreeMap<String, CpuUse>,
    /// The floor's processes' (`source`, `hop`, `sink`; empty over Zenoh).
    pub floor_cpu: std::collections::BTreeMap<String, CpuUse>,
    /// Waiting by `anticipate`: how observations came against the controller's poll
    /// windows, and commands against the bridge's.
    pub catches: std::collections::BTreeMap<String, Catches>,
    /// How long the planner thread polled after each plan, µs.
    pub planner_idle_spin_us: u64,
    /// Mean time between actions in our run, which the floor's source kept too, µs.
    pub cycle_us: u64,
    /// The seed.
    pub seed: u64,
    /// The controller's acting thread's CPU, and the floor's hop's (null: unpinned).
    pub acting_cpu: Option<usize>,
    /// The controller's planner thread's CPU (null: unpinned).
    pub planner_cpu: Option<usize>,
    /// Plans the controller's planner finished and the acting loop adopted.
    pub plans: u64,
    /// Who planned: `thread` or `between-polls`.
    pub planning: String,
    /// With `record`: the group with and without the recorder, in alternating blocks (null
    /// without).
    pub recorder: Option<RecorderComparison>,
    /// With `foxglove`: the group with and without the live Foxglove server and a viewer
    /// reading every channel, in alternating blocks (null without).
    pub foxglove: Option<RecorderComparison>,
    /// With `rerun`: the group with and without the live Foxglove server and Rerun's own
    /// viewer following it (`rerun_view.py --live`), in alternating blocks (null without).
    pub rerun: Option<RecorderComparison>,
    /// With `ros2`: the group with and without its ROS 2 side publishing the run on DDS, in
    /// alternating blocks (null without).
    pub ros2: Option<RecorderComparison>,
}

impl LatencyResult {
    /// The observers' comparisons this run made (recorder, Foxglove, Rerun, ROS 2), in that
    /// order.
    pub fn observers(&self) -> impl Iterator<Item = &RecorderComparison> {
        [&self.recorder, &self.foxglove, &self.rerun, &self.ros2]
            .into_iter()
            .flatten()
    }

    /// Ours, observation → bridge, as a report (the run's own fields).
    pub fn ours(&self) -> LatencyReport {
        LatencyReport {
            count: self.actions,
            p50_us: self.p50_us,
            p90_us: self.p90_us,
            p99_us: self.p99_us,
            p999_us: self.p999_us,
            max_us: self.max_us,
            misses: self.misses,
            ..LatencyReport::default()
        }
    }

    /// The floor's round trip, as a report (the run's own fields).
    pub fn floor(&self) -> LatencyReport {
        LatencyReport {
            p50_us: self.floor_p50_us,
            p90_us: self.floor_p90_us,
            p99_us: self.floor_p99_us,
            p999_us: self.floor_p999_us,
            max_us: self.floor_max_us,
            misses: self.floor_misses,
            ..LatencyReport::default()
        }
    }
}

/// Ours over the floor's below this, at the median or the 99th percentile, and the floor is
/// not comparable.
pub const COMPARABLE_RATIO: f64 = 0.9;

/// Whether a floor with these ratios (ours over the floor's) can be compared with.
pub(crate) fn comparable(ratio_p50: f64, ratio_p99: f64) -> bool {
    ratio_p50 >= COMPARABLE_RATIO && ratio_p99 >= COMPARABLE_RATIO
}

/// The floor measured with every CPU kept awake, and ours against it.
#[derive(Debug, Clone, Serialize)]
pub struct AwakeFloor {
    /// Observation stamped → command at the sink.
    pub round_trip: LatencyReport,
    /// Observation stamped → the hop's command published.
    pub first_hop: LatencyReport,
    /// The hop's command published → received at the sink.
    pub second_hop: LatencyReport,
    /// Ours over this floor's, at the median.
    pub ratio_p50: f64,
    /// Ours over this floor's, at the 99th percentile.
    pub ratio_p99: f64,
    /// Whether this floor can be compared with (both ratios at least [`COMPARABLE_RATIO`]).
    pub comparable: bool,
}

impl AwakeFloor {
    pub(crate) fn against(ours: &LatencyReport, floor: Floor) -> Self {
        let (ratio_p50, ratio_p99) = (
            ratio(ours.p50_us, floor.round_trip.p50_us),
            ratio(ours.p99_us, floor.round_trip.p99_us),
        );
        Self {
            round_trip: floor.round_trip,
            first_hop: floor.first_hop,
            second_hop: floor.second_hop,
            ratio_p50,
            ratio_p99,
            comparable: comparable(ratio_p50, ratio_p99),
        }
    }
}

/// Our group's run: the bridge's report, the controller's summary, the processes' CPU, and
/// the mean time between actions.
pub(crate) struct Ours {
    pub(crate) report: LatencyReport,
    pub(crate) controller: ControllerSummary,
    pub(crate) cpu: std::collections::BTreeMap<String, CpuUse>,
    pub(crate) catches: std::collections::BTreeMap<String, Catches>,
    pub(crate) command_hop: LatencyReport,
    pub(crate) cycle_us: u64,
}

/// What a floor measured: its round trip, its first hop, and its processes' CPU.
#[derive(Debug, Clone, PartialEq)]
pub struct Floor {
    /// Observation stamped → command at the sink.
    pub round_trip: LatencyReport,
    /// Observation stamped → the hop's command published.
    pub first_hop: LatencyReport,
    /// The hop's command published → received at the sink (empty over Zenoh, where the
    /// link's hops are not timed apart).
    pub second_hop: LatencyReport,
    /// Each role's CPU (`source`, `hop`, `sink`; empty where not measured).
    pub cpu: std::collections::BTreeMap<String, CpuUse>,
    /// How the hop's observations came against its poll windows, when it anticipated them.
    pub hop_catches: Option<Catches>,
}

/// The observer a comparison switches on and off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Watcher {
    /// The launcher's recorder writing the run to MCAP (its drawings for viewers included).
    Recorder,
    /// The launcher's live Foxglove server, with a viewer subscribed to every channel.
    Foxglove,
    /// The launcher's live Foxglove server, followed by Rerun's own viewer
    /// (`rerun_view.py --live`, logging every drawing through rerun-sdk).
    Rerun,
    /// The launcher's ROS 2 side (`tes launch --ros2`), publishing the run on DDS.
    Ros2,
}

impl Watcher {
    /// As the tables name it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Recorder => "recorder",
            Self::Foxglove => "Foxglove server",
            Self::Rerun => "Rerun viewer",
            Self::Ros2 => "ROS 2 node",
        }
    }
}

/// One block of the comparison: a run of the group from the starting library, with or
/// without the observer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct RecorderBlock {
    /// Whether the observer ran (the recorder, or the Foxglove server and its viewer).
    pub recorded: bool,
    /// Observation → bridge, median, µs.
    pub p50_us: u64,
    /// Observation → bridge, 99th percentile, µs.
    pub p99_us: u64,
    /// Actions over the budget.
    pub misses: u64,
    /// Heap allocations on the controller's acting path (null if not counted).
    pub allocations: Option<u64>,
    /// With the recorder: the observations, commands and motor states it wrote.
    pub written: Option<[u64; 3]>,
    /// With the recorder: the samples it could not take in time.
    pub missed: Option<u64>,
    /// With the Foxglove server: the messages its viewer received.
    pub viewer_messages: Option<u64>,
}

/// An observer's cost as the medians over blocks of each kind.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecorderComparison {
    /// The observer compared.
    pub watcher: Watcher,
    /// In the order they ran.
    pub blocks: Vec<RecorderBlock>,
    /// Median over the blocks without the recorder of their p50, µs.
    pub without_p50_us: f64,
    /// Median over the blocks without the recorder of their p99, µs.
    pub without_p99_us: f64,
    /// Median over the blocks with the recorder of their p50, µs.
    pub with_p50_us: f64,
    /// Median over the blocks with the recorder of their p99, µs.
    pub with_p99_us: f64,
    /// `with / without − 1` of the p50 medians (0.05 = 5 % slower with the recorder).
    pub change_p50: f64,
    /// `with / without − 1` of the p99 medians.
    pub change_p99: f64,
    /// The most allocations any block counted on the acting path with the recorder.
    pub allocations_with: Option<u64>,
}

/// Ours over the floor's (the floor at least 1 µs).
pub(crate) fn ratio(ours: u64, floor: u64) -> f64 {
    ours as f64 / floor.max(1) as f64
}

#[cfg(test)]
mod tests {
    use clap::{Args, Command, FromArgMatches};

    use super::*;
    use crate::scaling::ScalingSettings;

    fn parse<T: Args + FromArgMatches>(args: &[&str]) -> Result<T, clap::Error> {
        let matches = T::augment_args(Command::new("bench"))
            .try_get_matches_from(std::iter::once("bench").chain(args.iter().copied()))?;
        T::from_arg_matches(&matches)
    }

    /// The flags are the settings' fields: no flag is the settings' `Default`, and every
    /// default the help prints is that `Default`'s value.
    #[test]
    fn no_flag_is_the_default_settings_and_the_help_prints_their_values() {
        assert_eq!(
            parse::<LatencySettings>(&[]).unwrap(),
            LatencySettings::default()
        );
        assert_eq!(
            parse::<ScalingSettings>(&[]).unwrap(),
            ScalingSettings::default()
        );
        let help = LatencySettings::augment_args(Command::new("bench"))
            .render_help()
            .to_string();
        let d = LatencySettings::default();
        for said in [
            format!("[default: {}]", d.budget_us),
            format!("[default: {}]", d.wait),
            format!("[default: {}]", d.acting_cpu),
            format!("[default: {}]", d.planning),
            format!("[default: {}]", d.order),
            format!("[default: {}]", d.record_blocks),
            format!(
                "[default: {} at the fastest pace, {} at the robot's]",
                Pace::Fastest.default_actions(),
                Pace::Real.default_actions()
            ),
        ] {
            assert!(help.contains(&said), "{said} in {help}");
        }
    }

    #[test]
    fn the_pace_decides_the_unset_counts_and_a_bad_value_names_its_flag() {
        let real: LatencySettings = parse(&["--pace", "real", "--via", "zenoh-tls"]).unwrap();
        assert_eq!((real.actions(), real.warmup()), (1000, 50));
        assert_eq!(real.via, Via::ZenohTls);
        let given: LatencySettings = parse(&["--actions", "7", "--wait", "spin"]).unwrap();
        assert_eq!((given.actions(), given.warmup()), (7, 1000));
        assert_eq!(given.wait, WaitStrategy::Spin);
        let err = parse::<LatencySettings>(&["--planning", "sometimes"]).unwrap_err();
        assert!(err.to_string().contains("--planning"), "{err}");
    }
}
