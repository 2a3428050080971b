//! The acting loop: what the controller does with each [`Observation`], as a plain struct with
//! no ports, threads of its own or clock inside — [`crate::process`] wraps it in iceoryx2, and
//! tests drive it directly.
//!
//! The command an observation gets does not depend on what that observation teaches: the
//! action comes from the last adopted plan (ε-greedy over its policy), and that plan was made
//! from an earlier hand-over of the model. So the loop decides first and learns after (the
//! split of Hester & Stone's RTMBA, inside one thread). For every observation
//! ([`ActingLoop::on_observation`]) it:
//!
//! 1. refuses what it cannot use (a stale or duplicate sequence number, a state outside the
//!    map, a non-finite reward) — nothing is learned from or answered;
//! 2. adopts the planner's latest finished plan;
//! 3. picks the next action (ε-greedy) and returns the [`Command`] to publish.
//!
//! Once the caller has published the command it calls [`ActingLoop::command_sent`], which
//! learns from the observation — derives the effect the last action had
//! ([`WorldMap::effect_between`]) and hands it to the agent, which scores and updates every
//! view of that action (TES; with an empty library this is loreRL) — hands the planner the new
//! model, records the decision's latency against the budget and the learning's time, and
//! reports an episode that ended before this command. An observation that ends an episode gets
//! no command, so it is learned from at once. [`Order::LearnFirst`] keeps the older order
//! (learn, then decide), which makes the same decisions bit for bit
//! (`controller/tests/it/decide_first.rs`) and serves as the baseline of the latency benchmark.
//! Everything from the observation to the end of the learning allocates nothing after warm-up
//! (`controller/tests/allocations.rs` drives this struct to show it).
//!
//! ```
//! use tes_controller::acting::{ActingLoop, ActingSettings, Step};
//! use tes_controller::realtime::{Planner, SlicedPlanner};
//! use tes_learning::library::{LibraryParams, ViewLibrary};
//! use tes_learning::plan::PlannerParams;
//! use tes_runtime::clock::ManualClock;
//! use tes_topics::{Observation, StateAttributes, WorldMap, observation_flags};
//!
//! // A corridor of 3 cells facing east: effect 0 moves one cell on, effect 1 stays.
//! let mut map = WorldMap::EMPTY;
//! (map.width, map.height, map.orientations) = (3, 1, 1);
//! (map.n_states, map.n_actions, map.n_effects, map.n_features) = (4, 2, 2, 1);
//! for s in 0..3 {
//!     map.next_state[s][..2].copy_from_slice(&[s as u16 + 1, s as u16]);
//!     map.reward[s] = -0.05;
//! }
//! map.next_state[3][..2].copy_from_slice(&[3, 3]);
//! (map.terminal[3], map.reward[3]) = (1, 1.0);
//! map.action_wheels[0] = [246, 246];
//!
//! let library = ViewLibrary::new(2, 2, 1, LibraryParams::default())?;
//! let planner = |structure| {
//!     let planner = SlicedPlanner::new(structure, PlannerParams::default(), 32)?;
//!     Ok(Planner::BetweenPolls(Box::new(planner)))
//! };
//! let clock = ManualClock::new(1_000_000);
//! let mut acting = ActingLoop::new(Box::new(map), library, ActingSettings::default(), planner)?;
//!
//! let obs = Observation {
//!     seq: 1,
//!     stamp_ns: 1_000_000,
//!     state: StateAttributes::at(0, 0, 0),
//!     n_features: 1,
//!     flags: observation_flags::EPISODE_START,
//!     ..Observation::default()
//! };
//! clock.advance(3_000);
//! let Step::Act { command, .. } = acting.on_observation(&obs, &clock)? else {
//!     return Err("a good observation is answered".into());
//! };
//! assert_eq!(command.answers, 1);
//! acting.command_sent(&clock)?;
//! assert_eq!(acting.counts().actions, 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::sync::Arc;
use std::time::Duration;

use tes_learning::agents::{Agent, AgentError, Tes, TesParams};
use tes_learning::cmdp::{CmdpError, CmdpStructure};
use tes_learning::library::ViewLibrary;
use tes_runtime::clock::Clock;
use tes_runtime::latency::{LatencyRecorder, LatencyReport};
use tes_topics::{Command, Observation, WorldMap, observation_flags};
use thiserror::Error;

pub use crate::config::Order;
use crate::realtime::{Planner, PlannerThreadError};
use crate::summary::EpisodeLine;

/// Why the acting loop cannot go on.
#[derive(Debug, Error)]
pub enum ActingError {
    /// The world map is malformed.
    #[error("the world map is malformed: {0}")]
    BadMap(String),
    /// The map does not form a CMDP.
    #[error("the world map does not form a CMDP: {0}")]
    Cmdp(#[from] CmdpError),
    /// The agent refused its settings or a step.
    #[error("agent: {0}")]
    Agent(#[from] AgentError),
    /// The planner failed.
    #[error(transparent)]
    Planner(#[from] PlannerThreadError),
}

/// What the acting loop is told once, at start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActingSettings {
    /// When an observation is learned from: after its command (the default) or before.
    pub order: Order,
    /// The per-action latency budget, µs: decisions slower than this are counted as misses.
    pub budget_us: u64,
    /// Actions left out of the latency figures at the start.
    pub warmup_actions: u64,
    /// Probability of a random action.
    pub epsilon: f64,
    /// Exploration seed.
    pub seed: u64,
    /// While a command's move is under way, a keep-alive for the bridge's watchdog this often
    /// (`None`: never).
    pub keepalive: Option<Duration>,
    /// At an episode's end, say a library save is due if this long has passed since the last.
    pub save_interval: Duration,
    /// With [`Order::LearnFirst`]: whether the planner gets the new model before the command
    /// is published (with a bridge that sleeps on events: waking the idle planner gets the
    /// other CPU out of halt for the bridge's wake-up) rather than after it (with a bridge that
    /// busy-polls). Deciding first, the model is handed over after learning, after the command.
    pub offer_before_command: bool,
    /// How long to wait for the first plan at start.
    pub first_plan_timeout: Duration,
}

impl Default for ActingSettings {
    fn default() -> Self {
        Self {
            order: Order::DecideFirst,
            budget_us: tes_runtime::settings::DEFAULT_BUDGET_US,
            warmup_actions: 0,
            epsilon: 0.05,
            seed: 1,
            keepalive: None,
            save_interval: Duration::from_secs(10),
            offer_before_command: true,
            first_plan_timeout: Duration::from_secs(10),
        }
    }
}

/// Why an observation was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// Its state is not on the map.
    UnknownState,
    /// Its sequence number is not newer than the last accepted one.
    Stale {
        /// The last accepted sequence number.
        last_seq: u64,
    },
    /// Its reward is NaN or infinite.
    NonFiniteReward,
}

/// What the caller does with an observation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    /// Publish this command, then call [`ActingLoop::command_sent`].
    Act {
        /// The command answering the observation.
        command: Command,
        /// The observation said the outcome of the command in flight was lost, so nothing was
        /// learned from it.
        lost_outcome: bool,
    },
    /// The episode ended with this observation: no command. An episode that had ended
    /// before it without a command since is reported now.
    EpisodeEnded {
        /// The earlier ended episode, now reported.
        report: Option<EpisodeLine>,
    },
    /// The observation was refused; nothing was learned from it and nothing answers it.
    Refused(Refusal),
}

/// What follows a published command.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sent {
    /// An episode that ended before this command, reported now that the command is out.
    pub report: Option<EpisodeLine>,
    /// Whether a library save is due (an episode ended, `save_interval` has passed, and
    /// something was learned since the last save).
    pub save_due: bool,
}

/// The loop's counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counts {
    /// Episodes that ended.
    pub episodes: u64,
    /// Commands published (keep-alives aside).
    pub actions: u64,
    /// Observations refused.
    pub refused: u64,
    /// Keep-alives sent.
    pub keepalives: u64,
    /// Steps learned from: a command's outcome observed after a real motion (a `RESYNC` or an
    /// episode's first observation teaches nothing).
    pub learned: u64,
}

/// The loop's latency figures, after the warm-up: whole decisions (observation stamped →
/// command stamped) and their two parts, and the learning that follows a command.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Latencies {
    /// Observation stamped → command stamped.
    pub decision: LatencyReport,
    /// Observation stamped → received by the loop (publication and wake-up).
    pub wake: LatencyReport,
    /// Observation received → command stamped (the loop's own work).
    pub compute: LatencyReport,
    /// Command published → learned from the observation and handed the planner the model
    /// (deciding first; learning first, this work is part of `compute`). Its misses count
    /// against the same budget.
    pub learn: LatencyReport,
    /// Observations published before the learning of the one before had finished (deciding
    /// first): each waited for that learning, and the wait is part of its decision's latency.
    pub learning_overran: u64,
}

/// One step to learn from: the action taken in `from`, which led to `to` with `reward`.
#[derive(Debug, Clone, Copy)]
struct Lesson {
    from: usize,
    action: usize,
    to: usize,
    reward: f32,
}

/// A decision between [`ActingLoop::on_observation`] and [`ActingLoop::command_sent`].
#[derive(Debug, Clone, Copy)]
struct InFlight {
    state: usize,
    action: usize,
    observed_ns: u64,
    received_ns: u64,
    decided_ns: u64,
    /// Deciding first: what the observation teaches, learned once the command is out.
    lesson: Option<Lesson>,
}

/// The running episode.
#[derive(Debug, Clone, Copy, Default)]
struct EpisodeTally {
    reward: f64,
    steps: u32,
    misses: u64,
    /// The episode ended (its line is made); until the next starts, no step is unfinished.
    ended: bool,
}

/// The acting loop of the controller (see the [module docs](self)).
pub struct ActingLoop {
    map: Box<WorldMap>,
    n_states: usize,
    agent: Tes,
    planner: Planner,
    settings: ActingSettings,
    decision: LatencyRecorder,
    wake: LatencyRecorder,
    compute: LatencyRecorder,
    learning: LatencyRecorder,
    episode_latency: LatencyRecorder,
    counts: Counts,
    last_seq: u64,
    command_seq: u64,
    /// (state, action) of the command whose outcome the next observation tells.
    pending: Option<(usize, usize)>,
    in_flight: Option<InFlight>,
    episode: EpisodeTally,
    /// The episode that just ended, reported once the next command is out: perception
    /// publishes the next episode's first observation right after the last one at the
    /// fastest pace, so reporting first would delay that action.
    ended: Option<EpisodeLine>,
    last_sent_ns: u64,
    /// When the learning after the last command finished (deciding first), until the next
    /// observation checks it was published later.
    learned_ns: Option<u64>,
    learning_overran: u64,
    last_save_ns: u64,
    /// [`Counts::learned`] at the last save due: nothing new, no save.
    learned_at_save: u64,
    /// The last command returned (a keep-alive carries it).
    last_command: Command,
    /// What went wrong adopting a plan in [`prepare`](Self::prepare), reported by the next
    /// observation.
    prepare_failed: Option<ActingError>,
}

impl ActingLoop {
    /// A loop on `map` starting from `library`, planning with the planner `planner` makes
    /// for the map's CMDP; waits for the first plan.
    pub fn new(
        map: Box<WorldMap>,
        library: ViewLibrary,
        settings: ActingSettings,
        planner: impl FnOnce(Arc<CmdpStructure>) -> Result<Planner, PlannerThreadError>,
    ) -> Result<Self, ActingError> {
        Self::starting_at(map, library, settings, planner, 0, 0)
    }

    /// [`new`](Self::new), with command sequence numbers continuing from `command_seq` (a
    /// respawned controller starts from the monotonic clock, so that its commands are newer
    /// than its predecessor's) and `now_ns` as the time of the last save.
    pub fn starting_at(
        map: Box<WorldMap>,
        library: ViewLibrary,
        settings: ActingSettings,
        planner: impl FnOnce(Arc<CmdpStructure>) -> Result<Planner, PlannerThreadError>,
        command_seq: u64,
        now_ns: u64,
    ) -> Result<Self, ActingError> {
        let structure = Arc::new(structure_from_map(&map)?);
        let n_states = structure.n_states();
        let mut planner = planner(structure.clone())?;
        let params = TesParams {
            epsilon: settings.epsilon,
            ..TesParams::default()
        };
        let mut agent = Tes::new(structure, library, params, settings.seed)?;
        agent.model_mut().plan_elsewhere();
        // The first policy before the first action.
        planner.offer(agent.model_mut())?;
        planner.wait(agent.model_mut(), settings.first_plan_timeout)?;
        let recorder = |warmup| LatencyRecorder::new(settings.budget_us, warmup);
        Ok(Self {
            map,
            n_states,
            agent,
            planner,
            decision: recorder(settings.warmup_actions),
            wake: recorder(settings.warmup_actions),
            compute: recorder(settings.warmup_actions),
            learning: recorder(settings.warmup_actions),
            episode_latency: recorder(0),
            settings,
            counts: Counts::default(),
            last_seq: 0,
            command_seq,
            pending: None,
            in_flight: None,
            episode: EpisodeTally::default(),
            ended: None,
            last_sent_ns: now_ns,
            learned_ns: None,
            learning_overran: 0,
            last_save_ns: now_ns,
            learned_at_save: 0,
            last_command: Command::default(),
            prepare_failed: None,
        })
    }

    /// Takes an observation: decides the next action, and learns from the last command's
    /// outcome before (learning first) or once the command is out (deciding first; see the
    /// [module docs](self)). `clock` stamps the receipt and the command.
    pub fn on_observation(
        &mut self,
        obs: &Observation,
        clock: &impl Clock,
    ) -> Result<Step, ActingError> {
        let received_ns = clock.now_ns();
        if let Some(e) = self.prepare_failed.take() {
            return Err(e);
        }
        let state = match self.admit(obs) {
            Ok(state) => state,
            Err(why) => {
                self.counts.refused += 1;
                return Ok(Step::Refused(why));
            }
        };
        self.last_seq = obs.seq;
        if let Some(learned_ns) = self.learned_ns.take()
            && learned_ns > obs.stamp_ns
        {
            self.learning_overran += 1;
        }
        let (mut lesson, lost_outcome) = self.lesson_of(obs, state);
        let ends = obs.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED) != 0;
        if self.settings.order == Order::LearnFirst || ends {
            // Nothing answers an episode's last observation: nothing to put first.
            if let Some(lesson) = lesson.take() {
                self.learn(lesson)?;
            }
        }
        self.planner.collect(self.agent.model_mut())?;
        if ends {
            return self.end_episode(obs);
        }
        let command = self.decide(obs, state, received_ns, lesson, clock)?;
        Ok(Step::Act {
            command,
            lost_outcome,
        })
    }

    /// The state `obs` is in, if the loop can use it: a state on the map, a sequence number
    /// newer than the last accepted one, a finite reward (checked in that order).
    #[inline]
    fn admit(&self, obs: &Observation) -> Result<usize, Refusal> {
        let Some(state) = self
            .map
            .state_index(obs.state)
            .filter(|&s| s < self.n_states)
        else {
            return Err(Refusal::UnknownState);
        };
        if obs.seq <= self.last_seq {
            return Err(Refusal::Stale {
                last_seq: self.last_seq,
            });
        }
        if !obs.reward.is_finite() {
            return Err(Refusal::NonFiniteReward);
        }
        Ok(state)
    }

    /// What the accepted `obs`, in `state`, teaches of the command in flight, and whether
    /// its outcome was lost (`RESYNC`); an episode's first observation teaches nothing and
    /// starts the episode's tally.
    #[inline]
    fn lesson_of(&mut self, obs: &Observation, state: usize) -> (Option<Lesson>, bool) {
        if obs.flags & observation_flags::EPISODE_START != 0 {
            self.pending = None;
            self.episode = EpisodeTally::default();
            (None, false)
        } else if obs.flags & observation_flags::RESYNC != 0 {
            (None, self.pending.take().is_some())
        } else {
            let lesson = self.pending.take().map(|(from, action)| Lesson {
                from,
                action,
                to: state,
                reward: obs.reward,
            });
            (lesson, false)
        }
    }

    /// The episode ended with `obs`: hands the planner the model, counts the episode and
    /// keeps its line to report once the next command is out.
    #[inline]
    fn end_episode(&mut self, obs: &Observation) -> Result<Step, ActingError> {
        self.planner.offer(self.agent.model_mut())?;
        self.counts.episodes += 1;
        self.episode.ended = true;
        // Two episode ends in a row (no command between): report the first now.
        let report = self.ended.take().map(|line| self.report(line));
        self.ended = Some(EpisodeLine {
            episode: obs.episode,
            reward: self.episode.reward,
            steps: self.episode.steps,
            p50_us: 0,
            p99_us: 0,
            max_us: 0,
            misses: self.episode.misses,
        });
        Ok(Step::EpisodeEnded { report })
    }

    /// Picks the action for `state` and makes the command answering `obs`, keeping the
    /// decision in flight (with `lesson`, when it is learned once the command is out) until
    /// [`command_sent`](Self::command_sent).
    #[inline]
    fn decide(
        &mut self,
        obs: &Observation,
        state: usize,
        received_ns: u64,
        lesson: Option<Lesson>,
        clock: &impl Clock,
    ) -> Result<Command, ActingError> {
        let action = self.agent.act(state)?;
        if self.settings.order == Order::LearnFirst && self.settings.offer_before_command {
            self.planner.offer(self.agent.model_mut())?;
        }
        let [left_deg, right_deg] = self.map.action_wheels[action];
        self.command_seq += 1;
        let decided_ns = clock.now_ns();
        self.in_flight = Some(InFlight {
            state,
            action,
            observed_ns: obs.stamp_ns,
            received_ns,
            decided_ns,
            lesson,
        });
        let command = Command {
            seq: self.command_seq,
            answers: obs.seq,
            stamp_ns: decided_ns,
            observed_ns: obs.stamp_ns,
            action: action as u32,
            left_deg,
            right_deg,
            in_flight_action: 0,
            reserved: 0,
            // A counter read: what a replay needs to adopt each plan where this run did.
            plans: self.planner.plans(),
        };
        self.last_command = command;
        Ok(command)
    }

    /// The command [`on_observation`](Self::on_observation) returned is out: learns from the
    /// observation (deciding first), hands the planner the model (unless that was done before
    /// the command), records the decision's latency and the learning's time, and reports an
    /// episode that ended before the command. A call without a command in flight does nothing.
    pub fn command_sent(&mut self, clock: &impl Clock) -> Result<Sent, ActingError> {
        let Some(decided) = self.in_flight.take() else {
            return Ok(Sent::default());
        };
        let now_ns = clock.now_ns();
        self.last_sent_ns = now_ns;
        match self.settings.order {
            Order::DecideFirst => {
                if let Some(lesson) = decided.lesson {
                    self.learn(lesson)?;
                }
                self.planner.offer(self.agent.model_mut())?;
                let learned_ns = clock.now_ns();
                self.learning.record_ns(learned_ns.saturating_sub(now_ns));
                self.learned_ns = Some(learned_ns);
            }
            Order::LearnFirst => {
                if !self.settings.offer_before_command {
                    self.planner.offer(self.agent.model_mut())?;
                }
            }
        }
        // Reporting is not on the acting path: the command is out.
        let mut sent = Sent::default();
        if let Some(line) = self.ended.take() {
            sent.report = Some(self.report(line));
            let since_save = Duration::from_nanos(now_ns.saturating_sub(self.last_save_ns));
            if since_save >= self.settings.save_interval
                && self.counts.learned > self.learned_at_save
            {
                sent.save_due = true;
                self.last_save_ns = now_ns;
                self.learned_at_save = self.counts.learned;
            }
        }
        self.pending = Some((decided.state, decided.action));
        self.episode.steps += 1;
        self.counts.actions += 1;
        let latency_ns = decided.decided_ns.saturating_sub(decided.observed_ns);
        let misses_before = self.episode_latency.misses();
        self.decision.record_ns(latency_ns);
        self.wake
            .record_ns(decided.received_ns.saturating_sub(decided.observed_ns));
        self.compute
            .record_ns(decided.decided_ns.saturating_sub(decided.received_ns));
        self.episode_latency.record_ns(latency_ns);
        self.episode.misses += self.episode_latency.misses() - misses_before;
        Ok(sent)
    }

    /// Learns one step: the agent scores and updates the views of its action.
    fn learn(&mut self, lesson: Lesson) -> Result<(), ActingError> {
        let effect = self.map.effect_between(lesson.from, lesson.to);
        self.agent.observe(lesson.from, lesson.action, effect)?;
        self.counts.learned += 1;
        self.episode.reward += f64::from(lesson.reward);
        Ok(())
    }

    /// No observation came for a while: a keep-alive for the bridge's watchdog if a move is
    /// under way and the last command is older than the keep-alive period.
    pub fn on_idle(&mut self, clock: &impl Clock) -> Option<Command> {
        let period = self.settings.keepalive?;
        let now_ns = clock.now_ns();
        if self.pending.is_none()
            || Duration::from_nanos(now_ns.saturating_sub(self.last_sent_ns)) < period
        {
            return None;
        }
        self.command_seq += 1;
        self.counts.keepalives += 1;
        self.last_sent_ns = now_ns;
        // It carries the command in flight: it replaces that command as the latest one the
        // bridge can read, and a bridge that starts now must still find it.
        Some(Command::keep_alive(
            self.command_seq,
            now_ns,
            Some(&self.last_command),
        ))
    }

    /// One slice of planning while waiting, when planning between polls (a planner thread
    /// needs none); returns whether work is left.
    pub fn plan_between_polls(&mut self) -> bool {
        self.planner.work(self.agent.model_mut())
    }

    /// Gets ready for an observation due any moment (an anticipating wait calls it between
    /// its polls): adopts a finished plan now rather than when the observation comes, and
    /// reads the adopted policy once, so that the decision finds it in this CPU's cache
    /// instead of in the planner's. The plan is the one the observation would have adopted
    /// (the last offer was with the last command), so the decisions are the same. An error
    /// is reported by the next [`on_observation`](Self::on_observation).
    pub fn prepare(&mut self) {
        if self.prepare_failed.is_some() {
            return;
        }
        match self.planner.collect(self.agent.model_mut()) {
            Ok(Some(_)) => {
                let policy = self.agent.model_mut().planner().policy();
                std::hint::black_box(policy.iter().fold(0, |a, &p| a ^ p));
            }
            Ok(None) => {}
            Err(e) => self.prepare_failed = Some(e.into()),
        }
    }

    /// Waits up to `timeout` for the plan in flight to be made, leaving its adoption to the
    /// next observation (see [`Planner::settle`]); returns whether none is left in the
    /// making. For tests and replays that need each plan adopted at a known observation.
    pub fn settle_planner(&mut self, timeout: Duration) -> Result<bool, ActingError> {
        Ok(self.planner.settle(timeout)?)
    }

    /// Holds back (`true`) or allows the adoption of finished plans at the next observations
    /// (see [`Planner::hold`]; a planner thread cannot be held, and `false` says so). With
    /// [`settle_planner`](Self::settle_planner), a replay adopts each plan at the observation
    /// the recorded run adopted it at ([`Command::plans`]).
    pub fn hold_plans(&mut self, hold: bool) -> bool {
        self.planner.hold(hold)
    }

    /// When the last command or keep-alive went out (the clock's reading in
    /// [`command_sent`](Self::command_sent) or [`on_idle`](Self::on_idle)).
    pub fn last_sent_ns(&self) -> u64 {
        self.last_sent_ns
    }

    /// Whether the warm-up actions are behind (the latency figures count from here).
    pub fn warmed_up(&self) -> bool {
        self.decision.warmed_up()
    }

    /// The agent, e.g. to save its library.
    pub fn agent(&self) -> &Tes {
        &self.agent
    }

    /// The counters so far.
    pub fn counts(&self) -> Counts {
        self.counts
    }

    /// Plans adopted so far.
    pub fn plans(&self) -> u64 {
        self.planner.plans()
    }

    /// The latency figures so far.
    pub fn latencies(&self) -> Latencies {
        Latencies {
            decision: self.decision.report(),
            wake: self.wake.report(),
            compute: self.compute.report(),
            learn: self.learning.report(),
            learning_overran: self.learning_overran,
        }
    }

    /// Commands of the episode under way, which has not ended (0 between episodes): a run
    /// stopped mid-episode learned from them though no episode line counts them.
    pub fn unfinished_steps(&self) -> u32 {
        if self.episode.ended {
            0
        } else {
            self.episode.steps
        }
    }

    /// Ends the run: the last ended episode, if not yet reported, and the agent.
    pub fn finish(mut self) -> (Option<EpisodeLine>, Tes) {
        let last = self.ended.take().map(|line| self.report(line));
        (last, self.agent)
    }

    /// Completes an ended episode's line with its decision-latency percentiles and starts the
    /// next episode's latency record.
    fn report(&mut self, mut line: EpisodeLine) -> EpisodeLine {
        line.p50_us = self.episode_latency.quantile_us(0.5);
        line.p99_us = self.episode_latency.quantile_us(0.99);
        line.max_us = self.episode_latency.max_us();
        self.episode_latency.reset();
        line
    }
}

/// Builds the agent-known CMDP from a world map.
pub fn structure_from_map(map: &WorldMap) -> Result<CmdpStructure, ActingError> {
    map.check().map_err(ActingError::BadMap)?;
    let n = map.n_states as usize;
    let features: Vec<Vec<u32>> = map.features[..n]
        .iter()
        .map(|f| f.iter_ones().map(|i| i as u32).collect())
        .collect();
    Ok(CmdpStructure::new(
        n,
        map.n_actions as usize,
        map.n_effects as usize,
        map.n_features as usize,
        |s, e| usize::from(map.next_state[s][e]),
        map.reward[..n].iter().map(|&r| f64::from(r)).collect(),
        map.terminal[..n].iter().map(|&t| t != 0).collect(),
        |s| &features[s],
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::realtime::SlicedPlanner;
    use tes_learning::library::LibraryParams;
    use tes_learning::plan::PlannerParams;
    use tes_runtime::clock::ManualClock;
    use tes_topics::KEEP_ALIVE_ACTION;
    use tes_topics::StateAttributes;
    use tes_topics::observation_flags::{EPISODE_START, TERMINAL};

    /// A corridor of 4 cells facing east and its exit: effect 0 moves one cell on, effect 1
    /// stays; 2 actions.
    fn corridor() -> Box<WorldMap> {
        let mut map = Box::new(WorldMap::EMPTY);
        (map.width, map.height, map.orientations) = (4, 1, 1);
        (map.n_states, map.n_actions, map.n_effects, map.n_features) = (5, 2, 2, 2);
        for s in 0..4u16 {
            map.next_state[usize::from(s)][..2].copy_from_slice(&[s + 1, s]);
            map.reward[usize::from(s)] = -0.05;
            map.features[usize::from(s)].set(usize::from(s % 2));
        }
        map.next_state[4][..2].copy_from_slice(&[4, 4]);
        (map.terminal[4], map.reward[4]) = (1, 1.0);
        map.action_wheels = [[246, 246], [90, -90], [0, 0], [0, 0]];
        map
    }

    fn acting(settings: ActingSettings) -> ActingLoop {
        let library = ViewLibrary::new(2, 2, 2, LibraryParams::default()).unwrap();
        ActingLoop::new(corridor(), library, settings, |s| {
            Ok(Planner::BetweenPolls(Box::new(SlicedPlanner::new(
                s,
                PlannerParams::default(),
                32,
            )?)))
        })
        .unwrap()
    }

    fn observation(seq: u64, stamp_ns: u64, x: u16, reward: f32, flags: u32) -> Observation {
        Observation {
            seq,
            stamp_ns,
            // x = 4 is the exit: the map's out state.
            state: if x >= 4 {
                StateAttributes::OUT
            } else {
                StateAttributes::at(x, 0, 0)
            },
            n_features: 2,
            reward,
            flags,
            ..Observation::default()
        }
    }

    /// With a clock that reads 400 µs later each time, every decision's wake-up is the time
    /// from the stamp to the first reading and its compute one step: latency, its split and
    /// the budget misses add up to what the clock says, per run and per episode.
    #[test]
    fn latency_and_budget_misses_follow_the_clock() {
        let settings = ActingSettings {
            budget_us: 1000,
            warmup_actions: 1,
            ..ActingSettings::default()
        };
        let mut acting = acting(settings);
        let clock = ManualClock::new(10_000_000).stepping(400_000);
        // Wake-ups of 100, 100, 700 and 900 µs: decisions of 500, 500, 1100 and 1300 µs.
        let mut stamps = Vec::new();
        for (seq, wake_us) in [(1u64, 100u64), (2, 100), (3, 700), (4, 900)] {
            let reading = clock.now_ns();
            clock.set(reading);
            let stamp = reading - wake_us * 1000;
            stamps.push(stamp);
            let flags = if seq == 1 { EPISODE_START } else { 0 };
            let obs = observation(seq, stamp, (seq - 1) as u16, -0.05, flags);
            let Step::Act { command, .. } = acting.on_observation(&obs, &clock).unwrap() else {
                panic!("observation {seq} not answered");
            };
            assert_eq!(command.answers, seq);
            assert_eq!(command.observed_ns, stamp);
            assert_eq!(
                command.stamp_ns - stamp,
                (wake_us + 400) * 1000,
                "{command:?}"
            );
            let sent = acting.command_sent(&clock).unwrap();
            assert_eq!(sent.report, None);
        }
        // The first decision is the warm-up: three counted, two over the 1 ms budget.
        let l = acting.latencies();
        assert_eq!((l.decision.count, l.decision.warmup), (3, 1), "{l:?}");
        assert_eq!(l.decision.misses, 2, "{l:?}");
        assert_eq!((l.compute.misses, l.wake.misses), (0, 0), "{l:?}");
        assert_eq!(l.compute.max_us, 400, "{l:?}");
        assert_eq!(l.wake.max_us, 900, "{l:?}");
        assert!((1290..=1310).contains(&l.decision.max_us), "{l:?}");
        // The episode ends; it is reported once the next episode's first command is out, with
        // its own misses (all four decisions count there).
        let t = clock.now_ns();
        let end = observation(5, t, 4, 1.0, TERMINAL);
        assert!(matches!(
            acting.on_observation(&end, &clock).unwrap(),
            Step::EpisodeEnded { report: None }
        ));
        let t = clock.now_ns();
        let start = observation(6, t, 0, 0.0, EPISODE_START);
        assert!(matches!(
            acting.on_observation(&start, &clock).unwrap(),
            Step::Act { .. }
        ));
        let sent = acting.command_sent(&clock).unwrap();
        let line = sent.report.expect("the ended episode is reported");
        assert_eq!((line.steps, line.misses), (4, 2), "{line:?}");
        assert!((line.reward - (3.0 * -0.05 + 1.0)).abs() < 1e-6, "{line:?}");
        assert!(line.p50_us >= 500 && line.p99_us >= 1100, "{line:?}");
        assert_eq!(acting.counts().episodes, 1);
    }

    /// Deciding first, the learning after each command is timed on its own, and an
    /// observation published before that learning finished is counted as having waited.
    #[test]
    fn deciding_first_times_the_learning_and_counts_observations_that_waited_for_it() {
        let mut acting = acting(ActingSettings::default());
        assert_eq!(acting.settings.order, Order::DecideFirst);
        // Every reading 100 µs after the last.
        let clock = ManualClock::new(10_000_000).stepping(100_000);
        let start = clock.now_ns();
        let first = observation(1, start, 0, 0.0, EPISODE_START);
        assert!(matches!(
            acting.on_observation(&first, &clock).unwrap(),
            Step::Act { .. }
        ));
        acting.command_sent(&clock).unwrap();
        assert_eq!(
            acting.counts().learned,
            0,
            "an episode's start teaches nothing"
        );
        let l = acting.latencies();
        assert_eq!((l.learn.count, l.learn.max_us), (1, 100), "{l:?}");
        // Stamped before the learning ended: it waited.
        let early = observation(2, start, 1, -0.05, 0);
        assert!(matches!(
            acting.on_observation(&early, &clock).unwrap(),
            Step::Act { .. }
        ));
        assert_eq!(
            acting.counts().learned,
            0,
            "learned only once the command is out"
        );
        acting.command_sent(&clock).unwrap();
        assert_eq!(acting.counts().learned, 1);
        assert_eq!(acting.latencies().learning_overran, 1);
        // Stamped after it: no wait.
        let late = observation(3, clock.now_ns(), 2, -0.05, 0);
        assert!(matches!(
            acting.on_observation(&late, &clock).unwrap(),
            Step::Act { .. }
        ));
        acting.command_sent(&clock).unwrap();
        let l = acting.latencies();
        assert_eq!((l.learning_overran, l.learn.count), (1, 3), "{l:?}");
        assert_eq!(
            acting.unfinished_steps(),
            3,
            "three commands of a running episode"
        );
        // An episode's last observation has no command: it is learned from at once.
        let end = observation(4, clock.now_ns(), 4, 1.0, TERMINAL);
        assert!(matches!(
            acting.on_observation(&end, &clock).unwrap(),
            Step::EpisodeEnded { .. }
        ));
        assert_eq!(acting.counts().learned, 3);
        assert_eq!(acting.unfinished_steps(), 0, "the episode ended");
    }

    /// Learning first, the learning is part of the decision and no learning is timed apart.
    #[test]
    fn learning_first_learns_before_the_command() {
        let mut acting = acting(ActingSettings {
            order: Order::LearnFirst,
            ..ActingSettings::default()
        });
        let clock = ManualClock::new(10_000_000);
        for (seq, x, flags) in [(1, 0, EPISODE_START), (2, 1, 0)] {
            let obs = observation(seq, clock.now_ns(), x, -0.05, flags);
            assert!(matches!(
                acting.on_observation(&obs, &clock).unwrap(),
                Step::Act { .. }
            ));
            assert_eq!(
                acting.counts().learned,
                seq - 1,
                "learned before the command"
            );
            acting.command_sent(&clock).unwrap();
        }
        assert_eq!(acting.latencies().learn.count, 0);
        assert_eq!("learn-first".parse(), Ok(Order::LearnFirst));
        assert_eq!(Order::DecideFirst.to_string(), "decide-first");
        assert!("later".parse::<Order>().is_err());
    }

    /// Stale, duplicate and malformed observations are refused and counted, answer nothing and
    /// teach nothing; a keep-alive goes out only while a move is under way and the period has
    /// passed.
    #[test]
    fn refusals_and_keepalives() {
        let settings = ActingSettings {
            keepalive: Some(Duration::from_millis(250)),
            ..ActingSettings::default()
        };
        let mut acting = acting(settings);
        let clock = ManualClock::new(1_000_000_000);
        assert_eq!(acting.on_idle(&clock), None, "no move under way");
        let first = observation(10, 1, 0, 0.0, EPISODE_START);
        assert!(matches!(
            acting.on_observation(&first, &clock).unwrap(),
            Step::Act { .. }
        ));
        acting.command_sent(&clock).unwrap();
        for (obs, why) in [
            (
                observation(10, 2, 1, -0.05, 0),
                Refusal::Stale { last_seq: 10 },
            ),
            (
                observation(9, 2, 1, -0.05, 0),
                Refusal::Stale { last_seq: 10 },
            ),
            (observation(11, 2, 1, f32::NAN, 0), Refusal::NonFiniteReward),
            (
                Observation {
                    state: StateAttributes::at(0, 3, 0),
                    ..observation(12, 2, 1, -0.05, 0)
                },
                Refusal::UnknownState,
            ),
        ] {
            assert_eq!(
                acting.on_observation(&obs, &clock).unwrap(),
                Step::Refused(why)
            );
        }
        assert_eq!(acting.counts().refused, 4);
        assert_eq!(acting.counts().actions, 1);
        clock.advance(100_000_000);
        assert_eq!(acting.on_idle(&clock), None, "within the period");
        clock.advance(200_000_000);
        let keepalive = acting.on_idle(&clock).expect("a keep-alive is due");
        assert_eq!(keepalive.action, KEEP_ALIVE_ACTION);
        // It carries the command in flight, for a bridge that starts while it is the latest.
        let in_flight = keepalive.in_flight().expect("the command in flight");
        assert_eq!(in_flight.seq, acting.last_command.seq);
        assert_eq!(in_flight.action, acting.last_command.action);
        assert!(keepalive.seq > in_flight.seq);
        assert_eq!(acting.on_idle(&clock), None, "just sent one");
        assert_eq!(acting.counts().keepalives, 1);
    }
}
