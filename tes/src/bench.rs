//! `tes bench latency` and `tes bench scaling`: the controller's per-action latency measured
//! against the raw iceoryx2 floor, and how a decision's cost grows with features and views.
//!
//! `latency` runs, one after the other in the same invocation:
//!
//! 1. **ours** — the real group (`tes launch` machinery): perception-sim on arena Env 3 at the
//!    fastest real-time factor, the controller with a view library trained in Env 1 and 2,
//!    the bridge with the simulated brick; the bridge records each command's latency from
//!    the observation's stamp, on arrival;
//! 2. **the floor** — [`tes_bench::relay`]: three processes relaying the loop's payloads
//!    (Observation → Command → MotorState) with the same wait strategy, no work, and the
//!    same cadence (the mean time between our actions, mostly the simulated robot moving),
//!    measured where the bridge measures.
//!
//! Both leave out the same warm-up and count overruns of the same budget. `--wait` applies to
//! the two measured receivers (controller and bridge, hop and sink); perception and the
//! floor's source wait for the robot's motion by blocking, since on 2 cores three
//! busy-polling processes starve each other. The controller also reports its own decision
//! latency and the heap allocations on its acting path.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use serde::Serialize;
use tes_bench::relay::{self, RelayConfig};
use tes_bench::{fixtures, scaling};
use tes_controller::config::{ControllerConfig, Order, PlanningMode, ThreadPlacement};
use tes_controller::process::ControllerSummary;
use tes_learning::library::store::{self, StoredLibrary};
use tes_runtime::affinity::Placement;
use tes_runtime::channel::WaitStrategy;
use tes_runtime::latency::LatencyReport;
use tes_topics::Role;

use tes_launch::children::{self, ChildCommand, Process};
use tes_launch::{LaunchFile, LaunchSection};

/// Arguments of `tes bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchCommand,
}

#[derive(Debug, Subcommand)]
enum BenchCommand {
    /// End-to-end per-action latency (observation published → command at the bridge) of the
    /// real process group, against a raw iceoryx2 relay measured in the same run.
    Latency(LatencyArgs),
    /// Decision time in process against feature count (52-5000) and library size (1-20).
    Scaling(ScalingArgs),
    /// The controller's side of `latency --via zenoh`'s floor, in a process of its own, as
    /// the controller's launch is in the measured run (started by `latency`, not by hand).
    #[command(hide = true)]
    ZenohFloorHop(FloorHopArgs),
    /// One process of the floor's relay (started by `latency`, not by hand).
    #[command(hide = true)]
    Relay {
        /// relay-source, relay-hop or relay-sink.
        role: String,
        /// Its settings (TOML).
        #[arg(long)]
        config: PathBuf,
    },
}

/// Arguments of the floor's controller side (`tes bench zenoh-floor-hop`).
#[derive(Debug, Args)]
pub struct FloorHopArgs {
    /// The robot side's endpoint.
    #[arg(long)]
    connect: String,
    /// The link's group.
    #[arg(long)]
    group: String,
    /// This side's service-name prefix.
    #[arg(long)]
    prefix: String,
    /// How the hop waits for an observation.
    #[arg(long)]
    wait: String,
    /// The CPU the hop runs on.
    #[arg(long)]
    hop_cpu: Option<usize>,
    /// Observations answered (warm-up included) before the hop stops.
    #[arg(long)]
    answer: u64,
    /// Of those, the first left out of the report.
    #[arg(long)]
    warmup: u64,
    /// The per-action budget, µs.
    #[arg(long)]
    budget_us: u64,
    /// Where the first hop's report goes.
    #[arg(long)]
    report: PathBuf,
}

/// Arguments of `tes bench latency`.
#[derive(Debug, Args)]
pub struct LatencyArgs {
    /// Actions measured (after the warm-up).
    #[arg(long, default_value_t = 10_000)]
    actions: u64,
    /// The per-action budget, µs.
    #[arg(long, default_value_t = 1000)]
    budget_us: u64,
    /// How every process waits: block, spin, spin-then-block or spin-then-block:<µs>.
    #[arg(long, default_value = "block")]
    wait: String,
    /// Views in the controller's library (trained in Env 1 and Env 2).
    #[arg(long, default_value_t = 9)]
    views: usize,
    /// Actions run first and left out of every figure.
    #[arg(long, default_value_t = 1000)]
    warmup: u64,
    /// Seed of the library's training, the world and the controller.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Keep the run's files (library, settings, raw reports) here instead of a temporary
    /// directory.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// The controller's acting thread's CPU — a number, auto or none — and the floor's hop
    /// (its place in the relay) is pinned the same way, so both paths run with the same
    /// placement. auto: with --wait block, the last allowed CPU (the controller's default)
    #[arg(long, default_value = "auto")]
    acting_cpu: Placement,
    /// The controller's planner thread's CPU — a number, auto or none. auto: the first
    /// allowed CPU other than the acting thread's, where that is pinned
    #[arg(long, default_value = "auto")]
    planner_cpu: Placement,
    /// Who plans in the controller: thread or between-polls (the acting thread, in slices,
    /// while it spins) [default: between-polls with --wait spin, else thread].
    #[arg(long)]
    planning: Option<String>,
    /// When the controller learns from an observation: decide-first (after publishing the
    /// command; the default) or learn-first (before deciding, the older order, for a
    /// before/after comparison in one build).
    #[arg(long, default_value = "decide-first")]
    order: Order,
    /// How long the controller's planner thread polls for its next job after a plan, µs
    /// [default: the controller's, 5000; 0 = sleeps at once].
    #[arg(long)]
    planner_idle_spin_us: Option<u64>,
    /// Also compare the group with and without the recorder (`tes launch --record`): after
    /// the main run and the floor, blocks of each kind alternate (without, with, with,
    /// without, …), each from the same library, and the medians over the blocks are compared.
    #[arg(long)]
    record: bool,
    /// With `--record`: blocks of each kind; each measures `--actions / N` actions after the
    /// warm-up.
    #[arg(long, default_value_t = 4, value_name = "N")]
    record_blocks: u64,
    /// How the processes reach each other: shm (one host, iceoryx2 only; the floor a raw
    /// iceoryx2 relay) or zenoh (the group split in two launches, perception-sim and bridge
    /// in one, the controller in the other, each in an iceoryx2 domain of its own, linked by
    /// Zenoh over loopback TCP; the floor the same two hops over a Zenoh link with no work).
    #[arg(long, value_enum, default_value = "shm")]
    via: Via,
}

/// `tes bench latency --via`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Via {
    /// One host, shared memory.
    Shm,
    /// Two launches linked by Zenoh.
    Zenoh,
}

/// Arguments of `tes bench scaling`.
#[derive(Debug, Args)]
pub struct ScalingArgs {
    /// Decisions measured per point (after the warm-up).
    #[arg(long, default_value_t = 5000)]
    actions: u64,
    /// Decisions run first at each point and left out.
    #[arg(long, default_value_t = 500)]
    warmup: u64,
    /// Seed of the structures, libraries and steps.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write scaling.json, scaling.csv and the two SVG charts here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// The acting loop's order: decide-first (the decision and the learning timed apart) or
    /// learn-first (the older order: the decision includes the learning).
    #[arg(long, default_value = "decide-first")]
    order: Order,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

/// Runs `tes bench …`.
pub fn run(args: &BenchArgs) -> Result<()> {
    match &args.what {
        BenchCommand::Latency(a) => latency(a),
        BenchCommand::Scaling(a) => scaling_sweep(a),
        BenchCommand::ZenohFloorHop(a) => zenoh_floor_hop(a),
        BenchCommand::Relay { role, config } => run_relay(role, config),
    }
}

/// One process of the floor's relay.
fn run_relay(role: &str, config: &Path) -> Result<()> {
    tes_runtime::logging::init("warn");
    let text = std::fs::read_to_string(config)
        .with_context(|| format!("cannot read {}", config.display()))?;
    let origin = tes_runtime::settings::Origin::File(config.to_owned());
    let cfg = RelayConfig::from_toml_in(&text, origin)?;
    let stop = tes_runtime::signals::stop_on_signals()?;
    relay::run(role, &cfg, &stop)?;
    Ok(())
}

/// What `tes bench latency --json` prints.
#[derive(Debug, Serialize)]
struct LatencyResult {
    /// How the processes reached each other: `shm` or `zenoh`.
    via: &'static str,
    wait: String,
    actions: u64,
    budget_us: u64,
    views: usize,
    p50_us: u64,
    p90_us: u64,
    p99_us: u64,
    p999_us: u64,
    max_us: u64,
    misses: u64,
    /// Heap allocations on the controller's acting path (null if not counted).
    allocations: Option<u64>,
    /// Of those, the ones inside iceoryx2 sending the command.
    ipc_allocations: Option<u64>,
    /// The controller's own decision latency (observation stamped → command published).
    decision: LatencyReport,
    /// Its first part: observation stamped → received by the controller's acting loop.
    wake: LatencyReport,
    /// Its second part: observation received → command published (the acting path's work).
    compute: LatencyReport,
    /// When the controller learned: `decide-first` or `learn-first`.
    order: String,
    /// Deciding first, the learning after each command (command published → views scored and
    /// updated, the planner handed the model).
    learn: LatencyReport,
    /// Observations published before the previous learning had finished (they waited for it).
    learning_overran: u64,
    floor_p50_us: u64,
    floor_p90_us: u64,
    floor_p99_us: u64,
    floor_p999_us: u64,
    floor_max_us: u64,
    floor_misses: u64,
    /// The floor's first hop alone (observation stamped → the hop's command published): the
    /// counterpart of `decision` with no work.
    floor_decision: LatencyReport,
    ratio_p50: f64,
    ratio_p99: f64,
    /// Mean time between actions in our run, which the floor's source kept too, µs.
    cycle_us: u64,
    seed: u64,
    /// The controller's acting thread's CPU, and the floor's hop's (null: unpinned).
    acting_cpu: Option<usize>,
    /// The controller's planner thread's CPU (null: unpinned).
    planner_cpu: Option<usize>,
    /// Plans the controller's planner finished and the acting loop adopted.
    plans: u64,
    /// Who planned: `thread` or `between-polls`.
    planning: String,
    /// With `--record`: the group with and without the recorder, in alternating blocks
    /// (null without `--record`).
    recorder: Option<RecorderComparison>,
}

/// One block of `tes bench latency --record`: a run of the group from the starting library,
/// with or without the recorder.
#[derive(Debug, Clone, Copy, Serialize)]
struct RecorderBlock {
    /// Whether the launcher's recorder ran.
    recorded: bool,
    /// Observation → bridge.
    p50_us: u64,
    p99_us: u64,
    misses: u64,
    /// Heap allocations on the controller's acting path (null if not counted).
    allocations: Option<u64>,
    /// With the recorder: the observations, commands and motor states it wrote.
    written: Option<[u64; 3]>,
    /// With the recorder: the samples it could not take in time.
    missed: Option<u64>,
}

/// `tes bench latency --record`: the recorder's cost as the medians over blocks of each kind.
#[derive(Debug, Clone, Serialize)]
struct RecorderComparison {
    /// In the order they ran.
    blocks: Vec<RecorderBlock>,
    /// Medians over the blocks without the recorder, then with it.
    without_p50_us: f64,
    without_p99_us: f64,
    with_p50_us: f64,
    with_p99_us: f64,
    /// `with / without − 1` of the medians (0.05 = 5 % slower with the recorder).
    change_p50: f64,
    change_p99: f64,
    /// The most allocations any block counted on the acting path with the recorder.
    allocations_with: Option<u64>,
}

/// The median of `values` (the mean of the middle two for an even count); 0 for none.
fn median(values: impl IntoIterator<Item = u64>) -> f64 {
    let mut v: Vec<u64> = values.into_iter().collect();
    v.sort_unstable();
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2] as f64,
        n => (v[n / 2 - 1] + v[n / 2]) as f64 / 2.0,
    }
}

/// Whether block `i` of the comparison runs with the recorder: without, with, with, without,
/// and again, so that a drift of the machine over the run weighs on both kinds alike.
fn block_is_recorded(i: u64) -> bool {
    matches!(i % 4, 1 | 2)
}

fn ratio(ours: u64, floor: u64) -> f64 {
    ours as f64 / floor.max(1) as f64
}

fn latency(args: &LatencyArgs) -> Result<()> {
    let wait: WaitStrategy = args
        .wait
        .parse()
        .map_err(|e| anyhow::anyhow!("--wait: {e}"))?;
    if args.actions == 0 || args.budget_us == 0 || args.views == 0 {
        bail!("--actions, --budget-us and --views must be at least 1");
    }
    let settings = ControllerConfig {
        wait,
        acting_cpu: args.acting_cpu,
        planner_cpu: args.planner_cpu,
        planning: planning_mode(args)?,
        ..ControllerConfig::default()
    };
    let planning = settings
        .planning_for(wait)
        .map_err(|e| anyhow::anyhow!("--planning: {}", e.reason))?;
    // Resolved (and checked) here, so that the floor's hop gets the acting thread's very CPU.
    let placement = settings
        .placement(wait, planning)
        .map_err(|e| anyhow::anyhow!("--{}: {}", e.key.replace('_', "-"), e.reason))?;
    let temp;
    let dir: &Path = match &args.out {
        Some(d) => {
            std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
            d
        }
        None => {
            temp = tempfile::tempdir().context("cannot create a temporary directory")?;
            temp.path()
        }
    };
    let total = args.actions + args.warmup;
    let prefix = format!("tes-bench-{}/", std::process::id());

    eprintln!(
        "bench: training a {}-view library in Env 1 and Env 2",
        args.views
    );
    let library = fixtures::arena_library(args.views, 3000, args.seed)?;
    let files = RunFiles::in_dir(dir);
    let stored = StoredLibrary {
        library,
        world: "arena 1+2 (bench)".into(),
        action_names: Vec::new(),
        feature_names: Vec::new(),
    };
    eprintln!("bench: ours — perception-sim → controller → bridge on Env 3, {total} actions");
    let file = group_file(dir, &prefix, wait, args, placement, &files)?;
    let started = Instant::now();
    let (ours, controller) = match args.via {
        Via::Shm => run_group(&file, &stored, &files)?,
        Via::Zenoh => run_split_group(&file, &stored, &files, dir)?,
    };
    let elapsed = started.elapsed();
    if ours.count < args.actions {
        bail!(
            "the bridge saw {} measured commands, expected {} (see the run's files with --out)",
            ours.count,
            args.actions
        );
    }
    if controller.placement != placement {
        bail!(
            "the controller placed its threads at {:?}, not at {placement:?} as asked: the floor's hop would not match",
            controller.placement
        );
    }
    let cycle_us = (elapsed.as_micros() / u128::from(total)) as u64;
    let floor_kind = match args.via {
        Via::Shm => "a raw iceoryx2 two-hop relay",
        Via::Zenoh => {
            "the same two hops through the split launch's own Zenoh link on loopback TCP, with no work"
        }
    };
    eprintln!(
        "bench: the floor — {floor_kind}, {total} round trips, wait {wait}, one every {cycle_us} us"
    );
    let (floor, floor_decision) = match args.via {
        Via::Shm => run_floor(dir, &prefix, wait, cycle_us, args, placement.acting)?,
        Via::Zenoh => zenoh_floor(cycle_us, wait, placement.acting, args, dir)?,
    };
    let recorder = if args.record {
        Some(compare_recorder(&file, &stored, &files, dir, args)?)
    } else {
        None
    };
    let result = LatencyResult {
        via: match args.via {
            Via::Shm => "shm",
            Via::Zenoh => "zenoh",
        },
        wait: wait.to_string(),
        actions: ours.count,
        budget_us: args.budget_us,
        views: args.views,
        p50_us: ours.p50_us,
        p90_us: ours.p90_us,
        p99_us: ours.p99_us,
        p999_us: ours.p999_us,
        max_us: ours.max_us,
        misses: ours.misses,
        allocations: controller.allocations,
        ipc_allocations: controller.ipc_allocations,
        decision: controller.latency,
        wake: controller.wake,
        compute: controller.compute,
        order: controller.order.clone(),
        learn: controller.learn,
        learning_overran: controller.learning_overran,
        floor_p50_us: floor.p50_us,
        floor_p90_us: floor.p90_us,
        floor_p99_us: floor.p99_us,
        floor_p999_us: floor.p999_us,
        floor_max_us: floor.max_us,
        floor_misses: floor.misses,
        floor_decision,
        ratio_p50: ratio(ours.p50_us, floor.p50_us),
        ratio_p99: ratio(ours.p99_us, floor.p99_us),
        cycle_us,
        seed: args.seed,
        acting_cpu: placement.acting,
        planner_cpu: placement.planner,
        plans: controller.plans,
        planning: controller.planning.clone(),
        recorder,
    };
    if args.json {
        println!("{}", serde_json::to_string(&result)?);
        return Ok(());
    }
    let cpu = |c: Option<usize>| c.map_or("unpinned".to_owned(), |c| format!("CPU {c}"));
    println!(
        "tes bench latency: wait {}, {}, {} actions measured (+{} warm-up), {} views, budget {} us, one action every {} us; \
         acting thread and floor hop {}, planner {}",
        result.wait,
        result.order,
        result.actions,
        args.warmup,
        args.views,
        args.budget_us,
        cycle_us,
        cpu(placement.acting),
        cpu(placement.planner)
    );
    println!(
        "{:<34} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "", "p50 us", "p90 us", "p99 us", "p99.9 us", "max us", "misses"
    );
    let row = |name: &str, r: &LatencyReport| {
        println!(
            "{:<34} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
            name, r.p50_us, r.p90_us, r.p99_us, r.p999_us, r.max_us, r.misses
        );
    };
    row(
        match args.via {
            Via::Shm => "floor (raw two-hop relay)",
            Via::Zenoh => "floor (two hops over Zenoh)",
        },
        &floor,
    );
    row("floor: first hop only", &result.floor_decision);
    row("ours: observation -> bridge", &ours);
    row("ours: controller decision only", &controller.latency);
    row("  of which: stamp -> received", &controller.wake);
    row("  of which: received -> published", &controller.compute);
    if controller.learn.count > 0 {
        row("learning after the command", &controller.learn);
    }
    println!(
        "ratio ours/floor: p50 {:.2}, p99 {:.2}; allocations on the acting path: {}",
        result.ratio_p50,
        result.ratio_p99,
        match (result.allocations, result.ipc_allocations) {
            (Some(n), Some(ipc)) => format!("{n} ({ipc} inside iceoryx2's send)"),
            _ => "not counted".to_owned(),
        }
    );
    if let Some(r) = &result.recorder {
        print_recorder(r);
    }
    // A planner thread yields to everything: where the measured loops keep both CPUs busy
    // (spin on two cores) it barely runs, and the agent acts on an old policy.
    if controller.learn.count > 0 {
        println!(
            "learning finished before the next observation in {:.3} % of actions ({} observations waited for it)",
            100.0 * (1.0 - result.learning_overran as f64 / result.actions.max(1) as f64),
            result.learning_overran
        );
    }
    println!(
        "planner ({}): {} plans finished and adopted, one per {:.0} actions",
        result.planning,
        result.plans,
        (args.actions + args.warmup) as f64 / result.plans.max(1) as f64
    );
    Ok(())
}

/// Runs the group from the starting library `stored` and reads the bridge's latency report
/// and the controller's summary.
fn run_group(
    file: &LaunchFile,
    stored: &StoredLibrary,
    files: &RunFiles,
) -> Result<(LatencyReport, ControllerSummary)> {
    // Every run starts from the same library (the previous one saved what it learned).
    store::save(&files.library, stored)?;
    crate::launch::run_file(file, false).context("the process group failed")?;
    let report = LatencyReport::load(&files.bridge_report)
        .with_context(|| format!("no bridge report at {}", files.bridge_report.display()))?;
    let path = &files.controller_report;
    let summary: ControllerSummary = serde_json::from_str(
        &std::fs::read_to_string(path)
            .with_context(|| format!("no controller report at {}", path.display()))?,
    )
    .context("the controller's report is malformed")?;
    Ok((report, summary))
}

/// [`run_group`] split in two launches linked by Zenoh over loopback TCP: perception-sim and
/// the bridge in this process's launch, the controller in a `tes launch` of its own with an
/// iceoryx2 domain of its own (so only the link connects them).
fn run_split_group(
    file: &LaunchFile,
    stored: &StoredLibrary,
    files: &RunFiles,
    dir: &Path,
) -> Result<(LatencyReport, ControllerSummary)> {
    store::save(&files.library, stored)?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .context("no free TCP port on loopback")?;
    let group = format!("tes-bench/{}", std::process::id());
    let mut robot = file.clone();
    robot.launch.roles = vec![Role::Perception, Role::Bridge];
    let link = &mut robot.launch.link;
    link.group.clone_from(&group);
    link.listen = vec![format!("tcp/127.0.0.1:{port}")];
    link.connect = Vec::new();
    link.multicast_scouting = Some(false);
    // One machine, one clock: the latency is measured across the link.
    link.restamp = false;
    let mut workstation = robot.clone();
    workstation.launch.roles = vec![Role::Controller];
    workstation.launch.run_dir = Some(dir.join("run-controller"));
    let link = &mut workstation.launch.link;
    link.listen = Vec::new();
    link.connect = vec![format!("tcp/127.0.0.1:{port}")];
    let text = tes_launch::reference::render_resolved(&workstation)?;
    let path = dir.join("controller-launch.toml");
    std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    let exe = std::env::current_exe().context("cannot find the tes executable")?;
    let log = std::fs::File::create(dir.join("controller-launch.log"))
        .context("cannot create the controller launch's log")?;
    let mut other = std::process::Command::new(exe)
        .arg("launch")
        .arg("--config")
        .arg(&path)
        .env(
            tes_runtime::channel::DOMAIN_VAR,
            format!("bench{}", std::process::id()),
        )
        .stdin(std::process::Stdio::null())
        .stdout(log.try_clone().context("cannot share the log")?)
        .stderr(log)
        .spawn()
        .context("cannot start the controller's launch")?;
    let ran = crate::launch::run_file(&robot, false).context("the robot's launch failed");
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(s) = other
            .try_wait()
            .context("cannot poll the controller's launch")?
        {
            break Some(s);
        }
        if Instant::now() > deadline {
            let _ = other.kill();
            let _ = other.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    ran?;
    match status {
        Some(s) if s.success() => {}
        Some(s) => bail!(
            "the controller's launch {} (see {})",
            children::describe(s),
            dir.join("controller-launch.log").display()
        ),
        None => bail!("the controller's launch did not stop"),
    }
    let report = LatencyReport::load(&files.bridge_report)
        .with_context(|| format!("no bridge report at {}", files.bridge_report.display()))?;
    let path = &files.controller_report;
    let summary: ControllerSummary = serde_json::from_str(
        &std::fs::read_to_string(path)
            .with_context(|| format!("no controller report at {}", path.display()))?,
    )
    .context("the controller's report is malformed")?;
    Ok((report, summary))
}

/// Marks the probes the floor sends until its link carries a first round trip: not measured.
const FLOOR_PROBE: u32 = u32::MAX;

/// The arena the floor's samples are checked against (the measured run's).
fn floor_map() -> Result<Box<tes_topics::WorldMap>> {
    use tes_perception_sim::arena::{Arena, ArenaId};
    Ok(tes_perception_sim::process::world_map(&Arena::new(
        ArenaId::Env3,
    ))?)
}

/// One end of the floor's link.
fn floor_link_settings(
    group: &str,
    listen: Vec<String>,
    connect: Vec<String>,
) -> tes_link::LinkSection {
    tes_link::LinkSection {
        group: group.to_owned(),
        listen,
        connect,
        multicast_scouting: Some(false),
        // One machine, one clock, as in the measured run.
        restamp: false,
        ..tes_link::LinkSection::default()
    }
}

/// Waits until `link` sees a peer for every role it does not play.
fn floor_wait_for_peer(link: &tes_link::Link, side: &str) -> Result<()> {
    let started = Instant::now();
    while !link.missing().is_empty() {
        if started.elapsed() > Duration::from_secs(20) {
            bail!(
                "the floor's {side} side waited 20 s for {:?} on loopback",
                link.missing()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

/// The floor of `--via zenoh`: the loop's two hops through the very link a split launch uses
/// ([`tes_link::Link`] on loopback TCP) with no work at either end. The robot's side runs
/// here, the controller's in a child process (`tes bench zenoh-floor-hop`) with an iceoryx2
/// domain of its own, as the controller's launch in the measured run: an observation
/// published here is forwarded, checked and republished there, answered at once with a
/// command that comes back the same way. One round trip every `cycle_us`; the round trip, and
/// its first hop alone.
fn zenoh_floor(
    cycle_us: u64,
    wait: WaitStrategy,
    hop_cpu: Option<usize>,
    args: &LatencyArgs,
    dir: &Path,
) -> Result<(LatencyReport, LatencyReport)> {
    use std::sync::atomic::AtomicBool;
    use tes_runtime::channel::{self, LatestInbox, Outbox};
    use tes_runtime::clock::monotonic_ns;
    use tes_runtime::latency::LatencyRecorder;
    use tes_topics::{Command, Observation, Role, ServiceNames, StateAttributes, WorldMap};

    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .context("no free TCP port on loopback")?;
    let pid = std::process::id();
    let group = format!("tes-bench-floor/{pid}");
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let names = ServiceNames::with_prefix(&format!("tes-bench-{pid}/floor-robot/"));
    let robot = tes_link::Link::open(
        &floor_link_settings(&group, vec![endpoint.clone()], Vec::new()),
        &[Role::Perception, Role::Bridge],
        &names,
    )
    .context("the floor's robot side")?;

    let total = args.actions + args.warmup;
    let hop_report = dir.join("floor-first-hop.json");
    let log_path = dir.join("floor-hop.log");
    let log = std::fs::File::create(&log_path)
        .with_context(|| format!("cannot create {}", log_path.display()))?;
    let exe = std::env::current_exe().context("cannot find the tes executable")?;
    let mut hop = std::process::Command::new(exe);
    hop.args([
        "bench",
        "zenoh-floor-hop",
        "--connect",
        &endpoint,
        "--group",
        &group,
    ])
    .args(["--prefix", &format!("tes-bench-{pid}/floor-desk/")])
    .args(["--wait", &wait.to_string()])
    .args(["--answer", &total.to_string()])
    .args(["--warmup", &args.warmup.to_string()])
    .args(["--budget-us", &args.budget_us.to_string()])
    .arg("--report")
    .arg(&hop_report);
    if let Some(cpu) = hop_cpu {
        hop.args(["--hop-cpu", &cpu.to_string()]);
    }
    let mut hop = hop
        .env(tes_runtime::channel::DOMAIN_VAR, format!("benchfloor{pid}"))
        .stdin(std::process::Stdio::null())
        .stdout(log.try_clone().context("cannot share the log")?)
        .stderr(log)
        .spawn()
        .context("cannot start the floor's controller side")?;

    let stop = AtomicBool::new(false);
    let measured = (|| -> Result<LatencyReport> {
        floor_wait_for_peer(&robot, "robot's")?;
        let map: Box<WorldMap> = floor_map()?;
        let node = channel::node(false)?;
        let maps: Outbox<WorldMap> =
            Outbox::open(&node, &names.world_map, &names.world_map_event, 1)?;
        maps.send(*map)?;
        let observations: Outbox<Observation> =
            Outbox::open(&node, &names.observation, &names.observation_event, 0)?;
        let commands: LatestInbox<Command> =
            LatestInbox::open(&node, &names.command, &names.command_event, wait)?;
        let mut seq = 0;
        let mut observation = |step: u32| {
            seq += 1;
            Observation {
                seq,
                stamp_ns: monotonic_ns(),
                step,
                state: StateAttributes::at(0, 0, 0),
                n_features: map.n_features,
                ..Observation::default()
            }
        };
        // The world map crosses within a second, and until it has, the controller's side
        // refuses observations: probe until a first round trip.
        let probing = Instant::now();
        loop {
            if probing.elapsed() > Duration::from_secs(20) {
                bail!("the floor's link never carried a round trip");
            }
            observations.update_connections()?;
            let probe = observation(FLOOR_PROBE);
            observations.send(probe)?;
            if let Ok(c) = commands.next(Duration::from_millis(50), &stop)?
                && c.answers == probe.seq
            {
                break;
            }
        }
        let mut round = LatencyRecorder::new(args.budget_us, args.warmup);
        let gap = Duration::from_micros(cycle_us);
        for step in 0..total {
            let next = Instant::now() + gap;
            let o = observation(u32::try_from(step).unwrap_or(FLOOR_PROBE - 1));
            observations.send(o)?;
            let deadline = Instant::now() + Duration::from_secs(5);
            loop {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    bail!("the floor's link lost a round trip (observation {})", o.seq);
                }
                if let Ok(c) = commands.next(left, &stop)?
                    && c.answers == o.seq
                {
                    round.record_ns(monotonic_ns().saturating_sub(c.observed_ns));
                    break;
                }
            }
            let left = next.saturating_duration_since(Instant::now());
            if !left.is_zero() {
                std::thread::sleep(left);
            }
        }
        Ok(round.report())
    })();
    let deadline = Instant::now() + Duration::from_secs(10);
    let status = loop {
        if let Some(s) = hop
            .try_wait()
            .context("cannot poll the floor's controller side")?
        {
            break Some(s);
        }
        if measured.is_err() || Instant::now() > deadline {
            let _ = hop.kill();
            let _ = hop.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    drop(robot);
    let round = measured.with_context(|| format!("see also {}", log_path.display()))?;
    match status {
        Some(s) if s.success() => {}
        Some(s) => bail!(
            "the floor's controller side {} (see {})",
            children::describe(s),
            log_path.display()
        ),
        None => bail!(
            "the floor's controller side did not stop (see {})",
            log_path.display()
        ),
    }
    let first_hop = LatencyReport::load(&hop_report)
        .with_context(|| format!("no floor report at {}", hop_report.display()))?;
    Ok((round, first_hop))
}

/// `tes bench zenoh-floor-hop`: the floor's controller side. Answers each observation that
/// crosses at once, the first `answer` of them, then saves the first hop's latencies.
fn zenoh_floor_hop(args: &FloorHopArgs) -> Result<()> {
    use std::sync::atomic::AtomicBool;
    use tes_runtime::channel::{self, Inbox, LatestOutbox};
    use tes_runtime::clock::monotonic_ns;
    use tes_runtime::latency::LatencyRecorder;
    use tes_topics::{Command, Observation, Role, ServiceNames};

    let wait: WaitStrategy = args
        .wait
        .parse()
        .map_err(|e| anyhow::anyhow!("--wait: {e}"))?;
    if let Some(cpu) = args.hop_cpu {
        tes_runtime::affinity::pin_this_thread(cpu)?;
    }
    let names = ServiceNames::with_prefix(&args.prefix);
    let wheels = floor_map()?.action_wheels[0];
    let link = tes_link::Link::open(
        &floor_link_settings(&args.group, Vec::new(), vec![args.connect.clone()]),
        &[Role::Controller],
        &names,
    )
    .context("the floor's controller side")?;
    floor_wait_for_peer(&link, "controller's")?;
    let node = channel::node(false)?;
    let observations: Inbox<Observation> =
        Inbox::open(&node, &names.observation, &names.observation_event, 0, wait)?;
    let commands: LatestOutbox<Command> =
        LatestOutbox::open(&node, &names.command, &names.command_event)?;
    let mut first_hop = LatencyRecorder::new(args.budget_us, args.warmup);
    let stop = AtomicBool::new(false);
    let (mut seq, mut answered) = (0, 0);
    let mut idle_since = Instant::now();
    while answered < args.answer {
        let Ok(o) = observations.next(Duration::from_millis(50), &stop)? else {
            if idle_since.elapsed() > Duration::from_secs(30) {
                bail!("no observation crossed the floor's link for 30 s");
            }
            continue;
        };
        idle_since = Instant::now();
        let now = monotonic_ns();
        if o.step != FLOOR_PROBE {
            first_hop.record_ns(now.saturating_sub(o.stamp_ns));
            answered += 1;
        }
        seq += 1;
        commands.send(Command {
            seq,
            answers: o.seq,
            stamp_ns: now,
            observed_ns: o.stamp_ns,
            action: 0,
            left_deg: wheels[0],
            right_deg: wheels[1],
            ..Command::default()
        })?;
    }
    // The last command must cross before this side leaves.
    std::thread::sleep(Duration::from_millis(200));
    first_hop
        .report()
        .save(&args.report)
        .with_context(|| format!("cannot write {}", args.report.display()))?;
    drop(link);
    Ok(())
}

/// `--record`: blocks without and with the recorder, alternating, each of
/// `--actions / --record-blocks` measured actions.
fn compare_recorder(
    file: &LaunchFile,
    stored: &StoredLibrary,
    files: &RunFiles,
    dir: &Path,
    args: &LatencyArgs,
) -> Result<RecorderComparison> {
    if args.record_blocks == 0 {
        bail!("--record-blocks must be at least 1");
    }
    let measured = (args.actions / args.record_blocks).max(1);
    let mut block_file = file.clone();
    block_file.perception.actions = measured + args.warmup;
    let mcap = dir.join("bench.mcap");
    let kinds = 2 * args.record_blocks;
    let mut blocks = Vec::new();
    for i in 0..kinds {
        let recorded = block_is_recorded(i);
        eprintln!(
            "bench: recorder comparison, block {} of {kinds}: {} the recorder, {measured} actions",
            i + 1,
            if recorded { "with" } else { "without" }
        );
        let mut f = block_file.clone();
        f.launch.record = recorded.then(|| mcap.clone());
        let (report, summary) = run_group(&f, stored, files)?;
        if report.count < measured {
            bail!(
                "block {}: the bridge saw {} measured commands, expected {measured}",
                i + 1,
                report.count
            );
        }
        let (written, missed) = if recorded {
            let recording = tes_recorder::reader::Recording::open(&mcap)?;
            if let Some(why) = &recording.truncated {
                bail!("block {}: the recording is incomplete: {why}", i + 1);
            }
            let missed = recording.end.as_ref().map_or(0, |end| {
                [
                    "missed_observations",
                    "missed_commands",
                    "missed_motor_states",
                ]
                .iter()
                .filter_map(|k| end.get(*k).and_then(|v| v.parse::<u64>().ok()))
                .sum()
            });
            let written = [
                recording.observations.len() as u64,
                recording.commands.len() as u64,
                recording.motor_states.len() as u64,
            ];
            (Some(written), Some(missed))
        } else {
            (None, None)
        };
        blocks.push(RecorderBlock {
            recorded,
            p50_us: report.p50_us,
            p99_us: report.p99_us,
            misses: report.misses,
            allocations: summary.allocations,
            written,
            missed,
        });
    }
    let of = |recorded: bool, pick: fn(&RecorderBlock) -> u64| {
        median(blocks.iter().filter(|b| b.recorded == recorded).map(pick))
    };
    let (without_p50_us, without_p99_us) = (of(false, |b| b.p50_us), of(false, |b| b.p99_us));
    let (with_p50_us, with_p99_us) = (of(true, |b| b.p50_us), of(true, |b| b.p99_us));
    let change = |with: f64, without: f64| with / without.max(1.0) - 1.0;
    let allocations_with = blocks
        .iter()
        .filter(|b| b.recorded)
        .map(|b| b.allocations)
        .try_fold(0, |most, n| n.map(|n| most.max(n)));
    Ok(RecorderComparison {
        change_p50: change(with_p50_us, without_p50_us),
        change_p99: change(with_p99_us, without_p99_us),
        blocks,
        without_p50_us,
        without_p99_us,
        with_p50_us,
        with_p99_us,
        allocations_with,
    })
}

/// The recorder comparison's blocks and medians, as a table.
fn print_recorder(r: &RecorderComparison) {
    println!("the recorder's cost (blocks in the order they ran; observation -> bridge):");
    println!(
        "{:>5} {:>9} {:>8} {:>8} {:>7} {:>12} {:>24} {:>7}",
        "block",
        "recorder",
        "p50 us",
        "p99 us",
        "misses",
        "allocations",
        "written obs/cmd/motor",
        "missed"
    );
    for (i, b) in r.blocks.iter().enumerate() {
        let written = b
            .written
            .map_or("-".to_owned(), |[o, c, m]| format!("{o}/{c}/{m}"));
        println!(
            "{:>5} {:>9} {:>8} {:>8} {:>7} {:>12} {:>24} {:>7}",
            i + 1,
            if b.recorded { "with" } else { "without" },
            b.p50_us,
            b.p99_us,
            b.misses,
            b.allocations.map_or("-".to_owned(), |n| n.to_string()),
            written,
            b.missed.map_or("-".to_owned(), |n| n.to_string()),
        );
    }
    println!(
        "medians: without p50 {:.1} us, p99 {:.1} us; with p50 {:.1} us ({:+.1} %), p99 {:.1} us ({:+.1} %); \
         allocations on the acting path with the recorder: {}",
        r.without_p50_us,
        r.without_p99_us,
        r.with_p50_us,
        100.0 * r.change_p50,
        r.with_p99_us,
        100.0 * r.change_p99,
        r.allocations_with
            .map_or("not counted".to_owned(), |n| n.to_string())
    );
}

/// The files of one `tes bench latency` run, in its directory.
struct RunFiles {
    /// The controller's view library.
    library: PathBuf,
    /// The controller's summary (`report`).
    controller_report: PathBuf,
    /// The bridge's latency report (observation → command at the bridge).
    bridge_report: PathBuf,
}

impl RunFiles {
    fn in_dir(dir: &Path) -> Self {
        Self {
            library: dir.join("library.tesl"),
            controller_report: dir.join("controller.json"),
            bridge_report: dir.join("bridge.json"),
        }
    }
}

/// `--planning`, or `auto` without it.
fn planning_mode(args: &LatencyArgs) -> Result<PlanningMode> {
    args.planning
        .as_deref()
        .map_or(Ok(PlanningMode::Auto), |p| {
            p.parse().map_err(|e| anyhow::anyhow!("--planning: {e}"))
        })
}

fn group_file(
    dir: &Path,
    prefix: &str,
    wait: WaitStrategy,
    args: &LatencyArgs,
    placement: ThreadPlacement,
    files: &RunFiles,
) -> Result<LaunchFile> {
    let total = args.actions + args.warmup;
    let mut file = LaunchFile {
        launch: LaunchSection {
            episodes: u32::MAX,
            arena: 3,
            real_time_factor: 0.0,
            wait,
            service_prefix: prefix.to_owned(),
            run_dir: Some(dir.join("run")),
            seed: args.seed,
            ..LaunchSection::default()
        },
        ..LaunchFile::default()
    };
    file.perception.actions = total;
    // The return path (robot motion) is not measured: block, as the floor's source does.
    file.perception.wait = WaitStrategy::Block;
    file.keep("perception", "wait");
    let c = &mut file.controller;
    c.library = Some(files.library.clone());
    c.budget_us = args.budget_us;
    c.warmup_actions = args.warmup;
    c.report = Some(files.controller_report.clone());
    // Resolved CPUs or "none", never "auto": the floor's hop was given the same CPU.
    c.acting_cpu = placement.acting.map_or(Placement::Unpinned, Placement::Cpu);
    c.planner_cpu = placement
        .planner
        .map_or(Placement::Unpinned, Placement::Cpu);
    c.planning = planning_mode(args)?;
    c.order = args.order;
    if let Some(us) = args.planner_idle_spin_us {
        c.planner_idle_spin_us = us;
    }
    // The bridge's [ipc] table as the bench writes it: the launch-wide prefix and wait go in.
    let ipc = &mut file.bridge.ipc;
    ipc.budget_us = args.budget_us;
    ipc.warmup_commands = args.warmup;
    ipc.latency_report = Some(files.bridge_report.clone());
    Ok(file)
}

/// Runs the three relay processes and returns the sink's reports: the round trip, and its
/// first hop alone.
fn run_floor(
    dir: &Path,
    prefix: &str,
    wait: WaitStrategy,
    cycle_us: u64,
    args: &LatencyArgs,
    hop_cpu: Option<usize>,
) -> Result<(LatencyReport, LatencyReport)> {
    let report = dir.join("floor.json");
    let hop_report = dir.join("floor-first-hop.json");
    let cfg = RelayConfig {
        service_prefix: format!("{prefix}floor/"),
        wait,
        messages: args.actions + args.warmup,
        warmup: args.warmup,
        budget_us: args.budget_us,
        report: Some(report.clone()),
        hop_report: Some(hop_report.clone()),
        // The source's own round trip is part of the cycle.
        gap_us: cycle_us.saturating_sub(50),
        hop_cpu,
        ..RelayConfig::default()
    };
    cfg.check()?;
    let config = dir.join("relay.toml");
    std::fs::write(&config, toml::to_string(&cfg)?)
        .with_context(|| format!("cannot write {}", config.display()))?;
    let mut children: Vec<Process> = Vec::new();
    let relay_command =
        ChildCommand::new(std::env::current_exe().context("cannot find the tes executable")?)
            .arg("bench")
            .arg("relay");
    // The receivers first, so the source's first observations find them sooner.
    for role in [relay::ROLES[2], relay::ROLES[1], relay::ROLES[0]] {
        let child = children::spawn_as(&relay_command, role, &config)?;
        children.push(Process::new(role, child));
    }
    let limit = Duration::from_millis(cfg.idle_timeout_ms)
        + Duration::from_micros(cfg.gap_us + 500)
            .saturating_mul(u32::try_from(cfg.messages).unwrap_or(u32::MAX));
    let started = Instant::now();
    while children.iter().any(|c| c.status.is_none()) && started.elapsed() < limit {
        for c in children.iter_mut().filter(|c| c.status.is_none()) {
            c.status = c.child.try_wait().context("cannot poll a relay process")?;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut processes: Vec<&mut Process> = children.iter_mut().collect();
    children::shutdown(&mut processes, Duration::from_secs(1));
    for c in &children {
        match c.status {
            Some(s) if s.success() => {}
            Some(s) => bail!("the floor's {} {}", c.name, children::describe(s)),
            None => bail!("the floor's {} did not finish", c.name),
        }
    }
    let load = |path: &Path| {
        LatencyReport::load(path).with_context(|| format!("no floor report at {}", path.display()))
    };
    Ok((load(&report)?, load(&hop_report)?))
}

fn scaling_sweep(args: &ScalingArgs) -> Result<()> {
    if args.actions == 0 {
        bail!("--actions must be at least 1");
    }
    if !args.json {
        println!(
            "{:>9} {:>6} | {:>8} {:>8} {:>8} | {:>8} {:>8} {:>8} | {:>8} {:>8}",
            "", "", "decision", "", "", "learning", "", "", "whole", ""
        );
        println!(
            "{:>9} {:>6} | {:>8} {:>8} {:>8} | {:>8} {:>8} {:>8} | {:>8} {:>8}",
            "features",
            "views",
            "p50 us",
            "p99 us",
            "max us",
            "p50 us",
            "p99 us",
            "max us",
            "p50 us",
            "p99 us"
        );
    }
    let points = scaling::sweep(args.actions, args.warmup, args.seed, args.order, |p| {
        if !args.json {
            let (d, l, w) = (&p.decision, &p.learn, &p.latency);
            println!(
                "{:>9} {:>6} | {:>8} {:>8} {:>8} | {:>8} {:>8} {:>8} | {:>8} {:>8}",
                p.features,
                p.views,
                d.p50_us,
                d.p99_us,
                d.max_us,
                l.p50_us,
                l.p99_us,
                l.max_us,
                w.p50_us,
                w.p99_us
            );
        }
    })?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let mut csv = String::from(
            "features,views,count,p50_us,p90_us,p99_us,p999_us,max_us,\
             decision_p50_us,decision_p99_us,decision_max_us,learn_p50_us,learn_p99_us,learn_max_us\n",
        );
        for p in &points {
            let (l, d, n) = (&p.latency, &p.decision, &p.learn);
            csv.push_str(&format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                p.features,
                p.views,
                l.count,
                l.p50_us,
                l.p90_us,
                l.p99_us,
                l.p999_us,
                l.max_us,
                d.p50_us,
                d.p99_us,
                d.max_us,
                n.p50_us,
                n.p99_us,
                n.max_us
            ));
        }
        let [by_features, by_views] = scaling::charts(&points);
        for (name, text) in [
            ("scaling.csv", csv),
            (
                "scaling.json",
                serde_json::to_string_pretty(&points)? + "\n",
            ),
            ("scaling-features.svg", by_features.to_svg()),
            ("scaling-views.svg", by_views.to_svg()),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, text)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        if !args.json {
            println!("wrote {}", dir.display());
        }
    }
    if args.json {
        println!("{}", serde_json::to_string(&points)?);
    }
    Ok(())
}
