//! Beyond the paper: a lifelong benchmark where TES's growth, pruning and recency matter.
//!
//! A long, non-stationary sequence of grid tasks: [`LifelongConfig::worlds`] worlds, each a
//! task of its own dynamics — logistic sets drawn at random, and interaction tables that are
//! not logistic in the features ([`Dynamics::random_table`]) — visited in
//! [`LifelongConfig::rounds`] shuffled passes, so every world recurs, some after long gaps.
//! Each run draws its own worlds and order from the world seed and the run (unless
//! [`LifelongConfig::same_worlds`]), so the runs vary the sequence, not only the agents' luck.
//! The worlds need more views (up to one per action each) than a library of `M = 20` holds.
//! Along the same sequence, with the same world stream per task:
//!
//! * **TES** — the library carried from task to task, `M = 20`, recency `μ > 0`;
//! * **TES, unbounded** — the same with no practical limit on the library;
//! * **TES, no recency** — the bounded library with `μ = 0` (the paper's setting): the
//!   ablation of recency;
//! * **LWT** — at each task, the best-track-record view per action of TES's library as TES
//!   starts the task, frozen;
//! * **loreRL** — a fresh agent on every task;
//! * **loreRL, continual** — one mDAGL model per action carried from task to task and never
//!   reset: the baseline that keeps learning across the sequence without a library.
//!
//! Reported: each task's accumulated reward per method over the sequence, the library's size
//! after each task, the time per episode, and questions of our own judged by paired tests.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use tes_learning::agents::{Agent, LoreRl, LoreRlParams, Tes, TesParams, ViewPolicy};
use tes_learning::library::{LibraryParams, ViewLibrary};
use tes_learning::mdagl::Mdagl;
use tes_learning::plan::PlannerParams;
use tes_perception_sim::grid::{Dynamics, GridParams, GridSuite, GridTask};

use crate::episode::{
    AgentSettings, Episode, EpisodicTask, RunOutcome, build_agent, run_episode, write_file,
    write_summary,
};
use crate::experiment::Experiment;
use crate::grid::GridEnv;
use crate::jobs::{self, JobOptions, Manifest};
use crate::method::Method;
use crate::settings::{Kind, Setting, Settings, number};
use crate::stats::{Summary, summarise};
use crate::svg::{LineChart, Series};
use crate::verdict::{Paired, TIME_RATIO_TEST, TargetCheck, Verdict, difference, paired, ratio};

/// Settings of `tes experiment lifelong`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LifelongConfig {
    /// Independent runs of the whole sequence.
    pub runs: usize,
    /// Worlds with logistic dynamics drawn at random.
    pub logistic_worlds: usize,
    /// Worlds whose dynamics are interaction tables, not logistic in the features.
    pub table_worlds: usize,
    /// Shuffled passes over all worlds: the sequence has `rounds × worlds` tasks.
    pub rounds: usize,
    /// Episodes on each task of the sequence.
    pub episodes: usize,
    /// The bounded library's `M` (the paper's 20).
    pub max_views: usize,
    /// The unbounded library's `M`: more than the sequence can add.
    pub unbounded_views: usize,
    /// The recency decay `μ` of the track record (the paper's experiments: 0).
    pub recency: f64,
    /// Irrelevant features per cell (the paper's grid: 200).
    pub irrelevant: usize,
    /// Seed of the worlds (dynamics, layouts) and of the sequence; each run draws its own from
    /// it unless `same_worlds`.
    pub world_seed: u64,
    /// Every run visits the same worlds in the same order, drawn once from `world_seed` (the
    /// benchmark's first design; its earlier manifests, which lack the setting, ran so).
    #[serde(default = "the_first_design")]
    pub same_worlds: bool,
    /// Base agent seed; run `r` derives its agents' and its world stream's seeds from it.
    pub seed: u64,
    /// Whether this is the reduced `--quick` configuration.
    pub quick: bool,
}

impl LifelongConfig {
    /// Our defaults: 8 logistic and 4 table worlds, 4 passes (48 tasks), 50 episodes each,
    /// `M = 20`, `μ = 0.1`, 200 irrelevant features, 20 runs, each with worlds and order of
    /// its own.
    pub fn standard() -> Self {
        Self {
            runs: 20,
            logistic_worlds: 8,
            table_worlds: 4,
            rounds: 4,
            episodes: 50,
            max_views: 20,
            unbounded_views: 10_000,
            recency: 0.1,
            irrelevant: 200,
            world_seed: 2017,
            same_worlds: false,
            seed: 1,
            quick: false,
        }
    }

    /// A first look in seconds: 3 + 1 worlds, 2 passes, 8 episodes, 2 runs, `M = 6`.
    pub fn quick() -> Self {
        Self {
            runs: 2,
            logistic_worlds: 3,
            table_worlds: 1,
            rounds: 2,
            episodes: 8,
            max_views: 6,
            irrelevant: 20,
            quick: true,
            ..Self::standard()
        }
    }

    /// Worlds in all.
    pub fn worlds(&self) -> usize {
        self.logistic_worlds + self.table_worlds
    }

    fn check(&self) -> Result<()> {
        if self.runs == 0 || self.episodes == 0 || self.rounds == 0 || self.worlds() == 0 {
            bail!("runs, episodes, rounds and worlds must all be at least 1");
        }
        if self.max_views == 0 || self.unbounded_views < self.max_views {
            bail!("the library must keep at least 1 view, the unbounded one at least as many");
        }
        if !(self.recency >= 0.0 && self.recency.is_finite()) {
            bail!("the recency decay must be a finite number >= 0");
        }
        Ok(())
    }
}

/// The flags of `tes experiment`'s sub-command, defined once (see [`crate::settings`]).
impl Settings for LifelongConfig {
    const QUICK_HELP: &'static str = "Small settings for a first look: seconds.";
    const SETTINGS: &'static [Setting<Self>] = &[
        Setting {
            flag: "runs",
            value_name: "RUNS",
            help: "Independent runs of the whole sequence.",
            kind: Kind::Value,
            show: |c| c.runs.to_string(),
            take: |c, v| {
                c.runs = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "episodes",
            value_name: "EPISODES",
            help: "Episodes on each task of the sequence.",
            kind: Kind::Value,
            show: |c| c.episodes.to_string(),
            take: |c, v| {
                c.episodes = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "rounds",
            value_name: "ROUNDS",
            help: "Shuffled passes over every world.",
            kind: Kind::Value,
            show: |c| c.rounds.to_string(),
            take: |c, v| {
                c.rounds = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "recency",
            value_name: "RECENCY",
            help: "The recency decay μ of the library's track record.",
            kind: Kind::Value,
            show: |c| c.recency.to_string(),
            take: |c, v| {
                c.recency = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "seed",
            value_name: "SEED",
            help: "Base agent seed.",
            kind: Kind::Value,
            show: |c| c.seed.to_string(),
            take: |c, v| {
                c.seed = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "world-seed",
            value_name: "WORLD_SEED",
            help: "Seed of the worlds and of the sequence (each run draws its own from it).",
            kind: Kind::Value,
            show: |c| c.world_seed.to_string(),
            take: |c, v| {
                c.world_seed = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "same-worlds",
            value_name: "",
            help: "Every run visits the same worlds in the same order, drawn once from the \
                   world seed (the benchmark's first design), instead of worlds and an order \
                   of its own.",
            kind: Kind::Switch,
            show: |c| crate::settings::on_off(c.same_worlds),
            take: |c, _| {
                c.same_worlds = true;
                Ok(())
            },
        },
    ];

    fn standard() -> Self {
        LifelongConfig::standard()
    }

    fn quick() -> Self {
        Self::quick()
    }
}

/// What a manifest written before [`LifelongConfig::same_worlds`] existed ran: one sequence
/// for every run.
fn the_first_design() -> bool {
    true
}

/// The compared methods, in report order.
pub const METHODS: [Method; 6] = [
    Method::Tes,
    Method::TesUnbounded,
    Method::TesNoRecency,
    Method::Lwt,
    Method::LoreRl,
    Method::LoreRlContinual,
];

/// The methods that carry a view library, whose size is reported after each task.
const LIBRARIES: [Method; 3] = [Method::Tes, Method::TesUnbounded, Method::TesNoRecency];

/// One task of the sequence.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SequenceTask {
    /// Position in the sequence, from 0.
    pub position: usize,
    /// The world visited.
    pub world: usize,
    /// Whether the world's dynamics are logistic in the features.
    pub logistic: bool,
    /// Width × height.
    pub size: String,
    /// Tasks since the world was last visited (`None` on its first visit).
    pub gap: Option<usize>,
}

/// The worlds (one task each, its own dynamics and layout) and the order they are visited.
struct Worlds {
    envs: Vec<GridEnv>,
    sequence: Vec<SequenceTask>,
}

impl Worlds {
    /// The worlds and order of run `run`: its own, or with `same_worlds` those of every run.
    fn of_run(config: &LifelongConfig, run: usize) -> Result<Self> {
        let world_seed = if config.same_worlds {
            config.world_seed
        } else {
            // Run 0 keeps the first design's draw; each later run is another.
            config
                .world_seed
                .wrapping_add((run as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
        };
        Self::drawn(config, world_seed)
    }

    fn drawn(config: &LifelongConfig, world_seed: u64) -> Result<Self> {
        let mut rng = ChaCha8Rng::seed_from_u64(world_seed ^ 0x11FE_10E6);
        let mut envs = Vec::with_capacity(config.worlds());
        for w in 0..config.worlds() {
            let logistic = w < config.logistic_worlds;
            let dynamics = if logistic {
                Dynamics::random_logistic(&mut rng)
            } else {
                Dynamics::random_table(&mut rng)
            };
            // The suite's layouts, cycled: sizes 20×20 to 30×30 and their walls and exits.
            let params = GridParams {
                dynamics_set: w,
                ..GridSuite::params(1 + w % (GridSuite::TASKS - 1), config.irrelevant)
            };
            let seed = world_seed.wrapping_mul(7_919).wrapping_add(w as u64);
            let task = GridTask::generate_with(params, dynamics, seed)
                .with_context(|| format!("world {w}"))?;
            envs.push(GridEnv::new(task)?);
        }
        let mut sequence = Vec::new();
        let mut last_seen: BTreeMap<usize, usize> = BTreeMap::new();
        for _ in 0..config.rounds {
            let mut order: Vec<usize> = (0..config.worlds()).collect();
            order.shuffle(&mut rng);
            for world in order {
                let position = sequence.len();
                let task = envs[world].task();
                sequence.push(SequenceTask {
                    position,
                    world,
                    logistic: world < config.logistic_worlds,
                    size: format!("{}x{}", task.width(), task.height()),
                    gap: last_seen.insert(world, position).map(|p| position - p - 1),
                });
            }
        }
        Ok(Self { envs, sequence })
    }
}

/// One run's record: its sequence; per method, each task's episodes; the libraries' sizes
/// after each task.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct RunRecord {
    run: usize,
    sequence: Vec<SequenceTask>,
    episodes: BTreeMap<Method, Vec<Vec<Episode>>>,
    library_views: BTreeMap<Method, Vec<usize>>,
}

/// The experiment's name in manifests.
pub const EXPERIMENT: &str = "lifelong";

/// The manifest of a run of `config` (or its `shard`): a job is a run of the sequence.
pub fn manifest(config: &LifelongConfig, shard: jobs::Shard) -> Result<Manifest> {
    Manifest::new(EXPERIMENT, config, config.runs, shard)
}

fn planner() -> PlannerParams {
    // As in the transfer experiment: a re-plan stops at the drift that triggered it.
    PlannerParams {
        stop_at_drift: true,
        ..PlannerParams::default()
    }
}

fn empty_library(worlds: &Worlds, max_views: usize, recency: f64) -> Result<ViewLibrary> {
    let s = worlds.envs[0].structure();
    Ok(ViewLibrary::new(
        s.n_actions(),
        s.n_effects(),
        s.n_features(),
        LibraryParams {
            max_views,
            recency,
            ..LibraryParams::default()
        },
    )?)
}

/// The seeds of (run, position): the agents' and the world stream's.
fn seeds(config: &LifelongConfig, run: usize, position: usize) -> (u64, u64) {
    let base = config
        .seed
        .wrapping_add(10_000 * run as u64)
        .wrapping_mul(31)
        .wrapping_add(position as u64);
    (base, base ^ 0x7E57_11FE)
}

/// Runs `agent` for the task's episodes on the world stream `world_seed`.
fn live(
    agent: &mut dyn Agent,
    env: &GridEnv,
    episodes: usize,
    world_seed: u64,
) -> Result<Vec<Episode>> {
    let structure = env.structure();
    let mut world = ChaCha8Rng::seed_from_u64(world_seed);
    (0..episodes)
        .map(|_| Ok(run_episode(agent, env, &structure, &mut world)?))
        .collect()
}

fn run_job(config: &LifelongConfig, run: usize) -> Result<RunRecord> {
    let worlds = Worlds::of_run(config, run)?;
    let mut episodes: BTreeMap<Method, Vec<Vec<Episode>>> = BTreeMap::new();
    let mut library_views: BTreeMap<Method, Vec<usize>> = BTreeMap::new();
    let mut libraries = Vec::with_capacity(LIBRARIES.len());
    for (method, max_views, recency) in [
        (Method::Tes, config.max_views, config.recency),
        (Method::TesUnbounded, config.unbounded_views, config.recency),
        (Method::TesNoRecency, config.max_views, 0.0),
    ] {
        libraries.push((method, empty_library(&worlds, max_views, recency)?));
    }
    let mut continual: Option<Vec<Mdagl>> = None;
    let tes = |policy| TesParams {
        policy,
        planner: planner(),
        ..TesParams::default()
    };
    for task in &worlds.sequence {
        let env = &worlds.envs[task.world];
        let (agent_seed, world_seed) = seeds(config, run, task.position);
        let context = |m: Method| {
            format!(
                "run {run}, task {} (world {}): {m}",
                task.position, task.world
            )
        };
        let mut record = |m: Method, e: Vec<Episode>| episodes.entry(m).or_default().push(e);
        for (method, library) in &mut libraries {
            if *method == Method::Tes {
                // LWT takes the bounded library as TES starts the task.
                let mut lwt = Tes::new(
                    env.structure(),
                    library.clone(),
                    tes(ViewPolicy::Lwt),
                    agent_seed,
                )
                .with_context(|| context(Method::Lwt))?;
                record(
                    Method::Lwt,
                    live(&mut lwt, env, config.episodes, world_seed)?,
                );
            }
            let mut agent = Tes::new(
                env.structure(),
                library.clone(),
                tes(ViewPolicy::Tes),
                agent_seed,
            )
            .with_context(|| context(*method))?;
            record(*method, live(&mut agent, env, config.episodes, world_seed)?);
            *library = agent.finish_task().with_context(|| context(*method))?.0;
            library_views
                .entry(*method)
                .or_default()
                .push(library.len());
        }
        let settings = AgentSettings {
            planner: planner(),
            ..AgentSettings::default()
        };
        let mut lore = build_agent(Method::LoreRl, env, agent_seed, settings)
            .with_context(|| context(Method::LoreRl))?;
        record(
            Method::LoreRl,
            live(lore.as_mut(), env, config.episodes, world_seed)?,
        );
        let params = LoreRlParams {
            planner: planner(),
            ..LoreRlParams::default()
        };
        let mut carried = match continual.take() {
            None => LoreRl::new(env.structure(), params, agent_seed),
            Some(views) => LoreRl::with_views(env.structure(), params, views, agent_seed),
        }
        .with_context(|| context(Method::LoreRlContinual))?;
        record(
            Method::LoreRlContinual,
            live(&mut carried, env, config.episodes, world_seed)?,
        );
        continual = Some(carried.into_views());
    }
    Ok(RunRecord {
        run,
        sequence: worlds.sequence,
        episodes,
        library_views,
    })
}

/// Runs the benchmark, writes its files into `out`, and returns the summary.
pub fn run(
    config: &LifelongConfig,
    out: &Path,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<LifelongReport> {
    run_with(config, out, JobOptions::default(), progress)?
        .context("a run over every job gives a summary")
}

/// [`run`] with `options`: a share of the runs (then only their records and the manifest
/// are written, and `None` returned) or a resumed run.
pub fn run_with(
    config: &LifelongConfig,
    out: &Path,
    options: JobOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Option<LifelongReport>> {
    config.check()?;
    let started = Instant::now();
    fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let manifest = manifest(config, options.shard)?;
    let results = jobs::run_jobs(out, &manifest, options, progress, |run| {
        run_job(config, run)
    })?;
    if !options.shard.is_all() {
        return Ok(None);
    }
    report_from(config, results.into_values().collect(), out, started).map(Some)
}

/// Computes the summary and figures of a complete result folder from its job records.
pub fn summarise_dir(out: &Path) -> Result<LifelongReport> {
    let started = Instant::now();
    let manifest = Manifest::read(out)?;
    let config: LifelongConfig = manifest.settings()?;
    config.check()?;
    let results: BTreeMap<usize, RunRecord> = jobs::read_all(out, &manifest)?;
    report_from(&config, results.into_values().collect(), out, started)
}

impl Experiment for LifelongConfig {
    type Report = LifelongReport;
    const NAME: &'static str = EXPERIMENT;

    fn describe(&self) -> String {
        format!(
            "{} runs (the progress counts these runs) of a sequence of {} tasks from {} worlds ({} not logistic), {} episodes each, M = {}, recency {}, seed {}",
            self.runs,
            self.rounds * self.worlds(),
            self.worlds(),
            self.table_worlds,
            self.episodes,
            self.max_views,
            self.recency,
            self.seed
        )
    }

    fn run_with(
        &self,
        out: &Path,
        options: JobOptions,
        progress: &(dyn Fn(u64, u64) + Sync),
    ) -> Result<Option<LifelongReport>> {
        run_with(self, out, options, progress)
    }

    fn summarise_dir(out: &Path) -> Result<LifelongReport> {
        summarise_dir(out)
    }
}

/// The summary written to `summary.json`.
#[derive(Debug, Serialize, Deserialize)]
pub struct LifelongReport {
    /// The settings, seeds included.
    pub config: LifelongConfig,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// Each run's sequence of tasks, in run order (all alike with `same_worlds`); empty in a
    /// summary written before runs drew their own (see [`sequence_of`](Self::sequence_of)).
    #[serde(default)]
    pub sequences: Vec<Vec<SequenceTask>>,
    /// The one sequence every run lived, in a summary written before runs drew their own.
    #[serde(default, rename = "sequence", skip_serializing)]
    first_design: Vec<SequenceTask>,
    /// Per method, each task's accumulated reward over runs, in sequence order.
    pub per_task: BTreeMap<String, Vec<Summary>>,
    /// Per library (TES, TES unbounded, TES without recency), its views after each task over
    /// runs.
    pub library_views: BTreeMap<String, Vec<Summary>>,
    /// Agent seconds per episode over the whole sequence, per method.
    pub seconds_per_episode: BTreeMap<String, Summary>,
    /// Every run's outcome per method and task: `runs[method][run][position]`.
    pub runs: BTreeMap<String, Vec<Vec<RunOutcome>>>,
    /// Our questions, the test of each and its verdict.
    pub targets: Vec<TargetCheck>,
}

impl LifelongReport {
    /// Tasks in each run's sequence.
    pub fn tasks(&self) -> usize {
        self.config.rounds * self.config.worlds()
    }

    /// The sequence run `run` lived.
    pub fn sequence_of(&self, run: usize) -> &[SequenceTask] {
        self.sequences
            .get(run)
            .map_or(&self.first_design, Vec::as_slice)
    }

    /// Every run's sequence, in run order.
    pub fn run_sequences(&self) -> impl Iterator<Item = &[SequenceTask]> + '_ {
        (0..self.config.runs).map(|run| self.sequence_of(run))
    }

    /// Each run's task at `position`, in run order.
    pub fn at_position(&self, position: usize) -> impl Iterator<Item = &SequenceTask> + '_ {
        self.run_sequences().filter_map(move |s| s.get(position))
    }
}

fn report_from(
    config: &LifelongConfig,
    mut records: Vec<RunRecord>,
    out: &Path,
    started: Instant,
) -> Result<LifelongReport> {
    records.sort_by_key(|r| r.run);
    let runs: BTreeMap<String, Vec<Vec<RunOutcome>>> = METHODS
        .iter()
        .map(|&m| {
            let per_run = records
                .iter()
                .map(|r| {
                    r.episodes
                        .get(&m)
                        .map(|tasks| tasks.iter().map(|e| RunOutcome::of(e, false)).collect())
                        .unwrap_or_default()
                })
                .collect();
            (m.name().into_owned(), per_run)
        })
        .collect();
    let positions = config.rounds * config.worlds();
    let per_task = runs
        .iter()
        .map(|(m, per_run)| {
            let by_task = (0..positions)
                .map(|p| {
                    summarise(
                        &per_run
                            .iter()
                            .filter_map(|r: &Vec<RunOutcome>| r.get(p).map(|o| o.accumulated))
                            .collect::<Vec<_>>(),
                    )
                })
                .collect();
            (m.clone(), by_task)
        })
        .collect();
    let library_views = LIBRARIES
        .iter()
        .map(|&m| {
            let sizes = (0..positions)
                .map(|p| {
                    summarise(
                        &records
                            .iter()
                            .filter_map(|r| r.library_views.get(&m)?.get(p).map(|&v| v as f64))
                            .collect::<Vec<_>>(),
                    )
                })
                .collect();
            (m.name().into_owned(), sizes)
        })
        .collect();
    let seconds_per_episode = runs
        .iter()
        .map(|(m, per_run)| {
            let per_run_mean: Vec<f64> = per_run
                .iter()
                .map(|tasks| {
                    tasks.iter().map(|o| o.seconds_per_episode).sum::<f64>()
                        / tasks.len().max(1) as f64
                })
                .collect();
            (m.clone(), summarise(&per_run_mean))
        })
        .collect();
    let mut report = LifelongReport {
        config: config.clone(),
        wall_seconds: 0.0,
        sequences: records.iter().map(|r| r.sequence.clone()).collect(),
        first_design: Vec::new(),
        per_task,
        library_views,
        seconds_per_episode,
        runs,
        targets: Vec::new(),
    };
    report.targets = targets(&report);
    write_figures(&report, out)?;
    report.wall_seconds = started.elapsed().as_secs_f64();
    write_summary(out, &report)?;
    Ok(report)
}

/// Per run, the sum over the tasks `which` admits of `a`'s accumulated reward minus `b`'s.
fn over_tasks(
    report: &LifelongReport,
    a: Method,
    b: Method,
    which: &dyn Fn(&SequenceTask) -> bool,
) -> Vec<f64> {
    let (Some(a), Some(b)) = (report.runs.get(&*a.name()), report.runs.get(&*b.name())) else {
        return Vec::new();
    };
    a.iter()
        .zip(b)
        .zip(report.run_sequences())
        .map(|((ra, rb), sequence)| {
            sequence
                .iter()
                .filter(|t| which(t))
                .filter_map(|t| {
                    Some(ra.get(t.position)?.accumulated - rb.get(t.position)?.accumulated)
                })
                .sum()
        })
        .collect()
}

/// Per run, the mean over the tasks `which` admits of `a`'s accumulated reward minus `b`'s.
fn mean_over_tasks(
    report: &LifelongReport,
    a: Method,
    b: Method,
    which: &dyn Fn(&SequenceTask) -> bool,
) -> Vec<f64> {
    over_tasks(report, a, b, which)
        .into_iter()
        .zip(report.run_sequences())
        .map(|(x, sequence)| x / sequence.iter().filter(|t| which(t)).count().max(1) as f64)
        .collect()
}

/// Our questions, each judged by a paired test over runs (two-sided, 5 %):
///
/// * does TES accumulate more than loreRL over the sequence? than LWT?
/// * does TES's lead over loreRL grow on a world's return visits (the library remembers)?
/// * does the unbounded library accumulate more than the bounded one, and on returns after
///   long gaps especially (what pruning forgets)?
/// * does TES beat loreRL on the worlds that are logistic in the features? on those that
///   are not?
/// * is the bounded library faster per episode than the unbounded one?
///
/// and the ablation's and continual baseline's ([`ablation_targets`]).
fn targets(report: &LifelongReport) -> Vec<TargetCheck> {
    let check = |target, measured, p: &Paired| paired_check(report, target, measured, p);
    let over =
        |a, b, which: &dyn Fn(&SequenceTask) -> bool| paired(&over_tasks(report, a, b, which));
    let all = |_: &SequenceTask| true;
    let tes_lore = over(Method::Tes, Method::LoreRl, &all);
    let tes_lwt = over(Method::Tes, Method::Lwt, &all);
    let unbounded = over(Method::TesUnbounded, Method::Tes, &all);
    let long_gap = report
        .run_sequences()
        .flatten()
        .filter_map(|t| t.gap)
        .max()
        .map_or(usize::MAX, |g| g / 2);
    let far = |t: &SequenceTask| t.gap.is_some_and(|g| g >= long_gap);
    let unbounded_far = over(Method::TesUnbounded, Method::Tes, &far);
    let logistic = over(Method::Tes, Method::LoreRl, &|t| t.logistic);
    let not_logistic = over(Method::Tes, Method::LoreRl, &|t| !t.logistic);
    let returns: Vec<f64> =
        mean_over_tasks(report, Method::Tes, Method::LoreRl, &|t| t.gap.is_some())
            .into_iter()
            .zip(mean_over_tasks(report, Method::Tes, Method::LoreRl, &|t| {
                t.gap.is_none()
            }))
            .map(|(r, f)| r - f)
            .collect();
    let returns = paired(&returns);
    let ratio_summary = summarise(&time_ratios(report, Method::Tes, Method::TesUnbounded));
    let n = report.tasks();
    let mut checks = vec![
        check(
            format!("ours: TES accumulates more than loreRL over the {n} tasks"),
            format!("TES − loreRL {}", difference(&tes_lore)),
            &tes_lore,
        ),
        check(
            format!("ours: TES accumulates more than LWT over the {n} tasks"),
            format!("TES − LWT {}", difference(&tes_lwt)),
            &tes_lwt,
        ),
        check(
            "ours: TES's lead over loreRL per task is larger on a world's return visits than on its first".into(),
            format!("(TES − loreRL) on returns − on first visits, per task {}", difference(&returns)),
            &returns,
        ),
        check(
            format!("ours: the unbounded library accumulates more than M = {} over the {n} tasks", report.config.max_views),
            format!("unbounded − bounded {}", difference(&unbounded)),
            &unbounded,
        ),
        check(
            format!("ours: ... and on returns after a gap of at least {long_gap} tasks"),
            format!("unbounded − bounded {}", difference(&unbounded_far)),
            &unbounded_far,
        ),
        check(
            "ours: TES accumulates more than loreRL on the worlds whose dynamics are logistic".into(),
            format!("TES − loreRL {}", difference(&logistic)),
            &logistic,
        ),
        check(
            "ours: TES accumulates more than loreRL on the worlds whose dynamics are not logistic".into(),
            format!("TES − loreRL {}", difference(&not_logistic)),
            &not_logistic,
        ),
        TargetCheck::new(
            format!("ours: the bounded library (M = {}) costs less time per episode than the unbounded one", report.config.max_views),
            TIME_RATIO_TEST,
            ratio(&ratio_summary),
            report.config.quick,
            Verdict::at_most(&ratio_summary, 1.0),
        ),
    ];
    checks.extend(ablation_targets(report));
    checks
}

/// The ablation of recency and the continual baseline: TES with `μ` above `μ = 0`, TES above
/// loreRL-continual, loreRL-continual above a fresh loreRL (preregistered as
/// `lifelong.ablations`).
fn ablation_targets(report: &LifelongReport) -> [TargetCheck; 3] {
    let all = |_: &SequenceTask| true;
    let over = |a, b| paired(&over_tasks(report, a, b, &all));
    let recency = over(Method::Tes, Method::TesNoRecency);
    let tes_continual = over(Method::Tes, Method::LoreRlContinual);
    let continual_lore = over(Method::LoreRlContinual, Method::LoreRl);
    let n = report.tasks();
    let check = |target, measured, p: &Paired| paired_check(report, target, measured, p);
    [
        check(
            format!(
                "ours: TES with recency μ = {} accumulates more than with μ = 0 over the {n} tasks",
                report.config.recency
            ),
            format!(
                "μ = {} − μ = 0 {}",
                report.config.recency,
                difference(&recency)
            ),
            &recency,
        ),
        check(
            format!(
                "ours: TES accumulates more than loreRL-continual (one model per action learning through all {n} tasks)"
            ),
            format!("TES − loreRL-continual {}", difference(&tes_continual)),
            &tes_continual,
        ),
        check(
            format!(
                "ours: loreRL-continual accumulates more than a fresh loreRL on every task over the {n} tasks"
            ),
            format!("loreRL-continual − loreRL {}", difference(&continual_lore)),
            &continual_lore,
        ),
    ]
}

/// A target judged by the paired t-test `p`.
fn paired_check(
    report: &LifelongReport,
    target: String,
    measured: String,
    p: &Paired,
) -> TargetCheck {
    TargetCheck::new(
        target,
        "paired t-test over runs, two-sided 5 %",
        measured,
        report.config.quick,
        Verdict::of_side(p.side),
    )
}

/// Per run, `a`'s mean time per episode over the sequence over `b`'s.
fn time_ratios(report: &LifelongReport, a: Method, b: Method) -> Vec<f64> {
    let time = |m: Method| {
        report
            .runs
            .get(&*m.name())
            .map(|runs| {
                runs.iter()
                    .map(|t| {
                        t.iter().map(|o| o.seconds_per_episode).sum::<f64>() / t.len().max(1) as f64
                    })
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default()
    };
    time(a).iter().zip(time(b)).map(|(a, b)| a / b).collect()
}

/// The figures: each task's accumulated reward per method over the sequence, TES's lead
/// over loreRL per task, and the libraries' sizes.
fn write_figures(report: &LifelongReport, out: &Path) -> Result<()> {
    let position = |p: usize| (p + 1) as f64;
    let chart = LineChart {
        title: format!(
            "Lifelong: accumulated reward on each task of the sequence ({} episodes each)",
            report.config.episodes
        ),
        x_label: "task in the sequence".into(),
        y_label: "accumulated reward on the task".into(),
        series: METHODS
            .iter()
            .filter_map(|&m| {
                let tasks = report.per_task.get(&*m.name())?;
                Some(Series::method(
                    m,
                    tasks
                        .iter()
                        .enumerate()
                        .map(|(p, s)| s.at(position(p)))
                        .collect(),
                ))
            })
            .collect(),
        markers: true,
    };
    write_file(&out.join("lifelong-reward.svg"), &chart.to_svg())?;
    let lead = |m: Method| -> Vec<crate::svg::BandPoint> {
        (0..report.tasks())
            .map(|p| {
                let d: Vec<f64> = over_tasks(report, m, Method::LoreRl, &|t| t.position == p);
                summarise(&d).at(position(p))
            })
            .collect()
    };
    let chart = LineChart {
        title: "Lifelong: each task's accumulated reward minus loreRL's (paired by run)".into(),
        x_label: "task in the sequence".into(),
        y_label: "difference to loreRL".into(),
        series: METHODS
            .into_iter()
            .filter(|&m| m != Method::LoreRl)
            .map(|m| Series::method(m, lead(m)))
            .collect(),
        markers: true,
    };
    write_file(&out.join("lifelong-lead.svg"), &chart.to_svg())?;
    let chart = LineChart {
        title: "Lifelong: views in the library after each task".into(),
        x_label: "task in the sequence".into(),
        y_label: "views".into(),
        series: report
            .library_views
            .iter()
            .filter_map(|(name, sizes)| {
                let m = Method::from_name(name)?;
                Some(Series::method(
                    m,
                    sizes
                        .iter()
                        .enumerate()
                        .map(|(p, s)| s.at(position(p)))
                        .collect(),
                ))
            })
            .collect(),
        markers: true,
    };
    write_file(&out.join("lifelong-library.svg"), &chart.to_svg())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sequence_visits_every_world_each_round_and_knows_the_gaps() {
        let config = LifelongConfig::quick();
        for run in 0..3 {
            let worlds = Worlds::of_run(&config, run).unwrap();
            assert_eq!(worlds.sequence.len(), config.rounds * config.worlds());
            for round in worlds.sequence.chunks(config.worlds()) {
                let mut seen: Vec<usize> = round.iter().map(|t| t.world).collect();
                seen.sort_unstable();
                assert_eq!(seen, (0..config.worlds()).collect::<Vec<_>>());
            }
            for t in &worlds.sequence {
                let earlier = worlds.sequence[..t.position]
                    .iter()
                    .rposition(|e| e.world == t.world);
                assert_eq!(t.gap, earlier.map(|e| t.position - e - 1));
                assert_eq!(
                    t.logistic,
                    worlds.envs[t.world].task().dynamics().is_logistic()
                );
            }
        }
    }

    /// What tells one run's worlds and order from another's: the order visited, and each
    /// world's size and dynamics.
    fn drawn(worlds: &Worlds) -> (Vec<usize>, Vec<String>) {
        (
            worlds.sequence.iter().map(|t| t.world).collect(),
            worlds
                .envs
                .iter()
                .map(|e| {
                    let task = e.task();
                    format!("{}x{} {:?}", task.width(), task.height(), task.dynamics())
                })
                .collect(),
        )
    }

    #[test]
    fn each_run_draws_worlds_and_an_order_of_its_own_from_the_seed() {
        let config = LifelongConfig::standard();
        let runs: Vec<_> = (0..4)
            .map(|run| drawn(&Worlds::of_run(&config, run).unwrap()))
            .collect();
        for (i, a) in runs.iter().enumerate() {
            for b in &runs[i + 1..] {
                assert_ne!(a.0, b.0, "orders differ between runs");
                assert_ne!(a.1, b.1, "worlds differ between runs");
            }
        }
        // Reproducible: the same seed and run, the same worlds and order.
        assert_eq!(runs[2], drawn(&Worlds::of_run(&config, 2).unwrap()));
        // `same_worlds`: every run is run 0's draw, which is the first design's.
        let same = LifelongConfig {
            same_worlds: true,
            ..config.clone()
        };
        for run in 0..3 {
            assert_eq!(drawn(&Worlds::of_run(&same, run).unwrap()), runs[0]);
        }
        // A manifest written before the setting existed ran the first design.
        let mut old = serde_json::to_value(&config).unwrap();
        old.as_object_mut().unwrap().remove("same_worlds");
        let old: LifelongConfig = serde_json::from_value(old).unwrap();
        assert!(old.same_worlds);
    }
}
