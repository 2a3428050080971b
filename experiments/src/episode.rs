//! Running agents on episodic tasks: the machinery the paper's experiments share.
//!
//! A task ([`EpisodicTask`]) is a CMDP the agent knows the structure of, plus the true
//! dynamics it does not know and samples effects from. An experiment builds agents
//! ([`build_agent`]), runs episodes ([`run_episode`]) and records, per episode, the reward
//! collected, the number of actions and the time the agent spent.

use std::sync::Arc;
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use tes_learning::agents::{
    Agent, AgentError, Contexts, CountingAgent, ExampleStore, LoreRl, LoreRlParams, LseRmax,
    LseRmaxParams, RlDt, RlDtParams,
};
use tes_learning::cmdp::CmdpStructure;
use tes_learning::plan::PlannerParams;

use crate::method::Method;

/// An episodic task: known structure, unknown (sampled) dynamics.
pub trait EpisodicTask: Sync {
    /// What the agent knows: states, effect semantics, rewards, terminals, features.
    fn structure(&self) -> Arc<CmdpStructure>;
    /// The true DBN contexts (for the oracle baselines fRmax and fEpsG).
    fn oracle_contexts(&self) -> Contexts;
    /// A start state for a new episode.
    fn random_start(&self, rng: &mut ChaCha8Rng) -> usize;
    /// The effect the true dynamics produce for `action` in `state`.
    fn sample_effect(&self, state: usize, action: usize, rng: &mut ChaCha8Rng) -> usize;
    /// Actions after which an unfinished episode is cut off.
    fn step_cap(&self) -> usize;
}

/// Why [`build_agent`] gave no agent.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// The agent refused its settings or the task.
    #[error(transparent)]
    Agent(#[from] AgentError),
    /// The method transfers a view library or needs a robot arena's features: its
    /// experiment builds its agents itself.
    #[error("{0} is not built from a task alone")]
    NotFromTask(Method),
}

/// A fresh agent of `method` for `task` with the paper's §5.1 settings but those `settings`
/// vary, exploring with `seed`. The methods that learn from the task alone (loreRL, bloreRL,
/// Rmax, fRmax, fEpsG, RL-DT, LSE-Rmax) are built here.
pub fn build_agent(
    method: Method,
    task: &dyn EpisodicTask,
    seed: u64,
    settings: AgentSettings,
) -> Result<Box<dyn Agent + Send>, BuildError> {
    let AgentSettings {
        planner,
        rl_dt_examples,
        fepsg_epsilon,
    } = settings;
    let structure = task.structure();
    let lore = |params: LoreRlParams| LoreRlParams { planner, ..params };
    Ok(match method {
        // λ = 0.05, α = 1.5, ε = 0.05.
        Method::LoreRl => Box::new(LoreRl::new(structure, lore(LoreRlParams::default()), seed)?),
        // λ = 0.
        Method::BloreRl => Box::new(LoreRl::new(
            structure,
            lore(LoreRlParams::blore_rl()),
            seed,
        )?),
        Method::Rmax => Box::new(CountingAgent::rmax(structure, 5, planner, seed)?),
        Method::FRmax => Box::new(CountingAgent::factored_rmax(
            structure,
            task.oracle_contexts(),
            10,
            planner,
            seed,
        )?),
        Method::FEpsG => Box::new(CountingAgent::factored_epsilon_greedy(
            structure,
            task.oracle_contexts(),
            fepsg_epsilon,
            planner,
            seed,
        )?),
        Method::RlDt => Box::new(RlDt::new(
            structure,
            RlDtParams {
                planner,
                examples: rl_dt_examples,
                ..RlDtParams::default()
            },
            seed,
        )?),
        // m = 10, σ = 0.99.
        Method::LseRmax => Box::new(LseRmax::new(
            structure,
            LseRmaxParams {
                planner,
                ..LseRmaxParams::default()
            },
            seed,
        )?),
        Method::Tes
        | Method::TesWoRi
        | Method::TesUnbounded
        | Method::TesNoRecency
        | Method::LoreRlContinual
        | Method::Lwt
        | Method::ManLoreRl
        | Method::Rands(_) => {
            return Err(BuildError::NotFromTask(method));
        }
    })
}

/// What happened in one episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Episode {
    /// Sum of the rewards received.
    pub reward: f64,
    /// Actions taken.
    pub steps: u32,
    /// Whether it ended in a terminal state (not by the step cap).
    pub finished: bool,
    /// Seconds the agent spent choosing actions and learning (the world's time excluded).
    pub agent_seconds: f64,
    /// How it ended.
    #[serde(default)]
    pub end: End,
}

impl Episode {
    /// An episode not yet begun.
    pub fn new() -> Self {
        Self {
            reward: 0.0,
            steps: 0,
            finished: false,
            agent_seconds: 0.0,
            end: End::Cap,
        }
    }
}

impl Default for Episode {
    fn default() -> Self {
        Self::new()
    }
}

/// How an episode ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum End {
    /// Cut off at the step cap.
    #[default]
    Cap,
    /// In a rewarding terminal state: a grid exit, the arena's ball.
    Goal,
    /// In a costly terminal state: fire, a death spot, off the arena.
    Death,
    /// Stuck: the robot did not move for the arena's limit of actions.
    Stuck,
}

impl End {
    /// How an episode that reached a terminal state with `last_reward` ended.
    pub fn terminal(last_reward: f64) -> Self {
        if last_reward > 0.0 {
            Self::Goal
        } else {
            Self::Death
        }
    }

    /// One letter for the per-run records: `g`oal, `d`eath, `c`ap, `s`tuck.
    pub fn letter(self) -> char {
        match self {
            Self::Goal => 'g',
            Self::Death => 'd',
            Self::Cap => 'c',
            Self::Stuck => 's',
        }
    }
}

/// One run's episodes, as a result folder's summary keeps them for every claim made of them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunOutcome {
    /// The first episode's reward (the jumpstart).
    #[serde(deserialize_with = "crate::stats::f64_or_nan")]
    pub first: f64,
    /// The reward of all the episodes.
    #[serde(deserialize_with = "crate::stats::f64_or_nan")]
    pub accumulated: f64,
    /// Agent seconds per episode.
    #[serde(deserialize_with = "crate::stats::f64_or_nan")]
    pub seconds_per_episode: f64,
    /// How each episode ended, one [`End::letter`] per episode.
    pub ends: String,
    /// Each episode's reward, where the experiment keeps them (the robot study's claims by
    /// episode range).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rewards: Option<Vec<f64>>,
}

impl RunOutcome {
    /// The outcome of `episodes`, each episode's reward kept if `keep_rewards`.
    pub fn of(episodes: &[Episode], keep_rewards: bool) -> Self {
        Self {
            first: episodes.first().map_or(f64::NAN, |e| e.reward),
            accumulated: episodes.iter().map(|e| e.reward).sum(),
            seconds_per_episode: episodes.iter().map(|e| e.agent_seconds).sum::<f64>()
                / episodes.len().max(1) as f64,
            ends: episodes.iter().map(|e| e.end.letter()).collect(),
            rewards: keep_rewards.then(|| episodes.iter().map(|e| e.reward).collect()),
        }
    }

    /// The share of episodes `from..to` (0-based, clipped) that ended as `end`.
    pub fn share(&self, end: End, from: usize, to: usize) -> f64 {
        let slice: Vec<char> = self
            .ends
            .chars()
            .skip(from)
            .take(to.saturating_sub(from))
            .collect();
        if slice.is_empty() {
            return f64::NAN;
        }
        slice.iter().filter(|&&c| c == end.letter()).count() as f64 / slice.len() as f64
    }

    /// The reward of episodes `from..to` (0-based, clipped), where kept.
    pub fn reward_between(&self, from: usize, to: usize) -> Option<f64> {
        let r = self.rewards.as_ref()?;
        Some(r.iter().skip(from).take(to.saturating_sub(from)).sum())
    }
}

/// What a watcher of a run sees ([`run_agent_watched`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Seen {
    /// An episode starts in `state`.
    Start {
        /// The episode, from 0.
        episode: usize,
        /// Its start state.
        state: usize,
    },
    /// The agent took `action` in `state`; it had `effect` and led to `next`.
    Step {
        /// Where the agent was.
        state: usize,
        /// What it did.
        action: usize,
        /// What that did.
        effect: usize,
        /// Where it is now.
        next: usize,
        /// The reward for entering `next`.
        reward: f64,
        /// Seconds the agent spent on this step (choosing and learning).
        agent_seconds: f64,
    },
    /// The episode ended.
    End(Episode),
}

/// Runs one episode of `agent` on `task`; `rng` drives the start state and the dynamics.
pub fn run_episode(
    agent: &mut dyn Agent,
    task: &dyn EpisodicTask,
    structure: &CmdpStructure,
    rng: &mut ChaCha8Rng,
) -> Result<Episode, AgentError> {
    run_episode_watched(agent, task, structure, rng, 0, &mut |_| {})
}

/// [`run_episode`], telling `watch` what happens (the episode numbered `number`).
pub fn run_episode_watched(
    agent: &mut dyn Agent,
    task: &dyn EpisodicTask,
    structure: &CmdpStructure,
    rng: &mut ChaCha8Rng,
    number: usize,
    watch: &mut dyn FnMut(Seen),
) -> Result<Episode, AgentError> {
    let mut state = task.random_start(rng);
    watch(Seen::Start {
        episode: number,
        state,
    });
    agent.begin_episode(state);
    let mut episode = Episode::new();
    let mut agent_time = std::time::Duration::ZERO;
    for _ in 0..task.step_cap() {
        let t = Instant::now();
        let action = agent.act(state)?;
        let mut step_time = t.elapsed();
        let effect = task.sample_effect(state, action, rng);
        let t = Instant::now();
        agent.observe(state, action, effect)?;
        step_time += t.elapsed();
        agent_time += step_time;
        let next = structure.next_state(state, effect);
        let reward = structure.reward(next);
        watch(Seen::Step {
            state,
            action,
            effect,
            next,
            reward,
            agent_seconds: step_time.as_secs_f64(),
        });
        state = next;
        episode.reward += reward;
        episode.steps += 1;
        if structure.is_terminal(state) {
            episode.finished = true;
            episode.end = End::terminal(reward);
            break;
        }
    }
    episode.agent_seconds = agent_time.as_secs_f64();
    watch(Seen::End(episode));
    Ok(episode)
}

/// fEpsG's exploration on the grid tasks (paper §5.1.2: ε = 0.1).
pub const PAPER_FEPSG_EPSILON: f64 = 0.1;

/// Settings an experiment may vary across every agent [`build_agent`] builds; the rest are the
/// paper's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AgentSettings {
    /// Every agent's planner.
    pub planner: PlannerParams,
    /// How RL-DT keeps its examples (same behaviour, different cost; default: the list, as
    /// Hester & Stone).
    pub rl_dt_examples: ExampleStore,
    /// fEpsG's exploration ε (default: the paper's 0.1).
    pub fepsg_epsilon: f64,
}

impl Default for AgentSettings {
    fn default() -> Self {
        Self {
            planner: PlannerParams::default(),
            rl_dt_examples: ExampleStore::default(),
            fepsg_epsilon: PAPER_FEPSG_EPSILON,
        }
    }
}

/// Runs `episodes` episodes of a fresh `method` agent on `task`, built with `settings`.
///
/// The agent explores with `seed`; the world (starts and dynamics) uses a stream derived from
/// it, so two methods given the same seed face the same start states as long as the
/// dynamics draw the same number of random numbers. `on_episode` is called after each.
pub fn run_agent(
    method: Method,
    task: &dyn EpisodicTask,
    episodes: usize,
    seed: u64,
    settings: AgentSettings,
    mut on_episode: impl FnMut(&Episode),
) -> Result<Vec<Episode>, BuildError> {
    run_agent_watched(method, task, episodes, seed, settings, &mut |seen| {
        if let Seen::End(e) = seen {
            on_episode(&e);
        }
    })
}

/// [`run_agent`], telling `watch` every start, step and end: the same episodes, for the same
/// seed, as the run without a watcher.
pub fn run_agent_watched(
    method: Method,
    task: &dyn EpisodicTask,
    episodes: usize,
    seed: u64,
    settings: AgentSettings,
    watch: &mut dyn FnMut(Seen),
) -> Result<Vec<Episode>, BuildError> {
    let structure = task.structure();
    let mut agent = build_agent(method, task, seed, settings)?;
    let mut world = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_0F70_121D);
    let mut out = Vec::with_capacity(episodes);
    for number in 0..episodes {
        let e = run_episode_watched(agent.as_mut(), task, &structure, &mut world, number, watch)?;
        out.push(e);
    }
    Ok(out)
}

/// Writes `episodes.csv`-style rows: the key columns named by `key_header` (comma-separated),
/// then `episode,reward,steps,finished,agent_seconds,end` (`end` an [`End::letter`]), one row per episode of each
/// `(key, episodes)` group, the key already formatted as its comma-separated values.
pub(crate) fn write_episodes_csv<'a>(
    path: &std::path::Path,
    key_header: &str,
    groups: impl IntoIterator<Item = (String, &'a [Episode])>,
) -> anyhow::Result<()> {
    use anyhow::Context;
    use std::io::Write;
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    let write = || -> std::io::Result<()> {
        writeln!(
            out,
            "{key_header},episode,reward,steps,finished,agent_seconds,end"
        )?;
        for (key, episodes) in groups {
            for (i, e) in episodes.iter().enumerate() {
                writeln!(
                    out,
                    "{key},{},{},{},{},{:.6},{}",
                    i + 1,
                    e.reward,
                    e.steps,
                    e.finished,
                    e.agent_seconds,
                    e.end.letter()
                )?;
            }
        }
        out.flush()
    };
    write().with_context(|| format!("cannot write {}", path.display()))
}

/// Writes `text` to `path`, naming the file on failure.
pub(crate) fn write_file(path: &std::path::Path, text: &str) -> anyhow::Result<()> {
    use anyhow::Context;
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// Writes an experiment's report as `summary.json` in `out`.
pub(crate) fn write_summary(out: &std::path::Path, report: &impl Serialize) -> anyhow::Result<()> {
    use anyhow::Context;
    let json = serde_json::to_string_pretty(report).context("cannot encode the summary")?;
    write_file(&out.join("summary.json"), &json)
}
