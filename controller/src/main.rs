//! `controller` — the TES controller process: learns views, plans and acts on perception's
//! observations, commanding the bridge over iceoryx2. Usually started by `tes launch`.
//!
//! ```text
//! tes-controller run [--config FILE] [--library PATH] [--budget-us B] [--wait STRATEGY]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use tes_controller::config::ControllerConfig;
use tes_controller::process;

#[derive(Debug, Parser)]
#[command(
    name = "tes-controller",
    version,
    about = "TES controller process: learn, plan, act"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Run until SIGINT/SIGTERM.
    Run(RunArgs),
}

/// Options of `tes-controller run`; each overrides the config file's key of the same name.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// TOML file with the controller's settings (keys of `ControllerConfig`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// The view library file.
    #[arg(long)]
    library: Option<PathBuf>,
    /// Per-action latency budget, µs.
    #[arg(long)]
    budget_us: Option<u64>,
    /// block, spin, spin-then-block or spin-then-block:<µs>.
    #[arg(long)]
    wait: Option<String>,
    /// Exploration seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Prefix of every iceoryx2 service name.
    #[arg(long)]
    service_prefix: Option<String>,
}

fn config(args: &RunArgs) -> anyhow::Result<ControllerConfig> {
    let mut cfg = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read {}", path.display()))?;
            ControllerConfig::from_toml(&text).with_context(|| format!("in {}", path.display()))?
        }
        None => ControllerConfig::default(),
    };
    if let Some(v) = &args.library {
        cfg.library = Some(v.clone());
    }
    if let Some(v) = args.budget_us {
        cfg.budget_us = v;
    }
    if let Some(v) = &args.wait {
        cfg.wait = v.parse().with_context(|| "--wait")?;
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

/// Counts the acting loop's allocations for the run's report.
#[global_allocator]
static ALLOCATOR: tes_runtime::alloc_count::CountingAllocator =
    tes_runtime::alloc_count::CountingAllocator;

fn main() -> ExitCode {
    tes_runtime::logging::init("info");
    let Cmd::Run(args) = Cli::parse().command;
    let result = config(&args).and_then(|cfg| {
        let stop =
            tes_runtime::signals::stop_on_signals().context("cannot install signal handlers")?;
        let summary = process::run_to_end(&cfg, &stop)?;
        if summary.failed_saves > 0 {
            anyhow::bail!("{} library saves failed", summary.failed_saves);
        }
        Ok(())
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("controller: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
