//! `tes replay`: a recorded run replayed through the acting loop, summarised or exported.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use tes_recorder::reader::Recording;

/// Arguments of `tes replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// A recording (`tes launch --record FILE.mcap`).
    file: PathBuf,
    /// Print the run as `tes launch` did (episodes, rewards, latency percentiles) from the
    /// file alone, without replaying.
    #[arg(long)]
    summary: bool,
    /// Write one CSV file per topic into DIR, without replaying.
    #[arg(long, value_name = "DIR")]
    export_csv: Option<PathBuf>,
}

/// Runs `tes replay`.
pub fn run(args: &ReplayArgs) -> Result<()> {
    let recording = Recording::open(&args.file)?;
    if let Some(why) = &recording.truncated {
        eprintln!(
            "replay: {} is incomplete: {why}; read {} observations and {} commands up to there",
            args.file.display(),
            recording.observations.len(),
            recording.commands.len()
        );
    }
    if let Some(dir) = &args.export_csv {
        for path in tes_recorder::summary::export_csv(&recording, dir)? {
            println!("replay: wrote {}", path.display());
        }
    }
    if args.summary {
        println!("{}", tes_recorder::summary::summarise(&recording));
        if recording.observations.is_empty() && recording.commands.is_empty() {
            bail!(
                "{} holds no observation and no command: there is nothing of the run to summarise",
                args.file.display()
            );
        }
    }
    if args.summary || args.export_csv.is_some() {
        return Ok(());
    }
    let missed = recording
        .end
        .as_ref()
        .and_then(|e| e.get("missed_commands"))
        .map_or("0", String::as_str);
    if missed != "0" {
        eprintln!("replay: the recorder missed {missed} commands; those steps cannot be compared");
    }
    let outcome = tes_recorder::replay::replay(&recording)
        .with_context(|| format!("cannot replay {}", args.file.display()))?;
    println!("replay: {outcome}");
    if outcome.divergence.is_some() {
        bail!("the replay diverged from the recording");
    }
    if outcome.unanswerable > 0 {
        bail!(
            "{} misses observations its commands answer: the run cannot be checked whole",
            args.file.display()
        );
    }
    Ok(())
}
