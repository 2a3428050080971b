//! The controller process: the central processor of the paper's Fig. 7.
//!
//! It receives the world's structure once ([`WorldMap`], from perception), loads the view
//! library, and then, for every [`Observation`] perception publishes when the robot comes to
//! rest:
//!
//! 1. derives the effect the last action had (the map's effect whose known outcome matches
//!    the state change; the nearest one when the robot moved further than any effect says);
//! 2. scores and updates the views of that action (TES — with an empty library this is
//!    loreRL);
//! 3. adopts the planner thread's latest policy;
//! 4. picks the next action (ε-greedy) and publishes the [`Command`];
//! 5. hands the planner thread the updated model.
//!
//! Steps 1–5 allocate nothing after warm-up — the command goes out through a blackboard entry
//! ([`LatestOutbox`]), since iceoryx2 0.10's publisher allocates per loaned sample — and steps 1–4 are timed from the observation's stamp to the
//! command's publication against a budget (default 1 ms); misses are counted. At an
//! episode's end, at most every `save_interval_s`, the library — as it would be if the task
//! ended now — is saved atomically on a thread of its own, and again on shutdown. One line per episode goes to stdout; diagnostics go to `tracing`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use tes_runtime::channel::{self, Idle, Inbox, IpcError, LatestOutbox, WaitStrategy};
use tes_runtime::clock::monotonic_ns;
use tes_runtime::latency::{LatencyRecorder, LatencyReport};
use tes_topics::{
    Command, KEEP_ALIVE_ACTION, Observation, ServiceNames, WorldMap, observation_flags,
};
use thiserror::Error;

use crate::config::{ConfigError, ControllerConfig, Planning, ThreadPlacement};

use crate::realtime::{Planner, PlannerThread, PlannerThreadError, SlicedPlanner};
use tes_learning::agents::{Agent, AgentError, Tes, TesParams};
use tes_learning::cmdp::{CmdpError, CmdpStructure};
use tes_learning::library::store::{self, StoreError, StoredLibrary};
use tes_learning::library::{LibraryError, LibraryParams, ViewLibrary};
use tes_learning::mdagl::MdaglParams;
use tes_learning::plan::PlannerParams;
use tes_runtime::alloc_count;

/// Why the controller stopped with an error.
#[derive(Debug, Error)]
pub enum ControllerError {
    /// A bad setting.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// An iceoryx2 failure.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// No world map arrived in time.
    #[error("no world map from perception within {0:?} (is perception-sim running?)")]
    NoMap(Duration),
    /// The world map is malformed.
    #[error("the world map is malformed: {0}")]
    BadMap(String),
    /// The map does not form a CMDP.
    #[error("the world map does not form a CMDP: {0}")]
    Cmdp(#[from] CmdpError),
    /// The library file cannot be used.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The library's directory cannot be created.
    #[error("cannot create the data directory {}: {error}", path.display())]
    DataDir {
        /// The directory.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// The library cannot be built or updated.
    #[error("view library: {0}")]
    Library(#[from] LibraryError),
    /// The agent refused its settings or a step.
    #[error("agent: {0}")]
    Agent(#[from] AgentError),
    /// The planner thread failed.
    #[error(transparent)]
    Planner(#[from] PlannerThreadError),
    /// The library saver thread could not start.
    #[error("cannot start the library saver thread: {0}")]
    SaverThread(std::io::Error),
    /// The acting thread could not be pinned to `acting_cpu`.
    #[error("acting thread: {0}")]
    Affinity(#[from] tes_runtime::affinity::AffinityError),
    /// The run's report could not be written.
    #[error("cannot write the report {}: {error}", path.display())]
    Report {
        /// The report file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

/// What a controller run did.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ControllerSummary {
    /// Episodes that ended.
    pub episodes: u64,
    /// Commands published.
    pub actions: u64,
    /// Decisions over the latency budget (after the warm-up).
    pub misses: u64,
    /// Decision latency (observation stamped → command published), after the warm-up.
    pub latency: LatencyReport,
    /// The decision's first part: observation stamped → received by the acting loop (the
    /// publication and this process's wake-up; the operating system's share).
    #[serde(default)]
    pub wake: LatencyReport,
    /// The decision's second part: observation received → command published (the acting
    /// path's own work), against the same budget.
    #[serde(default)]
    pub compute: LatencyReport,
    /// Heap allocations on the acting path (observation received → command published) after
    /// the warm-up; `None` if the process does not count them (no
    /// [`CountingAllocator`](tes_runtime::alloc_count::CountingAllocator)).
    pub allocations: Option<u64>,
    /// Of `allocations`, those made inside iceoryx2 sending the command (0 since commands go
    /// through a blackboard entry; iceoryx2 0.10's publisher allocated one object per sample).
    pub ipc_allocations: Option<u64>,
    /// Observations refused (stale or duplicate sequence number, unknown state, bad reward).
    pub refused: u64,
    /// Library saves that failed (each is also logged).
    pub failed_saves: u64,
    /// Plans adopted from the planner.
    pub plans: u64,
    /// Who planned: `thread` or `between-polls` ([`Planning`]).
    #[serde(default)]
    pub planning: String,
    /// Keep-alives sent to the bridge's watchdog while moves were under way
    /// ([`ControllerConfig::keepalive_ms`]).
    #[serde(default)]
    pub keepalives: u64,
    /// Where the acting and planner threads ran ([`ControllerConfig::placement`]).
    #[serde(default)]
    pub placement: ThreadPlacement,
}

impl std::fmt::Display for ControllerSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let l = &self.latency;
        write!(
            f,
            "{} episodes, {} actions, decision latency p50 {} us p99 {} us max {} us, {} over the {} us budget \
             (wake-up p50 {} p99 {} max {} us; compute p50 {} p99 {} max {} us, {} over), ",
            self.episodes,
            self.actions,
            l.p50_us,
            l.p99_us,
            l.max_us,
            self.misses,
            l.budget_us,
            self.wake.p50_us,
            self.wake.p99_us,
            self.wake.max_us,
            self.compute.p50_us,
            self.compute.p99_us,
            self.compute.max_us,
            self.compute.misses,
        )?;
        match self.allocations {
            Some(n) => write!(
                f,
                "{n} allocations on the acting path ({} inside iceoryx2's send), ",
                self.ipc_allocations.unwrap_or(0)
            )?,
            None => f.write_str("allocations not counted, ")?,
        }
        write!(
            f,
            "{} observations refused, {} plans ({}), {} keep-alives; acting thread {}, planner {}",
            self.refused,
            self.plans,
            self.planning,
            self.keepalives,
            on_cpu(self.placement.acting),
            on_cpu(self.placement.planner),
        )
    }
}

/// "CPU n" or "unpinned".
fn on_cpu(cpu: Option<usize>) -> String {
    cpu.map_or("unpinned".to_owned(), |c| format!("CPU {c}"))
}

/// One finished episode, as printed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeLine {
    /// Episode index (from perception).
    pub episode: u32,
    /// Reward collected.
    pub reward: f64,
    /// Actions taken.
    pub steps: u32,
    /// Decision latency p50 / p99, µs.
    pub p50_us: u64,
    /// 99th percentile.
    pub p99_us: u64,
    /// Decisions over budget in the episode.
    pub misses: u64,
}

impl std::fmt::Display for EpisodeLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "episode {}: reward {:.2}, {} steps, decision latency p50 {} us p99 {} us, {} over budget",
            self.episode, self.reward, self.steps, self.p50_us, self.p99_us, self.misses
        )
    }
}

/// Builds the agent-known CMDP from a world map.
pub fn structure_from_map(map: &WorldMap) -> Result<CmdpStructure, ControllerError> {
    map.check().map_err(ControllerError::BadMap)?;
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

/// The effect that took the robot from `from` to `to`: the lowest effect whose known outcome
/// is `to`; if none (the robot moved further than any effect says), the one whose outcome is
/// nearest — fewest cells away (Chebyshev), then least turned. Allocation-free.
pub fn derive_effect(map: &WorldMap, from: usize, to: usize) -> usize {
    let e = map.n_effects as usize;
    if let Some(exact) = (0..e).find(|&k| usize::from(map.next_state[from][k]) == to) {
        return exact;
    }
    let target = map.attributes(to);
    let o = i32::from(map.orientations.max(1));
    let distance = |k: usize| {
        let a = map.attributes(usize::from(map.next_state[from][k]));
        if a.x == u16::MAX || target.x == u16::MAX {
            // One of the two is "out of the area": as far as it gets.
            let same = (a.x == u16::MAX) == (target.x == u16::MAX);
            return (if same { 0 } else { i32::MAX }, 0);
        }
        let cells = (i32::from(a.x) - i32::from(target.x))
            .abs()
            .max((i32::from(a.y) - i32::from(target.y)).abs());
        let turn = (i32::from(a.orientation) - i32::from(target.orientation)).rem_euclid(o);
        (cells, turn.min(o - turn))
    };
    (0..e).min_by_key(|&k| distance(k)).unwrap_or(0)
}

/// The library as it would be if the task ended now, saved atomically.
fn save_library(agent: Tes, path: &Path, world: u32) -> Result<(), ControllerError> {
    let (library, _) = agent.finish_task()?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|error| ControllerError::DataDir {
            path: dir.to_owned(),
            error,
        })?;
    }
    store::save(
        path,
        &StoredLibrary {
            library,
            world: format!("arena {world}"),
            action_names: Vec::new(),
            feature_names: Vec::new(),
        },
    )?;
    Ok(())
}

/// Saves libraries on a thread of its own, so that encoding and `fsync` never delay the
/// acting loop (the next episode's first observation arrives right after the last one's).
struct Saver {
    jobs: Option<crossbeam::channel::Sender<Box<Tes>>>,
    failures: Arc<std::sync::atomic::AtomicU64>,
    handle: Option<std::thread::JoinHandle<()>>,
}

impl Saver {
    fn spawn(path: PathBuf, world: u32) -> Result<Self, ControllerError> {
        let (jobs, queue) = crossbeam::channel::bounded::<Box<Tes>>(1);
        let failures = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let failed = failures.clone();
        let handle = std::thread::Builder::new()
            .name("library-saver".into())
            .spawn(move || {
                crate::realtime::lower_this_threads_priority();
                while let Ok(agent) = queue.recv() {
                    if let Err(e) = save_library(*agent, &path, world) {
                        failed.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        tracing::error!(error = %e, "the library was not saved; the previous file is intact");
                    }
                }
            })
            .map_err(ControllerError::SaverThread)?;
        Ok(Self {
            jobs: Some(jobs),
            failures,
            handle: Some(handle),
        })
    }

    /// Queues a save of `agent`'s library as it would be if the task ended now, unless one
    /// is already waiting (the next episode's save will carry this one's learning).
    fn offer(&self, agent: &Tes) {
        if let Some(jobs) = self.jobs.as_ref().filter(|j| j.is_empty()) {
            let _ = jobs.try_send(Box::new(agent.clone()));
        }
    }

    /// Waits for the queued saves; returns how many failed.
    fn finish(mut self) -> u64 {
        self.jobs = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
        self.failures.load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// Completes an ended episode's line with its decision-latency percentiles, hands it to
/// `on_episode`, and starts the next episode's latency record.
fn report_episode(
    mut line: EpisodeLine,
    episode_latency: &mut LatencyRecorder,
    on_episode: &mut impl FnMut(&EpisodeLine),
) {
    line.p50_us = episode_latency.quantile_us(0.5);
    line.p99_us = episode_latency.quantile_us(0.99);
    on_episode(&line);
    episode_latency.reset();
}

/// Runs the controller until `stop` is raised. `on_episode` receives each finished episode
/// (once the next episode's first command is out, or at the end of the run).
pub fn run(
    config: &ControllerConfig,
    stop: &AtomicBool,
    mut on_episode: impl FnMut(&EpisodeLine),
) -> Result<ControllerSummary, ControllerError> {
    let strategy = config.check()?;
    let planning = config.planning_for(strategy)?;
    let placement = config.placement(strategy, planning)?;
    tracing::info!(
        acting = %on_cpu(placement.acting),
        planner = %on_cpu(placement.planner),
        %planning,
        "thread placement"
    );
    if strategy == WaitStrategy::Spin
        && planning == Planning::Thread
        && std::thread::available_parallelism().is_ok_and(|n| n.get() <= 2)
    {
        // Measured on two cores (docs/performance.md): one plan per ~100 actions.
        tracing::warn!(
            "wait = \"spin\" with planning = \"thread\" on 2 CPUs: the busy-polling acting \
             loop and bridge leave the planner thread, which yields to everything, almost no \
             time; the policy will lag far behind learning (use planning = \"between-polls\")"
        );
    }
    let names = ServiceNames::with_prefix(&config.service_prefix);
    let node = channel::node(false)?;
    let maps: Inbox<WorldMap> = Inbox::open(
        &node,
        &names.world_map,
        &names.world_map_event,
        1,
        WaitStrategy::Block,
    )?;
    let observations: Inbox<Observation> = Inbox::open(
        &node,
        &names.observation,
        &names.observation_event,
        0,
        strategy,
    )?;
    // A blackboard, not a publisher: sending a command allocates nothing (see LatestOutbox).
    let commands: LatestOutbox<Command> =
        LatestOutbox::open(&node, &names.command, &names.command_event)?;

    tracing::info!(service = %names.world_map, "waiting for the world map");
    let map_timeout = Duration::from_secs_f64(config.map_timeout_s);
    // A boxed map: it is ~90 kB, too big to pass around on the stack comfortably.
    let map: Box<WorldMap> = match maps.next(map_timeout, stop)? {
        Ok(m) => Box::new(m),
        Err(Idle::Timeout) => return Err(ControllerError::NoMap(map_timeout)),
        Err(Idle::Stopped) => return Ok(empty_summary()),
    };
    let structure = Arc::new(structure_from_map(&map)?);
    let library_path = config.library_path();
    let library = if library_path.exists() {
        store::load_for(
            &library_path,
            structure.n_actions(),
            structure.n_effects(),
            structure.n_features(),
        )?
        .library
    } else {
        let params = LibraryParams {
            max_views: config.max_views,
            mdagl: MdaglParams {
                lambda: config.lambda,
                alpha: config.alpha,
                intercept: false,
            },
            ..LibraryParams::default()
        };
        ViewLibrary::new(
            structure.n_actions(),
            structure.n_effects(),
            structure.n_features(),
            params,
        )?
    };
    tracing::info!(
        library = %library_path.display(),
        views = library.len(),
        states = structure.n_states(),
        "controller ready"
    );
    let params = TesParams {
        epsilon: config.epsilon,
        ..TesParams::default()
    };
    let mut agent = Tes::new(structure.clone(), library, params, config.seed)?;
    agent.model_mut().set_inline_planning(false);
    let planner_params = PlannerParams {
        max_sweeps: config.plan_sweeps,
        ..PlannerParams::default()
    };
    let mut planner = match planning {
        Planning::Thread => Planner::Thread(PlannerThread::spawn_on(
            structure.clone(),
            planner_params,
            placement.planner,
        )?),
        Planning::BetweenPolls => Planner::BetweenPolls(Box::new(SlicedPlanner::new(
            structure.clone(),
            planner_params,
            config.plan_slice,
        )?)),
    };
    // The first policy before the first action.
    planner.offer(agent.model_mut())?;
    planner.wait(agent.model_mut(), Duration::from_secs(10))?;

    let saver = Saver::spawn(library_path.clone(), map.world)?;
    let save_interval = Duration::from_secs_f64(config.save_interval_s);
    let mut last_save = std::time::Instant::now();
    let mut all = LatencyRecorder::new(config.budget_us, config.warmup_actions);
    let mut wake = LatencyRecorder::new(config.budget_us, config.warmup_actions);
    let mut compute = LatencyRecorder::new(config.budget_us, config.warmup_actions);
    let mut episode_latency = LatencyRecorder::new(config.budget_us, 0);
    let mut summary = empty_summary();
    // Allocations on the acting path before the warm-up ended, to subtract.
    let mut warmup_allocations = None;
    let mut ipc_allocations = 0u64;
    let mut last_seq = 0u64;
    // From the monotonic clock, so a respawned controller's commands are newer than its
    // predecessor's (perception and the bridge ignore stale command numbers).
    let mut command_seq = monotonic_ns();
    // (state, action) of the command in flight, and the episode's running totals.
    let mut pending: Option<(usize, usize)> = None;
    let (mut reward, mut steps, mut episode_misses) = (0.0f64, 0u32, 0u64);
    // The episode that just ended, reported (and the library saved, if due) only once the
    // next command is out: perception publishes the next episode's first observation right
    // after the last one, so reporting before answering it would delay that action (measured:
    // wake-up p50 39 µs for episode starts against 1 µs for other observations, spinning).
    let mut ended: Option<EpisodeLine> = None;
    let keepalive = (config.keepalive_ms > 0).then(|| Duration::from_millis(config.keepalive_ms));
    let idle_timeout = keepalive.map_or(Duration::from_millis(100), |k| {
        k.min(Duration::from_millis(100))
    });
    let mut last_sent = std::time::Instant::now();
    if let Some(cpu) = placement.acting {
        tes_runtime::affinity::pin_this_thread(cpu)?;
    }
    // When to wake the planner with the new model: before the command when the bridge sleeps
    // on events, after it when the bridge busy-polls. A bridge woken while this CPU is busy
    // goes to the other, idle CPU; in a VM whose idle vCPUs halt, it ran there ~30 µs later
    // (its hop 34-36 µs p50 against the floor's 14-15). Waking the planner first (~5 µs on
    // the acting path) gets that CPU out of halt while the command is sent, and the
    // SCHED_IDLE planner gives way to the bridge at once (its hop 10-14 µs; docs/
    // performance.md, "A new machine"). A spinning bridge needs no wake-up.
    let offer_before_command = strategy != WaitStrategy::Spin;
    loop {
        // Spinning, the wait does the planner's slices and adopts its plan (a planner thread
        // needs none).
        let work = || planner.work(agent.model_mut());
        let obs = match observations.next_or_work(idle_timeout, stop, work)? {
            Ok(o) => o,
            Err(Idle::Stopped) => break,
            Err(Idle::Timeout) => {
                // A move is under way: tell the bridge's watchdog we are still here.
                if let Some(period) = keepalive
                    && pending.is_some()
                    && last_sent.elapsed() >= period
                {
                    command_seq += 1;
                    commands.send(Command {
                        seq: command_seq,
                        action: KEEP_ALIVE_ACTION,
                        stamp_ns: monotonic_ns(),
                        ..Command::default()
                    })?;
                    last_sent = std::time::Instant::now();
                    summary.keepalives += 1;
                }
                continue;
            }
        };
        let received_ns = monotonic_ns();
        // The acting path, from here to the command's publication.
        let counting = alloc_count::count_here();
        if warmup_allocations.is_none() && all.warmed_up() {
            warmup_allocations = Some(alloc_count::counted());
        }
        let Some(state) = map
            .state_index(obs.state)
            .filter(|&s| s < structure.n_states())
        else {
            summary.refused += 1;
            tracing::warn!(seq = obs.seq, state = ?obs.state, "observation of an unknown state refused");
            continue;
        };
        if obs.seq <= last_seq || !obs.reward.is_finite() {
            summary.refused += 1;
            tracing::warn!(
                seq = obs.seq,
                last_seq,
                "stale, duplicate or non-finite observation refused"
            );
            continue;
        }
        last_seq = obs.seq;
        if obs.flags & observation_flags::EPISODE_START != 0 {
            pending = None;
            (reward, steps, episode_misses) = (0.0, 0, 0);
        } else if obs.flags & observation_flags::RESYNC != 0 {
            if pending.take().is_some() {
                tracing::warn!(
                    seq = obs.seq,
                    "the last command's outcome was lost; not learning from it"
                );
            }
        } else if let Some((from, action)) = pending.take() {
            let effect = derive_effect(&map, from, state);
            agent.observe(from, action, effect)?;
            reward += f64::from(obs.reward);
        }
        planner.collect(agent.model_mut())?;
        if obs.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED) != 0 {
            planner.offer(agent.model_mut())?;
            summary.episodes += 1;
            drop(counting);
            if let Some(line) = ended.take() {
                // Two episode ends in a row (no command between): report the first now.
                report_episode(line, &mut episode_latency, &mut on_episode);
            }
            ended = Some(EpisodeLine {
                episode: obs.episode,
                reward,
                steps,
                p50_us: 0,
                p99_us: 0,
                misses: episode_misses,
            });
            continue;
        }
        let action = agent.act(state)?;
        if offer_before_command {
            planner.offer(agent.model_mut())?;
        }
        let [left_deg, right_deg] = map.action_wheels[action];
        command_seq += 1;
        let now = monotonic_ns();
        let before_send = alloc_count::counted();
        commands.send(Command {
            seq: command_seq,
            answers: obs.seq,
            stamp_ns: now,
            observed_ns: obs.stamp_ns,
            action: action as u32,
            left_deg,
            right_deg,
            reserved: 0,
        })?;
        if warmup_allocations.is_some() {
            ipc_allocations += alloc_count::counted() - before_send;
        }
        last_sent = std::time::Instant::now();
        if !offer_before_command {
            planner.offer(agent.model_mut())?;
        }
        drop(counting);
        // Reporting and saving are not on the acting path: the command is out.
        if let Some(line) = ended.take() {
            report_episode(line, &mut episode_latency, &mut on_episode);
            if last_save.elapsed() >= save_interval {
                saver.offer(&agent);
                last_save = std::time::Instant::now();
            }
        }
        pending = Some((state, action));
        steps += 1;
        summary.actions += 1;
        let latency_ns = now.saturating_sub(obs.stamp_ns);
        let misses_before = episode_latency.misses();
        all.record_ns(latency_ns);
        wake.record_ns(received_ns.saturating_sub(obs.stamp_ns));
        compute.record_ns(now.saturating_sub(received_ns));
        episode_latency.record_ns(latency_ns);
        episode_misses += episode_latency.misses() - misses_before;
    }
    if let Some(line) = ended.take() {
        report_episode(line, &mut episode_latency, &mut on_episode);
    }
    summary.latency = all.report();
    summary.wake = wake.report();
    summary.compute = compute.report();
    summary.misses = summary.latency.misses;
    summary.allocations = alloc_count::installed()
        .then(|| alloc_count::counted() - warmup_allocations.unwrap_or(alloc_count::counted()));
    summary.ipc_allocations = alloc_count::installed().then_some(ipc_allocations);
    summary.plans = planner.plans();
    summary.planning = planning.to_string();
    summary.placement = placement;
    summary.failed_saves += saver.finish();
    if let Err(e) = save_library(agent, &library_path, map.world) {
        summary.failed_saves += 1;
        tracing::error!(error = %e, "the library was not saved at shutdown; the previous file is intact");
    }
    Ok(summary)
}

/// [`run`] as a process runs it: episode lines and the final summary on stdout, the
/// summary as JSON to `config.report` if set.
pub fn run_to_end(
    config: &ControllerConfig,
    stop: &AtomicBool,
) -> Result<ControllerSummary, ControllerError> {
    let summary = run(config, stop, |line| println!("{line}"))?;
    println!("controller: {summary}");
    if let Some(path) = &config.report {
        let write = || -> std::io::Result<()> {
            let text = serde_json::to_string_pretty(&summary).map_err(std::io::Error::other)?;
            std::fs::write(path, text + "\n")
        };
        write().map_err(|error| ControllerError::Report {
            path: path.clone(),
            error,
        })?;
    }
    Ok(summary)
}

fn empty_summary() -> ControllerSummary {
    ControllerSummary {
        episodes: 0,
        actions: 0,
        misses: 0,
        latency: LatencyReport::default(),
        wake: LatencyReport::default(),
        compute: LatencyReport::default(),
        allocations: None,
        ipc_allocations: None,
        refused: 0,
        failed_saves: 0,
        plans: 0,
        planning: String::new(),
        keepalives: 0,
        placement: ThreadPlacement::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_runtime::channel::{LatestInbox, Outbox};
    use tes_topics::StateAttributes;

    /// A 3×3 arena-like map: 4 orientations, effects 0 = forward (east when o = 0), 1 = stay,
    /// 2 = turn left.
    fn map() -> WorldMap {
        let mut m = WorldMap::EMPTY;
        (m.width, m.height, m.orientations) = (3, 3, 4);
        m.n_states = 3 * 3 * 4 + 1;
        (m.n_actions, m.n_effects, m.n_features) = (2, 3, 4);
        let out = m.out_state();
        for s in 0..out {
            let a = m.attributes(s);
            let (dx, dy) = [(1i32, 0i32), (0, 1), (-1, 0), (0, -1)][a.orientation as usize];
            let (x, y) = (i32::from(a.x) + dx, i32::from(a.y) + dy);
            let forward = if (0..3).contains(&x) && (0..3).contains(&y) {
                m.state_index(StateAttributes {
                    x: x as u16,
                    y: y as u16,
                    ..a
                })
                .unwrap()
            } else {
                out
            };
            let left = m
                .state_index(StateAttributes {
                    orientation: (a.orientation + 1) % 4,
                    ..a
                })
                .unwrap();
            m.next_state[s][..3].copy_from_slice(&[forward as u16, s as u16, left as u16]);
            m.reward[s] = -0.05;
            m.features[s].set(a.orientation as usize);
        }
        m.next_state[out][..3].copy_from_slice(&[out as u16; 3]);
        m.terminal[out] = 1;
        m.reward[out] = -1.0;
        m
    }

    fn at(m: &WorldMap, x: u16, y: u16, o: u16) -> usize {
        m.state_index(StateAttributes {
            x,
            y,
            orientation: o,
            reserved: 0,
        })
        .unwrap()
    }

    #[test]
    fn effects_are_derived_exactly_or_by_the_nearest_outcome() {
        let m = map();
        let s = at(&m, 0, 1, 0);
        assert_eq!(derive_effect(&m, s, at(&m, 1, 1, 0)), 0, "forward");
        assert_eq!(derive_effect(&m, s, s), 1, "stayed");
        assert_eq!(derive_effect(&m, s, at(&m, 0, 1, 1)), 2, "turned left");
        // Two cells forward: nearest to "forward".
        assert_eq!(derive_effect(&m, s, at(&m, 2, 1, 0)), 0);
        // Turned right (no such effect): "stay" and "turn left" are both one cell away (0),
        // then one turn each way; the lowest such effect wins.
        assert_eq!(derive_effect(&m, s, at(&m, 0, 1, 3)), 1);
        // Out of the area from the east edge going east.
        let edge = at(&m, 2, 1, 0);
        assert_eq!(derive_effect(&m, edge, m.out_state()), 0);
    }

    #[test]
    fn the_map_becomes_a_cmdp() {
        let m = map();
        let c = structure_from_map(&m).unwrap();
        assert_eq!((c.n_states(), c.n_actions(), c.n_effects()), (37, 2, 3));
        let s = at(&m, 1, 1, 2);
        assert_eq!(c.features(s), &[2]);
        assert!(c.is_terminal(m.out_state()));
        let mut bad = map();
        bad.next_state[3][1] = 99;
        assert!(matches!(
            structure_from_map(&bad),
            Err(ControllerError::BadMap(_))
        ));
    }

    /// Raises a stop flag when dropped (also while unwinding from a failed assertion).
    struct StopOnDrop<'a>(&'a AtomicBool);

    impl Drop for StopOnDrop<'_> {
        fn drop(&mut self) {
            self.0.store(true, std::sync::atomic::Ordering::SeqCst);
        }
    }

    /// An observation of `state` on `map`, stamped now.
    fn observation_of(
        map: &WorldMap,
        seq: u64,
        episode: u32,
        state: usize,
        reward: f32,
        flags: u32,
    ) -> Observation {
        Observation {
            seq,
            stamp_ns: monotonic_ns(),
            episode,
            state: map.attributes(state),
            n_features: map.n_features,
            features: map.features[state],
            reward,
            flags,
            ..Observation::default()
        }
    }

    /// The other end of a controller under test: a temporary library, the services perception
    /// and the bridge would hold (under a prefix unique to the test and process), and a way to
    /// start the controller once it is listening. Every port here and in the controller is
    /// dropped when the test ends, passing or failing, which removes the services.
    struct Rig {
        prefix: String,
        config: ControllerConfig,
        commands: LatestInbox<Command>,
        maps: Outbox<WorldMap>,
        observations: Outbox<Observation>,
        observation_service: iceoryx2::service::port_factory::publish_subscribe::PortFactory<
            iceoryx2::service::ipc::Service,
            Observation,
            (),
        >,
        _node: iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
        // Last: removed after everything that may write into it.
        _dir: tempfile::TempDir,
    }

    impl Rig {
        fn new(test: &str) -> Self {
            let prefix = format!("tes-test/{test}/{}/", std::process::id());
            let dir = tempfile::tempdir().unwrap();
            let config = ControllerConfig {
                service_prefix: prefix.clone(),
                library: Some(dir.path().join("library.tesl")),
                map_timeout_s: 20.0,
                keepalive_ms: 0,
                ..ControllerConfig::default()
            };
            let names = ServiceNames::with_prefix(&prefix);
            let node = channel::node(false).unwrap();
            // Subscribed before the controller publishes, so no command is missed.
            let commands = LatestInbox::open(
                &node,
                &names.command,
                &names.command_event,
                WaitStrategy::Block,
            )
            .unwrap();
            let maps = Outbox::open(&node, &names.world_map, &names.world_map_event, 1).unwrap();
            let observations =
                Outbox::open(&node, &names.observation, &names.observation_event, 0).unwrap();
            let observation_service =
                channel::pubsub::<Observation>(&node, &names.observation, 0).unwrap();
            Self {
                prefix,
                config,
                commands,
                maps,
                observations,
                observation_service,
                _node: node,
                _dir: dir,
            }
        }

        /// Sends `map` once the controller (started elsewhere) listens for observations: it
        /// subscribes to the map, then to observations, then waits for the map, so once it
        /// has an observation subscriber both reach it.
        fn send_map_when_listening(&self, map: WorldMap) {
            use iceoryx2::prelude::PortFactory;
            let deadline = std::time::Instant::now() + Duration::from_secs(20);
            while self
                .observation_service
                .dynamic_config()
                .number_of_subscribers()
                == 0
            {
                assert!(
                    std::time::Instant::now() < deadline,
                    "the controller never subscribed"
                );
                std::thread::sleep(Duration::from_millis(5));
            }
            self.maps.send(map).unwrap();
        }

        /// The next command, waiting up to 20 s.
        fn next_command(&self) -> Command {
            let never = AtomicBool::new(false);
            match self.commands.next(Duration::from_secs(20), &never).unwrap() {
                Ok(c) => c,
                Err(idle) => panic!("no command within 20 s ({idle:?})"),
            }
        }

        /// Drops every port and checks that no service of the test is left behind.
        fn close(self) {
            let prefix = self.prefix.clone();
            drop(self);
            assert_eq!(
                channel::services_with_prefix(&prefix).unwrap(),
                Vec::<String>::new()
            );
        }
    }

    /// The controller's rule for observations, over real iceoryx2 services with the real
    /// loop: one whose `seq` is not newer than the last accepted one (a duplicate, or an older
    /// one out of order), one with a non-finite reward and one of a state outside the map are
    /// refused and counted in `refused`; no command answers them and nothing is learned from
    /// them. Each good observation is answered by exactly one command.
    ///
    /// The refused observations follow an accepted one with a command in flight and are not
    /// episode starts, so taking any of them would have taught the agent that command's
    /// effect; the last good observation starts a new episode, which drops the command in
    /// flight unlearned. So the library saved at shutdown must be empty: a view is kept only
    /// for an action with an observed effect.
    #[test]
    fn stale_duplicate_and_non_finite_observations_are_refused_and_answered_by_nothing() {
        use std::sync::atomic::Ordering;

        let rig = Rig::new("controller-seq");
        let (config, observations) = (&rig.config, &rig.observations);
        let m = map();
        let (a, b, c) = (at(&m, 0, 1, 0), at(&m, 1, 1, 0), at(&m, 2, 2, 3));
        let observation = |seq: u64, state: usize, reward: f32, flags: u32| {
            observation_of(&m, seq, 0, state, reward, flags)
        };
        let next_command = || rig.next_command();
        let stop = AtomicBool::new(false);
        let summary = std::thread::scope(|s| {
            let controller = s.spawn(|| run(config, &stop, |_| {}));
            // A failed assertion below must not leave the controller running (the scope
            // joins it): stop it on the way out, however that is.
            let _stop_controller = StopOnDrop(&stop);
            rig.send_map_when_listening(m);

            let first = observation(100, a, 0.0, observation_flags::EPISODE_START);
            observations.send(first).unwrap();
            let answer = next_command();
            assert_eq!(answer.answers, 100, "{answer:?}");
            assert!((answer.action as usize) < 2 && answer.seq > 0, "{answer:?}");
            assert_eq!(answer.observed_ns, first.stamp_ns);

            // The refused: a duplicate, an older seq, a non-finite reward (with a fresh seq)
            // and a state outside the map (with a fresh seq). All but the last are
            // well-formed moves a → b that would be learned from if taken.
            observations.send(observation(100, b, -0.05, 0)).unwrap();
            observations.send(observation(99, b, -0.05, 0)).unwrap();
            observations.send(observation(101, b, f32::NAN, 0)).unwrap();
            observations
                .send(observation(102, b, f32::INFINITY, 0))
                .unwrap();
            let mut outside = observation(103, b, -0.05, 0);
            outside.state.x = 7;
            observations.send(outside).unwrap();

            // The next good one: newer than the last accepted (100), not than every seq sent
            // (a refused seq does not count as seen).
            let last = observation(101, c, 0.0, observation_flags::EPISODE_START);
            observations.send(last).unwrap();
            // Observations are taken in order, so had a refused one been answered, its
            // command would come first.
            let second = next_command();
            assert_eq!(second.answers, 101, "{second:?}");
            // This one, not the refused one with the same seq and a NaN reward.
            assert_eq!(second.observed_ns, last.stamp_ns, "{second:?}");
            assert!(second.seq > answer.seq, "{second:?} after {answer:?}");

            stop.store(true, Ordering::SeqCst);
            controller.join().unwrap().unwrap()
        });
        assert_eq!(rig.commands.try_next().unwrap(), None, "no other command");
        assert_eq!(summary.refused, 5, "{summary:?}");
        assert_eq!(summary.actions, 2, "{summary:?}");
        assert_eq!(
            (summary.episodes, summary.keepalives),
            (0, 0),
            "{summary:?}"
        );
        assert_eq!(summary.failed_saves, 0, "{summary:?}");
        // Blocking, with the default placement: pinned where two CPUs allow it.
        let pinned = tes_runtime::affinity::auto_pair().map(|(a, p)| (Some(a), Some(p)));
        assert_eq!(
            (summary.placement.acting, summary.placement.planner),
            pinned.unwrap_or((None, None)),
            "{summary:?}"
        );
        let library = rig.config.library.as_ref().unwrap();
        let saved = store::load_for(library, 2, 3, 4).unwrap();
        assert!(
            saved.library.is_empty(),
            "nothing learned: {} views",
            saved.library.len()
        );
        // With the last port gone, no service of the test is left behind.
        rig.close();
    }

    /// Perception publishes the next episode's first observation right after the last one,
    /// so the controller answers it before reporting the episode that ended (the report and
    /// a due library save are not on the acting path). (The last episode of a run is reported
    /// when the controller stops: the launch tests count every episode's line.)
    #[test]
    fn an_ended_episode_is_reported_once_the_next_command_is_out() {
        use std::sync::atomic::Ordering;

        use observation_flags::{EPISODE_START as START, TERMINAL};

        let rig = Rig::new("controller-report");
        let (config, observations) = (&rig.config, &rig.observations);
        let m = map();
        let (a, b) = (at(&m, 0, 1, 0), at(&m, 1, 1, 0));
        let observation = |seq: u64, episode: u32, state: usize, reward: f32, flags: u32| {
            observation_of(&m, seq, episode, state, reward, flags)
        };
        let next_command = || rig.next_command();
        let (lines_tx, lines) = std::sync::mpsc::channel::<EpisodeLine>();
        let stop = AtomicBool::new(false);
        let summary = std::thread::scope(|s| {
            let controller = s.spawn(|| {
                let lines_tx = lines_tx;
                run(config, &stop, move |line| {
                    let _ = lines_tx.send(*line);
                })
            });
            let _stop_controller = StopOnDrop(&stop);
            rig.send_map_when_listening(m);

            // Episode 7 starts.
            observations
                .send(observation(
                    100,
                    7,
                    a,
                    0.0,
                    observation_flags::EPISODE_START,
                ))
                .unwrap();
            assert_eq!(next_command().answers, 100);
            for (episode, last_reward, last_seq) in [(7u32, 1.0f32, 101u64), (8, -1.0, 103)] {
                // The episode ends after one action…
                observations
                    .send(observation(last_seq, episode, b, last_reward, TERMINAL))
                    .unwrap();
                if episode == 7 {
                    // …and is not reported yet: no command has gone out since it ended.
                    // (Reporting at once would show within this wait.)
                    assert_eq!(
                        lines.recv_timeout(Duration::from_millis(300)).ok(),
                        None,
                        "reported before the next episode's first command"
                    );
                }
                // The next starts: its first command goes out, then the ended one is reported.
                observations
                    .send(observation(last_seq + 1, episode + 1, a, 0.0, START))
                    .unwrap();
                assert_eq!(next_command().answers, last_seq + 1);
                let line = lines.recv_timeout(Duration::from_secs(20)).unwrap();
                assert_eq!(
                    (line.episode, line.steps, line.reward),
                    (episode, 1, f64::from(last_reward)),
                    "{line:?}"
                );
            }
            stop.store(true, Ordering::SeqCst);
            controller.join().unwrap().unwrap()
        });
        // Episode 9 never ended: nothing more to report.
        assert_eq!(lines.try_recv().ok(), None, "one line per ended episode");
        assert_eq!((summary.episodes, summary.actions), (2, 3), "{summary:?}");
        rig.close();
    }

    /// Spinning, the controller plans between its polls (no planner thread): every learned
    /// step gets a plan in the pause before the next observation, and the loop still answers
    /// each observation once.
    #[test]
    fn a_spinning_controller_plans_between_polls() {
        use std::sync::atomic::Ordering;

        let mut rig = Rig::new("controller-between-polls");
        rig.config.wait = "spin".into();
        let (config, observations) = (&rig.config, &rig.observations);
        let m = map();
        let (a, b) = (at(&m, 0, 1, 0), at(&m, 1, 1, 0));
        let steps = 20u64;
        let stop = AtomicBool::new(false);
        let summary = std::thread::scope(|s| {
            let controller = s.spawn(|| run(config, &stop, |_| {}));
            let _stop_controller = StopOnDrop(&stop);
            rig.send_map_when_listening(m);
            for seq in 100..=100 + steps {
                let (state, flags) = match seq {
                    100 => (a, observation_flags::EPISODE_START),
                    _ if seq % 2 == 0 => (a, 0),
                    _ => (b, 0),
                };
                observations
                    .send(observation_of(&m, seq, 0, state, -0.05, flags))
                    .unwrap();
                assert_eq!(rig.next_command().answers, seq);
                // Time for the plan (a few microseconds of slices on this small map).
                std::thread::sleep(Duration::from_millis(10));
            }
            stop.store(true, Ordering::SeqCst);
            controller.join().unwrap().unwrap()
        });
        assert_eq!(summary.planning, "between-polls", "{summary:?}");
        // Spinning, nothing is pinned.
        assert_eq!(summary.placement, ThreadPlacement::default(), "{summary:?}");
        assert_eq!(summary.actions, steps + 1, "{summary:?}");
        // The start-up plan, then one per learned step that finished before the next
        // observation (all of them unless the machine stalled the test for 10 ms).
        assert!(summary.plans > steps / 2, "{summary:?}");
        rig.close();
    }
}
