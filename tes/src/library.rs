//! `tes library show|export [PATH]`: what a saved view library holds — by default the robot's
//! own, `library.tesl` in the data directory, which `tes launch` loads and saves.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use serde::Serialize;
use tes_learning::library::store::{self, FORMAT_VERSION, MAGIC, StoredLibrary};

/// Arguments of `tes library`.
#[derive(Debug, Args)]
pub struct LibraryArgs {
    #[command(subcommand)]
    which: Which,
}

#[derive(Debug, Subcommand)]
enum Which {
    /// Print each view: its action, selected features, track record, tasks won, scores.
    Show {
        /// The library file (default: the robot's library, `library.tesl` in the data
        /// directory: `$TES_DATA_DIR`, else `$XDG_DATA_HOME/tes`, else `~/.local/share/tes`).
        path: Option<PathBuf>,
    },
    /// The same as one JSON object on stdout.
    Export {
        /// The library file (default: the robot's library, as for `show`).
        path: Option<PathBuf>,
        /// Emit JSON: the only format, and the default; accepted so that scripts may say it.
        #[arg(long)]
        json: bool,
    },
}

/// The report `show` prints and `export` emits as JSON.
#[derive(Debug, Serialize)]
struct Report {
    file: String,
    format_version: u32,
    world: String,
    actions: usize,
    effects: usize,
    features: usize,
    tasks_seen: u32,
    max_views: usize,
    growth_threshold: f64,
    recency: f64,
    lambda: f64,
    alpha: f64,
    views: Vec<ViewReport>,
}

#[derive(Debug, Serialize)]
struct ViewReport {
    id: u64,
    action: usize,
    action_name: Option<String>,
    updates: u64,
    selected_features: Vec<usize>,
    selected_feature_names: Option<Vec<String>>,
    /// Φ for the next task.
    track_record: f64,
    tasks_won: Vec<u32>,
    scores: Vec<ScoreReport>,
}

#[derive(Debug, Serialize)]
struct ScoreReport {
    task: u32,
    score: f64,
    observations: u64,
    won: bool,
}

/// The format version the file at `path` says it is in (a library that prunes to its limit
/// is written as version 1, which older builds read, though this build writes up to
/// [`FORMAT_VERSION`]); `None` if its header cannot be read.
fn format_version_of(path: &Path) -> Option<u32> {
    use std::io::Read as _;
    let mut header = [0u8; 12];
    std::fs::File::open(path)
        .ok()?
        .read_exact(&mut header)
        .ok()?;
    let (magic, version) = header.split_at(8);
    if magic != MAGIC {
        return None;
    }
    Some(u32::from_le_bytes(version.try_into().ok()?))
}

fn report(path: &std::path::Path, stored: &StoredLibrary) -> Report {
    let l = &stored.library;
    let p = l.params();
    let name = |names: &[String], i: usize| names.get(i).cloned();
    Report {
        file: path.display().to_string(),
        format_version: format_version_of(path).unwrap_or(FORMAT_VERSION),
        world: stored.world.clone(),
        actions: l.n_actions(),
        effects: l.n_effects(),
        features: l.n_features(),
        tasks_seen: l.tasks_seen(),
        max_views: p.max_views,
        growth_threshold: p.growth_threshold,
        recency: p.recency,
        lambda: p.mdagl.lambda,
        alpha: p.mdagl.alpha,
        views: l
            .views()
            .iter()
            .map(|v| {
                let selected: Vec<usize> = v.model().selected_features().collect();
                ViewReport {
                    id: v.id(),
                    action: v.action(),
                    action_name: name(&stored.action_names, v.action()),
                    updates: v.model().n_updates(),
                    selected_feature_names: (!stored.feature_names.is_empty()).then(|| {
                        selected
                            .iter()
                            .map(|&i| name(&stored.feature_names, i).unwrap_or_default())
                            .collect()
                    }),
                    selected_features: selected,
                    track_record: l.track_record(v),
                    tasks_won: v.wins().to_vec(),
                    scores: v
                        .history()
                        .iter()
                        .map(|h| ScoreReport {
                            task: h.task,
                            score: h.score,
                            observations: h.observations,
                            won: h.won,
                        })
                        .collect(),
                }
            })
            .collect(),
    }
}

/// Runs `tes library`.
pub fn run(args: &LibraryArgs) -> Result<()> {
    let default = tes_controller::config::default_library_path;
    match &args.which {
        Which::Show { path } => {
            let path = library_file(path.as_deref(), default)?;
            let r = report(&path, &store::load(&path)?);
            print_report(&r);
        }
        Which::Export { path, .. } => {
            let path = library_file(path.as_deref(), default)?;
            let r = report(&path, &store::load(&path)?);
            println!("{}", serde_json::to_string_pretty(&r)?);
        }
    }
    Ok(())
}

/// The library file to read: `path` if given (the loader names it if it cannot be read),
/// else the `default` one — which must be there: without it, says that there is no library
/// yet and how one comes about, rather than a bare "no such file".
fn library_file(path: Option<&Path>, default: impl FnOnce() -> PathBuf) -> Result<PathBuf> {
    if let Some(path) = path {
        return Ok(path.to_owned());
    }
    let path = default();
    match std::fs::symlink_metadata(&path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "no library at {} yet: run `tes launch` first (it saves the robot's view library \
             there), or give a library file",
            path.display()
        ),
        // Anything there is the loader's to open, or to say why it cannot.
        _ => Ok(path),
    }
}

fn print_report(r: &Report) {
    println!("view library {} (format v{})", r.file, r.format_version);
    println!(
        "  world: {}; {} actions, {} effects, {} features",
        r.world, r.actions, r.effects, r.features
    );
    println!(
        "  {} tasks seen; M = {}, c = {:.3}, mu = {}; fresh views: lambda = {}, alpha = {}",
        r.tasks_seen, r.max_views, r.growth_threshold, r.recency, r.lambda, r.alpha
    );
    println!("  {} views", r.views.len());
    for v in &r.views {
        let action = v
            .action_name
            .as_ref()
            .map_or_else(|| v.action.to_string(), |n| format!("{} ({n})", v.action));
        println!(
            "view {}: action {action}, {} updates, track record {:.3}",
            v.id, v.updates, v.track_record
        );
        let features = match &v.selected_feature_names {
            Some(names) => names.join(", "),
            None => v
                .selected_features
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", "),
        };
        println!(
            "  selected features ({}): {}",
            v.selected_features.len(),
            if features.is_empty() {
                "none"
            } else {
                &features
            }
        );
        println!(
            "  tasks won: {}",
            v.tasks_won
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        );
        let scores: Vec<String> = v
            .scores
            .iter()
            .map(|s| {
                format!(
                    "task {}: {:.2} over {} obs{}",
                    s.task,
                    s.score,
                    s.observations,
                    if s.won { " (won)" } else { "" }
                )
            })
            .collect();
        println!("  scores: {}", scores.join("; "));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_a_path_the_default_library_is_read_and_its_absence_said() {
        let dir = tempfile::tempdir().unwrap();
        let default = dir.path().join("data/library.tesl");
        let err = library_file(None, || default.clone())
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with(&format!("no library at {} yet: ", default.display()))
                && err.contains("run `tes launch` first"),
            "{err}"
        );
        std::fs::create_dir_all(dir.path().join("data")).unwrap();
        std::fs::write(&default, b"whatever is there is the loader's to judge").unwrap();
        assert_eq!(library_file(None, || default.clone()).unwrap(), default);
        // A given path is used as it is, there or not (the loader names it).
        let given = dir.path().join("elsewhere.tesl");
        assert_eq!(
            library_file(Some(&given), || unreachable!("no default needed")).unwrap(),
            given
        );
    }
}
