//! The paper's §5.2 robot study on the simulated arenas: Fig. 8, Fig. 9, Tables 5 and 6.
//!
//! In-process (the same agent code as the controller process, without IPC, so many repeats
//! run quickly); `tes launch` is the multi-process path. Each step the agent acts in the
//! discretised state, the arena moves the simulated robot by that action's wheel rotations
//! (with motor noise and surface slip), and the agent learns the effect derived from the state
//! change — exactly what the controller derives from perception's observations.
//!
//! Scenarios (the paper's Table 4), all tested on Env 3:
//!
//! * **loreRL** — no experience;
//! * **LWT** — experienced Env 2; its best view per action, frozen;
//! * **TES-woRi** — experienced Env 2; TES;
//! * **TES** — experienced Env 1, then Env 2; TES;
//!
//! plus, for Fig. 8, **fRmax** and **fEpsG** (true DBN contexts: orientation × governing mark)
//! and **man-loreRL** (loreRL on the 12 hand-picked features: 8 orientations + 4 mark bits).
//! Paper settings: α = 0.5, λ = 0.05, γ = 0.95, ε = 0.05, m = 10.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use tes_learning::agents::{
    Agent, Contexts, CountingAgent, LoreRl, LoreRlParams, Tes, TesParams, ViewPolicy,
};
use tes_learning::cmdp::CmdpStructure;
use tes_learning::library::{LibraryParams, ViewLibrary};
use tes_learning::mdagl::MdaglParams;
use tes_learning::plan::PlannerParams;
use tes_perception_sim::arena::{Arena, ArenaId, Episode as ArenaEpisode, EpisodeStatus};
use tes_perception_sim::structure::{self, ArenaFeatures};

use crate::episode::{End, Episode, RunOutcome, write_episodes_csv, write_file, write_summary};
use crate::experiment::Experiment;
use crate::jobs::{self, JobOptions, Manifest};
use crate::method::Method;
use crate::prereg;
use crate::settings::{Kind, Setting, Settings, number};
use crate::stats::{ALPHA, Summary, holm, sign_test, summarise};
use crate::svg::{BandPoint, LineChart, Series};
use crate::verdict::{
    Paired, Side, TargetCheck, Verdict, difference, p_value, paired, paired_family, ratio,
};

/// Settings of `tes experiment robot`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RobotConfig {
    /// Independent repeats (paper: 20 for Fig. 8, 10 for Table 5).
    pub runs: usize,
    /// Episodes on Env 3 (paper: 50).
    pub episodes: usize,
    /// Episodes in each earlier arena the transfer agents experience first.
    pub train_episodes: usize,
    /// Actions after which an episode is cut off (besides terminal states and being stuck).
    pub step_cap: usize,
    /// Base seed; run `r` uses `seed + r`.
    pub seed: u64,
    /// Whether this is the reduced `--quick` configuration.
    pub quick: bool,
}

impl RobotConfig {
    /// The paper's setting: 20 runs, 50 episodes on Env 3, 50 in each earlier arena.
    pub fn paper() -> Self {
        Self {
            runs: 20,
            episodes: 50,
            train_episodes: 50,
            step_cap: 100,
            seed: 1,
            quick: false,
        }
    }

    /// A first look in seconds: 3 runs, 15 episodes, 15 training episodes per arena.
    pub fn quick() -> Self {
        Self {
            runs: 3,
            episodes: 15,
            train_episodes: 15,
            quick: true,
            ..Self::paper()
        }
    }
}

/// The flags of `tes experiment`'s sub-command, defined once (see [`crate::settings`]).
impl Settings for RobotConfig {
    const QUICK_HELP: &'static str = "Small settings for a first look: seconds.";
    const SETTINGS: &'static [Setting<Self>] = &[
        Setting {
            flag: "runs",
            value_name: "RUNS",
            help: "Independent repeats.",
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
            help: "Episodes on Env 3.",
            kind: Kind::Value,
            show: |c| c.episodes.to_string(),
            take: |c, v| {
                c.episodes = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "train-episodes",
            value_name: "TRAIN_EPISODES",
            help: "Episodes in each arena experienced before Env 3.",
            kind: Kind::Value,
            show: |c| c.train_episodes.to_string(),
            take: |c, v| {
                c.train_episodes = number(v)?;
                Ok(())
            },
        },
        Setting {
            flag: "seed",
            value_name: "SEED",
            help: "Base seed; run r uses seed + r.",
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

/// The compared methods, in report order (the order of the jobs, too).
pub const METHODS: [Method; 7] = [
    Method::Tes,
    Method::TesWoRi,
    Method::Lwt,
    Method::LoreRl,
    Method::ManLoreRl,
    Method::FRmax,
    Method::FEpsG,
];

/// The arenas `method` experiences before Env 3: TES after Env 1 and Env 2, TES-woRi and LWT
/// after Env 2 only, the others none.
fn experience(method: Method) -> &'static [ArenaId] {
    match method {
        Method::Tes => &[ArenaId::Env1, ArenaId::Env2],
        Method::TesWoRi | Method::Lwt => &[ArenaId::Env2],
        _ => &[],
    }
}

/// An arena with its agent-known CMDP structures (all 312 features, and the 12 hand-picked).
struct World {
    arena: Arena,
    full: Arc<CmdpStructure>,
    manual: Arc<CmdpStructure>,
    contexts: Contexts,
}

impl World {
    fn new(id: ArenaId) -> Result<Self> {
        let arena = Arena::new(id);
        let n = arena.n_states();
        let full = structure::arena(&arena, ArenaFeatures::All)
            .with_context(|| format!("{id} does not form a CMDP"))?;
        let manual = structure::arena(&arena, ArenaFeatures::HandPicked)
            .with_context(|| format!("{id}'s hand-picked features do not form a CMDP"))?;
        let of_state = (0..n)
            .map(|s| arena.oracle_context(s).unwrap_or(0) as u32)
            .collect();
        let contexts = Contexts::new(of_state, arena.n_oracle_contexts())
            .context("the arena's oracle contexts are out of range")?;
        Ok(Self {
            arena,
            full: Arc::new(full),
            manual: Arc::new(manual),
            contexts,
        })
    }
}

/// Runs one episode of `agent` in `world` from a random start.
fn run_episode(
    agent: &mut dyn Agent,
    world: &World,
    step_cap: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Episode> {
    let arena = &world.arena;
    let mut pose = arena.random_start(rng);
    let mut state = arena.discretise(pose);
    let mut tracker = ArenaEpisode::new(arena, state)?;
    agent.begin_episode(state);
    let mut agent_time = std::time::Duration::ZERO;
    let mut episode = Episode::new();
    while (episode.steps as usize) < step_cap {
        let t = Instant::now();
        let action = agent.act(state)?;
        agent_time += t.elapsed();
        let outcome = arena.step(pose, action, rng)?;
        let effect = arena.effect_between(state, outcome.state);
        let t = Instant::now();
        agent.observe(state, action, effect)?;
        agent_time += t.elapsed();
        pose = outcome.pose;
        state = outcome.state;
        let step = tracker.observe(arena, state)?;
        episode.reward += step.reward;
        episode.steps += 1;
        match step.status {
            EpisodeStatus::Continuing => {}
            EpisodeStatus::Terminal => {
                episode.finished = true;
                episode.end = End::terminal(step.reward);
                break;
            }
            EpisodeStatus::Stuck => {
                episode.end = End::Stuck;
                break;
            }
        }
    }
    episode.agent_seconds = agent_time.as_secs_f64();
    Ok(episode)
}

fn library_params() -> LibraryParams {
    LibraryParams {
        mdagl: mdagl_params(),
        ..LibraryParams::default()
    }
}

/// The paper's §5.2 view settings: λ = 0.05, α = 0.5.
fn mdagl_params() -> MdaglParams {
    MdaglParams {
        lambda: 0.05,
        alpha: 0.5,
        intercept: false,
    }
}

/// One (method, run) job: experience the earlier arenas (transfer methods), then Env 3.
fn run_job(
    config: &RobotConfig,
    worlds: &BTreeMap<u32, World>,
    method: Method,
    run: usize,
) -> Result<Vec<Episode>> {
    let seed = config.seed + run as u64;
    let test = &worlds[&ArenaId::Env3.number()];
    let s = &test.full;
    let mut library = ViewLibrary::new(
        s.n_actions(),
        s.n_effects(),
        s.n_features(),
        library_params(),
    )?;
    for (i, id) in experience(method).iter().enumerate() {
        let world = &worlds[&id.number()];
        let agent_seed = seed.wrapping_mul(97).wrapping_add(i as u64);
        let mut agent = Tes::new(
            world.full.clone(),
            library,
            TesParams::default(),
            agent_seed,
        )?;
        let mut rng = ChaCha8Rng::seed_from_u64(agent_seed ^ 0xA2E4A);
        for _ in 0..config.train_episodes {
            run_episode(&mut agent, world, config.step_cap, &mut rng)?;
        }
        library = agent.finish_task()?.0;
    }
    let lore = LoreRlParams {
        mdagl: mdagl_params(),
        ..LoreRlParams::default()
    };
    let planner = PlannerParams::default();
    let agent_seed = seed.wrapping_mul(97).wrapping_add(100);
    let transfer = |policy| {
        let params = TesParams {
            policy,
            ..TesParams::default()
        };
        Tes::new(s.clone(), library.clone(), params, agent_seed)
            .map(|a| Box::new(a) as Box<dyn Agent>)
    };
    let mut agent: Box<dyn Agent> = match method {
        Method::Tes | Method::TesWoRi => transfer(ViewPolicy::Tes)?,
        Method::Lwt => transfer(ViewPolicy::Lwt)?,
        Method::LoreRl => Box::new(LoreRl::new(s.clone(), lore, agent_seed)?),
        Method::ManLoreRl => Box::new(LoreRl::new(test.manual.clone(), lore, agent_seed)?),
        Method::FRmax => Box::new(CountingAgent::factored_rmax(
            s.clone(),
            test.contexts.clone(),
            10,
            planner,
            agent_seed,
        )?),
        Method::FEpsG => Box::new(CountingAgent::factored_epsilon_greedy(
            s.clone(),
            test.contexts.clone(),
            0.05,
            planner,
            agent_seed,
        )?),
        other => bail!("{other} is not one of the robot study's methods"),
    };
    // Every method of a run faces the same start and slip stream.
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x007E_57E3);
    let mut episodes = Vec::with_capacity(config.episodes);
    for _ in 0..config.episodes {
        episodes.push(run_episode(
            agent.as_mut(),
            test,
            config.step_cap,
            &mut rng,
        )?);
    }
    Ok(episodes)
}

/// The summary written to `summary.json`.
#[derive(Debug, Serialize, Deserialize)]
pub struct RobotReport {
    /// The settings, seeds included.
    pub config: RobotConfig,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// Accumulated reward after the last Env 3 episode, per method (Fig. 8, Fig. 9's end).
    pub accumulated: BTreeMap<String, Summary>,
    /// Accumulated-reward difference to TES after the last episode, per method (Fig. 9).
    pub difference_to_tes: BTreeMap<String, Summary>,
    /// First-episode reward of every run, per method (Table 5).
    pub first_episode: BTreeMap<String, Vec<f64>>,
    /// Agent seconds per episode, per method (Table 6 / Table 3).
    pub seconds_per_episode: BTreeMap<String, Summary>,
    /// The paper's §5.2 claims, the test of each and its verdict (a `--quick` run says it is
    /// too small to judge).
    pub targets: Vec<TargetCheck>,
    /// Every run's outcome (each episode's reward kept), per method, runs in order.
    pub runs: RunsByMethod,
}

/// The experiment's name in manifests.
pub const EXPERIMENT: &str = "robot";

/// The experiment's independent jobs, in index order: (method, run), runs innermost.
fn job_list(config: &RobotConfig) -> Vec<(Method, usize)> {
    METHODS
        .into_iter()
        .flat_map(|m| (0..config.runs).map(move |r| (m, r)))
        .collect()
}

/// The manifest of a run of `config` (or its `shard`).
pub fn manifest(config: &RobotConfig, shard: jobs::Shard) -> Result<Manifest> {
    Manifest::new(EXPERIMENT, config, job_list(config).len(), shard)
}

fn check(config: &RobotConfig) -> Result<()> {
    if config.runs == 0 || config.episodes == 0 || config.step_cap == 0 {
        bail!("runs, episodes and the step cap must all be at least 1");
    }
    Ok(())
}

/// Runs the robot experiment, writes its files into `out`, and returns the summary.
///
/// `progress(done, total)` is called as jobs (method, run) finish (from worker threads).
pub fn run(
    config: &RobotConfig,
    out: &Path,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<RobotReport> {
    run_with(config, out, JobOptions::default(), progress)?
        .context("a run over every job gives a summary")
}

/// [`run`] with `options`: a share of the jobs (then only their records and the manifest are
/// written, and `None` returned: [`jobs::merge`] and [`summarise_dir`] finish the work) or a
/// resumed run.
pub fn run_with(
    config: &RobotConfig,
    out: &Path,
    options: JobOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Option<RobotReport>> {
    check(config)?;
    let started = Instant::now();
    fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let worlds: BTreeMap<u32, World> = ArenaId::ALL
        .into_iter()
        .map(|id| Ok((id.number(), World::new(id)?)))
        .collect::<Result<_>>()?;
    let jobs = job_list(config);
    let manifest = manifest(config, options.shard)?;
    let results = jobs::run_jobs(out, &manifest, options, progress, |index| {
        let (m, r) = jobs[index];
        run_job(config, &worlds, m, r).with_context(|| format!("{m} run {r}"))
    })?;
    if !options.shard.is_all() {
        return Ok(None);
    }
    report_from(config, results, out, started).map(Some)
}

/// Computes the summary, tables and figures of a complete result folder (one run, a resumed
/// one, or merged shards) from its job records.
pub fn summarise_dir(out: &Path) -> Result<RobotReport> {
    let started = Instant::now();
    let manifest = Manifest::read(out)?;
    let config: RobotConfig = manifest.settings()?;
    check(&config)?;
    let results = jobs::read_all(out, &manifest)?;
    report_from(&config, results, out, started)
}

impl Experiment for RobotConfig {
    type Report = RobotReport;
    const NAME: &'static str = EXPERIMENT;

    fn describe(&self) -> String {
        format!(
            "{} runs of each method (the progress counts these runs), {} episodes on Env 3 after {} per earlier arena, seeds {}..",
            self.runs, self.episodes, self.train_episodes, self.seed
        )
    }

    fn run_with(
        &self,
        out: &Path,
        options: JobOptions,
        progress: &(dyn Fn(u64, u64) + Sync),
    ) -> Result<Option<RobotReport>> {
        run_with(self, out, options, progress)
    }

    fn summarise_dir(out: &Path) -> Result<RobotReport> {
        summarise_dir(out)
    }
}

/// Every job's Env 3 episodes, by (method, run).
type ByJob = BTreeMap<(Method, usize), Vec<Episode>>;

fn report_from(
    config: &RobotConfig,
    results: BTreeMap<usize, Vec<Episode>>,
    out: &Path,
    started: Instant,
) -> Result<RobotReport> {
    let jobs = job_list(config);
    let by: ByJob = results.into_iter().map(|(i, e)| (jobs[i], e)).collect();
    let runs_of = |m: Method| -> Vec<&Vec<Episode>> {
        (0..config.runs).filter_map(|r| by.get(&(m, r))).collect()
    };
    let by_method = |f: &dyn Fn(&[&Vec<Episode>]) -> Summary| -> BTreeMap<String, Summary> {
        METHODS
            .iter()
            .map(|&m| (m.name().into_owned(), f(&runs_of(m))))
            .collect()
    };
    let accumulated =
        by_method(&|runs| summarise(&runs.iter().map(|e| total_reward(e)).collect::<Vec<_>>()));
    let seconds_per_episode = by_method(&|runs| {
        summarise(
            &runs
                .iter()
                .map(|e| e.iter().map(|x| x.agent_seconds).sum::<f64>() / e.len() as f64)
                .collect::<Vec<_>>(),
        )
    });
    let first_episode = METHODS
        .iter()
        .map(|&m| {
            let firsts = runs_of(m)
                .iter()
                .map(|e| e.first().map_or(f64::NAN, |x| x.reward))
                .collect();
            (m.name().into_owned(), firsts)
        })
        .collect();
    let difference_to_tes = differences_to_tes(config, &by);
    let runs: RunsByMethod = METHODS
        .iter()
        .map(|&m| {
            let outcomes = runs_of(m).iter().map(|e| RunOutcome::of(e, true)).collect();
            (m.name().into_owned(), outcomes)
        })
        .collect();
    let targets = targets(config.quick, &runs);
    write_figures(config, &by, out)?;
    write_episodes_csv(
        &out.join("episodes.csv"),
        "method,run,seed",
        by.iter().map(|((m, r), eps)| {
            let key = format!("{m},{r},{}", config.seed + *r as u64);
            (key, eps.as_slice())
        }),
    )?;
    let report = RobotReport {
        config: config.clone(),
        wall_seconds: started.elapsed().as_secs_f64(),
        accumulated,
        difference_to_tes,
        first_episode,
        seconds_per_episode,
        targets,
        runs,
    };
    write_summary(out, &report)?;
    Ok(report)
}

/// The reward of all of a run's episodes.
fn total_reward(episodes: &[Episode]) -> f64 {
    episodes.iter().map(|e| e.reward).sum()
}

/// Per method but TES, its accumulated reward minus TES's, paired by run.
fn differences_to_tes(config: &RobotConfig, by: &ByJob) -> BTreeMap<String, Summary> {
    METHODS
        .iter()
        .filter(|&&m| m != Method::Tes)
        .map(|&m| {
            let diffs: Vec<f64> = (0..config.runs)
                .filter_map(|r| {
                    Some(total_reward(by.get(&(m, r))?) - total_reward(by.get(&(Method::Tes, r))?))
                })
                .collect();
            (m.name().into_owned(), summarise(&diffs))
        })
        .collect()
}

/// Every run's outcome on Env 3, per method.
pub type RunsByMethod = BTreeMap<String, Vec<RunOutcome>>;

/// The paper's §5.2 claims, each judged by a paired test over runs:
///
/// * Fig. 9: TES accumulates more than TES-woRi, loreRL and LWT;
/// * §5.2.3: LWT accumulates least (below loreRL and TES-woRi);
/// * §5.2.3: TES-woRi loses to loreRL, "but not to a large extent" (our bound: by less than
///   10 % of loreRL's accumulated reward);
/// * Table 5: TES's first episode beats loreRL's, LWT's and TES-woRi's (sign test);
/// * Table 3: loreRL's time per episode is "only slightly" above man-loreRL's (our bound:
///   at most 1.5 times; paper 1.16).
fn targets(quick: bool, runs: &RunsByMethod) -> Vec<TargetCheck> {
    let of = |m: Method| runs.get(&*m.name()).map_or(&[][..], Vec::as_slice);
    let by_run = |a: Method, b: Method, f: &dyn Fn(&RunOutcome, &RunOutcome) -> f64| -> Vec<f64> {
        of(a).iter().zip(of(b)).map(|(a, b)| f(a, b)).collect()
    };
    let accumulated = |a: Method, b: Method| by_run(a, b, &|a, b| a.accumulated - b.accumulated);
    let family = |a: Method, others: &[Method]| {
        paired_family(
            &others
                .iter()
                .map(|&b| accumulated(a, b))
                .collect::<Vec<_>>(),
        )
    };
    let listed = |names: &[Method], tests: &[Paired]| {
        names
            .iter()
            .zip(tests)
            .map(|(m, p)| format!("{m} {}", difference(p)))
            .collect::<Vec<_>>()
            .join("; ")
    };
    let fig9_others = [Method::TesWoRi, Method::LoreRl, Method::Lwt];
    let fig9 = family(Method::Tes, &fig9_others);
    let lwt_least = paired_family(&[
        accumulated(Method::LoreRl, Method::Lwt),
        accumulated(Method::TesWoRi, Method::Lwt),
    ]);
    let wo_ri_loses = paired(&accumulated(Method::LoreRl, Method::TesWoRi));
    let share_of_lore = prereg::ROBOT_WORI_NOT_BY_MUCH.threshold.value();
    let not_by_much = paired(&by_run(Method::TesWoRi, Method::LoreRl, &|w, l| {
        w.accumulated - share_of_lore * l.accumulated
    }));
    let jumpstart = first_episode_wins(of(Method::Tes), &fig9_others.map(of));
    let time_ratio = summarise(&by_run(Method::LoreRl, Method::ManLoreRl, &|l, m| {
        l.seconds_per_episode / m.seconds_per_episode
    }));
    vec![
        TargetCheck::new(
            prereg::FIG9_TES_AHEAD.target,
            prereg::FIG9_TES_AHEAD.test,
            format!("TES − {}", listed(&fig9_others, &fig9)),
            quick,
            Verdict::all(fig9.iter().map(|p| Verdict::of_side(p.side))),
        ),
        TargetCheck::new(
            prereg::ROBOT_LWT_LEAST.target,
            prereg::ROBOT_LWT_LEAST.test,
            format!(
                "loreRL − LWT {}; TES-woRi − LWT {}",
                difference(&lwt_least[0]),
                difference(&lwt_least[1])
            ),
            quick,
            Verdict::all(lwt_least.iter().map(|p| Verdict::of_side(p.side))),
        ),
        TargetCheck::new(
            prereg::ROBOT_WORI_LOSES.target,
            prereg::ROBOT_WORI_LOSES.test,
            format!("loreRL − TES-woRi {}", difference(&wo_ri_loses)),
            quick,
            Verdict::of_side(wo_ri_loses.side),
        ),
        TargetCheck::new(
            prereg::ROBOT_WORI_NOT_BY_MUCH.target,
            prereg::ROBOT_WORI_NOT_BY_MUCH.test,
            format!(
                "TES-woRi − {share_of_lore} × loreRL {}",
                difference(&not_by_much)
            ),
            quick,
            Verdict::of_side(not_by_much.side),
        ),
        TargetCheck::new(
            prereg::TABLE5_FIRST_EPISODE.target,
            prereg::TABLE5_FIRST_EPISODE.test,
            jumpstart
                .iter()
                .zip(&fig9_others)
                .map(|(w, m)| format!("vs {m}: {}", w.describe()))
                .collect::<Vec<_>>()
                .join("; "),
            quick,
            Verdict::all(jumpstart.iter().map(|w| Verdict::of_side(w.side))),
        ),
        TargetCheck::new(
            prereg::TABLE3_LORE_OVER_MAN.target,
            prereg::TABLE3_LORE_OVER_MAN.test,
            ratio(&time_ratio),
            quick,
            Verdict::at_most(&time_ratio, prereg::TABLE3_LORE_OVER_MAN.threshold.value()),
        ),
    ]
}

/// TES's first episodes against each of `others`' runs: wins, draws, losses and the sign
/// tests, Holm-corrected over the comparisons.
fn first_episode_wins(tes: &[RunOutcome], others: &[&[RunOutcome]]) -> Vec<WinsAndLosses> {
    let counts: Vec<[usize; 3]> = others
        .iter()
        .map(|other| {
            let mut c = [0; 3];
            for (t, o) in tes.iter().zip(other.iter()) {
                let i = match t.first.total_cmp(&o.first) {
                    std::cmp::Ordering::Greater => 0,
                    std::cmp::Ordering::Equal => 1,
                    std::cmp::Ordering::Less => 2,
                };
                c[i] += 1;
            }
            c
        })
        .collect();
    let p: Vec<f64> = counts.iter().map(|c| sign_test(c[0], c[2])).collect();
    let adjusted = holm(&p);
    counts
        .into_iter()
        .zip(p.into_iter().zip(adjusted))
        .map(|([wins, draws, losses], (p, p_holm))| WinsAndLosses {
            wins,
            draws,
            losses,
            p,
            p_holm,
            side: Side::of(wins as f64 - losses as f64, p_holm < ALPHA),
        })
        .collect()
}

/// Wins, draws and losses of paired runs, with the sign test.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WinsAndLosses {
    /// Runs won.
    pub wins: usize,
    /// Runs drawn.
    pub draws: usize,
    /// Runs lost.
    pub losses: usize,
    /// Two-sided sign test.
    #[serde(deserialize_with = "crate::stats::f64_or_nan")]
    pub p: f64,
    /// `p` after Holm's correction over its family.
    #[serde(deserialize_with = "crate::stats::f64_or_nan")]
    pub p_holm: f64,
    /// The side decided.
    pub side: Side,
}

impl WinsAndLosses {
    /// In words: "41 wins, 30 draws, 29 losses (p = 0.1900, Holm p = 0.3800)".
    pub fn describe(&self) -> String {
        format!(
            "{} wins, {} draws, {} losses (p {}, Holm p {})",
            self.wins,
            self.draws,
            self.losses,
            p_value(self.p),
            p_value(self.p_holm)
        )
    }
}

/// Fig. 8 (the single-environment learners' accumulated reward) and Fig. 9 (the transfer
/// methods' and loreRL's accumulated reward minus TES's).
fn write_figures(config: &RobotConfig, by: &ByJob, out: &Path) -> Result<()> {
    let fig8 = LineChart {
        title: "Fig. 8 — accumulated reward on Env 3 (simulated arena)".into(),
        x_label: "episode".into(),
        y_label: "accumulated reward".into(),
        series: [
            Method::LoreRl,
            Method::ManLoreRl,
            Method::FRmax,
            Method::FEpsG,
        ]
        .into_iter()
        .map(|m| Series::method(m, curve(config, by, m, None)))
        .collect(),
        markers: false,
    };
    write_file(&out.join("fig8.svg"), &fig8.to_svg())?;
    let fig9 = LineChart {
        title: "Fig. 9 — accumulated reward minus TES's on Env 3".into(),
        x_label: "episode".into(),
        y_label: "difference to TES".into(),
        series: [Method::Lwt, Method::TesWoRi, Method::LoreRl]
            .into_iter()
            .map(|m| Series::method(m, curve(config, by, m, Some(Method::Tes))))
            .collect(),
        markers: false,
    };
    write_file(&out.join("fig9.svg"), &fig9.to_svg())
}

/// `m`'s accumulated reward episode by episode (minus `minus`'s, paired by run), mean and
/// 95 % band over runs.
fn curve(config: &RobotConfig, by: &ByJob, m: Method, minus: Option<Method>) -> Vec<BandPoint> {
    let mut acc = vec![0.0; config.runs];
    (0..config.episodes)
        .map(|e| {
            for (r, a) in acc.iter_mut().enumerate() {
                let mine = by.get(&(m, r)).map_or(0.0, |x| x[e].reward);
                let base = minus
                    .and_then(|b| by.get(&(b, r)))
                    .map_or(0.0, |x| x[e].reward);
                *a += mine - base;
            }
            let s = summarise(&acc);
            s.at((e + 1) as f64)
        })
        .collect()
}
