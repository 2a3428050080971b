//! What every experiment of the study offers the command line and the study: one trait, so
//! running, resuming, summarising and printing an experiment is written once.

use std::fmt;
use std::path::Path;

use anyhow::Result;
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::jobs::JobOptions;

/// An experiment, named by its settings type: the settings a manifest records run it, and a
/// finished folder's job records summarise it.
///
/// ```
/// use tes_experiments::experiment::Experiment;
/// use tes_experiments::robot::RobotConfig;
///
/// let quick = RobotConfig::quick();
/// assert_eq!(RobotConfig::NAME, "robot");
/// assert!(quick.describe().contains("runs of each method"));
/// ```
pub trait Experiment: Serialize + DeserializeOwned {
    /// What a complete run gives: the summary written to `summary.json`.
    type Report: Console;

    /// The experiment's name: its sub-command, its folder in a study, and the `experiment`
    /// its manifests record.
    const NAME: &'static str;

    /// What a run of these settings does, in one line, for the start of a run.
    fn describe(&self) -> String;

    /// Runs (a share of) the jobs into `out`, calling `progress(done, total)` as runs end;
    /// `None` for a shard, whose folder [`crate::jobs::merge`] and [`Self::summarise_dir`]
    /// finish.
    fn run_with(
        &self,
        out: &Path,
        options: JobOptions,
        progress: &(dyn Fn(u64, u64) + Sync),
    ) -> Result<Option<Self::Report>>;

    /// Recomputes the summary, tables and figures of a complete folder from its job records.
    fn summarise_dir(out: &Path) -> Result<Self::Report>;

    /// The summary as the console prints it at the end of a run.
    fn console(report: &Self::Report, out: &Path) -> Result<String, fmt::Error> {
        report.console(out)
    }
}

/// A report as `tes experiment` prints it when its run ends (each report's text is in
/// [`crate::console`]).
pub trait Console {
    /// The text, for the result folder `out`.
    fn console(&self, out: &Path) -> Result<String, fmt::Error>;
}
