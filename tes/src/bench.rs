//! `tes bench latency` and `tes bench scaling`: the command line of [`tes_bench`]'s
//! harnesses — the controller's per-action latency measured against its floor in the same
//! run ([`tes_bench::latency`]), and how a decision's cost grows with features and views
//! ([`tes_bench::scaling`]). This module reads the flags, names this executable as every
//! program the harness starts, prints the launches' warnings and the harness's progress, and
//! prints the results.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use tes_bench::floor::{self, HopSettings};
use tes_bench::relay::{self, RelayConfig};
use tes_bench::scaling::{self, ScalingSettings};
use tes_bench::{Harness, LatencySettings, Note, Programs};
use tes_runtime::channel::WaitStrategy;

use crate::launch::{
    Printer, exit_as_signalled, signal_received, stop_on_signals, this_executable,
};

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

/// Arguments of `tes bench latency`: the harness's settings (defined once, in
/// [`LatencySettings`]) and how to print.
#[derive(Debug, Args)]
pub struct LatencyArgs {
    #[command(flatten)]
    settings: LatencySettings,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

/// Arguments of `tes bench scaling`: the sweep's settings (defined once, in
/// [`ScalingSettings`]) and where its results go.
#[derive(Debug, Args)]
pub struct ScalingArgs {
    #[command(flatten)]
    settings: ScalingSettings,
    /// Write scaling.json, scaling.csv and the two SVG charts here.
    #[arg(long)]
    out: Option<PathBuf>,
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
    let checked = args.settings.clone().check()?;
    let mut printer = Printer {
        echo: false,
        ..Printer::default()
    };
    let mut notes = |note: &Note| eprintln!("{note}");
    let signalled = signal_received()?;
    let mut harness = Harness {
        programs: programs()?,
        stop: stop_on_signals()?,
        observer: &mut printer,
        notes: &mut notes,
    };
    let result = tes_bench::latency::run(&checked, &mut harness);
    exit_if_stopped(&signalled, "tes bench latency");
    let result = result?;
    if args.json {
        println!("{}", serde_json::to_string(&result)?);
    } else {
        print!(
            "{}",
            tes_bench::table::latency(&result, checked.settings().warmup())
        );
    }
    Ok(())
}

/// A bench that Ctrl-C or SIGTERM stopped has no figures to give (its runs were cut short):
/// it says so, instead of the shortfall the cut left, and exits as a signalled command does
/// (130 after Ctrl-C, 143 after SIGTERM).
fn exit_if_stopped(signalled: &AtomicUsize, what: &str) {
    if signalled.load(Ordering::Relaxed) != 0 {
        eprintln!("{what}: stopped before its runs were complete; no figures");
        exit_as_signalled(signalled);
    }
}

/// `tes bench scaling`: the sweep, a row per point as it is measured (or one JSON array at
/// the end), and with `--out` its files.
fn scaling_sweep(args: &ScalingArgs) -> Result<()> {
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
    let points = args.settings.sweep(|p| {
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
