//! The controller's per-action latency measured against the raw transport's floor (`tes bench
//! latency`).
//!
//! [`run`] runs, one after the other:
//!
//! 1. **ours** — the real group (through [`tes_launch::run`]): perception-sim on arena Env 3
//!    at the fastest real-time factor, the controller with a view library trained in Env 1
//!    and 2, the bridge with the simulated brick; the bridge records each command's latency
//!    from the observation's stamp, on arrival. With [`Via::Zenoh`] the group is split in two
//!    launches linked by Zenoh on loopback TCP;
//! 2. **the floor** ([`crate::floor`]) — the loop's payloads relayed (Observation → Command →
//!    MotorState) with the same wait strategy, no work, and the same cadence (the mean time
//!    between our actions, mostly the simulated robot moving), measured where the bridge
//!    measures: by [`crate::relay`]'s three processes over iceoryx2, or by the same two hops
//!    over the split launch's Zenoh link; at the fastest pace it runs again with every CPU
//!    kept out of its idle state ([`crate::keep_awake`]), the help the group's busy
//!    processes give each other;
//! 3. with `record` and `foxglove`, what the recorder and the live Foxglove server (with a
//!    viewer) cost the group ([`crate::recorder_cost`]).
//!
//! Both leave out the same warm-up and count overruns of the same budget. `wait` applies to
//! the two measured receivers (controller and bridge, hop and sink); perception and the
//! floor's source wait for the robot's motion by blocking, since on 2 cores three
//! busy-polling processes starve each other.
//!
//! Every process the harness starts is a program of the caller's ([`Programs`]): the
//! command line passes its own executable in each role.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use serde::Serialize;
use tes_controller::config::{ControllerConfig, Order, PlanningMode, ThreadPlacement};
use tes_controller::process::ControllerSummary;
use tes_launch::ChildCommand;
use tes_launch::event::Observer;
use tes_learning::library::store::StoredLibrary;
use tes_runtime::affinity::{self, Placement};
use tes_runtime::channel::Catches;
use tes_runtime::channel::WaitStrategy;
use tes_runtime::cpu::CpuUse;
use tes_runtime::latency::LatencyReport;

use crate::error::{BenchError, Result};
use crate::fixtures;
use crate::floor;
use crate::group::{Carrier, Group};
use crate::keep_awake::KeepAwake;
use crate::recorder_cost::{self, RecorderComparison, Watcher};

/// How the group's processes reach each other.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
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

/// The settings of a latency run (`tes bench latency`'s flags).
#[derive(Debug, Clone, PartialEq)]
pub struct LatencySettings {
    /// Actions measured (after the warm-up).
    pub actions: u64,
    /// The per-action budget, µs.
    pub budget_us: u64,
    /// How the measured receivers wait.
    pub wait: WaitStrategy,
    /// Views in the controller's library (trained in Env 1 and Env 2).
    pub views: usize,
    /// Actions run first and left out of every figure.
    pub warmup: u64,
    /// Seed of the library's training, the world and the controller.
    pub seed: u64,
    /// Keep the run's files here instead of a temporary directory.
    pub out: Option<PathBuf>,
    /// The controller's acting thread's CPU, and the floor's hop's.
    pub acting_cpu: Placement,
    /// The controller's planner thread's CPU.
    pub planner_cpu: Placement,
    /// Who plans in the controller.
    pub planning: PlanningMode,
    /// When the controller learns from an observation.
    pub order: Order,
    /// How long the planner thread polls for its next job after a plan, µs (`None`: the
    /// controller's default).
    pub planner_idle_spin_us: Option<u64>,
    /// Also compare the group with and without the recorder.
    pub record: bool,
    /// Also compare the group with and without the live Foxglove server and a viewer.
    pub foxglove: bool,
    /// Also compare the group with and without the live Foxglove server and Rerun's own
    /// viewer following it: this script (`python/tes/rerun_view.py`) run with `--live`.
    pub rerun: Option<PathBuf>,
    /// With `record`, `foxglove` or `rerun`: blocks of each kind.
    pub record_blocks: u64,
    /// How the processes reach each other.
    pub via: Via,
    /// The pace the group runs at.
    pub pace: Pace,
}

impl Default for LatencySettings {
    /// `tes bench latency`'s defaults.
    fn default() -> Self {
        Self {
            actions: 10_000,
            budget_us: tes_runtime::settings::DEFAULT_BUDGET_US,
            wait: WaitStrategy::Block,
            views: 9,
            warmup: 1000,
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
            record_blocks: 4,
            via: Via::Shm,
            pace: Pace::Fastest,
        }
    }
}

impl LatencySettings {
    /// Checks the settings once, and resolves where the controller's threads (and so the
    /// floor's hop) run on this machine. Errors name the flag.
    pub fn check(self) -> Result<CheckedLatency> {
        if self.actions == 0 || self.budget_us == 0 || self.views == 0 {
            return Err(BenchError::Settings(
                "--actions, --budget-us and --views must be at least 1".into(),
            ));
        }
        let controller = ControllerConfig {
            wait: self.wait,
            acting_cpu: self.acting_cpu,
            planner_cpu: self.planner_cpu,
            planning: self.planning,
            ..ControllerConfig::default()
        };
        let planning = controller
            .planning_for(self.wait)
            .map_err(|e| BenchError::Settings(format!("--planning: {}", e.reason)))?;
        // Resolved here, so that the floor's hop gets the acting thread's very CPU.
        let placement = controller.placement(self.wait, planning).map_err(|e| {
            BenchError::Settings(format!("--{}: {}", e.key.replace('_', "-"), e.reason))
        })?;
        if (self.record || self.foxglove || self.rerun.is_some()) && self.record_blocks == 0 {
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
    settings: LatencySettings,
    placement: ThreadPlacement,
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
        self.settings.actions + self.settings.warmup
    }

    /// How long the controller's planner thread polls after a plan, µs: the floor's helper
    /// polls as long.
    pub fn planner_idle_spin_us(&self) -> u64 {
        let s = &self.settings;
        let config = ControllerConfig {
            planner_idle_spin_us: s.planner_idle_spin_us,
            ..ControllerConfig::default()
        };
        config.planner_idle_spin(s.wait).as_micros() as u64
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
    /// The Zenoh floor's controller side; [`floor::HopSettings::args`] are added (`tes
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
            } => write!(
                f,
                "bench: ours — perception-sim → controller → bridge on Env 3, {total} actions"
            ),
            Self::Ours {
                total,
                pace: Pace::Real,
            } => write!(
                f,
                "bench: ours — perception-sim → controller → bridge on Env 3, {total} actions \
                 at the robot's pace (200 ms settle, Bluetooth-like link delay): about {} \
                 minutes, and as long again for the floor",
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
    /// How the measured receivers waited.
    pub wait: String,
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
}

impl LatencyResult {
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
fn comparable(ratio_p50: f64, ratio_p99: f64) -> bool {
    ratio_p50 >= COMPARABLE_RATIO && ratio_p99 >= COMPARABLE_RATIO
}

/// The floor measured with every CPU kept awake, and ours against it.
#[derive(Debug, Clone, Serialize)]
pub struct AwakeFloor {
    /// Observation stamped → command at the sink.
    pub round_trip: LatencyReport,
    /// Observation stamped → the hop's command published.
    pub first_hop: LatencyReport,
    /// Ours over this floor's, at the median.
    pub ratio_p50: f64,
    /// Ours over this floor's, at the 99th percentile.
    pub ratio_p99: f64,
    /// Whether this floor can be compared with (both ratios at least [`COMPARABLE_RATIO`]).
    pub comparable: bool,
}

impl AwakeFloor {
    fn against(ours: &LatencyReport, floor: Floor) -> Self {
        let (ratio_p50, ratio_p99) = (
            ratio(ours.p50_us, floor.round_trip.p50_us),
            ratio(ours.p99_us, floor.round_trip.p99_us),
        );
        Self {
            round_trip: floor.round_trip,
            first_hop: floor.first_hop,
            ratio_p50,
            ratio_p99,
            comparable: comparable(ratio_p50, ratio_p99),
        }
    }
}

/// Our group's run: the bridge's report, the controller's summary, the processes' CPU, and
/// the mean time between actions.
struct Ours {
    report: LatencyReport,
    controller: ControllerSummary,
    cpu: std::collections::BTreeMap<String, CpuUse>,
    catches: std::collections::BTreeMap<String, Catches>,
    cycle_us: u64,
}

/// What a floor measured: its round trip, its first hop, and its processes' CPU.
#[derive(Debug, Clone, PartialEq)]
pub struct Floor {
    /// Observation stamped → command at the sink.
    pub round_trip: LatencyReport,
    /// Observation stamped → the hop's command published.
    pub first_hop: LatencyReport,
    /// Each role's CPU (`source`, `hop`, `sink`; empty where not measured).
    pub cpu: std::collections::BTreeMap<String, CpuUse>,
}

/// Runs the group, then the floor, then (with `record`, `foxglove`) the observers'
/// comparisons; keeps the
/// run's files in `out` (else in a temporary directory).
pub fn run(latency: &CheckedLatency, harness: &mut Harness<'_>) -> Result<LatencyResult> {
    let s = &latency.settings;
    let temp;
    let dir: &Path = match &s.out {
        Some(d) => {
            std::fs::create_dir_all(d)
                .map_err(BenchError::io(format!("cannot create {}", d.display())))?;
            d
        }
        None => {
            temp = tempfile::tempdir()
                .map_err(BenchError::io("cannot create a temporary directory".into()))?;
            temp.path()
        }
    };
    let prefix = format!("tes-bench-{}/", std::process::id());
    (harness.notes)(&Note::Training { views: s.views });
    let library = fixtures::arena_library(s.views, 3000, s.seed).map_err(BenchError::fixture)?;
    let stored = StoredLibrary {
        library,
        world: "arena 1+2 (bench)".into(),
        action_names: Vec::new(),
        feature_names: Vec::new(),
    };
    let group = Group::new(dir, &prefix, latency, stored);
    let ours = measure_ours(latency, &group, harness)?;
    let floor = measure_floor(latency, dir, &prefix, ours.cycle_us, false, harness)?;
    // At the robot's pace both sides wake from the same idleness (that is what the pace
    // measures); back to back, the group's busy processes keep CPUs awake for each other,
    // which the bare floor lacks: it runs again with that help.
    let floor_awake = match s.pace {
        Pace::Fastest => Some(measure_floor(
            latency,
            dir,
            &prefix,
            ours.cycle_us,
            true,
            harness,
        )?),
        Pace::Real => None,
    };
    let recorder = if s.record {
        Some(recorder_cost::compare(
            &group,
            s,
            harness,
            Watcher::Recorder,
        )?)
    } else {
        None
    };
    let foxglove = if s.foxglove {
        Some(recorder_cost::compare(
            &group,
            s,
            harness,
            Watcher::Foxglove,
        )?)
    } else {
        None
    };
    let rerun = if s.rerun.is_some() {
        Some(recorder_cost::compare(&group, s, harness, Watcher::Rerun)?)
    } else {
        None
    };
    Ok(result(
        latency,
        ours,
        floor,
        floor_awake,
        [recorder, foxglove, rerun],
    ))
}

/// Runs our group (shared memory or split) and checks it measured what was asked.
fn measure_ours(
    latency: &CheckedLatency,
    group: &Group,
    harness: &mut Harness<'_>,
) -> Result<Ours> {
    let s = &latency.settings;
    let total = latency.total();
    (harness.notes)(&Note::Ours {
        total,
        pace: s.pace,
    });
    let started = Instant::now();
    let (report, controller) = match s.via {
        Via::Shm => group.run(&group.file, harness)?,
        Via::Zenoh | Via::ZenohTls => {
            group.run_split(&Carrier::for_via(s.via, &group.dir)?, harness)?
        }
    };
    let (cpu, catches) = group.cpu_and_catches(&controller)?;
    let elapsed = started.elapsed();
    if report.count < s.actions {
        return Err(BenchError::Run(format!(
            "the bridge saw {} measured commands, expected {} (see the run's files with --out)",
            report.count, s.actions
        )));
    }
    if controller.placement != latency.placement {
        return Err(BenchError::Run(format!(
            "the controller placed its threads at {:?}, not at {:?} as asked: the floor's hop would not match",
            controller.placement, latency.placement
        )));
    }
    let cycle_us = (elapsed.as_micros() / u128::from(total)) as u64;
    Ok(Ours {
        report,
        controller,
        cpu,
        catches,
        cycle_us,
    })
}

/// Runs the floor of `via` at our cadence (with `awake`, every CPU kept out of its idle
/// state, in a folder and service names of its own): its round trip, and its first hop alone.
fn measure_floor(
    latency: &CheckedLatency,
    dir: &Path,
    prefix: &str,
    cycle_us: u64,
    awake: bool,
    harness: &mut Harness<'_>,
) -> Result<Floor> {
    let s = &latency.settings;
    (harness.notes)(&Note::Floor {
        via: s.via,
        total: latency.total(),
        wait: s.wait,
        cycle_us,
        awake,
    });
    if !awake {
        return floor_of_via(latency, dir, prefix, cycle_us, harness);
    }
    let dir = dir.join("floor-awake");
    std::fs::create_dir_all(&dir)
        .map_err(BenchError::io(format!("cannot create {}", dir.display())))?;
    let _awake = KeepAwake::start(&affinity::allowed_cpus())?;
    floor_of_via(latency, &dir, &format!("{prefix}awake-"), cycle_us, harness)
}

/// The floor of `via`: a raw relay over shared memory, or the link's two hops.
fn floor_of_via(
    latency: &CheckedLatency,
    dir: &Path,
    prefix: &str,
    cycle_us: u64,
    harness: &mut Harness<'_>,
) -> Result<Floor> {
    let s = &latency.settings;
    let hop_cpu = latency.placement.acting;
    match s.via {
        Via::Shm => {
            let helps = floor::Helps {
                hop_cpu,
                helper_cpu: latency.placement.planner,
                helper_idle_spin_us: latency.planner_idle_spin_us(),
            };
            floor::relay_floor(dir, prefix, cycle_us, s, helps, &harness.programs.relay)
        }
        Via::Zenoh | Via::ZenohTls => {
            let carrier = Carrier::for_via(s.via, &dir.join("floor"))?;
            let (round_trip, first_hop) = floor::zenoh_floor(
                dir,
                cycle_us,
                s,
                hop_cpu,
                &harness.programs.floor_hop,
                &carrier,
            )?;
            Ok(Floor {
                round_trip,
                first_hop,
                cpu: Default::default(),
            })
        }
    }
}

/// Ours over the floor's (the floor at least 1 µs).
fn ratio(ours: u64, floor: u64) -> f64 {
    ours as f64 / floor.max(1) as f64
}

/// The run's result from its parts.
fn result(
    latency: &CheckedLatency,
    ours: Ours,
    floor: Floor,
    floor_awake: Option<Floor>,
    [recorder, foxglove, rerun]: [Option<RecorderComparison>; 3],
) -> LatencyResult {
    let s = &latency.settings;
    let Ours {
        report,
        controller,
        cpu,
        catches,
        cycle_us,
    } = ours;
    let Floor {
        round_trip: floor,
        first_hop: floor_decision,
        cpu: floor_cpu,
    } = floor;
    let (ratio_p50, ratio_p99) = (
        ratio(report.p50_us, floor.p50_us),
        ratio(report.p99_us, floor.p99_us),
    );
    let floor_awake = floor_awake.map(|f| AwakeFloor::against(&report, f));
    LatencyResult {
        via: s.via,
        wait: s.wait.to_string(),
        actions: report.count,
        budget_us: s.budget_us,
        views: s.views,
        p50_us: report.p50_us,
        p90_us: report.p90_us,
        p99_us: report.p99_us,
        p999_us: report.p999_us,
        max_us: report.max_us,
        misses: report.misses,
        allocations: controller.allocations,
        ipc_allocations: controller.ipc_allocations,
        decision: controller.latency,
        wake: controller.wake,
        compute: controller.compute,
        order: controller.order,
        learn: controller.learn,
        learning_overran: controller.learning_overran,
        floor_p50_us: floor.p50_us,
        floor_p90_us: floor.p90_us,
        floor_p99_us: floor.p99_us,
        floor_p999_us: floor.p999_us,
        floor_max_us: floor.max_us,
        floor_misses: floor.misses,
        floor_decision,
        ratio_p50,
        ratio_p99,
        floor_comparable: comparable(ratio_p50, ratio_p99),
        floor_awake,
        pace: s.pace,
        cpu,
        floor_cpu,
        catches,
        planner_idle_spin_us: latency.planner_idle_spin_us(),
        cycle_us,
        seed: s.seed,
        acting_cpu: latency.placement.acting,
        planner_cpu: latency.placement.planner,
        plans: controller.plans,
        planning: controller.planning,
        recorder,
        foxglove,
        rerun,
    }
}
