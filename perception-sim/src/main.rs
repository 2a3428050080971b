//! `perception-sim` — the TES perception process: a simulated §5.2 arena and its overhead
//! camera, publishing observations over iceoryx2. Usually started by `tes launch`.
//!
//! ```text
//! tes-perception-sim run [--config FILE] [--arena 1|2|3] [--episodes N] [--seed S]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use tes_perception_sim::process::{self, PerceptionConfig};

#[derive(Debug, Parser)]
#[command(
    name = "tes-perception-sim",
    version,
    about = "TES perception process: a simulated arena and its camera"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Run the configured episodes (or until SIGINT/SIGTERM).
    Run(RunArgs),
}

/// Options of `tes-perception-sim run`; each overrides the config file's key of the same name.
#[derive(Debug, clap::Args)]
struct RunArgs {
    /// TOML file with the perception settings (keys of `PerceptionConfig`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Arena 1, 2 or 3.
    #[arg(long)]
    arena: Option<u32>,
    /// Episodes to run.
    #[arg(long)]
    episodes: Option<u32>,
    /// Seed of start poses and slip.
    #[arg(long)]
    seed: Option<u64>,
    /// Prefix of every iceoryx2 service name.
    #[arg(long)]
    service_prefix: Option<String>,
}

fn config(args: &RunArgs) -> anyhow::Result<PerceptionConfig> {
    let mut cfg = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read {}", path.display()))?;
            PerceptionConfig::from_toml(&text).with_context(|| format!("in {}", path.display()))?
        }
        None => PerceptionConfig::default(),
    };
    if let Some(v) = args.arena {
        cfg.arena = v;
    }
    if let Some(v) = args.episodes {
        cfg.episodes = v;
    }
    if let Some(v) = args.seed {
        cfg.seed = v;
    }
    if let Some(v) = &args.service_prefix {
        cfg.service_prefix.clone_from(v);
    }
    cfg.check()?;
    Ok(cfg)
}

fn main() -> ExitCode {
    tes_runtime::logging::init("info");
    let Cmd::Run(args) = Cli::parse().command;
    let result = config(&args).and_then(|cfg| {
        let stop =
            tes_runtime::signals::stop_on_signals().context("cannot install signal handlers")?;
        let s = process::run(&cfg, &stop)?;
        println!(
            "perception-sim: {} episodes, {} observations ({} re-published), total reward {:.2}",
            s.episodes, s.observations, s.resyncs, s.reward
        );
        Ok(())
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("perception-sim: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
