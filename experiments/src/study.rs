//! The whole study (`tes experiment all`): the grid, transfer, robot, Fig. 4 and lifelong
//! experiments in one folder (`OUT/grid`, `OUT/transfer`, `OUT/robot`, `OUT/fig4`,
//! `OUT/lifelong`), then `OUT/report.md` with every table
//! and figure. A study is split into shards and resumed as each experiment is: every
//! experiment's manifest is written before the first job runs, so an interrupted study
//! resumes from any point, and shard folders of one study merge into one ([`merge`]).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use crate::experiment::Experiment;
use crate::fig4::{self, Fig4Config};
use crate::grid::{self, GridConfig};
use crate::jobs::{self, Manifest, Shard};
use crate::lifelong::{self, LifelongConfig};
use crate::report::Results;
use crate::robot::{self, RobotConfig};
use crate::transfer::{self, TransferConfig};

/// The experiments of a study, in the order they run (each one's folder name).
pub const EXPERIMENTS: [&str; 5] = [
    grid::EXPERIMENT,
    transfer::EXPERIMENT,
    robot::EXPERIMENT,
    fig4::EXPERIMENT,
    lifelong::EXPERIMENT,
];

/// Recomputes the summary, tables and figures of the complete folder `dir` of whichever
/// experiment its manifest names, from its job records; returns what the experiment prints.
pub fn summarise_folder(dir: &Path) -> Result<String> {
    fn summarise<E: Experiment>(dir: &Path) -> Result<String> {
        E::console(&E::summarise_dir(dir)?, dir).context("cannot write the experiment's summary")
    }
    let manifest = Manifest::read(dir)?;
    jobs::record_summariser(dir)?;
    match manifest.experiment.as_str() {
        GridConfig::NAME => summarise::<GridConfig>(dir),
        TransferConfig::NAME => summarise::<TransferConfig>(dir),
        RobotConfig::NAME => summarise::<RobotConfig>(dir),
        Fig4Config::NAME => summarise::<Fig4Config>(dir),
        LifelongConfig::NAME => summarise::<LifelongConfig>(dir),
        other => bail!("unknown experiment {other:?} in {}", dir.display()),
    }
}

/// Every experiment's settings as Markdown tables (`tes experiment settings`,
/// docs/experiments.md): each flag, its default, its `--quick` value and what it sets, from
/// the one definition the command line's flags come from ([`crate::settings`]).
pub fn settings_reference() -> String {
    use crate::settings::markdown;
    let tables = [
        markdown::<GridConfig>(grid::EXPERIMENT),
        markdown::<TransferConfig>(transfer::EXPERIMENT),
        markdown::<RobotConfig>(robot::EXPERIMENT),
        markdown::<Fig4Config>(fig4::EXPERIMENT),
        markdown::<LifelongConfig>(lifelong::EXPERIMENT),
    ];
    format!(
        "# Experiment settings\n\n<!-- Generated from the experiments' settings definitions \
         (experiments/src/settings.rs and each experiment's `impl Settings`): \
         `tes experiment settings > docs/experiments.md`; do not edit by hand. -->\n\n\
         Every setting of every `tes experiment` sub-command: its flag, its default, its value \
         under `--quick` and what it sets. Besides these, each takes `--out DIR`, \
         `--threads N`, `--shard K/N`, `--resume DIR` and `--allow-dirty` (see the README; a full \
         run from a modified tree is refused without it).\n\n{}",
        tables.join("\n")
    )
}

/// What does not hold of any experiment's settings definition ([`crate::settings::check`]).
pub fn settings_problems() -> Vec<String> {
    use crate::settings::check;
    [
        check::<GridConfig>(),
        check::<TransferConfig>(),
        check::<RobotConfig>(),
        check::<Fig4Config>(),
        check::<LifelongConfig>(),
    ]
    .concat()
}

/// The report of a whole study, in its folder.
pub const REPORT: &str = "report.md";

/// The settings of the study's experiments.
#[derive(Debug, Clone)]
pub struct StudyConfigs {
    /// The grid experiment's.
    pub grid: GridConfig,
    /// The transfer experiment's.
    pub transfer: TransferConfig,
    /// The robot experiment's.
    pub robot: RobotConfig,
    /// Fig. 4a's and 4c's.
    pub fig4: Fig4Config,
    /// The lifelong benchmark's.
    pub lifelong: LifelongConfig,
}

impl StudyConfigs {
    /// Each experiment at the paper's settings.
    pub fn paper() -> Self {
        Self {
            grid: GridConfig::paper(20, 800),
            transfer: TransferConfig::paper(),
            robot: RobotConfig::paper(),
            fig4: Fig4Config::paper(),
            lifelong: LifelongConfig::standard(),
        }
    }

    /// Each experiment at its quick settings.
    pub fn quick() -> Self {
        Self {
            grid: GridConfig::quick(),
            transfer: TransferConfig::quick(),
            robot: RobotConfig::quick(),
            fig4: Fig4Config::quick(),
            lifelong: LifelongConfig::quick(),
        }
    }

    /// The same with `runs` repeats of every experiment.
    pub fn with_runs(mut self, runs: usize) -> Self {
        (
            self.grid.runs,
            self.transfer.runs,
            self.robot.runs,
            self.fig4.runs,
            self.lifelong.runs,
        ) = (runs, runs, runs, runs, runs);
        self
    }
}

/// A study's folder, its shard and its settings, its manifests written.
#[derive(Debug, Clone)]
pub struct Study {
    /// The study's folder.
    pub out: PathBuf,
    /// The share of every experiment's jobs this folder holds.
    pub shard: Shard,
    /// The experiments' settings.
    pub configs: StudyConfigs,
}

impl Study {
    /// `tes experiment all`'s study: resumed from `resume` (which takes the settings and
    /// shard from its manifests: no other may be given), or prepared in `out` with each
    /// experiment's standard (or `quick`) settings, `runs` repeats of each if given, and
    /// share `shard` of the jobs.
    pub fn open(
        out: &Path,
        resume: Option<&Path>,
        quick: bool,
        runs: Option<usize>,
        shard: Option<Shard>,
    ) -> Result<Self> {
        if let Some(dir) = resume {
            if shard.is_some() || runs.is_some() || quick {
                bail!(
                    "--resume takes the settings and shard from the manifests in {}; give no other setting",
                    dir.display()
                );
            }
            return Self::resume(dir);
        }
        let configs = if quick {
            StudyConfigs::quick()
        } else {
            StudyConfigs::paper()
        };
        let configs = match runs {
            Some(runs) => configs.with_runs(runs),
            None => configs,
        };
        Self::prepare(out, configs, shard.unwrap_or(Shard::ALL))
    }

    /// A new study in `out`: every experiment's manifest is written first, so that an
    /// interrupted study resumes from any point.
    pub fn prepare(out: &Path, configs: StudyConfigs, shard: Shard) -> Result<Self> {
        let study = Self {
            out: out.to_owned(),
            shard,
            configs,
        };
        let c = &study.configs;
        jobs::prepare(
            &study.dir(grid::EXPERIMENT),
            &grid::manifest(&c.grid, shard)?,
        )?;
        jobs::prepare(
            &study.dir(transfer::EXPERIMENT),
            &transfer::manifest(&c.transfer, shard)?,
        )?;
        jobs::prepare(
            &study.dir(robot::EXPERIMENT),
            &robot::manifest(&c.robot, shard)?,
        )?;
        jobs::prepare(
            &study.dir(fig4::EXPERIMENT),
            &fig4::manifest(&c.fig4, shard)?,
        )?;
        jobs::prepare(
            &study.dir(lifelong::EXPERIMENT),
            &lifelong::manifest(&c.lifelong, shard)?,
        )?;
        Ok(study)
    }

    /// The study in `out`, as its manifests record it (to resume it).
    pub fn resume(out: &Path) -> Result<Self> {
        let manifest = |e: &str| Manifest::read(&out.join(e));
        Ok(Self {
            out: out.to_owned(),
            shard: manifest(grid::EXPERIMENT)?.shard,
            configs: StudyConfigs {
                grid: manifest(grid::EXPERIMENT)?.settings()?,
                transfer: manifest(transfer::EXPERIMENT)?.settings()?,
                robot: manifest(robot::EXPERIMENT)?.settings()?,
                fig4: manifest(fig4::EXPERIMENT)?.settings()?,
                lifelong: manifest(lifelong::EXPERIMENT)?.settings()?,
            },
        })
    }

    /// The folder of `experiment` ([`EXPERIMENTS`]) in the study's.
    pub fn dir(&self, experiment: &str) -> PathBuf {
        self.out.join(experiment)
    }

    /// Writes the study's report ([`REPORT`]) from its experiments' reports; its path.
    pub fn write_report(&self, reports: &[Results]) -> Result<PathBuf> {
        let path = self.out.join(REPORT);
        crate::report::write(&path, reports)?;
        Ok(path)
    }
}

/// Whether `dirs` are the shard folders of whole studies (each holds the experiments'
/// folders) rather than shards of one experiment (each holds its manifest).
pub fn are_studies(dirs: &[PathBuf]) -> bool {
    dirs.iter()
        .all(|d| !d.join("manifest.json").exists() && d.join(grid::EXPERIMENT).is_dir())
}

/// What merging study shards made: the experiments' reports and the study's report's path.
#[derive(Debug)]
pub struct MergedStudy {
    /// Every experiment's report, in [`EXPERIMENTS`]' order.
    pub reports: Vec<Results>,
    /// The study's report.
    pub report: PathBuf,
}

/// Merges the shard folders `dirs` of one study into `out`: each experiment's shards into
/// its folder, then the study's report.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<MergedStudy> {
    if !are_studies(dirs) {
        bail!(
            "not the shard folders of a study (each holds grid/, transfer/, robot/, fig4/ and lifelong/)"
        );
    }
    for experiment in EXPERIMENTS {
        let shards: Vec<PathBuf> = dirs.iter().map(|d| d.join(experiment)).collect();
        jobs::merge(&shards, &out.join(experiment))
            .with_context(|| format!("cannot merge the {experiment} shards"))?;
    }
    let reports = vec![
        Results::Grid(grid::summarise_dir(&out.join(grid::EXPERIMENT))?),
        Results::Transfer(transfer::summarise_dir(&out.join(transfer::EXPERIMENT))?),
        Results::Robot(robot::summarise_dir(&out.join(robot::EXPERIMENT))?),
        Results::Fig4(fig4::summarise_dir(&out.join(fig4::EXPERIMENT))?),
        Results::Lifelong(lifelong::summarise_dir(&out.join(lifelong::EXPERIMENT))?),
    ];
    let report = out.join(REPORT);
    crate::report::write(&report, &reports)?;
    Ok(MergedStudy { reports, report })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_set_every_experiments_repeats() {
        let c = StudyConfigs::quick().with_runs(7);
        assert_eq!(
            (
                c.grid.runs,
                c.transfer.runs,
                c.robot.runs,
                c.fig4.runs,
                c.lifelong.runs
            ),
            (7, 7, 7, 7, 7)
        );
        assert_eq!(StudyConfigs::paper().grid.episodes, 800);
    }

    #[test]
    fn a_prepared_study_resumes_with_its_settings_and_shard() {
        let dir = tempfile::tempdir().unwrap();
        let shard: Shard = "2/3".parse().unwrap();
        let configs = StudyConfigs::quick().with_runs(2);
        let study = Study::prepare(dir.path(), configs, shard).unwrap();
        for e in EXPERIMENTS {
            assert!(study.dir(e).join("manifest.json").is_file(), "{e}");
        }
        let resumed = Study::resume(dir.path()).unwrap();
        assert_eq!((resumed.out, resumed.shard), (study.out.clone(), shard));
        let json = |c: &StudyConfigs| {
            serde_json::to_string(&(&c.grid, &c.transfer, &c.robot, &c.fig4, &c.lifelong)).unwrap()
        };
        assert_eq!(json(&resumed.configs), json(&study.configs));
        assert!(!are_studies(&[study.dir(grid::EXPERIMENT)]));
        assert!(are_studies(&[dir.path().to_owned()]));
    }
}
