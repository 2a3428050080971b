//! The perception-sim process: the simulated arena and the overhead camera of the paper's
//! Fig. 7 (the observatory system).
//!
//! At start it publishes the arena's [`WorldMap`] (kept as history, so a controller that starts
//! later still gets it). Then, per episode: it places the robot at a random start, lets it
//! settle and publishes an [`Observation`]; every time the bridge reports that a commanded
//! motion has finished (a [`MotorState`] flagged `SETTLED` after a new command), it turns the
//! wheel rotations the brick measured into a new pose — with the arena's surface-dependent slip —
//! waits the settle time (the paper's 200 ms, scaled by the real-time factor), discretises the
//! pose and publishes the next observation with its reward. An episode ends at a terminal
//! state, when the robot is stuck for four actions, or at the step cap.
//!
//! Before the first episode it waits until the group is ready — the controller has reported
//! its progress (it has the map, its library and a first plan) and the bridge has reported
//! the brick at rest over a working link — so that the first observation has a reader and its
//! command a bridge. While it waits for a motion it keeps the world map reachable for a
//! controller that starts late (or is respawned), and says how far it got on its progress
//! service, at once when it takes a motion.
//!
//! A motion report flagged `LINK_DOWN` says nothing about the robot (the bridge could not
//! reach the brick), so it never moves the simulated robot nor sets the baseline of the next
//! motion. If no motion report arrives within `motor_timeout_ms` of an observation, the
//! observation is published again, flagged `RESYNC` (the controller then re-decides without
//! learning from a command whose outcome is unknown).

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tes_runtime::channel::{self, Idle, Inbox, IpcError, Loan, Outbox};
use tes_runtime::clock::monotonic_ns;
use tes_runtime::cpu::{CpuMeter, CpuUse};
use tes_runtime::progress::{ProgressOutbox, ProgressWatch};
use tes_runtime::wait::IDLE_TICK;
use tes_topics::{
    FeatureBits, HeadsUp, MAX_STATES, MotorState, NO_ACTION, Observation, Role, ServiceNames,
    StateAttributes, WorldMap, motor_flags, observation_flags, progress_flags,
};
use thiserror::Error;

use crate::arena::{Arena, ArenaError, ArenaId, Episode, EpisodeStatus, Pose};

pub mod config;
pub mod trajectory;
mod world_pose;
pub use config::{CheckedPerception, ConfigError, PerceptionConfig};
use trajectory::{EndReason, TrajectoryLog, TrajectoryRow};

/// Why perception stopped with an error.
#[derive(Debug, Error)]
pub enum PerceptionError {
    /// A bad setting.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// An iceoryx2 failure.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// The arena refused a state (a bug).
    #[error("arena: {0}")]
    Arena(#[from] ArenaError),
    /// The arena does not fit a world map.
    #[error("the arena has {0} states, more than a world map holds ({MAX_STATES})")]
    TooBig(usize),
    /// The report cannot be written.
    #[error("cannot write the report {}: {error}", path.display())]
    Report {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// The trajectory file cannot be written.
    #[error("cannot write the trajectory {}: {error}", path.display())]
    Trajectory {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

/// What a perception run did (written as JSON to `report`, if set).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct PerceptionSummary {
    /// Episodes finished.
    pub episodes: u32,
    /// Observations published.
    pub observations: u64,
    /// Observations re-published because no motion report came.
    pub resyncs: u64,
    /// Total reward over all episodes.
    pub reward: f64,
    /// The process's CPU over the actions after `warmup_actions` (`None` if there were too
    /// few).
    pub cpu: Option<CpuUse>,
}

/// The arena's structure as a [`WorldMap`].
pub fn world_map(arena: &Arena) -> Result<Box<WorldMap>, PerceptionError> {
    let n = arena.n_states();
    if n > MAX_STATES {
        return Err(PerceptionError::TooBig(n));
    }
    let mut map = Box::new(WorldMap::EMPTY);
    map.seq = 1;
    map.world = arena.id().map_or(0, ArenaId::number);
    map.n_states = n as u32;
    map.n_actions = arena.n_actions() as u32;
    map.n_effects = arena.n_effects() as u32;
    map.n_features = arena.n_features() as u32;
    map.width = arena.cells() as u16;
    map.height = arena.cells() as u16;
    map.orientations = crate::arena::N_ORIENTATIONS as u16;
    for (a, &(l, r)) in crate::arena::ACTIONS.iter().enumerate() {
        map.action_wheels[a] = [l.round() as i32, r.round() as i32];
    }
    for s in 0..n {
        for e in 0..arena.n_effects() {
            map.next_state[s][e] = arena.apply_effect(s, e) as u16;
        }
        map.reward[s] = arena.reward(s) as f32;
        map.terminal[s] = u8::from(arena.is_terminal(s));
        map.features[s] = bits(arena.features(s));
    }
    Ok(map)
}

fn bits(features: &[u32]) -> FeatureBits {
    let mut b = FeatureBits::EMPTY;
    for &i in features {
        b.set(i as usize);
    }
    b
}

fn attributes(arena: &Arena, state: usize) -> StateAttributes {
    arena.attributes(state).unwrap_or(StateAttributes::OUT)
}

/// Runs perception for the configured episodes, or until `stop` is raised.
pub fn run(
    config: &PerceptionConfig,
    stop: &AtomicBool,
) -> Result<PerceptionSummary, PerceptionError> {
    run_resuming(config, stop, false)
}

/// [`run`]; when `resume` is set (a respawn within a run), it goes on from the trajectory
/// its predecessor wrote: episode numbers continue after the last episode that ended there
/// and the configured number of episodes counts the run's, not this process's. Without a
/// trajectory file there is nothing to go on from and it starts at episode 0.
pub fn run_resuming(
    config: &PerceptionConfig,
    stop: &AtomicBool,
    resume: bool,
) -> Result<PerceptionSummary, PerceptionError> {
    let checked = config.check()?;
    let (strategy, settle) = (checked.wait(), checked.settle());
    let arena = Arena::new(ArenaId::from_number(config.arena).map_err(PerceptionError::Arena)?);
    let names = ServiceNames::with_prefix(&config.service_prefix);
    let node = channel::group_node(&names, Role::Perception, false)?;
    let maps: Outbox<WorldMap> = Outbox::open(&node, &names.world_map, &names.world_map_event, 1)?;
    let observations: Outbox<Observation> =
        Outbox::open(&node, &names.observation, &names.observation_event, 0)?;
    let heads_up: Outbox<HeadsUp> = Outbox::open(
        &node,
        &names.observation_due,
        &names.observation_due_event,
        0,
    )?;
    let motors: Inbox<MotorState> = Inbox::open(
        &node,
        &names.motor_state,
        &names.motor_state_event,
        0,
        strategy,
    )?;
    let world_poses = world_pose::WorldPoseOut::new(Outbox::open(
        &node,
        &names.world_pose,
        &names.world_pose_event,
        0,
    )?);
    let mut watch = ProgressWatch::open(&node, &names)?;
    let mut progress = ProgressOutbox::open(&node, &names, Role::Perception)?;
    let map = world_map(&arena)?;
    maps.send(*map)?;
    tracing::info!(arena = %arena.id().map_or("custom".into(), |a| a.to_string()), states = arena.n_states(), "world map published");

    // Tacho counts at the last settled motion (or heartbeat at rest), the baseline of the next.
    let Some(counts) = wait_for_the_group(&maps, &motors, &mut watch, &mut progress, config, stop)?
    else {
        return Ok(PerceptionSummary::default());
    };
    // Announcing its observations (at the robot's pace), perception publishes while
    // anticipating receivers poll: off the acting thread's CPU, that thread polls alone. Not
    // announcing, it shares that CPU, where the controller it wakes sleeps.
    tes_runtime::affinity::join_the_chain(
        !settle.is_zero() || strategy == tes_runtime::wait::WaitStrategy::Anticipate,
        "perception",
    );
    let (trajectory, first_episode) = open_trajectory(config, resume)?;
    if first_episode > 0 {
        tracing::info!(
            first_episode,
            episodes = config.episodes,
            "going on with the run after a restart"
        );
    }
    let mut camera = Camera {
        arena: &arena,
        config,
        maps: &maps,
        observations: &observations,
        world_poses: &world_poses,
        heads_up: &heads_up,
        motors: &motors,
        progress,
        settle,
        loan: None,
        motor_timeout: Duration::from_millis(config.motor_timeout_ms),
        rng: episode_rng(config.seed, first_episode),
        summary: PerceptionSummary::default(),
        counts,
        // Sequence numbers start from the monotonic clock, so a respawned perception's
        // observations are newer than anything its predecessor published: the controller,
        // which refuses stale or duplicate numbers, takes them without being told of the
        // restart.
        seq: monotonic_ns(),
        last_command: 0,
        actions: 0,
        trajectory,
        maps_updated: std::time::Instant::now(),
        cpu: CpuMeter::process(),
    };
    for episode in first_episode..config.episodes {
        if camera.run_episode(episode, stop)? == Flow::Stopped {
            return camera.stopped();
        }
        if camera.out_of_actions() {
            tracing::info!(actions = camera.actions, "action limit reached");
            break;
        }
    }
    camera.finish()
}

/// Writes `summary` as JSON to the config's `report`, if set.
fn write_report(
    config: &PerceptionConfig,
    summary: &PerceptionSummary,
) -> Result<(), PerceptionError> {
    let Some(path) = &config.report else {
        return Ok(());
    };
    let text = serde_json::to_string_pretty(summary).map_err(std::io::Error::other);
    text.and_then(|t| std::fs::write(path, t))
        .map_err(|error| PerceptionError::Report {
            path: path.clone(),
            error,
        })
}

/// The trajectory file, if one is asked for, and the episode to start with: 0, or when
/// `resume`, the one after the last that ended in the file ([`TrajectoryLog::resume`]).
fn open_trajectory(
    config: &PerceptionConfig,
    resume: bool,
) -> Result<(Option<TrajectoryLog>, u32), PerceptionError> {
    let Some(path) = config.trajectory.as_ref() else {
        return Ok((None, 0));
    };
    let opened = if resume {
        TrajectoryLog::resume(path)
    } else {
        TrajectoryLog::create(path).map(|log| (log, 0))
    };
    let (log, first) = opened.map_err(|error| PerceptionError::Trajectory {
        path: path.clone(),
        error,
    })?;
    Ok((Some(log), first))
}

/// The random starts of a run from episode `first` on: the seed's own sequence from the
/// run's start, a sequence of its own for a run going on after a restart (which would
/// otherwise repeat the first episodes' starts).
fn episode_rng(seed: u64, first: u32) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(u64::from(first));
    rng
}

/// Whether a run goes on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Flow {
    /// On to the next episode.
    Continue,
    /// `stop` was raised.
    Stopped,
}

/// What a wait for a motion report ended with.
#[derive(Debug, Clone, Copy)]
enum MotionWait {
    /// The motion a new command caused has finished.
    Moved(Motion),
    /// No report of one within the motor timeout.
    TimedOut,
    /// `stop` was raised.
    Stopped,
}

/// A finished motion the bridge reported, for a command newer than the last one used.
#[derive(Debug, Clone, Copy)]
struct Motion {
    /// The command that caused it.
    command: u64,
    /// The action the bridge carried out ([`NO_ACTION`] if it did not say).
    action: u16,
    /// The wheels' tacho counts since the last motion, left and right.
    left: i32,
    /// See `left`.
    right: i32,
}

/// The overhead camera over the simulated arena: the episodes' loop, one method per phase of
/// a step (publish the observation, wait for the motion, move the robot). (Fields drop in the
/// order declared: the trajectory is closed first, the progress service after it.)
struct Camera<'a> {
    trajectory: Option<TrajectoryLog>,
    arena: &'a Arena,
    config: &'a PerceptionConfig,
    maps: &'a Outbox<WorldMap>,
    observations: &'a Outbox<Observation>,
    /// Where the world has the robot, for viewers.
    world_poses: &'a world_pose::WorldPoseOut,
    /// Where perception says, as the robot starts to settle, when the observation is due.
    heads_up: &'a Outbox<HeadsUp>,
    motors: &'a Inbox<MotorState>,
    progress: ProgressOutbox,
    /// How long the robot settles after a motion (scaled by the real-time factor).
    settle: Duration,
    /// The next observation's sample, loaned as the settle ends.
    loan: Option<Loan<Observation>>,
    /// How long to wait for a motion report before re-publishing an observation.
    motor_timeout: Duration,
    rng: ChaCha8Rng,
    summary: PerceptionSummary,
    /// Tacho counts at the last settled motion (or heartbeat at rest), the baseline of the
    /// next.
    counts: [i32; 2],
    /// The last observation's sequence number.
    seq: u64,
    /// The last command whose motion we used.
    last_command: u64,
    /// Actions taken over all episodes.
    actions: u64,
    /// When the world map's connections were last updated (and progress reported).
    maps_updated: std::time::Instant,
    /// The process's CPU over the measured observations.
    cpu: CpuMeter,
}

/// The episode in progress: where the robot is and what its next observation says.
struct EpisodeRun {
    episode: u32,
    pose: Pose,
    state: usize,
    tracker: Episode,
    flags: u32,
    reward: f64,
    after_command: u64,
    step: u32,
    /// The pose before the last motion (the start's at an episode's start).
    moved_from: Pose,
    /// The last action's trajectory row, written after the observation it led to.
    pending: Option<TrajectoryRow>,
}

impl Camera<'_> {
    /// Ends the run: the last report of progress, then the trajectory file is closed.
    fn finish(self) -> Result<PerceptionSummary, PerceptionError> {
        let Self {
            mut progress,
            trajectory,
            mut summary,
            cpu,
            config,
            ..
        } = self;
        progress.publish(monotonic_ns())?;
        drop(trajectory);
        summary.cpu = cpu.report();
        write_report(config, &summary)?;
        Ok(summary)
    }

    /// The summary of a run `stop` ended, its report written.
    fn stopped(mut self) -> Result<PerceptionSummary, PerceptionError> {
        self.summary.cpu = self.cpu.report();
        write_report(self.config, &self.summary)?;
        Ok(self.summary)
    }

    /// Whether the configured number of actions (if any) has been taken.
    fn out_of_actions(&self) -> bool {
        self.config.actions > 0 && self.actions >= self.config.actions
    }

    /// Runs episode `episode` from a random start to its end.
    fn run_episode(&mut self, episode: u32, stop: &AtomicBool) -> Result<Flow, PerceptionError> {
        let pose = self.arena.random_start(&mut self.rng);
        let state = self.arena.discretise(pose);
        // The robot is put at its start and comes to rest there, as after any motion: at
        // the robot's pace the episode's first observation is announced like every other.
        self.settle()?;
        let mut run = EpisodeRun {
            episode,
            pose,
            state,
            tracker: Episode::new(self.arena, state)?,
            flags: observation_flags::EPISODE_START,
            reward: 0.0,
            after_command: 0,
            step: 0,
            moved_from: pose,
            pending: None,
        };
        loop {
            self.publish(&mut run)?;
            if run.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED) != 0 {
                break;
            }
            let motion = match self.wait_for_motion(stop)? {
                MotionWait::Moved(motion) => motion,
                MotionWait::Stopped => return Ok(Flow::Stopped),
                MotionWait::TimedOut => {
                    self.summary.resyncs += 1;
                    tracing::warn!(
                        seq = self.seq,
                        "no motion report within {:?}; re-publishing the observation",
                        self.motor_timeout
                    );
                    run.flags = observation_flags::RESYNC;
                    run.reward = 0.0;
                    continue;
                }
            };
            self.take_motion(&mut run, motion)?;
        }
        self.summary.episodes += 1;
        // The run's count (a restarted perception goes on with its predecessor's episodes).
        self.progress.report_mut().episodes = u64::from(episode) + 1;
        tracing::info!(
            episode,
            reward = run.tracker.total_reward(),
            actions = run.step,
            "episode over"
        );
        Ok(Flow::Continue)
    }

    /// Publishes the observation of where the robot is now; then (the controller decides
    /// meanwhile) writes the last action's trajectory row and notes the progress.
    fn publish(&mut self, run: &mut EpisodeRun) -> Result<(), PerceptionError> {
        self.seq += 1;
        let mut observation = Observation {
            seq: self.seq,
            stamp_ns: 0,
            after_command: run.after_command,
            episode: run.episode,
            step: run.step,
            state: attributes(self.arena, run.state),
            n_features: self.arena.n_features() as u32,
            features: bits(self.arena.features(run.state)),
            reward: run.reward as f32,
            flags: run.flags,
        };
        // An episode's last row is written before its last observation goes out: a restarted
        // perception goes on after the last episode its trajectory ends, and the controller
        // reports an episode once it has that observation — so no episode is run twice. (No
        // command answers that observation: no decision waits for the write.)
        if run.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED) != 0 {
            self.write_pending_row(run)?;
        }
        // Stamped as it is handed over, as the floor's source stamps: the latency measured
        // from here is the link's and the decision's, not what it took to see the world.
        observation.stamp_ns = monotonic_ns();
        self.observations.send_in(self.loan.take(), observation)?;
        // The receivers may be polling on this very CPU (two CPUs, three processes around
        // the observation's time): let them run before the rest of this step's work.
        if !self.settle.is_zero() {
            std::thread::yield_now();
        }
        self.summary.observations += 1;
        self.world_poses.send(
            self.seq,
            run.episode,
            run.after_command,
            run.moved_from,
            run.pose,
        )?;
        self.write_pending_row(run)?;
        self.progress.report_mut().out_seq = self.seq;
        self.progress.report_mut().steps = self.summary.observations;
        Ok(())
    }

    /// Writes the last action's trajectory row, if not yet written.
    fn write_pending_row(&mut self, run: &mut EpisodeRun) -> Result<(), PerceptionError> {
        if let (Some(log), Some(row)) = (self.trajectory.as_mut(), run.pending.take()) {
            log.push(self.arena, &row)
                .map_err(|error| PerceptionError::Trajectory {
                    path: log.path().to_owned(),
                    error,
                })?;
        }
        Ok(())
    }

    /// Waits for the motion a new command caused to finish.
    fn wait_for_motion(&mut self, stop: &AtomicBool) -> Result<MotionWait, PerceptionError> {
        let waiting = std::time::Instant::now();
        loop {
            let left = self.motor_timeout.saturating_sub(waiting.elapsed());
            if left.is_zero() {
                return Ok(MotionWait::TimedOut);
            }
            // Off the acting path (the command is out or the controller is gone): keep the
            // map reachable for a controller that starts now, and report.
            if self.maps_updated.elapsed() >= IDLE_TICK {
                self.maps_updated = std::time::Instant::now();
                self.maps.update_connections()?;
                self.world_poses.update_connections()?;
                self.progress.publish_due(monotonic_ns())?;
            }
            match self.motors.next(left.min(IDLE_TICK), stop)? {
                Err(Idle::Stopped) => return Ok(MotionWait::Stopped),
                Err(Idle::Timeout) => {}
                Ok(m) if m.flags & motor_flags::LINK_DOWN != 0 => {
                    // The bridge cannot reach the brick: nothing is known of the robot.
                }
                Ok(m) => {
                    if let Some(motion) = self.motion_of(&m)? {
                        return Ok(MotionWait::Moved(motion));
                    }
                }
            }
        }
    }

    /// The motion a report `m` over a working link tells of, if it is a settled one after a
    /// command newer than the last one used; a heartbeat at rest sets the baseline of the
    /// next motion.
    fn motion_of(&mut self, m: &MotorState) -> Result<Option<Motion>, PerceptionError> {
        let ports = [self.config.left_port, self.config.right_port];
        let now = [m.tacho_count[ports[0]], m.tacho_count[ports[1]]];
        let settled = m.flags & motor_flags::SETTLED != 0;
        if m.after_command > self.last_command && settled {
            let before = self.counts;
            self.counts = now;
            self.last_command = m.after_command;
            // Said at once: a bridge that starts now must know this motion was used (see the
            // bridge's take-over of a command in flight).
            self.progress.report_mut().in_seq = self.last_command;
            self.progress.publish(monotonic_ns())?;
            return Ok(Some(Motion {
                command: m.after_command,
                action: m.action,
                left: now[0] - before[0],
                right: now[1] - before[1],
            }));
        }
        if m.after_command <= self.last_command && settled {
            // A heartbeat at rest: the baseline for the next motion.
            self.counts = now;
        }
        Ok(None)
    }

    /// Lets the robot come to rest (the settle time; nothing at the fastest pace), having
    /// said first when the next observation is due, so that a receiver waiting by
    /// `anticipate` sleeps until just before it; and keeps that time, the observation's
    /// sample loaned just before.
    fn settle(&mut self) -> Result<(), PerceptionError> {
        if self.settle.is_zero() {
            return Ok(());
        }
        let due_ns = monotonic_ns() + self.settle.as_nanos() as u64;
        self.heads_up.send(HeadsUp {
            seq: self.seq + 1,
            due_ns,
        })?;
        self.loan = Some(tes_runtime::channel::sleep_until_with_loan(
            due_ns,
            self.observations,
        )?);
        Ok(())
    }

    /// Moves the robot by `motion` (with the arena's slip), lets it settle, and sets what the
    /// next observation says: the state, its reward, whether the episode ends.
    fn take_motion(&mut self, run: &mut EpisodeRun, motion: Motion) -> Result<(), PerceptionError> {
        let (pose_before, from) = (run.pose, run.state);
        run.moved_from = pose_before;
        run.pose = self.arena.move_robot(
            run.pose,
            f64::from(motion.left),
            f64::from(motion.right),
            &mut self.rng,
        );
        self.settle()?;
        run.state = self.arena.discretise(run.pose);
        let outcome = run.tracker.observe(self.arena, run.state)?;
        run.reward = outcome.reward;
        self.summary.reward += run.reward;
        run.step += 1;
        self.actions += 1;
        if self.actions >= self.config.warmup_actions.max(1) {
            self.cpu.mark();
        }
        run.after_command = motion.command;
        let out_of_actions = self.out_of_actions();
        let step_cap = run.step >= self.config.step_cap;
        run.flags = match outcome.status {
            EpisodeStatus::Terminal => observation_flags::TERMINAL,
            EpisodeStatus::Stuck => observation_flags::TRUNCATED,
            EpisodeStatus::Continuing if step_cap || out_of_actions => observation_flags::TRUNCATED,
            EpisodeStatus::Continuing => 0,
        };
        run.pending = self.trajectory.as_ref().map(|_| TrajectoryRow {
            episode: run.episode,
            step: run.step - 1,
            from,
            action: (motion.action != NO_ACTION).then_some(motion.action),
            to: run.state,
            reward: run.reward,
            pose_before,
            pose_after: run.pose,
            end: EndReason::of(
                self.arena,
                run.state,
                outcome.status,
                step_cap,
                out_of_actions,
            ),
        });
        Ok(())
    }
}

/// Waits until the controller has reported (it has the map, its library and a first plan)
/// and the bridge has reported the brick at rest over a working link; keeps the world map
/// reachable meanwhile. Returns the brick's tacho counts of the wheels at rest, or `None` if
/// `stop` was raised first.
fn wait_for_the_group(
    maps: &Outbox<WorldMap>,
    motors: &Inbox<MotorState>,
    watch: &mut ProgressWatch,
    progress: &mut ProgressOutbox,
    config: &PerceptionConfig,
    stop: &AtomicBool,
) -> Result<Option<[i32; 2]>, PerceptionError> {
    let started = std::time::Instant::now();
    let mut said = started;
    let mut at_rest = None;
    // A heartbeat of the brick at rest over a working link gives the wheels' counts.
    let rest = |m: MotorState| {
        (m.flags & motor_flags::LINK_DOWN == 0 && m.flags & motor_flags::SETTLED != 0).then(|| {
            [
                m.tacho_count[config.left_port],
                m.tacho_count[config.right_port],
            ]
        })
    };
    loop {
        maps.update_connections()?;
        watch.poll()?;
        progress.publish_due(monotonic_ns())?;
        while let Some(m) = motors.try_next()? {
            at_rest = rest(m).or(at_rest);
        }
        let controller_ready = watch.latest(Role::Controller).is_some();
        if let (true, Some(counts)) = (controller_ready, at_rest) {
            tracing::info!(
                waited_ms = started.elapsed().as_millis() as u64,
                "the controller and the bridge are ready; starting the first episode"
            );
            return Ok(Some(counts));
        }
        if stop.load(std::sync::atomic::Ordering::Relaxed) {
            return Ok(None);
        }
        if said.elapsed() >= Duration::from_secs(5) {
            said = std::time::Instant::now();
            let link_down = watch.latest(Role::Bridge).is_some_and(|b| {
                b.flags & (progress_flags::LINK_DOWN | progress_flags::LINK_NEVER_UP) != 0
            });
            tracing::info!(
                controller_ready,
                bridge_at_rest = at_rest.is_some(),
                link_down,
                "waiting for the group before the first episode"
            );
        }
        match motors.next(Duration::from_millis(10), stop)? {
            Err(Idle::Stopped) => return Ok(None),
            Err(Idle::Timeout) => {}
            Ok(m) => at_rest = rest(m).or(at_rest),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The world map the controller derives effects on and the arena itself name the same
    /// effect for every move, exact or not (one rule: `tes_topics::effect_between`).
    #[test]
    fn the_map_and_the_arena_agree_on_every_effect() {
        for id in [ArenaId::Env1, ArenaId::Env2, ArenaId::Env3] {
            let arena = Arena::new(id);
            let map = world_map(&arena).unwrap();
            let n = arena.n_states();
            for from in 0..n {
                for to in (from % 5..n).step_by(5) {
                    assert_eq!(
                        map.effect_between(from, to),
                        arena.effect_between(from, to),
                        "{id}: {from} -> {to}"
                    );
                }
            }
        }
    }
    use tes_runtime::channel::WaitStrategy;

    #[test]
    fn the_world_map_matches_the_arena() {
        for id in ArenaId::ALL {
            let arena = Arena::new(id);
            let map = world_map(&arena).unwrap();
            map.check().unwrap();
            assert_eq!(map.n_states as usize, arena.n_states());
            assert_eq!(map.out_state(), arena.out_state());
            for s in (0..arena.n_states()).step_by(7) {
                let a = attributes(&arena, s);
                assert_eq!(map.state_index(a), Some(s), "state {s}");
                assert_eq!(
                    map.features[s]
                        .iter_ones()
                        .map(|i| i as u32)
                        .collect::<Vec<_>>(),
                    arena.features(s)
                );
                assert_eq!(map.terminal[s] != 0, arena.is_terminal(s));
            }
            assert_eq!(map.action_wheels[0], [246, 246]);
        }
    }

    /// Perception's sequence-number rule for motion reports, over real iceoryx2 services: a
    /// report moves the robot only if it is SETTLED and follows a command newer than the last
    /// one used (`after_command` greater). A report of no command, a duplicate of the last
    /// command's, or one of an older command (out of order) moves nothing: the observation is
    /// re-published flagged RESYNC, with the same step and `after_command`. The rule holds
    /// across episodes.
    /// Raises a stop flag when dropped (also while unwinding from a failed assertion).
    struct StopOnDrop<'a>(&'a AtomicBool);

    impl Drop for StopOnDrop<'_> {
        fn drop(&mut self) {
            self.0.store(true, std::sync::atomic::Ordering::SeqCst);
        }
    }

    /// Perception starts its first episode once the controller has reported and the bridge
    /// has reported the brick at rest: plays both (`controller`'s progress, `at_rest`
    /// reporting the brick) until it does, and returns the first observation.
    fn first_observation(
        controller: &mut ProgressOutbox,
        observations: &Inbox<Observation>,
        mut at_rest: impl FnMut(),
    ) -> Observation {
        let never = AtomicBool::new(false);
        loop {
            controller.publish(monotonic_ns()).unwrap();
            at_rest();
            if let Ok(o) = observations
                .next(Duration::from_millis(20), &never)
                .unwrap()
            {
                return o;
            }
        }
    }

    #[test]
    fn duplicate_and_out_of_order_motion_reports_move_nothing() {
        let prefix = format!("tes-test/perception-seq/{}/", std::process::id());
        let config = PerceptionConfig {
            episodes: 2,
            step_cap: 1,
            motor_timeout_ms: 400,
            service_prefix: prefix.clone(),
            ..PerceptionConfig::default()
        };
        let names = ServiceNames::with_prefix(&prefix);
        let node = channel::node(false).unwrap();
        // Subscribed before perception's publisher exists, so no observation is missed.
        let observations: Inbox<Observation> = Inbox::open(
            &node,
            &names.observation,
            &names.observation_event,
            0,
            WaitStrategy::Block,
        )
        .unwrap();
        let motors: Outbox<MotorState> =
            Outbox::open(&node, &names.motor_state, &names.motor_state_event, 0).unwrap();
        let stop = AtomicBool::new(false);
        let never = AtomicBool::new(false);
        let next = || match observations.next(Duration::from_secs(10), &never).unwrap() {
            Ok(o) => o,
            Err(idle) => panic!("no observation within 10 s ({idle:?})"),
        };
        let mut report_seq = 0;
        let mut report = |after_command: u64| {
            motors.update_connections().unwrap();
            report_seq += 1;
            motors
                .send(MotorState {
                    seq: report_seq,
                    after_command,
                    flags: motor_flags::SETTLED,
                    ..MotorState::default()
                })
                .unwrap();
        };
        // A stale report must give a RESYNC of the same step: had it been taken as a motion,
        // the next observation would be the following step.
        let refused = |before: &Observation, after: &Observation| {
            assert_eq!(after.flags, observation_flags::RESYNC, "{after:?}");
            assert_eq!(
                (after.episode, after.step, after.after_command),
                (before.episode, before.step, before.after_command)
            );
            assert_eq!(after.state, before.state);
            assert!(after.seq > before.seq, "observation seq must increase");
        };
        // A fresh report moves the robot: one step on, after this command (past any RESYNC
        // published while it was on its way).
        let moved = |before: &Observation, command: u64| loop {
            let o = next();
            if o.flags == observation_flags::RESYNC {
                continue;
            }
            assert_eq!((o.episode, o.step), (before.episode, before.step + 1));
            assert_eq!(o.after_command, command);
            assert_ne!(
                o.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED),
                0,
                "step_cap 1 ends the episode"
            );
            return o;
        };
        let summary = std::thread::scope(|s| {
            let perception = s.spawn(|| run(&config, &stop));
            // A failed assertion below must not leave perception waiting forever (the scope
            // joins it): stop it on the way out, however that is.
            let _stop_perception = StopOnDrop(&stop);
            let mut controller = ProgressOutbox::open(&node, &names, Role::Controller).unwrap();
            let first = first_observation(&mut controller, &observations, || report(0));
            assert_eq!(first.flags, observation_flags::EPISODE_START);
            assert_eq!((first.episode, first.step), (0, 0));
            assert!(first.seq > 0);
            report(0); // no command yet: a heartbeat at rest
            let second = next();
            refused(&first, &second);
            report(5);
            moved(&second, 5);
            let start = next();
            assert_eq!(start.flags, observation_flags::EPISODE_START);
            assert_eq!((start.episode, start.step), (1, 0));
            report(5); // a duplicate of the command just used
            let dup = next();
            refused(&start, &dup);
            report(3); // an older command, out of order
            let old = next();
            refused(&dup, &old);
            report(6);
            moved(&old, 6);
            perception.join().unwrap().unwrap()
        });
        assert_eq!(summary.episodes, 2);
        assert!(summary.resyncs >= 3, "{summary:?}");
    }

    /// At a pace with a settle time, every observation — each episode's first included — is
    /// announced before it is published, and published no earlier than announced.
    #[test]
    fn every_observation_is_announced_and_kept_on_time() {
        let prefix = format!("tes-test/perception-heads-up/{}/", std::process::id());
        let config = PerceptionConfig {
            episodes: 3,
            step_cap: 1,
            real_time_factor: 0.05, // a 10 ms settle
            service_prefix: prefix.clone(),
            ..PerceptionConfig::default()
        };
        let names = ServiceNames::with_prefix(&prefix);
        let node = channel::node(false).unwrap();
        let (observations, heads_ups): (Inbox<Observation>, Inbox<HeadsUp>) = (
            Inbox::open(
                &node,
                &names.observation,
                &names.observation_event,
                0,
                WaitStrategy::Block,
            )
            .unwrap(),
            Inbox::open(
                &node,
                &names.observation_due,
                &names.observation_due_event,
                0,
                WaitStrategy::Block,
            )
            .unwrap(),
        );
        let motors: Outbox<MotorState> =
            Outbox::open(&node, &names.motor_state, &names.motor_state_event, 0).unwrap();
        let report = |after_command: u64| {
            motors.update_connections().unwrap();
            motors
                .send(MotorState {
                    seq: after_command + 1,
                    after_command,
                    flags: motor_flags::SETTLED,
                    ..MotorState::default()
                })
                .unwrap();
        };
        let (stop, never) = (AtomicBool::new(false), AtomicBool::new(false));
        let next = || match observations.next(Duration::from_secs(10), &never).unwrap() {
            Ok(o) => o,
            Err(idle) => panic!("no observation within 10 s ({idle:?})"),
        };
        let (seen, announced) = std::thread::scope(|s| {
            let perception = s.spawn(|| run(&config, &stop));
            let _stop_perception = StopOnDrop(&stop);
            let mut controller = ProgressOutbox::open(&node, &names, Role::Controller).unwrap();
            let first = first_observation(&mut controller, &observations, || report(0));
            let mut seen = vec![first];
            // Episodes of one step each: a motion after each episode's first observation ends
            // it, and the next one starts.
            for command in 1..=2 {
                report(command);
                seen.push(next());
                seen.push(next());
            }
            // Read while perception still runs (it waits for the third episode's motion): a
            // publisher's samples go with it.
            let mut announced = Vec::new();
            while let Some(h) = heads_ups.try_next().unwrap() {
                announced.push(h);
            }
            stop.store(true, std::sync::atomic::Ordering::SeqCst);
            perception.join().unwrap().unwrap();
            (seen, announced)
        });
        let ends = observation_flags::TERMINAL | observation_flags::TRUNCATED;
        let kinds: Vec<(bool, bool)> = seen
            .iter()
            .map(|o| {
                (
                    o.flags == observation_flags::EPISODE_START,
                    o.flags & ends != 0,
                )
            })
            .collect();
        assert_eq!(
            kinds,
            [
                (true, false),
                (false, true),
                (true, false),
                (false, true),
                (true, false)
            ],
            "{seen:?}"
        );
        assert_eq!(announced.len(), seen.len(), "{announced:?}");
        for (h, o) in announced.iter().zip(&seen) {
            assert_eq!(h.seq, o.seq, "announced as the observation that came");
            assert!(
                o.stamp_ns >= h.due_ns,
                "published before it was due: {h:?} {o:?}"
            );
        }
    }
}
