//! `tes bench latency` and `tes bench scaling`: the command line of [`tes_bench`]'s
//! harnesses — the controller's per-action latency measured against its floor in the same
//! run ([`tes_bench::latency`]), and how a decision's cost grows with features and views
//! ([`tes_bench::scaling`]). This module reads the flags, names this executable as every
//! program the harness starts, prints the launches' warnings and the harness's progress, and
//! prints the results.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use tes_bench::floor::{self, HopSettings};
use tes_bench::recorder_cost::{RecorderComparison, Watcher};
use tes_bench::relay::{self, RelayConfig};
use tes_bench::{Harness, LatencyResult, LatencySettings, Note, Pace, Programs, Via, scaling};
use tes_controller::config::{Order, PlanningMode};
use tes_runtime::affinity::Placement;
use tes_runtime::channel::WaitStrategy;
use tes_runtime::latency::LatencyReport;

use crate::launch::{Printer, stop_on_signals, this_executable};

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
    /// Over QUIC with the group's authority, this side's certificate and its key.
    #[arg(long, num_args = 3, value_names = ["CA", "CERT", "KEY"])]
    tls: Option<Vec<PathBuf>>,
}

/// Arguments of `tes bench latency`.
#[derive(Debug, Args)]
pub struct LatencyArgs {
    /// Actions measured (after the warm-up) [default: 10000 at the fastest pace, 1000 at the
    /// robot's].
    #[arg(long)]
    actions: Option<u64>,
    /// The per-action budget, µs.
    #[arg(long, default_value_t = tes_runtime::settings::DEFAULT_BUDGET_US)]
    budget_us: u64,
    /// How every process waits: block, spin, spin-then-block, spin-then-block:<µs> or
    /// anticipate.
    #[arg(long, default_value = "block")]
    wait: String,
    /// The pace the group runs at: fastest (actions back to back) or real (the robot's own:
    /// the paper's 200 ms settle after each motion, the simulated brick in real time, and a
    /// Bluetooth-like 30 ± 10 ms delay on each of its replies — about 0.8 s per action, so
    /// the default 1000 actions take some 14 minutes, and as long again for the floor). The
    /// floor runs at the group's measured cadence either way.
    #[arg(long, value_enum, default_value = "fastest")]
    pace: PaceArg,
    /// Views in the controller's library (trained in Env 1 and Env 2).
    #[arg(long, default_value_t = 9)]
    views: usize,
    /// Actions run first and left out of every figure [default: 1000 at the fastest pace, 50
    /// at the robot's].
    #[arg(long)]
    warmup: Option<u64>,
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
    /// (the floor's helper thread polls as long) [default: the controller's, 5000 with a
    /// spinning wait, else 0].
    #[arg(long)]
    planner_idle_spin_us: Option<u64>,
    /// Also compare the group with and without the recorder (`tes launch --record`): after
    /// the main run and the floor, blocks of each kind alternate (without, with, with,
    /// without, …), each from the same library, and the medians over the blocks are compared.
    #[arg(long)]
    record: bool,
    /// Also compare the group with and without the live Foxglove server (`tes launch
    /// --foxglove`) and a viewer subscribed to every channel, in alternating blocks as
    /// `--record`'s.
    #[arg(long)]
    foxglove: bool,
    /// Also compare the group with and without the live Foxglove server followed by Rerun's
    /// own viewer (`python3 SCRIPT --live ADDR -o FILE.rrd`, SCRIPT being
    /// `python/tes/rerun_view.py`; needs rerun-sdk, mcap and websockets), in alternating
    /// blocks as `--record`'s.
    #[arg(long, value_name = "SCRIPT")]
    rerun: Option<PathBuf>,
    /// With `--record`, `--foxglove` or `--rerun`: blocks of each kind; each measures `--actions / N`
    /// actions after the warm-up.
    #[arg(long, default_value_t = 4, value_name = "N")]
    record_blocks: u64,
    /// How the processes reach each other: shm (one host, iceoryx2 only; the floor a raw
    /// iceoryx2 relay) or zenoh (the group split in two launches, perception-sim and bridge
    /// in one, the controller in the other, each in an iceoryx2 domain of its own, linked by
    /// Zenoh over loopback TCP; the floor the same two hops over a Zenoh link with no work).
    #[arg(long, value_enum, default_value = "shm")]
    via: ViaArg,
}

/// `tes bench latency --pace`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum PaceArg {
    /// Actions back to back.
    Fastest,
    /// The robot's own.
    Real,
}

/// `tes bench latency --via`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ViaArg {
    /// One host, shared memory.
    Shm,
    /// Two launches linked by Zenoh over loopback TCP.
    Zenoh,
    /// Two launches linked by Zenoh over QUIC with the run's own keys (TLS 1.3, both sides
    /// authenticated), as hosts are linked.
    ZenohTls,
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

/// `tes bench zenoh-floor-hop`: the floor's controller side.
fn zenoh_floor_hop(args: &FloorHopArgs) -> Result<()> {
    let settings = HopSettings {
        connect: args.connect.clone(),
        group: args.group.clone(),
        prefix: args.prefix.clone(),
        wait: parse_wait(&args.wait)?,
        hop_cpu: args.hop_cpu,
        answer: args.answer,
        warmup: args.warmup,
        budget_us: args.budget_us,
        report: args.report.clone(),
        tls: args.tls.clone().and_then(|files| files.try_into().ok()),
    };
    Ok(floor::zenoh_hop(&settings)?)
}

/// `--wait`'s strategy.
fn parse_wait(wait: &str) -> Result<WaitStrategy> {
    wait.parse().map_err(|e| anyhow::anyhow!("--wait: {e}"))
}

/// The harness's settings from `tes bench latency`'s flags.
fn latency_settings(args: &LatencyArgs) -> Result<LatencySettings> {
    let planning = match args.planning.as_deref() {
        None => PlanningMode::Auto,
        Some(p) => p.parse().map_err(|e| anyhow::anyhow!("--planning: {e}"))?,
    };
    let pace = match args.pace {
        PaceArg::Fastest => Pace::Fastest,
        PaceArg::Real => Pace::Real,
    };
    Ok(LatencySettings {
        actions: args.actions.unwrap_or(pace.default_actions()),
        budget_us: args.budget_us,
        wait: parse_wait(&args.wait)?,
        views: args.views,
        warmup: args.warmup.unwrap_or(pace.default_warmup()),
        pace,
        seed: args.seed,
        out: args.out.clone(),
        acting_cpu: args.acting_cpu,
        planner_cpu: args.planner_cpu,
        planning,
        order: args.order,
        planner_idle_spin_us: args.planner_idle_spin_us,
        record: args.record,
        foxglove: args.foxglove,
        rerun: args.rerun.clone(),
        record_blocks: args.record_blocks,
        via: match args.via {
            ViaArg::Shm => Via::Shm,
            ViaArg::Zenoh => Via::Zenoh,
            ViaArg::ZenohTls => Via::ZenohTls,
        },
    })
}

/// Every program the harness starts is this executable: `tes child`, `tes launch`,
/// `tes bench relay`, `tes bench zenoh-floor-hop`.
fn programs() -> Result<Programs> {
    let child = this_executable()?;
    let exe = child.program.clone();
    let tes = |args: &[&str]| {
        args.iter()
            .fold(tes_launch::ChildCommand::new(exe.clone()), |c, a| c.arg(a))
    };
    Ok(Programs {
        child,
        launch: tes(&["launch"]),
        relay: tes(&["bench", "relay"]),
        floor_hop: tes(&["bench", "zenoh-floor-hop"]),
    })
}

/// `tes bench latency`: runs the harness, its progress on stderr, the launches' warnings and
/// failures as `tes launch` prints them; then the table, or one JSON object.
fn latency(args: &LatencyArgs) -> Result<()> {
    let checked = latency_settings(args)?.check()?;
    let mut printer = Printer {
        echo: false,
        ..Printer::default()
    };
    let mut notes = |note: &Note| eprintln!("{note}");
    let mut harness = Harness {
        programs: programs()?,
        stop: stop_on_signals()?,
        observer: &mut printer,
        notes: &mut notes,
    };
    let result = tes_bench::latency::run(&checked, &mut harness)?;
    if args.json {
        println!("{}", serde_json::to_string(&result)?);
    } else {
        print_latency(&result, checked.settings().warmup);
    }
    Ok(())
}

/// The latency run as a table: the floor, ours and the controller's parts, the ratios, the
/// recorder's cost, and the planner's work.
fn print_latency(result: &LatencyResult, warmup: u64) {
    let cpu = |c: Option<usize>| c.map_or("unpinned".to_owned(), |c| format!("CPU {c}"));
    println!(
        "tes bench latency: pace {}, wait {}, {}, {} actions measured (+{warmup} warm-up), {} views, budget {} us, one action every {} us; \
         acting thread and floor hop {}, planner (and the floor's helper) {}, polling {} us after each plan",
        result.pace,
        result.wait,
        result.order,
        result.actions,
        result.views,
        result.budget_us,
        result.cycle_us,
        cpu(result.acting_cpu),
        cpu(result.planner_cpu),
        result.planner_idle_spin_us
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
        match result.via {
            Via::Shm => "floor (raw two-hop relay)",
            Via::Zenoh => "floor (two hops over Zenoh)",
            Via::ZenohTls => "floor (two hops over Zenoh, QUIC with TLS)",
        },
        &result.floor(),
    );
    row("floor: first hop only", &result.floor_decision);
    if let Some(awake) = &result.floor_awake {
        row("floor, every CPU kept awake", &awake.round_trip);
        row("  its first hop only", &awake.first_hop);
    }
    row("ours: observation -> bridge", &result.ours());
    row("ours: controller decision only", &result.decision);
    row("  of which: stamp -> received", &result.wake);
    row("  of which: received -> published", &result.compute);
    if result.learn.count > 0 {
        row("learning after the command", &result.learn);
    }
    println!(
        "ratio ours/floor: p50 {:.2}, p99 {:.2}{}; allocations on the acting path: {}",
        result.ratio_p50,
        result.ratio_p99,
        if result.floor_comparable {
            ""
        } else {
            " — floor not comparable (a ratio below 0.9: the group had a help the floor lacked)"
        },
        match (result.allocations, result.ipc_allocations) {
            (Some(n), Some(ipc)) => format!("{n} ({ipc} inside iceoryx2's send)"),
            _ => "not counted".to_owned(),
        }
    );
    if let Some(awake) = &result.floor_awake {
        println!(
            "ratio ours/floor with every CPU kept awake: p50 {:.2}, p99 {:.2}{}",
            awake.ratio_p50,
            awake.ratio_p99,
            if awake.comparable {
                ""
            } else {
                " — not comparable either"
            }
        );
    }
    print_cpu(result);
    for r in [&result.recorder, &result.foxglove, &result.rerun]
        .into_iter()
        .flatten()
    {
        print_observer_cost(r);
    }
    // A planner thread yields to everything: where the measured loops keep both CPUs busy
    // (spin on two cores) it barely runs, and the agent acts on an old policy.
    if result.learn.count > 0 {
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
        (result.actions + warmup) as f64 / result.plans.max(1) as f64
    );
}

/// Each process's CPU, the group's then the floor's, and the anticipating receivers' catches.
fn print_cpu(result: &LatencyResult) {
    println!(
        "{:<34} {:>12} {:>12}",
        "CPU over the measured actions", "core share", "us/action"
    );
    let rows = result
        .cpu
        .iter()
        .map(|(name, used)| (format!("ours: {name}"), used))
        .chain(
            result
                .floor_cpu
                .iter()
                .map(|(role, used)| (format!("floor: {role}"), used)),
        );
    for (name, used) in rows {
        println!(
            "{:<34} {:>11.2}% {:>12.1}",
            name,
            100.0 * used.core_share,
            used.us_per_action
        );
    }
    for (who, c) in &result.catches {
        println!(
            "anticipation ({who}): {} caught polling, {} woken (early, late or unannounced), {} windows passed empty",
            c.polled, c.woken, c.missed_windows
        );
    }
}

/// An observer comparison's blocks and medians, as a table.
fn print_observer_cost(r: &RecorderComparison) {
    let name = r.watcher.name();
    println!("the {name}'s cost (blocks in the order they ran; observation -> bridge):");
    let what = match r.watcher {
        Watcher::Recorder => "written obs/cmd/motor",
        Watcher::Foxglove => "viewer received",
        Watcher::Rerun => "Rerun drew",
    };
    println!(
        "{:>5} {:>16} {:>8} {:>8} {:>7} {:>12} {:>24} {:>7}",
        "block", name, "p50 us", "p99 us", "misses", "allocations", what, "missed"
    );
    for (i, b) in r.blocks.iter().enumerate() {
        let count = match (b.written, b.viewer_messages) {
            (Some([o, c, m]), _) => format!("{o}/{c}/{m}"),
            (None, Some(n)) => n.to_string(),
            (None, None) => "-".to_owned(),
        };
        println!(
            "{:>5} {:>16} {:>8} {:>8} {:>7} {:>12} {:>24} {:>7}",
            i + 1,
            if b.recorded { "with" } else { "without" },
            b.p50_us,
            b.p99_us,
            b.misses,
            b.allocations.map_or("-".to_owned(), |n| n.to_string()),
            count,
            b.missed.map_or("-".to_owned(), |n| n.to_string()),
        );
    }
    println!(
        "medians: without p50 {:.1} us, p99 {:.1} us; with p50 {:.1} us ({:+.1} %), p99 {:.1} us ({:+.1} %); \
         allocations on the acting path with the {name}: {}",
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

/// `tes bench scaling`: the sweep, a row per point as it is measured (or one JSON array at
/// the end), and with `--out` its files.
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
        scaling::write(dir, &points)?;
        if !args.json {
            println!("wrote {}", dir.display());
        }
    }
    if args.json {
        println!("{}", serde_json::to_string(&points)?);
    }
    Ok(())
}
