//! Replaying a recording: the recorded observations fed to the controller's acting loop,
//! with the recorded settings, seed and starting library, each decision compared with the
//! recorded command.
//!
//! A live run's plans arrive when the planner finishes them, so which plan a decision used
//! depends on timing. Each recorded command carries [`Command::plans`], the plans its
//! controller had adopted: at most one plan is in flight and plans come back in the order
//! they were handed over, so that count names the hand-over the deciding plan came from. The
//! replay plans on the acting thread in pieces ([`SlicedPlanner`], whose plans equal a
//! planner thread's bit for bit), holds every finished plan back, and lets one be adopted
//! exactly at the observation where the recorded count says the run adopted it. Every
//! hand-over then happens where it happened live (a hand-over is tried once per
//! observation, and succeeds exactly when the planner is idle and the model has changed).
//! An observation that ended an episode has no command; a plan adopted there is told by the
//! next command's count (two more plans: one at the end, one at the start).

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use tes_controller::acting::{ActingError, ActingLoop, Step};
use tes_controller::config::{ConfigError, ControllerConfig};
use tes_controller::process::{acting_settings, empty_library_params};
use tes_controller::realtime::{Planner, PlannerThreadError, SlicedPlanner};
use tes_learning::library::{LibraryError, ViewLibrary};
use tes_learning::plan::PlannerParams;
use tes_runtime::clock::ManualClock;
use tes_topics::{Command, Observation, observation_flags};

use crate::reader::Recording;

/// Why a recording cannot be replayed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// It has no world map, and it is complete: the run never started.
    #[error("the recording has no world map (the run never started)")]
    NoMap,
    /// It was cut short before its world map was written whole: nothing of the run can be
    /// replayed.
    #[error("the recording was cut short before its world map ({0}); there is nothing to replay")]
    CutBeforeMap(String),
    /// Its controller settings do not parse.
    #[error("the recording's controller settings: {0}")]
    Config(#[from] ConfigError),
    /// Its starting library does not decode.
    #[error("the recording's starting library: {0}")]
    Library(String),
    /// The empty library cannot be built.
    #[error("view library: {0}")]
    EmptyLibrary(#[from] LibraryError),
    /// The acting loop failed.
    #[error(transparent)]
    Acting(#[from] ActingError),
    /// The planner failed.
    #[error(transparent)]
    Planner(#[from] PlannerThreadError),
}

/// What a decision was: its action and wheel targets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decision {
    /// The action.
    pub action: u32,
    /// Left wheel target, degrees.
    pub left_deg: i32,
    /// Right wheel target, degrees.
    pub right_deg: i32,
}

impl Decision {
    fn of(c: &Command) -> Self {
        Self {
            action: c.action,
            left_deg: c.left_deg,
            right_deg: c.right_deg,
        }
    }
}

impl std::fmt::Display for Decision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "action {} (wheels {}°, {}°)",
            self.action, self.left_deg, self.right_deg
        )
    }
}

/// The first place a replay went another way than the recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Divergence {
    /// The observation's sequence number.
    pub seq: u64,
    /// Its episode.
    pub episode: u32,
    /// Its step in the episode.
    pub step: u32,
    /// What the recording says (`None`: no command answered it).
    pub expected: Option<Decision>,
    /// What the replay did (`None`: no command).
    pub got: Option<Decision>,
    /// Anything else to say (a plan adoption the replay could not redo).
    pub note: Option<String>,
}

impl std::fmt::Display for Divergence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let show = |d: &Option<Decision>| d.map_or("no command".to_owned(), |d| d.to_string());
        write!(
            f,
            "first divergence at step {} of episode {} (observation {}): expected {}, got {}",
            self.step,
            self.episode,
            self.seq,
            show(&self.expected),
            show(&self.got)
        )?;
        if let Some(note) = &self.note {
            write!(f, " ({note})")?;
        }
        Ok(())
    }
}

/// How a replay went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplayOutcome {
    /// Recorded commands compared.
    pub compared: u64,
    /// Of those, identical in action and wheel targets.
    pub identical: u64,
    /// The first divergence (the replay stops there).
    pub divergence: Option<Divergence>,
    /// Observations fed to the acting loop.
    pub observations: u64,
    /// Recorded commands answering an observation the recording does not hold (a recorder
    /// that fell behind): they cannot be compared, and the replay cannot vouch for the run.
    pub unanswerable: u64,
}

impl std::fmt::Display for ReplayOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.divergence {
            None => write!(
                f,
                "{} of {} commands identical",
                self.identical, self.compared
            )?,
            Some(d) => write!(f, "{d}; {} commands identical before it", self.identical)?,
        }
        if self.unanswerable > 0 {
            let (commands, answer) = if self.unanswerable == 1 {
                ("command answers", "an observation")
            } else {
                ("commands answer", "observations")
            };
            write!(
                f,
                "; {} recorded {commands} {answer} the recording does not hold (not compared)",
                self.unanswerable
            )?;
        }
        Ok(())
    }
}

/// How long the replay waits for one plan (it plans on this thread: never in practice).
const PLAN_PATIENCE: Duration = Duration::from_secs(300);

/// Replays `recording` (see the [module docs](self)).
pub fn replay(recording: &Recording) -> Result<ReplayOutcome, ReplayError> {
    let mut acting = acting_loop(recording)?;
    let clock = ManualClock::new(1_000_000_000).stepping(1_000);
    let script = Script::of(recording);
    let mut outcome = ReplayOutcome {
        compared: 0,
        identical: 0,
        divergence: None,
        observations: 0,
        unanswerable: script.unanswerable(recording),
    };
    for (i, obs) in script.observations.iter().enumerate() {
        let recorded = Recorded {
            command: script.by_answer.get(&obs.seq).copied(),
            next_plans: script.next_plans[i],
        };
        outcome.divergence = replay_observation(&mut acting, &clock, obs, recorded, &mut outcome)?;
        if outcome.divergence.is_some() {
            // Everything recorded counts: "k of N identical" is over the whole run.
            outcome.compared = recording.commands.len() as u64;
            break;
        }
    }
    Ok(outcome)
}

/// The acting loop of the recorded run: its map, settings and starting library, planning on
/// this thread in pieces, every finished plan held back.
fn acting_loop(recording: &Recording) -> Result<ActingLoop, ReplayError> {
    let map = match (&recording.world_map, &recording.truncated) {
        (Some(map), _) => map.clone(),
        (None, Some(why)) => return Err(ReplayError::CutBeforeMap(why.clone())),
        (None, None) => return Err(ReplayError::NoMap),
    };
    let config = ControllerConfig::from_toml(recording.run_value("controller_toml"))?;
    let checked = config.check()?;
    let settings = acting_settings(&config, &checked);
    let library = match &recording.library {
        Some(bytes) => {
            tes_learning::library::store::decode(bytes)
                .map_err(|e| ReplayError::Library(e.to_string()))?
                .library
        }
        None => ViewLibrary::new(
            map.n_actions as usize,
            map.n_effects as usize,
            map.n_features as usize,
            empty_library_params(&config),
        )?,
    };
    let params = PlannerParams {
        max_sweeps: config.plan_sweeps,
        ..PlannerParams::default()
    };
    let planner = move |structure: Arc<_>| -> Result<Planner, PlannerThreadError> {
        Ok(Planner::BetweenPolls(Box::new(SlicedPlanner::new(
            structure,
            params,
            usize::MAX,
        )?)))
    };
    let mut acting = ActingLoop::new(map, library, settings, planner)?;
    acting.hold_plans(true);
    Ok(acting)
}

/// What the replay feeds and checks against: the observations up to the last one a command
/// answered, in sequence order, with the commands by the observation they answer.
struct Script<'a> {
    observations: Vec<&'a Observation>,
    by_answer: HashMap<u64, &'a Command>,
    /// For each observation, the plans count of the next command after it.
    next_plans: Vec<Option<u64>>,
}

impl<'a> Script<'a> {
    /// The recorded commands answering an observation the recording does not hold.
    fn unanswerable(&self, recording: &Recording) -> u64 {
        let held: std::collections::HashSet<u64> =
            recording.observations.iter().map(|o| o.seq).collect();
        recording
            .commands
            .iter()
            .filter(|c| !held.contains(&c.answers))
            .count() as u64
    }

    fn of(recording: &'a Recording) -> Self {
        let by_answer: HashMap<u64, &Command> =
            recording.commands.iter().map(|c| (c.answers, c)).collect();
        let last_answered = recording.commands.iter().map(|c| c.answers).max();
        let mut observations: Vec<&Observation> = recording
            .observations
            .iter()
            .filter(|o| last_answered.is_some_and(|last| o.seq <= last))
            .collect();
        observations.sort_by_key(|o| o.seq);
        let mut next_plans = vec![None; observations.len()];
        let mut upcoming = None;
        for (i, o) in observations.iter().enumerate().rev() {
            next_plans[i] = upcoming;
            if let Some(c) = by_answer.get(&o.seq) {
                upcoming = Some(c.plans);
            }
        }
        Self {
            observations,
            by_answer,
            next_plans,
        }
    }
}

/// What the recording says about one observation.
#[derive(Clone, Copy)]
struct Recorded<'a> {
    /// The command that answered it, if one did.
    command: Option<&'a Command>,
    /// The plans count of the next command after it.
    next_plans: Option<u64>,
}

impl Recorded<'_> {
    /// How many plans the run had adopted when it decided on `obs`, the replay having adopted
    /// `current`: the command's count, or for an observation that ended an episode (which
    /// has no command) one more when the next command counts two more.
    fn target_plans(&self, obs: &Observation, current: u64) -> u64 {
        let ends = obs.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED) != 0;
        match self.command {
            Some(c) => c.plans,
            None if ends && self.next_plans.is_some_and(|n| n >= current + 2) => current + 1,
            None => current,
        }
    }
}

/// Feeds `obs` to `acting`, adopting a plan first where the run did, and compares the
/// decision with the recorded one (counted in `outcome`); returns where it diverged, if it
/// did.
fn replay_observation(
    acting: &mut ActingLoop,
    clock: &ManualClock,
    obs: &Observation,
    recorded: Recorded<'_>,
    outcome: &mut ReplayOutcome,
) -> Result<Option<Divergence>, ReplayError> {
    let current = acting.plans();
    let target = recorded.target_plans(obs, current);
    let diverge = |got: Option<Decision>, note: Option<String>| Divergence {
        seq: obs.seq,
        episode: obs.episode,
        step: obs.step,
        expected: recorded.command.map(Decision::of),
        got,
        note,
    };
    if target > current + 1 || target < current {
        let note = format!("the run had adopted {target} plans here, the replay {current}");
        return Ok(Some(diverge(None, Some(note))));
    }
    let got = decide(acting, clock, obs, target == current + 1)?;
    outcome.observations += 1;
    if acting.plans() != target && got.is_some() {
        let note = format!(
            "the run decided with {target} plans adopted, the replay with {}",
            acting.plans()
        );
        return Ok(Some(diverge(got, Some(note))));
    }
    Ok(match (recorded.command, got) {
        (None, None) => None,
        (Some(e), Some(g)) if Decision::of(e) == g => {
            outcome.compared += 1;
            outcome.identical += 1;
            None
        }
        (e, g) => {
            if e.is_some() {
                outcome.compared += 1;
            }
            Some(diverge(g, None))
        }
    })
}

/// The acting loop's decision on `obs` (`None`: no command), letting the held-back plan be
/// adopted first if `adopt`.
fn decide(
    acting: &mut ActingLoop,
    clock: &ManualClock,
    obs: &Observation,
    adopt: bool,
) -> Result<Option<Decision>, ReplayError> {
    if adopt {
        acting.settle_planner(PLAN_PATIENCE)?;
        acting.hold_plans(false);
    }
    let step = acting.on_observation(obs, clock)?;
    if adopt {
        acting.hold_plans(true);
    }
    Ok(match step {
        Step::Act { command, .. } => {
            acting.command_sent(clock)?;
            Some(Decision::of(&command))
        }
        Step::EpisodeEnded { .. } | Step::Refused(_) => None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Commands whose observations the recording lacks are said, singular and plural.
    #[test]
    fn commands_without_their_observation_are_said() {
        let outcome = |unanswerable| ReplayOutcome {
            compared: 0,
            identical: 0,
            divergence: None,
            observations: 0,
            unanswerable,
        };
        assert_eq!(outcome(0).to_string(), "0 of 0 commands identical");
        assert_eq!(
            outcome(1).to_string(),
            "0 of 0 commands identical; 1 recorded command answers an observation the \
             recording does not hold (not compared)"
        );
        assert_eq!(
            outcome(95).to_string(),
            "0 of 0 commands identical; 95 recorded commands answer observations the \
             recording does not hold (not compared)"
        );
    }
}
