//! The paper's §5.1.2–5.1.3 transfer experiment: Table 2 (jumpstart) and Figure 4b.
//!
//! Leave-one-out over the 15 grid tasks: for every held-out *test* task and run, a TES agent
//! lives through the other 14 tasks (100 episodes each), growing its view library; then, on
//! the test task, each method runs from scratch for 50 episodes. A run draws one seeded random
//! order of all 15 tasks ([`run_order`]); held-out task `k` trains on it with `k` left out, so
//! the held-out tasks after position `p` share the library trained on positions `0..p`, which
//! is computed once per run (a job is a run). The methods:
//!
//! * **TES** — the trained library, scored and switched online;
//! * **LWT** — the library's best-track-record view per action, frozen;
//! * **Rands 1–5** — a random library view per action, learning but never switched;
//! * **loreRL** — no transfer;
//! * **fEpsG** — no transfer, the true DBN structure given (an oracle).
//!
//! Reported per test task and method: the reward of the first test episode (Table 2's
//! jumpstart), the accumulated reward over the test episodes, and the accumulated-reward
//! difference to TES episode by episode (Fig. 4b), each as mean and 95 % interval over runs.
//! All methods of a run face the same world random stream (start states and dynamics draws
//! line up while their actions do).

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tes_learning::agents::{Agent, Tes, TesParams, ViewPolicy};
use tes_learning::library::store::{self, StoredLibrary};
use tes_learning::library::{LibraryParams, ViewLibrary};
use tes_learning::plan::PlannerParams;
use tes_perception_sim::grid::GridSuite;

use crate::episode::{
    AgentSettings, BuildError, Episode, EpisodicTask, build_agent, run_episode, write_episodes_csv,
    write_file, write_summary,
};
use crate::grid::GridEnv;
use crate::jobs::{self, JobOptions, Manifest};
use crate::method::Method;
use crate::stats::{Summary, summarise};
use crate::svg::{CategoryChart, CategorySeries, Interval, LineChart, Series};
use crate::verdict::{TargetCheck, Verdict};

/// Settings of `tes experiment transfer`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TransferConfig {
    /// Independent runs per test task (paper: 20).
    pub runs: usize,
    /// Episodes on each training task (paper: 100).
    pub train_episodes: usize,
    /// Episodes on the test task (Fig. 4b: 50).
    pub test_episodes: usize,
    /// The held-out tasks (paper: all 15).
    pub test_tasks: Vec<usize>,
    /// How many of the other tasks to train on (paper: all 14).
    pub training_tasks: usize,
    /// Irrelevant features per cell (paper: 200).
    pub irrelevant: usize,
    /// How many random view combinations ("Rands") to compare (paper: 5).
    pub random_combinations: usize,
    /// The view library's settings (paper: M = 20, c = ln 300, μ = 0, λ = 0.05, α = 1.5);
    /// its `max_views` is replaced by [`max_views`](Self::max_views), the one that is
    /// recorded.
    #[serde(skip)]
    pub library: LibraryParams,
    /// The most views the library keeps, `M` (paper: 20): an ablation of the pruning. Recorded
    /// only when it differs from the paper's, so folders written before it existed read as 20.
    #[serde(
        default = "paper_max_views",
        skip_serializing_if = "is_paper_max_views"
    )]
    pub max_views: usize,
    /// Seed of the grid suite.
    pub world_seed: u64,
    /// Base agent seed; see [`run_seed`] and [`job_seed`].
    pub seed: u64,
    /// Whether this is the reduced `--quick` configuration.
    pub quick: bool,
    /// Every agent's planner, in training and test, stops a re-plan once no value moves by
    /// more than the model change that triggered it ([`PlannerParams::stop_at_drift`]), as in
    /// the grid experiment: the grid agents re-plan before every greedy step, and planning
    /// further than their views hold still is most of the study's time. Results written
    /// without this field were planned to the tolerance.
    #[serde(default)]
    pub stop_at_drift: bool,
}

impl TransferConfig {
    /// The paper's setting: 20 runs, train 14 × 100 episodes, test 50, all 15 tasks.
    pub fn paper() -> Self {
        Self {
            runs: 20,
            train_episodes: 100,
            test_episodes: 50,
            test_tasks: (0..GridSuite::TASKS).collect(),
            training_tasks: GridSuite::TASKS - 1,
            irrelevant: 200,
            random_combinations: 5,
            library: LibraryParams::default(),
            max_views: paper_max_views(),
            world_seed: 2017,
            seed: 1,
            quick: false,
            stop_at_drift: true,
        }
    }

    /// A first look in under two minutes on two cores: 3 test tasks, 2 runs, training on 4
    /// other tasks × 25 episodes, 12 test episodes, 2 random combinations.
    pub fn quick() -> Self {
        Self {
            runs: 2,
            train_episodes: 25,
            test_episodes: 12,
            test_tasks: vec![1, 2, 10],
            training_tasks: 4,
            random_combinations: 2,
            quick: true,
            ..Self::paper()
        }
    }

    fn check(&self) -> Result<()> {
        if self.runs == 0 || self.train_episodes == 0 || self.test_episodes == 0 {
            bail!("runs, training episodes and test episodes must all be at least 1");
        }
        if self.test_tasks.is_empty() {
            bail!("no test task given");
        }
        if let Some(&t) = self.test_tasks.iter().find(|&&t| t >= GridSuite::TASKS) {
            bail!(
                "test task {t} does not exist (the suite has tasks 0..{})",
                GridSuite::TASKS
            );
        }
        if self.max_views == 0 {
            bail!("the library must keep at least 1 view (--max-views)");
        }
        if self.training_tasks == 0 || self.training_tasks >= GridSuite::TASKS {
            bail!(
                "training tasks must be between 1 and {}",
                GridSuite::TASKS - 1
            );
        }
        Ok(())
    }

    /// The methods compared, in report order.
    pub fn methods(&self) -> Vec<Method> {
        let mut m = vec![Method::Tes, Method::Lwt, Method::LoreRl, Method::FEpsG];
        m.extend((1..=self.random_combinations).map(Method::Rands));
        m
    }
}

/// The seed of (test task, run): everything random in that task's test phase derives from
/// it (the training's randomness derives from [`run_seed`]).
pub fn job_seed(config: &TransferConfig, task: usize, run: usize) -> u64 {
    run_seed(config, run).wrapping_add(task as u64)
}

/// The seed of a run: its order of the tasks and its training agents derive from it.
pub fn run_seed(config: &TransferConfig, run: usize) -> u64 {
    config.seed.wrapping_add(1_000 * run as u64)
}

/// The run's random order of all the suite's tasks. Held-out task `k` trains on this order
/// with `k` left out, cut to [`TransferConfig::training_tasks`]; so the held-out tasks after
/// position `p` all start from the library trained on positions `0..p`.
pub fn run_order(config: &TransferConfig, run: usize) -> Vec<usize> {
    let mut rng = ChaCha8Rng::seed_from_u64(run_seed(config, run) ^ 0x0D3E_5EED);
    let mut order: Vec<usize> = (0..GridSuite::TASKS).collect();
    order.shuffle(&mut rng);
    order
}

/// Held-out task `task`'s training tasks in `run`, in the order lived.
pub fn training_order(config: &TransferConfig, run: usize, task: usize) -> Vec<usize> {
    let mut order = run_order(config, run);
    order.retain(|&t| t != task);
    order.truncate(config.training_tasks);
    order
}

/// The seed of the TES agent that trains on task `t` in `run` (its world stream derives from
/// it too): the same whichever task is held out, so a shared training prefix is computed once.
fn training_seed(config: &TransferConfig, run: usize, t: usize) -> u64 {
    run_seed(config, run)
        .wrapping_mul(31)
        .wrapping_add(2_000 + t as u64)
}

/// Offsets `method`'s agent seed within a job, so the methods of a run explore independently
/// (and the seeds stay those earlier runs recorded).
fn seed_offset(method: Method) -> usize {
    match method {
        Method::Tes => 0,
        Method::Lwt => 1,
        Method::LoreRl => 2,
        Method::FEpsG => 3,
        Method::Rands(i) => 3 + i,
        // Methods this experiment does not run: it builds no agent of theirs.
        _ => 0,
    }
}

/// One (test task, run)'s results (a job, a run, records one per test task).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct JobResult {
    task: usize,
    run: usize,
    seed: u64,
    training_order: Vec<usize>,
    library_views: usize,
    /// Per method, keyed by [`Method::name`] in the record.
    episodes: BTreeMap<Method, Vec<Episode>>,
}

/// Per test task, what `summary.json` records.
#[derive(Debug, Serialize)]
pub struct TaskSummary {
    /// Index in the suite (the paper numbers tasks from 1: task `i` is the paper's `i + 1`).
    pub task: usize,
    /// Width × height.
    pub size: String,
    /// Reward of the first test episode, per method (Table 2).
    pub jumpstart: BTreeMap<String, Summary>,
    /// Accumulated reward over all test episodes, per method.
    pub accumulated: BTreeMap<String, Summary>,
    /// Accumulated-reward difference to TES after the last test episode, per method (Fig. 4b's
    /// right end).
    pub difference_to_tes: BTreeMap<String, Summary>,
    /// First-episode reward minus TES's, paired by run, per method: the interval that decides
    /// whether TES's jumpstart is ahead on this task.
    pub jumpstart_difference_to_tes: BTreeMap<String, Summary>,
    /// Views in the trained library, over runs.
    pub library_views: Summary,
    /// Training order and seed of each run.
    pub runs: Vec<RunRecord>,
}

/// The test tasks on which TES's jumpstart is ahead of another method's, behind it, or
/// neither, each decided by the paired 95 % interval of the difference over runs
/// ([`TaskSummary::jumpstart_difference_to_tes`]).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct DecidedTasks {
    /// Tasks whose interval of the other method's jumpstart minus TES's lies below 0.
    pub ahead: Vec<usize>,
    /// Tasks whose interval lies above 0.
    pub behind: Vec<usize>,
    /// Tasks whose interval holds 0 (or that have no such interval).
    pub undecided: Vec<usize>,
}

impl DecidedTasks {
    /// Sorts each task of `tasks` by its paired jumpstart interval against `other`.
    pub fn against(tasks: &[TaskSummary], other: Method) -> Self {
        let mut decided = Self::default();
        for t in tasks {
            match t.jumpstart_difference_to_tes.get(&*other.name()) {
                Some(d) if d.hi < 0.0 => decided.ahead.push(t.task),
                Some(d) if d.lo > 0.0 => decided.behind.push(t.task),
                _ => decided.undecided.push(t.task),
            }
        }
        decided
    }

    /// In words, e.g. "10 ahead, 1 behind (task 0), 4 undecided (tasks 3, 6, 10, 12)".
    pub fn describe(&self) -> String {
        let named = |tasks: &[usize]| match tasks {
            [] => String::new(),
            [t] => format!(" (task {t})"),
            _ => format!(
                " (tasks {})",
                tasks
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        };
        format!(
            "{} ahead, {} behind{}, {} undecided{}",
            self.ahead.len(),
            self.behind.len(),
            named(&self.behind),
            self.undecided.len(),
            named(&self.undecided)
        )
    }
}

/// What one run of a test task did.
#[derive(Debug, Serialize)]
pub struct RunRecord {
    /// Run index.
    pub run: usize,
    /// Its seed.
    pub seed: u64,
    /// The training tasks, in the order lived.
    pub training_order: Vec<usize>,
}

/// The summary written to `summary.json`.
#[derive(Debug, Serialize)]
pub struct TransferReport {
    /// The settings, seeds included.
    pub config: TransferConfig,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// Per test task.
    pub tasks: Vec<TaskSummary>,
    /// Test tasks where TES's mean jumpstart beats loreRL's (target: ≥ 12 of 15).
    pub tes_beats_lore_rl: usize,
    /// Test tasks where TES's mean jumpstart beats LWT's (target: ≥ 10 of 15).
    pub tes_beats_lwt: usize,
    /// Per method (loreRL and LWT), the tasks where TES's jumpstart is ahead, behind or
    /// undecided by the paired 95 % interval over runs.
    pub jumpstart_decided: BTreeMap<String, DecidedTasks>,
    /// Test tasks where TES's mean accumulated reward beats every random combination's.
    pub tes_beats_all_rands: usize,
    /// Agent seconds per test episode, per method.
    pub seconds_per_episode: BTreeMap<String, Summary>,
    /// The paper's Table 2 targets and whether they hold (a `--quick` run says it is too
    /// small to judge them; a run over fewer than all 15 tasks, that it left tasks out).
    pub targets: Vec<TargetCheck>,
}

fn paper_max_views() -> usize {
    LibraryParams::default().max_views
}

fn is_paper_max_views(m: &usize) -> bool {
    *m == paper_max_views()
}

/// The experiment's name in manifests.
pub const EXPERIMENT: &str = "transfer";

/// The experiment's independent jobs, in index order: one per run, holding out every test
/// task (their trainings share prefixes of the run's task order).
fn job_list(config: &TransferConfig) -> Vec<usize> {
    (0..config.runs).collect()
}

/// The manifest of a run of `config` (or its `shard`).
pub fn manifest(config: &TransferConfig, shard: jobs::Shard) -> Result<Manifest> {
    Manifest::new(EXPERIMENT, config, job_list(config).len(), shard)
}

fn environments(config: &TransferConfig) -> Result<Vec<GridEnv>> {
    GridSuite::paper(config.world_seed, config.irrelevant)
        .into_iter()
        .map(GridEnv::new)
        .collect()
}

/// Runs the transfer experiment, writes its files into `out`, and returns the summary.
///
/// `progress(done, total)` is called as jobs (runs) finish (from worker threads).
pub fn run(
    config: &TransferConfig,
    out: &Path,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<TransferReport> {
    run_with(config, out, JobOptions::default(), progress)?
        .context("a run over every job gives a summary")
}

/// [`run`] with `options`: a share of the jobs (then only their records, run 0's libraries
/// and the manifest are written, and `None` returned: [`jobs::merge`] and [`summarise_dir`]
/// finish the work) or a resumed run.
pub fn run_with(
    config: &TransferConfig,
    out: &Path,
    options: JobOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Option<TransferReport>> {
    config.check()?;
    let started = Instant::now();
    fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let envs = environments(config)?;
    let methods = config.methods();
    let jobs = job_list(config);
    let manifest = manifest(config, options.shard)?;
    let results = jobs::run_jobs(out, &manifest, options, progress, |index| {
        run_job(config, &envs, &methods, jobs[index], out)
    })?;
    if !options.shard.is_all() {
        return Ok(None);
    }
    report_from(
        config,
        &envs,
        results.into_values().flatten().collect(),
        out,
        started,
    )
    .map(Some)
}

/// Computes the summary, tables and figures of a complete result folder (one run, a resumed
/// one, or merged shards) from its job records.
pub fn summarise_dir(out: &Path) -> Result<TransferReport> {
    let started = Instant::now();
    let manifest = Manifest::read(out)?;
    let config: TransferConfig = manifest.settings()?;
    config.check()?;
    let envs = environments(&config)?;
    let results: BTreeMap<usize, Vec<JobResult>> = jobs::read_all(out, &manifest)?;
    report_from(
        &config,
        &envs,
        results.into_values().flatten().collect(),
        out,
        started,
    )
}

fn report_from(
    config: &TransferConfig,
    envs: &[GridEnv],
    mut results: Vec<JobResult>,
    out: &Path,
    started: Instant,
) -> Result<TransferReport> {
    let methods = config.methods();
    results.sort_by_key(|r| (r.task, r.run));

    write_episodes_csv(
        &out.join("episodes.csv"),
        "test_task,run,seed,method",
        results.iter().flat_map(|r| {
            r.episodes.iter().map(move |(m, eps)| {
                let key = format!("{},{},{},{m}", r.task, r.run, r.seed);
                (key, eps.as_slice())
            })
        }),
    )?;
    let mut tasks = Vec::new();
    for &task in &config.test_tasks {
        let runs: Vec<&JobResult> = results.iter().filter(|r| r.task == task).collect();
        let env = &envs[task];
        tasks.push(summarise_task(task, env, &runs, &methods));
        write_fig4b(out, task, env, &runs, &methods, config.test_episodes)?;
    }
    write_jumpstart_chart(out, &tasks)?;

    let mean = |t: &TaskSummary, m: Method| t.jumpstart.get(&*m.name()).map(|s| s.mean);
    let beats = |other: Method| {
        tasks
            .iter()
            .filter(
                |t| matches!((mean(t, Method::Tes), mean(t, other)), (Some(a), Some(b)) if a > b),
            )
            .count()
    };
    let tes_beats_lore_rl = beats(Method::LoreRl);
    let tes_beats_lwt = beats(Method::Lwt);
    let tes_beats_all_rands = tasks
        .iter()
        .filter(|t| {
            t.difference_to_tes
                .iter()
                .filter(|(name, _)| matches!(Method::from_name(name), Some(Method::Rands(_))))
                .all(|(_, d)| d.mean < 0.0)
        })
        .count();
    let mut seconds_per_episode = BTreeMap::new();
    for &m in &methods {
        let per_run: Vec<f64> = results
            .iter()
            .filter_map(|r| r.episodes.get(&m))
            .map(|eps| eps.iter().map(|e| e.agent_seconds).sum::<f64>() / eps.len().max(1) as f64)
            .collect();
        seconds_per_episode.insert(m.name().into_owned(), summarise(&per_run));
    }
    let jumpstart_decided: BTreeMap<String, DecidedTasks> = [Method::LoreRl, Method::Lwt]
        .iter()
        .map(|&m| (m.name().into_owned(), DecidedTasks::against(&tasks, m)))
        .collect();
    let targets = targets(
        config.quick,
        tasks.len(),
        [tes_beats_lore_rl, tes_beats_lwt],
        [
            &jumpstart_decided[&*Method::LoreRl.name()],
            &jumpstart_decided[&*Method::Lwt.name()],
        ],
    );
    let report = TransferReport {
        config: config.clone(),
        wall_seconds: started.elapsed().as_secs_f64(),
        tasks,
        tes_beats_lore_rl,
        tes_beats_lwt,
        jumpstart_decided,
        tes_beats_all_rands,
        seconds_per_episode,
        targets,
    };
    write_summary(out, &report)?;
    Ok(report)
}

/// Trains a TES agent with `library` on task `t` of `run` for the training episodes; returns
/// the library it ends with.
fn train_on(
    config: &TransferConfig,
    envs: &[GridEnv],
    library: ViewLibrary,
    run: usize,
    t: usize,
) -> Result<ViewLibrary> {
    let context = |what: &str| format!("run {run}: {what} training task {t}");
    let env = &envs[t];
    let agent_seed = training_seed(config, run, t);
    let params = TesParams {
        planner: planner_of(config),
        ..TesParams::default()
    };
    let mut agent = Tes::new(env.structure(), library, params, agent_seed)
        .with_context(|| context("starting"))?;
    let mut world = ChaCha8Rng::seed_from_u64(agent_seed ^ 0x7EA1_D0A1);
    let s = env.structure();
    for _ in 0..config.train_episodes {
        run_episode(&mut agent, env, &s, &mut world).with_context(|| context("on"))?;
    }
    Ok(agent.finish_task().with_context(|| context("ending"))?.0)
}

/// Every agent's planner settings under `config` (the paper's γ, tolerance and sweep cap).
fn planner_of(config: &TransferConfig) -> PlannerParams {
    PlannerParams {
        stop_at_drift: config.stop_at_drift,
        ..PlannerParams::default()
    }
}

/// An empty library of the suite's shape.
fn empty_library(config: &TransferConfig, envs: &[GridEnv]) -> Result<ViewLibrary> {
    let structure = envs[0].structure();
    Ok(ViewLibrary::new(
        structure.n_actions(),
        structure.n_effects(),
        structure.n_features(),
        LibraryParams {
            max_views: config.max_views,
            ..config.library
        },
    )?)
}

/// Every test task's trained library in `run`, in the order of
/// [`TransferConfig::test_tasks`], each with its training order. The run's order's prefixes
/// are trained once: held-out task `k` at position `p` starts from the library after the
/// first `min(p, training_tasks)` tasks of the order (shared with every later held-out task)
/// and trains on the rest of its own list. The same libraries, bit for bit, as
/// `library_alone` (a test) trains for each task from scratch.
fn trained_libraries(
    config: &TransferConfig,
    envs: &[GridEnv],
    run: usize,
) -> Result<Vec<(Vec<usize>, ViewLibrary)>> {
    let order = run_order(config, run);
    let position = |k: usize| order.iter().position(|&t| t == k).unwrap_or(0);
    let shared = |k: usize| position(k).min(config.training_tasks);
    let longest = config
        .test_tasks
        .iter()
        .map(|&k| shared(k))
        .max()
        .unwrap_or(0);
    // prefixes[i]: the library after training on `order[..i]`.
    let mut prefixes = vec![empty_library(config, envs)?];
    for &t in &order[..longest] {
        let next = prefixes.last().cloned().context("a prefix library")?;
        prefixes.push(train_on(config, envs, next, run, t)?);
    }
    config
        .test_tasks
        .par_iter()
        .map(|&k| {
            let own = training_order(config, run, k);
            let from = shared(k);
            let mut library = prefixes[from].clone();
            for &t in &own[from..] {
                library = train_on(config, envs, library, run, t)?;
            }
            Ok((own, library))
        })
        .collect()
}

/// Held-out task `task`'s library in `run` trained from scratch on its own list (what
/// [`trained_libraries`] computes with shared prefixes).
#[cfg(test)]
fn library_alone(
    config: &TransferConfig,
    envs: &[GridEnv],
    run: usize,
    task: usize,
) -> Result<ViewLibrary> {
    let mut library = empty_library(config, envs)?;
    for t in training_order(config, run, task) {
        library = train_on(config, envs, library, run, t)?;
    }
    Ok(library)
}

/// One run: trains every test task's library, then runs every method on each test task.
fn run_job(
    config: &TransferConfig,
    envs: &[GridEnv],
    methods: &[Method],
    run: usize,
    out: &Path,
) -> Result<Vec<JobResult>> {
    let libraries = trained_libraries(config, envs, run)?;
    config
        .test_tasks
        .par_iter()
        .zip(libraries)
        .map(|(&task, (order, library))| {
            test_job(config, envs, methods, task, run, order, library, out)
        })
        .collect()
}

/// Runs every method on test task `task` of `run`, transferring `library` (trained on
/// `order`).
#[allow(clippy::too_many_arguments)]
fn test_job(
    config: &TransferConfig,
    envs: &[GridEnv],
    methods: &[Method],
    task: usize,
    run: usize,
    order: Vec<usize>,
    library: ViewLibrary,
    out: &Path,
) -> Result<JobResult> {
    let seed = job_seed(config, task, run);
    let test = &envs[task];
    let structure = test.structure();
    let context = |what: &str| format!("test task {task}, run {run}: {what}");

    if run == 0 {
        // Run 0's trained library, for `tes library show`.
        let path = out.join(format!("library-task{task}.tesl"));
        let stored = StoredLibrary {
            library: library.clone(),
            world: format!(
                "grid suite (world seed {}), trained for test task {task}",
                config.world_seed
            ),
            action_names: ["north", "east", "south", "west"]
                .map(String::from)
                .to_vec(),
            feature_names: (0..structure.n_features())
                .map(|i| test.task().feature_name(i))
                .collect(),
        };
        store::save(&path, &stored)?;
    }
    let settings = AgentSettings {
        planner: planner_of(config),
        ..AgentSettings::default()
    };
    let mut episodes = BTreeMap::new();
    for &m in methods {
        let agent_seed = seed
            .wrapping_mul(31)
            .wrapping_add(1_000 + seed_offset(m) as u64);
        let transfer = |policy| {
            let params = TesParams {
                policy,
                planner: planner_of(config),
                ..TesParams::default()
            };
            Tes::new(structure.clone(), library.clone(), params, agent_seed)
                .map(|a| Box::new(a) as Box<dyn Agent + Send>)
                .map_err(BuildError::from)
        };
        let mut agent: Box<dyn Agent + Send> = match m {
            Method::Tes => transfer(ViewPolicy::Tes),
            Method::Lwt => transfer(ViewPolicy::Lwt),
            Method::Rands(_) => transfer(ViewPolicy::RandomFixed),
            // loreRL and fEpsG.
            other => build_agent(other, test, agent_seed, settings),
        }
        .with_context(|| context(&m.name()))?;
        // The same world stream for every method of the run.
        let mut world = ChaCha8Rng::seed_from_u64(seed ^ 0x7E57_7A5C);
        let mut eps = Vec::with_capacity(config.test_episodes);
        for _ in 0..config.test_episodes {
            eps.push(
                run_episode(agent.as_mut(), test, &structure, &mut world)
                    .with_context(|| context(&m.name()))?,
            );
        }
        episodes.insert(m, eps);
    }
    Ok(JobResult {
        task,
        run,
        seed,
        training_order: order,
        library_views: library.len(),
        episodes,
    })
}

fn summarise_task(
    task: usize,
    env: &GridEnv,
    runs: &[&JobResult],
    methods: &[Method],
) -> TaskSummary {
    let mut jumpstart = BTreeMap::new();
    let mut accumulated = BTreeMap::new();
    let mut difference_to_tes = BTreeMap::new();
    let mut jumpstart_difference_to_tes = BTreeMap::new();
    let first = |eps: &[Episode]| eps.first().map_or(f64::NAN, |e| e.reward);
    let total = |eps: &[Episode]| eps.iter().map(|e| e.reward).sum::<f64>();
    for &m in methods {
        let of = |f: &dyn Fn(&JobResult, &[Episode]) -> f64| -> Vec<f64> {
            runs.iter()
                .filter_map(|r| r.episodes.get(&m).map(|eps| f(r, eps)))
                .collect()
        };
        jumpstart.insert(m.name().into_owned(), summarise(&of(&|_, eps| first(eps))));
        accumulated.insert(m.name().into_owned(), summarise(&of(&|_, eps| total(eps))));
        if m != Method::Tes {
            difference_to_tes.insert(
                m.name().into_owned(),
                summarise(&of(&|r, eps| total(eps) - total(&r.episodes[&Method::Tes]))),
            );
            jumpstart_difference_to_tes.insert(
                m.name().into_owned(),
                summarise(&of(&|r, eps| first(eps) - first(&r.episodes[&Method::Tes]))),
            );
        }
    }
    let views: Vec<f64> = runs.iter().map(|r| r.library_views as f64).collect();
    TaskSummary {
        task,
        size: format!("{}x{}", env.task().width(), env.task().height()),
        jumpstart,
        accumulated,
        difference_to_tes,
        jumpstart_difference_to_tes,
        library_views: summarise(&views),
        runs: runs
            .iter()
            .map(|r| RunRecord {
                run: r.run,
                seed: r.seed,
                training_order: r.training_order.clone(),
            })
            .collect(),
    }
}

/// Fig. 4b for one test task: accumulated reward minus TES's, episode by episode.
fn write_fig4b(
    out: &Path,
    task: usize,
    env: &GridEnv,
    runs: &[&JobResult],
    methods: &[Method],
    episodes: usize,
) -> Result<()> {
    let mut series = Vec::new();
    for &m in methods.iter().filter(|&&m| m != Method::Tes) {
        let mut acc = vec![0.0; runs.len()];
        let mut points = Vec::with_capacity(episodes);
        for e in 0..episodes {
            for (a, r) in acc.iter_mut().zip(runs) {
                let (Some(mine), Some(tes)) = (r.episodes.get(&m), r.episodes.get(&Method::Tes))
                else {
                    continue;
                };
                *a += mine[e].reward - tes[e].reward;
            }
            let s = summarise(&acc);
            points.push(s.at((e + 1) as f64));
        }
        series.push(Series::method(m, points));
    }
    let chart = LineChart {
        title: format!(
            "Fig. 4b — task {task} ({}x{}): accumulated reward minus TES's",
            env.task().width(),
            env.task().height()
        ),
        x_label: "test episode".into(),
        y_label: "difference to TES".into(),
        series,
        markers: false,
    };
    write_file(&out.join(format!("fig4b-task{task}.svg")), &chart.to_svg())
}

/// The paper's Table 2 targets: TES's jumpstart beats loreRL's on at least 12 of the 15
/// tasks and LWT's on at least 10 — once counted on the means (`beats`, as the paper counts)
/// and once counting only the tasks each paired 95 % interval decides (`decided`): that count
/// holds when the tasks decided ahead reach the target, fails when even every undecided task
/// would not, and is undecided in between.
fn targets(
    quick: bool,
    tasks: usize,
    beats: [usize; 2],
    decided: [&DecidedTasks; 2],
) -> Vec<TargetCheck> {
    let judged = |check: &mut TargetCheck| {
        if !quick && tasks < GridSuite::TASKS {
            check.verdict = Verdict::PartialRun;
        }
    };
    let on_means = |target: &str, beats: usize, needed: usize| {
        let mut check =
            TargetCheck::new(target, format!("{beats} / {tasks}"), quick, beats >= needed);
        judged(&mut check);
        check
    };
    let by_intervals = |target: &str, decided: &DecidedTasks, needed: usize| {
        let ahead = decided.ahead.len();
        let mut check = TargetCheck::new(target, decided.describe(), quick, ahead >= needed);
        if check.verdict == Verdict::DoesNotHold && ahead + decided.undecided.len() >= needed {
            check.verdict = Verdict::Undecided;
        }
        judged(&mut check);
        check
    };
    vec![
        on_means(
            "Table 2: TES's jumpstart beats loreRL's on >= 12 of 15 tasks (paper: 14)",
            beats[0],
            12,
        ),
        on_means(
            "Table 2: TES's jumpstart beats LWT's on >= 10 of 15 tasks (paper: 12)",
            beats[1],
            10,
        ),
        by_intervals(
            "Table 2, each task decided by its paired 95 % interval: TES's jumpstart ahead of loreRL's on >= 12 of 15",
            decided[0],
            12,
        ),
        by_intervals(
            "Table 2, each task decided by its paired 95 % interval: TES's jumpstart ahead of LWT's on >= 10 of 15",
            decided[1],
            10,
        ),
    ]
}

/// The methods Table 2's chart shows.
const TABLE2_METHODS: [Method; 4] = [Method::Tes, Method::Lwt, Method::LoreRl, Method::FEpsG];

/// Table 2 as a chart: the first-episode reward of TES, LWT, loreRL and fEpsG on each test
/// task, given per task as method name → summary. Tasks are categories — one slot per task
/// of the suite, each method a dot with its 95 % interval, nothing joining tasks — and a task
/// the run did not hold out is marked "not run".
pub fn jumpstart_chart(jumpstart: &BTreeMap<usize, BTreeMap<String, Summary>>) -> CategoryChart {
    let tasks: Vec<usize> = (0..GridSuite::TASKS)
        .chain(jumpstart.keys().copied().filter(|&t| t >= GridSuite::TASKS))
        .collect();
    let series = TABLE2_METHODS
        .iter()
        .map(|m| CategorySeries {
            name: m.name().into_owned(),
            values: tasks
                .iter()
                .map(|t| {
                    let s = jumpstart.get(t)?.get(&*m.name())?;
                    Some(Interval {
                        mean: s.mean,
                        lo: s.lo,
                        hi: s.hi,
                    })
                })
                .collect(),
        })
        .collect();
    CategoryChart {
        title: "Table 2 — reward of the first test episode (jumpstart), mean and 95 % interval"
            .into(),
        x_label: "held-out test task (suite index)".into(),
        y_label: "first-episode reward".into(),
        categories: tasks.iter().map(ToString::to_string).collect(),
        series,
    }
}

fn write_jumpstart_chart(out: &Path, tasks: &[TaskSummary]) -> Result<()> {
    let jumpstart = tasks
        .iter()
        .map(|t| (t.task, t.jumpstart.clone()))
        .collect();
    write_file(
        &out.join("table2.svg"),
        &jumpstart_chart(&jumpstart).to_svg(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_training_prefixes_give_each_held_out_task_the_library_trained_alone() {
        // Three training tasks each: the held-out tasks at positions 0-2 of the order share a
        // shorter prefix and train on the rest alone, the later ones share all three.
        let config = TransferConfig {
            runs: 2,
            train_episodes: 2,
            test_tasks: (0..GridSuite::TASKS).collect(),
            training_tasks: 3,
            ..TransferConfig::quick()
        };
        let envs = environments(&config).unwrap();
        let run = 1;
        let order = run_order(&config, run);
        assert_ne!(order, run_order(&config, 0));
        let shared = trained_libraries(&config, &envs, run).unwrap();
        for (&k, (own, library)) in config.test_tasks.iter().zip(&shared) {
            let expected: Vec<usize> = order.iter().copied().filter(|&t| t != k).take(3).collect();
            assert_eq!(own, &expected, "task {k}");
            assert_eq!(
                library,
                &library_alone(&config, &envs, run, k).unwrap(),
                "task {k}"
            );
        }
        // A subset of the tasks gets the same libraries.
        let subset = TransferConfig {
            test_tasks: vec![order[1], order[7]],
            ..config.clone()
        };
        let some = trained_libraries(&subset, &envs, run).unwrap();
        assert_eq!(some[0], shared[order[1]]);
        assert_eq!(some[1], shared[order[7]]);
    }

    #[test]
    fn table2_targets_are_judged_only_on_a_full_size_run_over_every_task() {
        let decided = |ahead: usize, behind: usize, undecided: usize| DecidedTasks {
            ahead: (0..ahead).collect(),
            behind: (ahead..ahead + behind).collect(),
            undecided: (ahead + behind..ahead + behind + undecided).collect(),
        };
        let verdicts = |quick, tasks, beats, decided: [&DecidedTasks; 2]| -> Vec<Verdict> {
            targets(quick, tasks, beats, decided)
                .into_iter()
                .map(|t| t.verdict)
                .collect()
        };
        // 12 decided ahead of 12 needed holds; 9 ahead with 5 undecided could reach 10 or
        // not (undecided), as could 10 ahead with 4 undecided of 12; 8 ahead with 1
        // undecided cannot reach 10.
        assert_eq!(
            verdicts(false, 15, [12, 9], [&decided(12, 0, 3), &decided(9, 1, 5)]),
            [
                Verdict::Holds,
                Verdict::DoesNotHold,
                Verdict::Holds,
                Verdict::Undecided
            ]
        );
        assert_eq!(
            verdicts(false, 15, [13, 13], [&decided(10, 1, 4), &decided(8, 6, 1)])[2..],
            [Verdict::Undecided, Verdict::DoesNotHold]
        );
        let some = decided(1, 1, 1);
        assert_eq!(
            verdicts(true, 3, [0, 0], [&some, &some]),
            [Verdict::QuickRun; 4]
        );
        assert_eq!(
            verdicts(false, 3, [3, 3], [&some, &some]),
            [Verdict::PartialRun; 4]
        );
        assert!(targets(true, 3, [1, 2], [&some, &some])[0].measured == "1 / 3");
    }

    #[test]
    fn the_library_cap_is_recorded_only_when_it_is_not_the_papers() {
        let paper = serde_json::to_value(TransferConfig::paper()).unwrap();
        assert!(paper.get("max_views").is_none(), "{paper}");
        let read: TransferConfig = serde_json::from_value(paper).unwrap();
        assert_eq!(read.max_views, 20);
        let wide = TransferConfig {
            max_views: 60,
            ..TransferConfig::paper()
        };
        let json = serde_json::to_value(&wide).unwrap();
        assert_eq!(json["max_views"], 60);
        let read: TransferConfig = serde_json::from_value(json).unwrap();
        assert_eq!(read.max_views, 60);
        let none = TransferConfig {
            max_views: 0,
            ..TransferConfig::paper()
        };
        assert!(none.check().is_err());
    }

    #[test]
    fn tasks_are_decided_by_the_paired_interval_of_the_jumpstart_difference() {
        let task = |task: usize, lo: f64, hi: f64| TaskSummary {
            task,
            size: "2x2".into(),
            jumpstart: BTreeMap::new(),
            accumulated: BTreeMap::new(),
            difference_to_tes: BTreeMap::new(),
            jumpstart_difference_to_tes: [(
                "loreRL".to_owned(),
                Summary {
                    mean: 0.5 * (lo + hi),
                    lo,
                    hi,
                    n: 100,
                },
            )]
            .into(),
            library_views: summarise(&[]),
            runs: Vec::new(),
        };
        // loreRL − TES: below 0 is TES ahead, above 0 behind, across 0 undecided.
        let tasks = [
            task(0, 0.18, 0.70),
            task(3, -0.45, 0.05),
            task(4, -0.75, -0.34),
            task(6, -0.05, 0.36),
        ];
        let decided = DecidedTasks::against(&tasks, Method::LoreRl);
        assert_eq!(decided.ahead, [4]);
        assert_eq!(decided.behind, [0]);
        assert_eq!(decided.undecided, [3, 6]);
        assert_eq!(
            decided.describe(),
            "1 ahead, 1 behind (task 0), 2 undecided (tasks 3, 6)"
        );
        // A method the tasks do not have is undecided everywhere.
        assert_eq!(
            DecidedTasks::against(&tasks, Method::Lwt).undecided.len(),
            4
        );
    }
}
