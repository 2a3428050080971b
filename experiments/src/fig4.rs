//! The paper's Fig. 4a and Fig. 4c (§5.1.2, §5.1.4): transfer between tasks of the same
//! dynamics, and TES over a long run against the methods that converge.
//!
//! * **Fig. 4a — same dynamics.** TES lives one training task for the training episodes,
//!   then each method runs on a test task of the *same* dynamics set (200 irrelevant
//!   features): TES with its library, loreRL without one, fRmax (m = 10) and fEpsG (ε = 0.1)
//!   told the true structure. The paper shows one pair; we run one per dynamics set
//!   ([`Fig4Config::pairs`]: the suite's tasks 4 → 1, 5 → 2 and 6 → 3, which share sets 1, 2
//!   and 0).
//! * **Fig. 4c — convergence.** On one held-out task (the suite's task 1), TES with the library
//!   of the other 14 tasks (trained as in the transfer experiment, same seeds) runs for many
//!   episodes against fRmax and Rmax (m = 5), which are known to converge, and loreRL.
//!
//! A job is one (pair, run) of Fig. 4a or one run of Fig. 4c; the training, seeds and test
//! phase are the transfer experiment's ([`crate::transfer`]).

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use tes_perception_sim::grid::GridSuite;

use crate::episode::{Episode, RunOutcome, write_episodes_csv, write_file, write_summary};
use crate::experiment::Experiment;
use crate::grid::GridEnv;
use crate::jobs::{self, JobOptions, Manifest};
use crate::method::Method;
use crate::settings::{Kind, Setting, Settings, number};
use crate::stats::{Summary, summarise};
use crate::svg::{BandPoint, LineChart, Series};
use crate::transfer::{self, JobResult, TransferConfig};
use crate::verdict::{TargetCheck, Verdict, difference, paired_family};

/// Settings of `tes experiment fig4`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Fig4Config {
    /// Independent runs of each pair and of the long run (paper: 20).
    pub runs: usize,
    /// Fig. 4a: (training task, test task) pairs of the same dynamics set.
    pub pairs: Vec<(usize, usize)>,
    /// Fig. 4a: episodes on the training task (as the transfer experiment: 100).
    pub train_episodes: usize,
    /// Fig. 4a: episodes on the test task (as Fig. 4b: 50).
    pub test_episodes: usize,
    /// Fig. 4a: the first episodes that count as "early" (ours: 10; the paper gives none).
    pub early_episodes: usize,
    /// Fig. 4c: the held-out task.
    pub convergence_task: usize,
    /// Fig. 4c: how many of the other tasks TES lives first (paper: all 14, 100 episodes
    /// each).
    pub convergence_training_tasks: usize,
    /// Fig. 4c: episodes on the held-out task (ours: 500; the paper does not say).
    pub convergence_episodes: usize,
    /// Irrelevant features per cell (paper: 200).
    pub irrelevant: usize,
    /// Seed of the grid suite.
    pub world_seed: u64,
    /// Base agent seed (as the transfer experiment's).
    pub seed: u64,
    /// Whether this is the reduced `--quick` configuration.
    pub quick: bool,
    /// Re-plans stop at the drift that triggered them, as in the transfer experiment.
    pub stop_at_drift: bool,
}

impl Fig4Config {
    /// The paper's settings where it gives them, ours (stated above) where it does not.
    pub fn paper() -> Self {
        Self {
            runs: 20,
            pairs: vec![(4, 1), (5, 2), (6, 3)],
            train_episodes: 100,
            test_episodes: 50,
            early_episodes: 10,
            convergence_task: 1,
            convergence_training_tasks: GridSuite::TASKS - 1,
            convergence_episodes: 500,
            irrelevant: 200,
            world_seed: 2017,
            seed: 1,
            quick: false,
            stop_at_drift: true,
        }
    }

    /// A first look in seconds: one pair, 2 runs, short training and runs.
    pub fn quick() -> Self {
        Self {
            runs: 2,
            pairs: vec![(4, 1)],
            train_episodes: 20,
            test_episodes: 12,
            early_episodes: 4,
            convergence_training_tasks: 3,
            convergence_episodes: 40,
            quick: true,
            ..Self::paper()
        }
    }

    fn check(&self) -> Result<()> {
        if self.runs == 0 || self.train_episodes == 0 || self.test_episodes == 0 {
            bail!("runs, training episodes and test episodes must all be at least 1");
        }
        if self.convergence_episodes < 2 || self.early_episodes == 0 {
            bail!("the long run needs at least 2 episodes and \"early\" at least 1");
        }
        let tasks = GridSuite::TASKS;
        for &(train, test) in &self.pairs {
            if train >= tasks || test >= tasks || train == test {
                bail!("pair {train} -> {test}: two different tasks of 0..{tasks} are needed");
            }
            if train % 3 != test % 3 {
                bail!(
                    "pair {train} -> {test}: the tasks have different dynamics (sets {} and {})",
                    train % 3,
                    test % 3
                );
            }
        }
        if self.convergence_task >= tasks
            || self.convergence_training_tasks == 0
            || self.convergence_training_tasks >= tasks
        {
            bail!(
                "the long run needs a task of 0..{tasks} and 1..{} training tasks",
                tasks - 1
            );
        }
        Ok(())
    }

    /// The transfer experiment's settings the jobs of `part` borrow (seeds, training,
    /// planning, the test phase's length).
    fn transfer(&self, part: Part) -> TransferConfig {
        let (test_tasks, training_tasks, test_episodes) = match part {
            Part::SameDynamics => (
                self.pairs.iter().map(|&(_, t)| t).collect(),
                1,
                self.test_episodes,
            ),
            Part::Convergence => (
                vec![self.convergence_task],
                self.convergence_training_tasks,
                self.convergence_episodes,
            ),
        };
        TransferConfig {
            runs: self.runs,
            train_episodes: self.train_episodes,
            test_episodes,
            test_tasks,
            training_tasks,
            irrelevant: self.irrelevant,
            world_seed: self.world_seed,
            seed: self.seed,
            quick: self.quick,
            stop_at_drift: self.stop_at_drift,
            ..TransferConfig::paper()
        }
    }
}

/// The flags of `tes experiment`'s sub-command, defined once (see [`crate::settings`]).
impl Settings for Fig4Config {
    const QUICK_HELP: &'static str = "Small settings for a first look: seconds.";
    const SETTINGS: &'static [Setting<Self>] = &[
        Setting {
            flag: "runs",
            value_name: "RUNS",
            help: "Independent runs of each pair and of the long run.",
            kind: Kind::Value,
            show: |c| c.runs.to_string(),
            take: |c, v| {
                c.runs = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "long-episodes",
            value_name: "LONG_EPISODES",
            help: "Episodes of the long run (Fig. 4c).",
            kind: Kind::Value,
            show: |c| c.convergence_episodes.to_string(),
            take: |c, v| {
                c.convergence_episodes = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "seed",
            value_name: "SEED",
            help: "Base seed, as the transfer experiment's.",
            kind: Kind::Value,
            show: |c| c.seed.to_string(),
            take: |c, v| {
                c.seed = number(v)?;
                Ok(())
            },
        },
    ];

    fn standard() -> Self {
        Self::paper()
    }

    fn quick() -> Self {
        Self::quick()
    }
}

/// The two halves of the experiment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum Part {
    SameDynamics,
    Convergence,
}

/// Fig. 4a's methods, TES first.
pub const FIG4A_METHODS: [Method; 4] = [Method::Tes, Method::LoreRl, Method::FRmax, Method::FEpsG];

/// Fig. 4c's methods, TES first.
pub const FIG4C_METHODS: [Method; 4] = [Method::Tes, Method::FRmax, Method::Rmax, Method::LoreRl];

/// One job: a run of a Fig. 4a pair (its index in [`Fig4Config::pairs`]) or of Fig. 4c.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Job {
    part: Part,
    pair: usize,
    run: usize,
}

/// The experiment's name in manifests.
pub const EXPERIMENT: &str = "fig4";

/// The jobs in index order: Fig. 4c's runs first (the longest), then every pair's runs.
fn job_list(config: &Fig4Config) -> Vec<Job> {
    let long = (0..config.runs).map(|run| Job {
        part: Part::Convergence,
        pair: 0,
        run,
    });
    let pairs = (0..config.pairs.len()).flat_map(|pair| {
        (0..config.runs).map(move |run| Job {
            part: Part::SameDynamics,
            pair,
            run,
        })
    });
    long.chain(pairs).collect()
}

/// The manifest of a run of `config` (or its `shard`).
pub fn manifest(config: &Fig4Config, shard: jobs::Shard) -> Result<Manifest> {
    Manifest::new(EXPERIMENT, config, job_list(config).len(), shard)
}

/// A job's record.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Record {
    part: Part,
    pair: usize,
    result: JobResult,
}

fn run_job(config: &Fig4Config, envs: &[GridEnv], job: Job, out: &Path) -> Result<Record> {
    let tc = config.transfer(job.part);
    let (methods, task, order, library) = match job.part {
        Part::SameDynamics => {
            let (train, test) = config.pairs[job.pair];
            let empty = transfer::empty_library(&tc, envs)?;
            let library = transfer::train_on(&tc, envs, empty, job.run, train)?;
            (&FIG4A_METHODS, test, vec![train], library)
        }
        Part::Convergence => {
            let (order, library) = transfer::trained_libraries(&tc, envs, job.run)?
                .pop()
                .context("the long run's library")?;
            (&FIG4C_METHODS, config.convergence_task, order, library)
        }
    };
    if job.run == 0 {
        let name = match job.part {
            Part::SameDynamics => format!("library-fig4a-task{task}.tesl"),
            Part::Convergence => format!("library-fig4c-task{task}.tesl"),
        };
        transfer::save_library(&tc, envs, task, &library, &out.join(name))?;
    }
    let result = transfer::test_job(&tc, envs, methods, task, job.run, order, library)?;
    Ok(Record {
        part: job.part,
        pair: job.pair,
        result,
    })
}

/// Runs the experiment, writes its files into `out`, and returns the summary.
pub fn run(
    config: &Fig4Config,
    out: &Path,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Fig4Report> {
    run_with(config, out, JobOptions::default(), progress)?
        .context("a run over every job gives a summary")
}

/// [`run`] with `options`: a share of the jobs (then only their records and the manifest
/// are written, and `None` returned) or a resumed run.
pub fn run_with(
    config: &Fig4Config,
    out: &Path,
    options: JobOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Option<Fig4Report>> {
    config.check()?;
    let started = Instant::now();
    fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let envs = transfer::environments(&config.transfer(Part::Convergence))?;
    let jobs = job_list(config);
    let manifest = manifest(config, options.shard)?;
    let results = jobs::run_jobs(out, &manifest, options, progress, |index| {
        run_job(config, &envs, jobs[index], out)
    })?;
    if !options.shard.is_all() {
        return Ok(None);
    }
    report_from(config, results.into_values().collect(), out, started).map(Some)
}

/// Computes the summary and figures of a complete result folder from its job records.
pub fn summarise_dir(out: &Path) -> Result<Fig4Report> {
    let started = Instant::now();
    let manifest = Manifest::read(out)?;
    let config: Fig4Config = manifest.settings()?;
    config.check()?;
    let results: BTreeMap<usize, Record> = jobs::read_all(out, &manifest)?;
    report_from(&config, results.into_values().collect(), out, started)
}

impl Experiment for Fig4Config {
    type Report = Fig4Report;
    const NAME: &'static str = EXPERIMENT;

    fn describe(&self) -> String {
        format!(
            "{} runs of the long run ({} episodes on task {}) and of each of {} same-dynamics pairs (the progress counts these runs), seed {}",
            self.runs,
            self.convergence_episodes,
            self.convergence_task,
            self.pairs.len(),
            self.seed
        )
    }

    fn run_with(
        &self,
        out: &Path,
        options: JobOptions,
        progress: &(dyn Fn(u64, u64) + Sync),
    ) -> Result<Option<Fig4Report>> {
        run_with(self, out, options, progress)
    }

    fn summarise_dir(out: &Path) -> Result<Fig4Report> {
        summarise_dir(out)
    }
}

/// One test task's methods over runs: what `summary.json` keeps of a Fig. 4a pair or of
/// Fig. 4c.
#[derive(Debug, Serialize, Deserialize)]
pub struct CaseSummary {
    /// The tasks TES lived first, in run 0's order.
    pub trained_on: Vec<usize>,
    /// The test task.
    pub test_task: usize,
    /// Its dynamics set.
    pub dynamics_set: usize,
    /// Accumulated reward over all the test episodes, per method.
    pub accumulated: BTreeMap<String, Summary>,
    /// Accumulated-reward difference to TES after the last episode, per method.
    pub difference_to_tes: BTreeMap<String, Summary>,
    /// Every run's outcome per method (each episode's reward kept), runs in order.
    pub runs: BTreeMap<String, Vec<RunOutcome>>,
}

/// The summary written to `summary.json`.
#[derive(Debug, Serialize, Deserialize)]
pub struct Fig4Report {
    /// The settings, seeds included.
    pub config: Fig4Config,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// Fig. 4a, one per pair.
    pub same_dynamics: Vec<CaseSummary>,
    /// Fig. 4c.
    pub convergence: CaseSummary,
    /// Agent seconds per episode in Fig. 4c, per method.
    pub convergence_seconds_per_episode: BTreeMap<String, Summary>,
    /// The paper's Fig. 4a and 4c claims, the test of each and its verdict.
    pub targets: Vec<TargetCheck>,
}

fn report_from(
    config: &Fig4Config,
    mut records: Vec<Record>,
    out: &Path,
    started: Instant,
) -> Result<Fig4Report> {
    records.sort_by_key(|r| (r.part == Part::SameDynamics, r.pair, r.result.run));
    write_episodes_csv(
        &out.join("episodes.csv"),
        "figure,test_task,run,seed,method",
        records.iter().flat_map(|r| {
            let figure = match r.part {
                Part::SameDynamics => "4a",
                Part::Convergence => "4c",
            };
            r.result.episodes.iter().map(move |(m, eps)| {
                let key = format!(
                    "{figure},{},{},{},{m}",
                    r.result.task, r.result.run, r.result.seed
                );
                (key, eps.as_slice())
            })
        }),
    )?;
    let of = |part: Part, pair: usize| -> Vec<&JobResult> {
        records
            .iter()
            .filter(|r| r.part == part && r.pair == pair)
            .map(|r| &r.result)
            .collect()
    };
    let mut same_dynamics = Vec::new();
    for (i, &(_, test)) in config.pairs.iter().enumerate() {
        let runs = of(Part::SameDynamics, i);
        same_dynamics.push(case_summary(test, &runs, &FIG4A_METHODS));
        write_fig4a(out, test, &runs, config.test_episodes)?;
    }
    let long = of(Part::Convergence, 0);
    let convergence = case_summary(config.convergence_task, &long, &FIG4C_METHODS);
    write_fig4c(out, config, &long)?;
    let convergence_seconds_per_episode = FIG4C_METHODS
        .iter()
        .map(|m| {
            let per_run: Vec<f64> = convergence.runs[&*m.name()]
                .iter()
                .map(|r| r.seconds_per_episode)
                .collect();
            (m.name().into_owned(), summarise(&per_run))
        })
        .collect();
    let targets = targets(config, &same_dynamics, &convergence);
    let report = Fig4Report {
        config: config.clone(),
        wall_seconds: started.elapsed().as_secs_f64(),
        same_dynamics,
        convergence,
        convergence_seconds_per_episode,
        targets,
    };
    write_summary(out, &report)?;
    Ok(report)
}

fn case_summary(task: usize, runs: &[&JobResult], methods: &[Method]) -> CaseSummary {
    let outcomes = |m: Method| -> Vec<RunOutcome> {
        runs.iter()
            .filter_map(|r| r.episodes.get(&m))
            .map(|eps| RunOutcome::of(eps, true))
            .collect()
    };
    let runs_by: BTreeMap<String, Vec<RunOutcome>> = methods
        .iter()
        .map(|&m| (m.name().into_owned(), outcomes(m)))
        .collect();
    let tes = &runs_by[&*Method::Tes.name()];
    let mut accumulated = BTreeMap::new();
    let mut difference_to_tes = BTreeMap::new();
    for (name, outcomes) in &runs_by {
        let totals: Vec<f64> = outcomes.iter().map(|o| o.accumulated).collect();
        accumulated.insert(name.clone(), summarise(&totals));
        if *name != Method::Tes.name() {
            let d: Vec<f64> = outcomes
                .iter()
                .zip(tes)
                .map(|(o, t)| o.accumulated - t.accumulated)
                .collect();
            difference_to_tes.insert(name.clone(), summarise(&d));
        }
    }
    CaseSummary {
        trained_on: runs
            .first()
            .map(|r| r.training_order.clone())
            .unwrap_or_default(),
        test_task: task,
        dynamics_set: task % 3,
        accumulated,
        difference_to_tes,
        runs: runs_by,
    }
}

/// Per run, `a`'s reward over episodes `from..to` minus `b`'s (0-based, clipped).
fn window_differences(
    case: &CaseSummary,
    a: Method,
    b: Method,
    from: usize,
    to: usize,
) -> Vec<f64> {
    let (Some(a), Some(b)) = (case.runs.get(&*a.name()), case.runs.get(&*b.name())) else {
        return Vec::new();
    };
    a.iter()
        .zip(b)
        .filter_map(|(a, b)| Some(a.reward_between(from, to)? - b.reward_between(from, to)?))
        .collect()
}

/// Fig. 4a's and Fig. 4c's claims, each judged by paired t-tests over runs with Holm's
/// correction over the claim's comparisons.
fn targets(config: &Fig4Config, pairs: &[CaseSummary], long: &CaseSummary) -> Vec<TargetCheck> {
    vec![
        tes_ahead_on_same_dynamics(config, pairs),
        learners_ahead_of_frmax_early(config, pairs),
        tes_ahead_early_in_long_run(config, long),
        oracles_catch_up(config, long),
    ]
}

/// The test every claim of this experiment states.
const HOLM_OVER_CLAIM: &str = "paired t-tests over runs, Holm's correction over every comparison of the claim, family-wise 5 %";

/// One comparison of a claim: its label in the report and its per-run paired differences.
type Labelled = (String, Vec<f64>);

/// A claim that holds when every one of its comparisons is decided positive, fails when one
/// is decided negative (Holm over the claim's comparisons).
fn every_ahead(
    target: String,
    config: &Fig4Config,
    measured_prefix: &str,
    comparisons: Vec<Labelled>,
) -> TargetCheck {
    let (labels, differences): (Vec<String>, Vec<Vec<f64>>) = comparisons.into_iter().unzip();
    let tests = paired_family(&differences);
    let measured = labels
        .iter()
        .zip(&tests)
        .map(|(label, p)| format!("{label} {}", difference(p)))
        .collect::<Vec<_>>()
        .join("; ");
    TargetCheck::new(
        target,
        HOLM_OVER_CLAIM,
        format!("{measured_prefix}{measured}"),
        config.quick,
        Verdict::all(tests.iter().map(|p| Verdict::of_side(p.side))),
    )
}

/// Fig. 4a: on a task of the training task's dynamics, TES accumulates more than loreRL,
/// fRmax and fEpsG over the test episodes (every pair).
fn tes_ahead_on_same_dynamics(config: &Fig4Config, pairs: &[CaseSummary]) -> TargetCheck {
    let n = config.test_episodes;
    let comparisons = pairs
        .iter()
        .flat_map(|c| {
            [Method::LoreRl, Method::FRmax, Method::FEpsG].map(|m| {
                (
                    format!("task {}: TES − {m}", c.test_task),
                    window_differences(c, Method::Tes, m, 0, n),
                )
            })
        })
        .collect();
    every_ahead(
        format!(
            "Fig. 4a: with the training task's dynamics, TES accumulates more than loreRL, fRmax and fEpsG over {n} test episodes"
        ),
        config,
        "",
        comparisons,
    )
}

/// Fig. 4a: loreRL and fEpsG are more effective than fRmax early (the first
/// [`Fig4Config::early_episodes`]).
fn learners_ahead_of_frmax_early(config: &Fig4Config, pairs: &[CaseSummary]) -> TargetCheck {
    let early = config.early_episodes;
    let comparisons = pairs
        .iter()
        .flat_map(|c| {
            [Method::LoreRl, Method::FEpsG].map(|m| {
                (
                    format!("task {}: {m} − fRmax", c.test_task),
                    window_differences(c, m, Method::FRmax, 0, early),
                )
            })
        })
        .collect();
    every_ahead(
        format!(
            "Fig. 4a: loreRL and fEpsG are more effective than fRmax early (ours: the first {early} episodes)"
        ),
        config,
        "",
        comparisons,
    )
}

/// Fig. 4c's early episodes of the long run: the first 50 (or half the run, if shorter).
fn long_run_head(config: &Fig4Config) -> usize {
    50.min(config.convergence_episodes / 2)
}

/// Fig. 4c: TES is ahead of fRmax and Rmax early (the first 50 episodes).
fn tes_ahead_early_in_long_run(config: &Fig4Config, long: &CaseSummary) -> TargetCheck {
    let head = long_run_head(config);
    let comparisons = [Method::FRmax, Method::Rmax]
        .map(|m| {
            (
                format!("TES − {m}"),
                window_differences(long, Method::Tes, m, 0, head),
            )
        })
        .into();
    every_ahead(
        format!("Fig. 4c: TES ahead of fRmax and Rmax early (the first {head} episodes)"),
        config,
        "",
        comparisons,
    )
}

/// Fig. 4c: fRmax and Rmax gradually catch up: TES's lead per episode over the last 100
/// episodes is smaller than over the first 50.
fn oracles_catch_up(config: &Fig4Config, long: &CaseSummary) -> TargetCheck {
    let long_n = config.convergence_episodes;
    let head = long_run_head(config);
    let tail = 100.min(long_n / 2);
    let narrowing = |other: Method| -> Vec<f64> {
        let first = window_differences(long, Method::Tes, other, 0, head);
        let last = window_differences(long, Method::Tes, other, long_n - tail, long_n);
        first
            .iter()
            .zip(last)
            .map(|(f, l)| f / head as f64 - l / tail as f64)
            .collect()
    };
    let comparisons = [Method::FRmax, Method::Rmax]
        .map(|m| (m.to_string(), narrowing(m)))
        .into();
    every_ahead(
        format!(
            "Fig. 4c: fRmax and Rmax gradually catch up: TES's lead per episode over the last {tail} of {long_n} episodes is smaller than over the first {head}"
        ),
        config,
        "lead first − lead last, per episode: ",
        comparisons,
    )
}

/// Per episode, the mean over runs of the accumulated reward of `m` (minus `minus`'s,
/// paired by run) with its 95 % band.
fn accumulated_band(
    runs: &[&JobResult],
    m: Method,
    minus: Option<Method>,
    episodes: usize,
) -> Vec<BandPoint> {
    let mut acc = vec![0.0; runs.len()];
    (0..episodes)
        .map(|e| {
            for (a, r) in acc.iter_mut().zip(runs) {
                let reward = |m: Method| {
                    r.episodes
                        .get(&m)
                        .and_then(|x| x.get(e))
                        .map_or(0.0, |x: &Episode| x.reward)
                };
                *a += reward(m) - minus.map_or(0.0, reward);
            }
            summarise(&acc).at((e + 1) as f64)
        })
        .collect()
}

fn write_fig4a(out: &Path, task: usize, runs: &[&JobResult], episodes: usize) -> Result<()> {
    let chart = LineChart {
        title: format!(
            "Fig. 4a — task {task}, the training task's dynamics: accumulated reward minus TES's"
        ),
        x_label: "test episode".into(),
        y_label: "difference to TES".into(),
        series: FIG4A_METHODS[1..]
            .iter()
            .map(|&m| Series::method(m, accumulated_band(runs, m, Some(Method::Tes), episodes)))
            .collect(),
        markers: false,
    };
    write_file(&out.join(format!("fig4a-task{task}.svg")), &chart.to_svg())
}

fn write_fig4c(out: &Path, config: &Fig4Config, runs: &[&JobResult]) -> Result<()> {
    let chart = LineChart {
        title: format!(
            "Fig. 4c — task {}: accumulated reward over {} episodes",
            config.convergence_task, config.convergence_episodes
        ),
        x_label: "episode".into(),
        y_label: "accumulated reward".into(),
        series: FIG4C_METHODS
            .iter()
            .map(|&m| {
                Series::method(
                    m,
                    accumulated_band(runs, m, None, config.convergence_episodes),
                )
            })
            .collect(),
        markers: false,
    };
    write_file(&out.join("fig4c.svg"), &chart.to_svg())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_must_share_their_dynamics() {
        assert!(Fig4Config::paper().check().is_ok());
        assert!(Fig4Config::quick().check().is_ok());
        let crossed = Fig4Config {
            pairs: vec![(4, 2)],
            ..Fig4Config::quick()
        };
        let err = crossed.check().unwrap_err().to_string();
        assert!(err.contains("different dynamics"), "{err}");
        let same = Fig4Config {
            pairs: vec![(4, 4)],
            ..Fig4Config::quick()
        };
        assert!(same.check().is_err());
    }

    #[test]
    fn the_long_run_comes_first_then_every_pair() {
        let config = Fig4Config::paper();
        let jobs = job_list(&config);
        assert_eq!(jobs.len(), 20 * 4);
        assert!(jobs[..20].iter().all(|j| j.part == Part::Convergence));
        assert_eq!(
            jobs[20],
            Job {
                part: Part::SameDynamics,
                pair: 0,
                run: 0
            }
        );
        // The long run borrows the transfer experiment's training of that task exactly.
        let tc = config.transfer(Part::Convergence);
        assert_eq!((tc.test_tasks.clone(), tc.training_tasks), (vec![1], 14));
        assert_eq!(tc.test_episodes, 500);
        assert_eq!(config.transfer(Part::SameDynamics).training_tasks, 1);
    }
}
