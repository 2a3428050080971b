//! Redraws the figures a result folder's `summary.json` holds the data of, without rerunning
//! the experiment — for when the figures' look changes and the runs took long.
//!
//! A transfer summary keeps every task's jumpstarts (Table 2, `table2.svg`), a grid summary
//! every final reward by feature count (Fig. 3c, `fig3c.svg`). The curves of Figs. 3a–b, 4b,
//! 8 and 9 are drawn from every episode of every run (`episodes.csv`), which the summaries do
//! not hold: those need the experiment rerun.

use std::collections::BTreeMap;
use std::fmt;
use std::fs;
use std::io;
use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::stats::Summary;
use crate::{grid, transfer};

/// What [`replot`] did in a result folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Replotted {
    /// Which experiment the summary came from: "grid", "transfer" or "robot".
    pub experiment: &'static str,
    /// The figures redrawn.
    pub written: Vec<PathBuf>,
    /// The experiment's other figures, which need its episodes and so a rerun.
    pub not_redrawn: Vec<&'static str>,
}

/// Why [`replot`] redrew nothing; every case names the file. Nothing is written unless the
/// whole summary reads.
#[derive(Debug)]
pub enum ReplotError {
    /// `summary.json` cannot be read (missing, unreadable, not text).
    Read {
        /// The summary's path.
        path: PathBuf,
        /// What reading it said.
        error: io::Error,
    },
    /// `summary.json` is not JSON.
    NotJson {
        /// The summary's path.
        path: PathBuf,
        /// Where and why parsing stopped.
        error: serde_json::Error,
    },
    /// The JSON is not the summary of `tes experiment grid`, `transfer` or `robot`.
    NotASummary {
        /// The summary's path.
        path: PathBuf,
    },
    /// The summary lacks, or mangles, the numbers a figure is drawn from.
    Malformed {
        /// The summary's path.
        path: PathBuf,
        /// The figure being redrawn.
        figure: &'static str,
        /// What is wrong, and where.
        problem: String,
    },
    /// The redrawn figure cannot be written.
    Write {
        /// The figure's path.
        path: PathBuf,
        /// What writing it said.
        error: io::Error,
    },
}

impl fmt::Display for ReplotError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ReplotError::Read { path, error } => {
                write!(f, "cannot read {}: {error}", path.display())
            }
            ReplotError::NotJson { path, error } => {
                write!(f, "{} is not JSON: {error}", path.display())
            }
            ReplotError::NotASummary { path } => write!(
                f,
                "{} is not the summary of `tes experiment grid`, `transfer` or `robot`",
                path.display()
            ),
            ReplotError::Malformed {
                path,
                figure,
                problem,
            } => write!(
                f,
                "{} lacks the numbers {figure} is drawn from: {problem}",
                path.display()
            ),
            ReplotError::Write { path, error } => {
                write!(f, "cannot write {}: {error}", path.display())
            }
        }
    }
}

/// The cause is part of the message (as the project's other errors do), not a separate source.
impl std::error::Error for ReplotError {}

/// Redraws, in `dir`, the figures its `summary.json` holds the data of.
pub fn replot(dir: &Path) -> Result<Replotted, ReplotError> {
    let path = dir.join("summary.json");
    let text = fs::read_to_string(&path).map_err(|error| ReplotError::Read {
        path: path.clone(),
        error,
    })?;
    let summary: Value = serde_json::from_str(&text).map_err(|error| ReplotError::NotJson {
        path: path.clone(),
        error,
    })?;
    let malformed = |figure| {
        let path = path.clone();
        move |problem| ReplotError::Malformed {
            path,
            figure,
            problem,
        }
    };
    let write = |file: PathBuf, svg: String| {
        fs::write(&file, svg)
            .map(|()| file.clone())
            .map_err(|error| ReplotError::Write { path: file, error })
    };
    if summary.get("tasks").is_some() {
        let jumpstart = transfer_jumpstarts(&summary).map_err(malformed("Table 2"))?;
        let file = write(
            dir.join("table2.svg"),
            transfer::jumpstart_chart(&jumpstart).to_svg(),
        )?;
        Ok(Replotted {
            experiment: "transfer",
            written: vec![file],
            not_redrawn: vec!["fig4b-task*.svg"],
        })
    } else if let Some(fig3c) = summary.get("fig3c") {
        let fig3c = grid_fig3c(fig3c).map_err(malformed("Fig. 3c"))?;
        let episodes = summary
            .pointer("/config/episodes")
            .and_then(Value::as_u64)
            .and_then(|n| usize::try_from(n).ok())
            .ok_or_else(|| malformed("Fig. 3c")("no episode count (config.episodes)".into()))?;
        let file = write(
            dir.join("fig3c.svg"),
            grid::fig3c_chart(&fig3c, episodes).to_svg(),
        )?;
        Ok(Replotted {
            experiment: "grid",
            written: vec![file],
            not_redrawn: vec!["fig3a.svg", "fig3b.svg"],
        })
    } else if summary.get("first_episode").is_some() {
        Ok(Replotted {
            experiment: "robot",
            written: Vec::new(),
            not_redrawn: vec!["fig8.svg", "fig9.svg"],
        })
    } else {
        Err(ReplotError::NotASummary { path })
    }
}

/// A [`Summary`] as `summary.json` writes it (a missing or null number is NaN, as an empty
/// summary's are written as null).
fn summary(value: &Value) -> Result<Summary, String> {
    let object = value
        .as_object()
        .ok_or("a summary is not an object of mean, lo, hi and n")?;
    let number = |key: &str| object.get(key).and_then(Value::as_f64).unwrap_or(f64::NAN);
    Ok(Summary {
        mean: number("mean"),
        lo: number("lo"),
        hi: number("hi"),
        n: object
            .get("n")
            .and_then(Value::as_u64)
            .and_then(|n| usize::try_from(n).ok())
            .unwrap_or(0),
    })
}

/// Method name → summary, from a JSON object.
fn by_name(value: &Value) -> Result<BTreeMap<String, Summary>, String> {
    value
        .as_object()
        .ok_or("not an object of summaries by name")?
        .iter()
        .map(|(name, s)| {
            Ok((
                name.clone(),
                summary(s).map_err(|e| format!("{name}: {e}"))?,
            ))
        })
        .collect()
}

/// Task → (method → first-episode reward summary), from a transfer summary.
fn transfer_jumpstarts(
    summary: &Value,
) -> Result<BTreeMap<usize, BTreeMap<String, Summary>>, String> {
    let tasks = summary
        .get("tasks")
        .and_then(Value::as_array)
        .ok_or("`tasks` is not a list")?;
    tasks
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let task = t
                .get("task")
                .and_then(Value::as_u64)
                .and_then(|n| usize::try_from(n).ok())
                .ok_or_else(|| format!("tasks[{i}] has no task index"))?;
            let jumpstart = t
                .get("jumpstart")
                .ok_or_else(|| format!("task {task} has no jumpstart"))?;
            let jumpstart =
                by_name(jumpstart).map_err(|e| format!("task {task}'s jumpstart: {e}"))?;
            Ok((task, jumpstart))
        })
        .collect()
}

/// Algorithm → (irrelevant features → final accumulated reward), from a grid summary's `fig3c`.
fn grid_fig3c(fig3c: &Value) -> Result<BTreeMap<String, BTreeMap<usize, Summary>>, String> {
    fig3c
        .as_object()
        .ok_or("`fig3c` is not an object")?
        .iter()
        .map(|(name, levels)| {
            let levels = levels
                .as_object()
                .ok_or_else(|| format!("{name}: not an object of feature counts"))?
                .iter()
                .map(|(level, s)| {
                    let n: usize = level
                        .parse()
                        .map_err(|_| format!("{name}: {level:?} is not a feature count"))?;
                    let s = summary(s).map_err(|e| format!("{name} at {level}: {e}"))?;
                    Ok((n, s))
                })
                .collect::<Result<_, String>>()?;
            Ok((name.clone(), levels))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::svg::drawn_series;

    fn write(dir: &Path, json: &str) {
        fs::write(dir.join("summary.json"), json).unwrap();
    }

    const SUMMARY: &str = r#"{"mean": -0.5, "lo": -1.0, "hi": 0.25, "n": 2}"#;

    #[test]
    fn a_transfer_summary_redraws_table2_with_unrun_tasks_marked() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            &format!(
                r#"{{"config": {{"quick": true}}, "tasks": [
                    {{"task": 1, "jumpstart": {{"TES": {SUMMARY}, "LWT": {SUMMARY}, "Rands 1": {SUMMARY}}}}},
                    {{"task": 10, "jumpstart": {{"TES": {SUMMARY}, "loreRL": {{"mean": null, "lo": null, "hi": null, "n": 0}}}}}}
                ]}}"#
            ),
        );
        let done = replot(dir.path()).unwrap();
        assert_eq!(done.experiment, "transfer");
        assert_eq!(done.written, vec![dir.path().join("table2.svg")]);
        let svg = fs::read_to_string(dir.path().join("table2.svg")).unwrap();
        assert!(!svg.contains("<polyline") && !svg.contains("<path"));
        // 15 task slots, 13 of them not run; TES twice, LWT once; the null loreRL not drawn.
        assert_eq!(svg.matches("<g class=\"category\"").count(), 15);
        assert_eq!(svg.matches(">not run</text>").count(), 13);
        assert_eq!(svg.matches("<circle").count() - 4, 3, "4 legend dots");
        let names: Vec<String> = drawn_series(&svg).into_iter().map(|d| d.name).collect();
        assert_eq!(names, ["TES", "LWT", "loreRL", "fEpsG"]);
    }

    #[test]
    fn a_grid_summary_redraws_fig3c_and_names_what_needs_a_rerun() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            &format!(
                r#"{{"config": {{"episodes": 60}}, "fig3c": {{"loreRL": {{"0": {SUMMARY}, "200": {SUMMARY}}}, "fEpsG": {{"0": {SUMMARY}}}}}}}"#
            ),
        );
        let done = replot(dir.path()).unwrap();
        assert_eq!(done.experiment, "grid");
        assert_eq!(done.not_redrawn, ["fig3a.svg", "fig3b.svg"]);
        let svg = fs::read_to_string(dir.path().join("fig3c.svg")).unwrap();
        assert!(svg.contains("after 60 episodes"));
        assert_eq!(svg.matches("<circle").count(), 3);
    }

    #[test]
    fn a_robot_summary_has_nothing_to_redraw() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), r#"{"first_episode": {}}"#);
        let done = replot(dir.path()).unwrap();
        assert_eq!(done.experiment, "robot");
        assert!(done.written.is_empty());
        assert_eq!(done.not_redrawn, ["fig8.svg", "fig9.svg"]);
    }

    #[test]
    fn a_missing_or_foreign_summary_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let err = replot(dir.path()).unwrap_err();
        assert!(format!("{err:#}").contains("summary.json"), "{err:#}");
        for bad in [
            "not json",
            r#"{"something": 1}"#,
            r#"{"tasks": 3}"#,
            r#"{"tasks": [{"jumpstart": {}}]}"#,
            r#"{"tasks": [{"task": 1, "jumpstart": {"TES": 7}}]}"#,
            r#"{"config": {"episodes": 60}, "fig3c": {"loreRL": {"many": {}}}}"#,
            r#"{"fig3c": {}}"#,
        ] {
            write(dir.path(), bad);
            let err = replot(dir.path()).unwrap_err();
            assert!(
                format!("{err:#}").contains("summary.json"),
                "{bad}: {err:#}"
            );
        }
        assert!(!dir.path().join("table2.svg").exists());
        assert!(!dir.path().join("fig3c.svg").exists());
    }
}
