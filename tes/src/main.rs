//! `tes` — the front door to TES: launch the process group and look at it (`status`,
//! `replay`), rerun the paper's experiments, fit views on data, inspect view libraries and run
//! benchmarks. Each subcommand is a thin shell over a library crate.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod bench;
mod experiment;
mod fit;
mod launch;
mod library;
mod link;
mod record;
mod status;

/// TES: online sparse view learning (mDAGL), model-based RL and transfer for a real-time robot.
#[derive(Debug, Parser)]
#[command(name = "tes", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run mDAGL once over a labelled CSV stream and report how well it predicted and what it kept.
    Fit(fit::FitArgs),
    /// Rerun the paper's experiments: summary.json, per-episode CSV and SVG plots.
    Experiment(experiment::ExperimentArgs),
    /// Inspect a saved view library.
    Library(library::LibraryArgs),
    /// Start perception-sim, controller and bridge as one process group.
    Launch(launch::LaunchArgs),
    /// List the process groups running on this machine: their processes, pids, uptime and
    /// progress, and crashed groups' stale resources.
    Status(status::StatusArgs),
    /// Replay a recorded run (`tes launch --record`) through the acting loop and check every
    /// decision; or summarise it, or export it as CSV.
    Replay(record::ReplayArgs),
    /// Latency benchmarks: the real loop against the raw iceoryx2 floor, and scaling sweeps.
    Bench(bench::BenchArgs),
    /// The link between hosts: `keygen` makes the keys of a TLS group.
    Link(link::LinkArgs),
    /// Run one process of the group (used by `tes launch`).
    #[command(hide = true)]
    Child {
        /// perception-sim, controller or bridge.
        role: tes_topics::Role,
        /// The role's settings (TOML).
        #[arg(long)]
        config: std::path::PathBuf,
    },
}

/// Children log to stderr (their log file in the run directory, which the launcher relays to
/// its terminal), level from `RUST_LOG` (default: warnings and errors only; the launcher
/// prints the per-episode lines). RustDDS's own lines are left out by default: a ROS 2
/// world's DDS logs every send to a peer's IPv6 locator this host cannot reach as a warning,
/// and a large map's fragment bookkeeping as an error, while the exchange works; what
/// matters is said by the world itself (no map, no step from the robot).
/// `RUST_LOG=warn,rustdds=warn` shows them.
fn init_child_logging() {
    tes_runtime::logging::init("warn,rustdds=off");
}

/// Counts the controller child's acting-path allocations for its report.
#[global_allocator]
static ALLOCATOR: tes_runtime::alloc_count::CountingAllocator =
    tes_runtime::alloc_count::CountingAllocator;

fn main() -> ExitCode {
    let cli = Cli::parse();
    // Die quietly on a closed pipe (`tes library show … | head`), as command-line tools do,
    // instead of panicking on the next print — but not the launcher nor its children: a
    // closed pipe must never end a run before the library is saved (their output is written
    // so that a closed pipe only silences it).
    if !matches!(cli.command, Command::Launch(_) | Command::Child { .. }) {
        // SAFETY: called in `main` before any other thread exists; SIG_DFL for SIGPIPE
        // installs no handler code.
        unsafe {
            let _ = nix::sys::signal::signal(
                nix::sys::signal::Signal::SIGPIPE,
                nix::sys::signal::SigHandler::SigDfl,
            );
        }
    }
    let result = match cli.command {
        Command::Fit(args) => fit::run(&args),
        Command::Experiment(args) => experiment::run(&args),
        Command::Library(args) => library::run(&args),
        Command::Launch(args) => launch::run(&args),
        Command::Status(args) => status::run(&args),
        Command::Replay(args) => record::run(&args),
        Command::Bench(args) => bench::run(&args),
        Command::Link(args) => link::run(&args),
        Command::Child { role, config } => {
            init_child_logging();
            return match tes_launch::run_role(role, &config) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    // The bridge's link-down status tells the supervisor not to respawn it.
                    let status = u8::try_from(e.exit_status()).unwrap_or(1);
                    eprintln!("error: {:#}", anyhow::Error::from(e));
                    ExitCode::from(status)
                }
            };
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
