//! `tes` — the front door to TES: fit views on data, and (as the system grows) launch the
//! process group, rerun the paper's experiments, inspect view libraries and run benchmarks.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod experiment;
mod fit;

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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Fit(args) => fit::run(&args),
        Command::Experiment(args) => experiment::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
