//! `tes experiment all --full`: every committed result folder regenerated, each from the
//! settings its manifest records, one after another with progress, resumable.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use tes_experiments::experiment::Experiment;
use tes_experiments::fig4::Fig4Config;
use tes_experiments::grid::GridConfig;
use tes_experiments::jobs::{JobOptions, Manifest, Shard};
use tes_experiments::lifelong::LifelongConfig;
use tes_experiments::robot::RobotConfig;
use tes_experiments::transfer::TransferConfig;

use super::print_summary;
use super::progress::{stop_on_interrupt, with_progress};

/// The result folders of `from` (those with an experiment's manifest), by name.
pub(super) fn committed_folders(from: &Path) -> Result<Vec<(String, Manifest)>> {
    let mut folders = Vec::new();
    let entries =
        std::fs::read_dir(from).with_context(|| format!("cannot list {}", from.display()))?;
    for entry in entries {
        let dir = entry
            .with_context(|| format!("cannot list {}", from.display()))?
            .path();
        if !dir.join("manifest.json").is_file() {
            continue;
        }
        let manifest = Manifest::read(&dir)?;
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .context("a result folder without a name")?;
        folders.push((name, manifest));
    }
    folders.sort_by(|a, b| a.0.cmp(&b.0));
    if folders.is_empty() {
        bail!("{} holds no result folder", from.display());
    }
    Ok(folders)
}

/// The folder `--from` takes when not given, and a regeneration did not record one.
const DEFAULT_FROM: &str = "docs/results";

/// The file in OUT that records the folder a regeneration into OUT is made from, so that
/// `--resume OUT` needs nothing else.
const FROM_RECORD: &str = "regenerated-from.txt";

/// The folder to regenerate into `out` from: `given`, or the one `out` records, or
/// [`DEFAULT_FROM`]. A `given` folder other than the recorded one is refused: the result
/// folders of one OUT come from one source.
fn source_of(given: Option<&Path>, out: &Path) -> Result<PathBuf> {
    let record = out.join(FROM_RECORD);
    let recorded = match std::fs::read_to_string(&record) {
        Ok(text) => Some(PathBuf::from(text.trim_end_matches('\n'))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", record.display())),
    };
    let from = match (given, recorded) {
        (Some(given), Some(recorded)) => {
            let given = std::path::absolute(given)
                .with_context(|| format!("cannot resolve {}", given.display()))?;
            if given != recorded {
                bail!(
                    "{} was regenerated from {}, not {}: resume it without --from, or give a new --out",
                    out.display(),
                    recorded.display(),
                    given.display()
                );
            }
            given
        }
        (None, Some(recorded)) => recorded,
        (given, None) => {
            let from = given.unwrap_or(Path::new(DEFAULT_FROM));
            std::path::absolute(from)
                .with_context(|| format!("cannot resolve {}", from.display()))?
        }
    };
    Ok(from)
}

/// Records in `out` the folder it is regenerated from (once that folder has been read).
fn record_source(from: &Path, out: &Path) -> Result<()> {
    let record = out.join(FROM_RECORD);
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let text = from
        .to_str()
        .with_context(|| format!("{} is not UTF-8", from.display()))?;
    std::fs::write(&record, format!("{text}\n"))
        .with_context(|| format!("cannot write {}", record.display()))
}

/// Regenerates every result folder of `from` (or of the folder `out` records) into
/// `out/NAME`; a folder `out/NAME` already holds is resumed (its finished runs kept), so an
/// interrupted `--full` goes on where it stopped when given the same `--out` again.
pub(super) fn run_full(from: Option<&Path>, out: &Path, allow_dirty: bool) -> Result<()> {
    let from = &source_of(from, out)?;
    // Read before it is recorded: a mistyped --from is not kept for every later --resume.
    let folders = committed_folders(from)?;
    record_source(from, out)?;
    let dirs: Vec<PathBuf> = folders.iter().map(|(name, _)| out.join(name)).collect();
    stop_on_interrupt(out, "all --full", &dirs)?;
    let started = std::time::Instant::now();
    for (i, ((name, manifest), dir)) in folders.iter().zip(&dirs).enumerate() {
        eprintln!(
            "[{}/{}] {name}: regenerating {} from {}",
            i + 1,
            folders.len(),
            manifest.experiment,
            from.join(name).display()
        );
        let options = JobOptions {
            shard: Shard::ALL,
            resume: dir.join("manifest.json").is_file(),
            allow_dirty,
        };
        match manifest.experiment.as_str() {
            GridConfig::NAME => one::<GridConfig>(manifest, dir, options)?,
            TransferConfig::NAME => one::<TransferConfig>(manifest, dir, options)?,
            RobotConfig::NAME => one::<RobotConfig>(manifest, dir, options)?,
            Fig4Config::NAME => one::<Fig4Config>(manifest, dir, options)?,
            LifelongConfig::NAME => one::<LifelongConfig>(manifest, dir, options)?,
            other => bail!(
                "unknown experiment {other:?} in {}",
                from.join(name).display()
            ),
        }
    }
    // Every stretch of every folder, resumed ones included, from the manifests.
    let mut running = 0.0;
    for dir in &dirs {
        running += Manifest::read(dir)?.run_seconds.unwrap_or(0.0);
    }
    println!(
        "regenerated {} result folders into {}: {:.0} s of running in all (this invocation: {:.0} s)",
        folders.len(),
        out.display(),
        running,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// One folder: its manifest's settings, run with progress, its summary printed.
fn one<E: Experiment>(manifest: &Manifest, dir: &Path, options: JobOptions) -> Result<()> {
    let config: E = manifest.settings()?;
    if let Some(report) = with_progress(&config, dir, options, options.resume)? {
        print_summary(E::console(&report, dir))?;
    }
    Ok(())
}
