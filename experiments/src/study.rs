//! The whole study (`tes experiment all`): the grid, transfer and robot experiments in one
//! folder (`OUT/grid`, `OUT/transfer`, `OUT/robot`), then `OUT/report.md` with every table
//! and figure. A study is split into shards and resumed as each experiment is: every
//! experiment's manifest is written before the first job runs, so an interrupted study
//! resumes from any point, and shard folders of one study merge into one ([`merge`]).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use crate::grid::{self, GridConfig, GridReport};
use crate::jobs::{self, Manifest, Shard};
use crate::robot::{self, RobotConfig, RobotReport};
use crate::transfer::{self, TransferConfig, TransferReport};

/// The experiments of a study, in the order they run (each one's folder name).
pub const EXPERIMENTS: [&str; 3] = [grid::EXPERIMENT, transfer::EXPERIMENT, robot::EXPERIMENT];

/// The report of a whole study, in its folder.
pub const REPORT: &str = "report.md";

/// The settings of the study's three experiments.
#[derive(Debug, Clone)]
pub struct StudyConfigs {
    /// The grid experiment's.
    pub grid: GridConfig,
    /// The transfer experiment's.
    pub transfer: TransferConfig,
    /// The robot experiment's.
    pub robot: RobotConfig,
}

impl StudyConfigs {
    /// Each experiment at the paper's settings.
    pub fn paper() -> Self {
        Self {
            grid: GridConfig::paper(20, 800),
            transfer: TransferConfig::paper(),
            robot: RobotConfig::paper(),
        }
    }

    /// Each experiment at its quick settings.
    pub fn quick() -> Self {
        Self {
            grid: GridConfig::quick(),
            transfer: TransferConfig::quick(),
            robot: RobotConfig::quick(),
        }
    }

    /// The same with `runs` repeats of every experiment.
    pub fn with_runs(mut self, runs: usize) -> Self {
        (self.grid.runs, self.transfer.runs, self.robot.runs) = (runs, runs, runs);
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
            },
        })
    }

    /// The folder of `experiment` ([`EXPERIMENTS`]) in the study's.
    pub fn dir(&self, experiment: &str) -> PathBuf {
        self.out.join(experiment)
    }

    /// Writes the study's report ([`REPORT`]) from its three experiments' reports; its path.
    pub fn write_report(
        &self,
        grid: &GridReport,
        transfer: &TransferReport,
        robot: &RobotReport,
    ) -> Result<PathBuf> {
        let path = self.out.join(REPORT);
        crate::report::write(&path, grid, transfer, robot)?;
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
    /// The grid experiment's report.
    pub grid: GridReport,
    /// The transfer experiment's report.
    pub transfer: TransferReport,
    /// The robot experiment's report.
    pub robot: RobotReport,
    /// The study's report.
    pub report: PathBuf,
}

/// Merges the shard folders `dirs` of one study into `out`: each experiment's shards into
/// its folder, then the study's report.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<MergedStudy> {
    if !are_studies(dirs) {
        bail!("not the shard folders of a study (each holds grid/, transfer/ and robot/)");
    }
    for experiment in EXPERIMENTS {
        let shards: Vec<PathBuf> = dirs.iter().map(|d| d.join(experiment)).collect();
        jobs::merge(&shards, &out.join(experiment))
            .with_context(|| format!("cannot merge the {experiment} shards"))?;
    }
    let grid = grid::summarise_dir(&out.join(grid::EXPERIMENT))?;
    let transfer = transfer::summarise_dir(&out.join(transfer::EXPERIMENT))?;
    let robot = robot::summarise_dir(&out.join(robot::EXPERIMENT))?;
    let report = out.join(REPORT);
    crate::report::write(&report, &grid, &transfer, &robot)?;
    Ok(MergedStudy {
        grid,
        transfer,
        robot,
        report,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_set_every_experiments_repeats() {
        let c = StudyConfigs::quick().with_runs(7);
        assert_eq!((c.grid.runs, c.transfer.runs, c.robot.runs), (7, 7, 7));
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
        let json =
            |c: &StudyConfigs| serde_json::to_string(&(&c.grid, &c.transfer, &c.robot)).unwrap();
        assert_eq!(json(&resumed.configs), json(&study.configs));
        assert!(!are_studies(&[study.dir(grid::EXPERIMENT)]));
        assert!(are_studies(&[dir.path().to_owned()]));
    }
}
