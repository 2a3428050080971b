//! The controller process: the [`ActingLoop`] between iceoryx2 services.
//!
//! It receives the world's structure once ([`WorldMap`], from perception), loads the view
//! library, starts the planner and the library saver, and then hands every [`Observation`] to
//! the acting loop and publishes the [`Command`] it decides — through a blackboard entry
//! ([`LatestOutbox`]), which allocates nothing per message. While no observation comes it
//! sends the bridge keep-alives, and when spinning it lets the acting loop plan between polls.
//! One line per episode goes to the caller; at an episode's end, at most every
//! `save_interval_s`, the library is saved on the saver's thread, and again at shutdown.
//! Diagnostics go to `tracing`, outside the acting path.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use tes_runtime::cpu::CpuMeter;

use tes_learning::agents::Tes;
use tes_learning::cmdp::CmdpStructure;
use tes_learning::library::store::{self, StoreError};
use tes_learning::library::{LibraryError, LibraryParams, ViewLibrary};
use tes_learning::mdagl::MdaglParams;
use tes_learning::plan::PlannerParams;
use tes_runtime::alloc_count;
use tes_runtime::channel::{self, Idle, Inbox, IpcError, LatestOutbox, ProcessNode, WaitStrategy};
use tes_runtime::clock::{Clock, MonotonicClock};
use tes_runtime::progress::ProgressOutbox;
use tes_runtime::ring::RingOutbox;
use tes_runtime::wait::IDLE_TICK;
use tes_topics::{Command, Observation, Role, ServiceNames, WorldMap};
use thiserror::Error;

use crate::acting::{ActingError, ActingLoop, ActingSettings, Refusal, Sent, Step};
use crate::config::{CheckedController, ConfigError, ControllerConfig, Planning};
use crate::realtime::{
    Planner, PlannerThread, PlannerThreadError, PlannerThreadOptions, SlicedPlanner,
};
use crate::saver::{SaveError, Saver, WorldNames, save_library};
pub use crate::summary::{ControllerSummary, EpisodeLine, LibraryCounts, LibraryEnd, LibraryFacts};

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
    /// The acting loop failed.
    #[error(transparent)]
    Acting(#[from] ActingError),
    /// The library file cannot be used.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// Another controller holds the library.
    #[error(transparent)]
    Busy(#[from] tes_runtime::lock::LockError),
    /// The library cannot be built or updated.
    #[error("view library: {0}")]
    Library(#[from] LibraryError),
    /// The planner thread failed.
    #[error(transparent)]
    Planner(#[from] PlannerThreadError),
    /// The library saver could not start.
    #[error(transparent)]
    Saver(#[from] SaveError),
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

/// How long a controller waits for another to let go of its library.
const LIBRARY_LOCK_PATIENCE: Duration = Duration::from_secs(10);

/// Takes the library's lock file (`PATH.lock`), creating the library's directory if needed.
fn lock_library(path: &std::path::Path) -> Result<tes_runtime::lock::Lock, ControllerError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|error| tes_runtime::lock::LockError::Io {
            what: "view library",
            path: dir.to_owned(),
            error,
        })?;
    }
    let mut name = path.as_os_str().to_owned();
    name.push(".lock");
    let lock_path = PathBuf::from(name);
    Ok(tes_runtime::lock::Lock::acquire_within(
        &lock_path,
        "view library",
        LIBRARY_LOCK_PATIENCE,
    )?)
}

/// The library the controller starts from, and whether it is a fresh one.
#[derive(Debug)]
struct StartingLibrary {
    /// The views.
    library: ViewLibrary,
    /// True when there was no library file and the controller starts from an empty library.
    started_empty: bool,
}

/// The library to start from. First removes the temporary files of saves a killed controller
/// left behind. Then: nothing at `path` (not even a dangling link) means a first start, with
/// an empty library of the configured parameters, said at info level; anything else at `path`
/// must load — a file that is unreadable, not a regular file, a dangling symbolic link,
/// corrupt, or for another world is an error naming it, never a silent fresh start (whose
/// first save would replace the robot's lifelong memory).
fn load_library(
    config: &ControllerConfig,
    path: &std::path::Path,
    map: &WorldMap,
) -> Result<StartingLibrary, ControllerError> {
    let (actions, effects, features) = (
        map.n_actions as usize,
        map.n_effects as usize,
        map.n_features as usize,
    );
    remove_stale_saves(path);
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        // Something is there (or cannot be looked at): the loader opens it and reports why it
        // cannot be used, if it cannot.
        _ => {
            return Ok(StartingLibrary {
                library: store::load_for(path, actions, effects, features)?.library,
                started_empty: false,
            });
        }
    }
    tracing::info!(
        "no view library at {}; starting from an empty library",
        path.display()
    );
    let params = empty_library_params(config);
    Ok(StartingLibrary {
        library: ViewLibrary::new(actions, effects, features, params)?,
        started_empty: true,
    })
}

/// Removes what interrupted saves of the library at `path` left behind, and says so. A
/// leftover that cannot be removed is only garbage: warned about, not a reason to stop.
fn remove_stale_saves(path: &std::path::Path) {
    match store::remove_stale_temp_files(path) {
        Ok(removed) => {
            for tmp in removed {
                tracing::info!(
                    file = %tmp.display(),
                    "removed the temporary file of an interrupted library save"
                );
            }
        }
        Err(e) => {
            tracing::warn!(error = %e, "cannot remove temporary files of interrupted library saves");
        }
    }
}

/// Runs the controller until `stop` is raised. `on_episode` receives each finished episode
/// (once the next episode's first command is out, or at the end of the run).
///
/// Three steps: the settings checked once ([`ControllerConfig::check`]), everything the run
/// needs opened in order by one constructor (`Shell::open`), then observations answered
/// until the stop (`Shell::serve`) and the run ended (`Shell::finish`).
pub fn run(
    config: &ControllerConfig,
    stop: &AtomicBool,
    mut on_episode: impl FnMut(&EpisodeLine),
) -> Result<ControllerSummary, ControllerError> {
    let checked = config.check()?;
    let Some(mut shell) = Shell::open(config, &checked, stop)? else {
        return Ok(ControllerSummary::default());
    };
    shell.serve(stop, &mut on_episode)?;
    // The launcher gives a controller still saving the library more time before SIGKILL;
    // this file tells it so.
    let saving = config.report.as_deref().map(SavingMarker::create);
    let summary = shell.finish(config, &checked, &mut on_episode);
    drop(saving);
    Ok(summary)
}

/// The file beside the controller's report that says the controller is finishing its run
/// (the final library save): `REPORT.saving`. The launcher waits for a controller while it
/// exists, within a bound, before it sends SIGKILL.
pub fn saving_marker(report: &std::path::Path) -> PathBuf {
    let mut name = report.as_os_str().to_owned();
    name.push(".saving");
    PathBuf::from(name)
}

/// The [`saving_marker`] of a controller that is finishing its run, removed when dropped.
struct SavingMarker(Option<PathBuf>);

impl SavingMarker {
    /// Creates the marker for `report`; a marker that cannot be written only costs the
    /// launcher's patience (said at debug level).
    fn create(report: &std::path::Path) -> Self {
        let path = saving_marker(report);
        match std::fs::write(&path, format!("{}\n", std::process::id())) {
            Ok(()) => Self(Some(path)),
            Err(e) => {
                tracing::debug!(error = %e, file = %path.display(), "cannot mark the final save");
                Self(None)
            }
        }
    }
}

impl Drop for SavingMarker {
    fn drop(&mut self) {
        if let Some(path) = self.0.take() {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// Says where the threads run, and warns of a spinning acting loop that would starve a
/// planner thread on two CPUs.
fn log_placement(checked: &CheckedController) {
    let (strategy, planning, placement) = (checked.wait(), checked.planning(), checked.placement());
    tracing::info!(
        acting = %crate::summary::on_cpu(placement.acting),
        planner = %crate::summary::on_cpu(placement.planner),
        %planning,
        "thread placement"
    );
    if strategy == WaitStrategy::Spin
        && planning == Planning::Thread
        && std::thread::available_parallelism().is_ok_and(|n| n.get() <= 2)
    {
        tracing::warn!(
            "wait = \"spin\" with planning = \"thread\" on 2 CPUs: the busy-polling acting \
             loop and bridge leave the planner thread, which yields to everything, almost no \
             time; the policy will lag far behind learning (use planning = \"between-polls\")"
        );
    }
}

/// The controller's iceoryx2 ports. (Fields drop in the order declared: the last opened
/// first.)
struct Ports {
    /// Every command, for a recorder (`None`: the log could not be opened).
    command_log: Option<RingOutbox<Command>>,
    /// The latest command, for the bridge.
    commands: LatestOutbox<Command>,
    /// The observations to answer.
    observations: Inbox<Observation>,
    /// The world map, once, from perception.
    maps: Inbox<WorldMap>,
}

impl Ports {
    /// Opens the controller's services on `node`: the map, the observations (waited for by
    /// `strategy`, with perception's heads-up when anticipating), the commands and their log.
    fn open(
        node: &ProcessNode,
        names: &ServiceNames,
        strategy: WaitStrategy,
    ) -> Result<Self, ControllerError> {
        Ok(Self {
            maps: Inbox::open(
                node,
                &names.world_map,
                &names.world_map_event,
                1,
                WaitStrategy::Block,
            )?,
            observations: Inbox::open(
                node,
                &names.observation,
                &names.observation_event,
                0,
                strategy,
            )?
            // Waiting by `anticipate`, perception's word of when the next observation is due.
            .with_heads_up(node, &names.observation_due, &names.observation_due_event)?,
            // A blackboard, not a publisher: sending a command allocates nothing (see
            // LatestOutbox).
            commands: LatestOutbox::open(node, &names.command, &names.command_event)?,
            // Every command again, by its number, for a recorder (written once the command is
            // out; nobody is notified). Without it the group runs on, unrecordable.
            command_log: RingOutbox::open(node, &names.command_log)
                .inspect_err(|e| {
                    tracing::warn!(error = %e, "no command log: a recording of this run misses its commands");
                })
                .ok(),
        })
    }

    /// Publishes `command` to the bridge.
    #[inline]
    fn send(&self, command: Command) -> Result<(), IpcError> {
        self.commands.send(command)
    }

    /// Writes `command` to the command log, if there is one.
    #[inline]
    fn log(&self, command: Command) {
        if let Some(log) = &self.command_log {
            log.put(command);
        }
    }
}

/// Waits up to `timeout` for perception's world map; `None` if `stop` was raised first.
fn wait_for_map(
    maps: &Inbox<WorldMap>,
    names: &ServiceNames,
    timeout: Duration,
    stop: &AtomicBool,
) -> Result<Option<Box<WorldMap>>, ControllerError> {
    tracing::info!(service = %names.world_map, "waiting for the world map");
    // A boxed map: it is ~90 kB, too big to pass around on the stack comfortably.
    match maps.next(timeout, stop)? {
        Ok(m) => Ok(Some(Box::new(m))),
        Err(Idle::Timeout) => Err(ControllerError::NoMap(timeout)),
        Err(Idle::Stopped) => Ok(None),
    }
}

/// The acting loop on `map` from the library `start` (loaded from `path`), with its first
/// plan made; and what the run's end needs to know of that library.
fn start_acting(
    config: &ControllerConfig,
    checked: &CheckedController,
    settings: ActingSettings,
    map: Box<WorldMap>,
    start: StartingLibrary,
    path: PathBuf,
) -> Result<(ActingLoop, LibraryRun), ControllerError> {
    let StartingLibrary {
        library,
        started_empty,
    } = start;
    let library_before = LibraryCounts::of(&library);
    tracing::info!(
        library = %path.display(),
        views = library.len(),
        started_empty,
        states = map.n_states,
        "controller ready"
    );
    let planner = planner_for(config, checked);
    // What the saved library calls the world, its actions and its features.
    let names = WorldNames::of_map(&map);
    // Command numbers from the monotonic clock, so a respawned controller's commands are newer
    // than its predecessor's (perception and the bridge ignore stale command numbers).
    let now = MonotonicClock.now_ns();
    let acting = ActingLoop::starting_at(map, library, settings, planner, now, now)?;
    let library = LibraryRun {
        path,
        names,
        started_empty,
        before: library_before,
    };
    Ok((acting, library))
}

/// What makes the configured planner for a CMDP structure: a thread of its own, or slices
/// between polls or inline.
fn planner_for<'c>(
    config: &'c ControllerConfig,
    checked: &CheckedController,
) -> impl FnOnce(Arc<CmdpStructure>) -> Result<Planner, PlannerThreadError> + 'c {
    let (planning, placement) = (checked.planning(), checked.placement());
    let idle_spin = config.planner_idle_spin(checked.wait());
    let planner_params = PlannerParams {
        max_sweeps: config.plan_sweeps,
        ..PlannerParams::default()
    };
    move |structure| {
        Ok(match planning {
            Planning::Thread => Planner::Thread(PlannerThread::spawn_with(
                structure,
                planner_params,
                PlannerThreadOptions {
                    cpu: placement.planner,
                    idle_spin,
                },
            )?),
            Planning::BetweenPolls => Planner::BetweenPolls(Box::new(SlicedPlanner::new(
                structure,
                planner_params,
                config.plan_slice,
            )?)),
            Planning::Inline => Planner::Inline(Box::new(SlicedPlanner::new(
                structure,
                planner_params,
                config.plan_slice,
            )?)),
        })
    }
}

/// What the acting path did with an observation.
enum Answer {
    /// The command went out; what follows it.
    Sent {
        /// The command.
        command: Command,
        /// What follows it.
        sent: Sent,
    },
    /// The episode ended with the observation; an earlier ended one to report, if any.
    EpisodeEnded(Option<EpisodeLine>),
    /// The observation was refused.
    Refused(Refusal),
}

/// The controller's loop: the acting loop between the ports, one method per phase of an
/// observation's handling (wait, act, what follows the command), and the run's end. (Fields
/// drop in the order declared: the last made first.)
struct Shell {
    progress: ProgressOutbox,
    saver: Saver,
    acting: ActingLoop,
    /// The library the run started from and saves to at its end.
    library: LibraryRun,
    /// One controller per library, until the run's last save is done.
    _library_lock: tes_runtime::lock::Lock,
    ports: Ports,
    /// The node the ports were opened on: dropped last.
    _node: ProcessNode,
    clock: MonotonicClock,
    /// How long a wait for an observation lasts before the idle work (keep-alive, progress).
    idle_timeout: Duration,
    /// Allocations of the commands' publication after the warm-up.
    ipc_allocations: u64,
    /// Allocations on the acting path before the warm-up ended, to subtract.
    warmup_allocations: Option<u64>,
    /// The process's CPU after the warm-up, marked after each command.
    cpu: CpuMeter,
    /// The acting thread's alone (this thread's).
    acting_thread_cpu: CpuMeter,
    /// Whether the acting thread yields its CPU once the command is out, before it learns: it
    /// does unless it polls alone, since the bridge the command wakes may be queued on this
    /// CPU (blocking, the chain shares it: see
    /// [`place_beside_the_acting_thread`](tes_runtime::affinity::place_beside_the_acting_thread)),
    /// and would otherwise wait for the learning.
    hands_over_after_send: bool,
}

impl Shell {
    /// Opens what the run needs, in order: the log of where its threads run, the node and
    /// its ports, perception's world map (`None`: `stop` was raised first), the library's
    /// lock and the library, the acting loop with its planner and first plan, the saver,
    /// the progress report (which tells perception it may start) and the acting thread's
    /// CPU.
    fn open(
        config: &ControllerConfig,
        checked: &CheckedController,
        stop: &AtomicBool,
    ) -> Result<Option<Self>, ControllerError> {
        log_placement(checked);
        let names = ServiceNames::with_prefix(&config.service_prefix);
        let node = channel::group_node(&names, Role::Controller, false)?;
        let mut ports = Ports::open(&node, &names, checked.wait())?;
        let Some(map) = wait_for_map(&ports.maps, &names, checked.map_timeout(), stop)? else {
            return Ok(None);
        };
        let library_path = config.library_path();
        // One controller per library: a predecessor still saving on its way out (its launcher
        // was killed) is waited for; a running one is refused, naming its pid.
        let library_lock = lock_library(&library_path)?;
        let start = load_library(config, &library_path, &map)?;
        let settings = acting_settings(config, checked);
        let (acting, library) = start_acting(config, checked, settings, map, start, library_path)?;
        let saver = Saver::spawn(library.path.clone(), library.names.clone())?;
        // Ready (map, library, first plan): the first report tells perception it may start.
        let progress = ProgressOutbox::open(&node, &names, Role::Controller)?;
        tes_runtime::memory::keep_resident("the controller");
        let mut alone = false;
        if let Some(cpu) = checked.placement().acting {
            let anticipates = ports.observations.strategy() == WaitStrategy::Anticipate;
            alone = tes_runtime::affinity::pin_acting_thread(cpu, anticipates)?;
            ports.observations.poll_alone(alone);
        }
        Ok(Some(Self {
            progress,
            saver,
            acting,
            library,
            _library_lock: library_lock,
            ports,
            _node: node,
            clock: MonotonicClock,
            idle_timeout: settings.keepalive.map_or(IDLE_TICK, |k| k.min(IDLE_TICK)),
            ipc_allocations: 0,
            warmup_allocations: None,
            cpu: CpuMeter::process(),
            acting_thread_cpu: CpuMeter::this_thread(),
            hands_over_after_send: !alone,
        }))
    }

    /// Answers observations until `stop` is raised.
    fn serve(
        &mut self,
        stop: &AtomicBool,
        on_episode: &mut impl FnMut(&EpisodeLine),
    ) -> Result<(), ControllerError> {
        while let Some(obs) = self.next_observation(stop)? {
            match self.act(&obs)? {
                Answer::Sent { command, sent } => {
                    self.after_command(&obs, command, sent, on_episode)?;
                }
                Answer::EpisodeEnded(report) => {
                    if let Some(line) = report {
                        on_episode(&line);
                    }
                }
                Answer::Refused(why) => log_refusal(&obs, why),
            }
        }
        Ok(())
    }

    /// The next observation, or `None` once `stop` is raised. Spinning, the wait does the
    /// planner's slices and adopts its plan (a planner thread needs none); while none comes,
    /// a move under way gets keep-alives and progress is reported when due.
    fn next_observation(
        &mut self,
        stop: &AtomicBool,
    ) -> Result<Option<Observation>, ControllerError> {
        let anticipating = self.ports.observations.strategy().anticipates();
        loop {
            let acting = &mut self.acting;
            // Anticipating, the work between polls is the poll window's: just before the
            // observation is due.
            let work = || {
                let more = acting.plan_between_polls();
                if anticipating {
                    acting.prepare();
                }
                more
            };
            match self
                .ports
                .observations
                .next_or_work(self.idle_timeout, stop, work)?
            {
                Ok(o) => return Ok(Some(o)),
                Err(Idle::Stopped) => return Ok(None),
                Err(Idle::Timeout) => self.on_idle()?,
            }
        }
    }

    /// No observation for a while: a move is under way, so tell the bridge's watchdog we are
    /// still here; and report progress when due.
    fn on_idle(&mut self) -> Result<(), ControllerError> {
        if let Some(keepalive) = self.acting.on_idle(&self.clock) {
            self.ports.send(keepalive)?;
            self.ports.log(keepalive);
        }
        self.progress.publish_due(self.clock.now_ns())?;
        Ok(())
    }

    /// The acting path, from the observation to the command's publication (and the learning
    /// that follows it): the allocations `alloc_count` counts.
    fn act(&mut self, obs: &Observation) -> Result<Answer, ControllerError> {
        let _counting = alloc_count::count_here();
        if self.warmup_allocations.is_none() && self.acting.warmed_up() {
            self.warmup_allocations = Some(alloc_count::counted());
        }
        let command = match self.acting.on_observation(obs, &self.clock)? {
            Step::Act {
                command,
                lost_outcome,
            } => {
                if lost_outcome {
                    tracing::warn!(
                        seq = obs.seq,
                        "the last command's outcome was lost; not learning from it"
                    );
                }
                command
            }
            Step::EpisodeEnded { report } => return Ok(Answer::EpisodeEnded(report)),
            Step::Refused(why) => return Ok(Answer::Refused(why)),
        };
        let before_send = alloc_count::counted();
        self.ports.send(command)?;
        if self.warmup_allocations.is_some() {
            self.ipc_allocations += alloc_count::counted() - before_send;
        }
        if self.hands_over_after_send {
            std::thread::yield_now();
        }
        let sent = self.acting.command_sent(&self.clock)?;
        Ok(Answer::Sent { command, sent })
    }

    /// Off the acting path, the command is out: logs it, reports progress, an ended episode
    /// and hands the saver the library when a save is due.
    fn after_command(
        &mut self,
        obs: &Observation,
        command: Command,
        sent: Sent,
        on_episode: &mut impl FnMut(&EpisodeLine),
    ) -> Result<(), ControllerError> {
        self.ports.log(command);
        let report = self.progress.report_mut();
        (report.in_seq, report.out_seq) = (obs.seq, command.seq);
        (report.steps, report.episodes) =
            (self.acting.counts().actions, self.acting.counts().episodes);
        self.progress.publish_due(self.acting.last_sent_ns())?;
        if let Some(line) = sent.report {
            on_episode(&line);
        }
        if sent.save_due {
            self.saver.offer(self.acting.agent());
        }
        if self.acting.warmed_up() {
            self.cpu.mark();
            self.acting_thread_cpu.mark();
        }
        Ok(())
    }

    /// Ends the run: reports the last episode, stops the saver, saves the library if
    /// anything was learned, and sums the run up.
    fn finish(
        self,
        config: &ControllerConfig,
        checked: &CheckedController,
        on_episode: &mut impl FnMut(&EpisodeLine),
    ) -> ControllerSummary {
        let counts = self.acting.counts();
        let unfinished_steps = u64::from(self.acting.unfinished_steps());
        let latencies = self.acting.latencies();
        let plans = self.acting.plans();
        let (last, agent) = self.acting.finish();
        if let Some(line) = last {
            on_episode(&line);
        }
        let warmup_allocations = self.warmup_allocations;
        let mut summary = ControllerSummary {
            episodes: counts.episodes,
            actions: counts.actions,
            unfinished_steps,
            misses: latencies.decision.misses,
            latency: latencies.decision,
            wake: latencies.wake,
            compute: latencies.compute,
            order: config.order.to_string(),
            learn: latencies.learn,
            learning_overran: latencies.learning_overran,
            allocations: alloc_count::installed().then(|| {
                alloc_count::counted() - warmup_allocations.unwrap_or(alloc_count::counted())
            }),
            ipc_allocations: alloc_count::installed().then_some(self.ipc_allocations),
            refused: counts.refused,
            failed_saves: self.saver.finish(),
            plans,
            planning: checked.planning().to_string(),
            keepalives: counts.keepalives,
            placement: checked.placement(),
            cpu: self.cpu.report(),
            acting_thread_cpu: self.acting_thread_cpu.report(),
            catches: self.ports.observations.catches(),
            library: None,
        };
        let facts = self
            .library
            .save_at_shutdown(agent, counts.learned, &mut summary.failed_saves);
        summary.library = Some(facts);
        summary
    }
}

/// The library a run starts from and saves to at its end, as the summary tells of it.
struct LibraryRun {
    /// The library file.
    path: PathBuf,
    /// What the saved library calls the world, its actions and its features.
    names: WorldNames,
    /// True when there was no library file.
    started_empty: bool,
    /// What the library held at the start.
    before: LibraryCounts,
}

impl LibraryRun {
    /// Saves `agent`'s library, if it `learned` anything from a real motion, and says what
    /// became of it; a failed save is counted in `failed_saves` (the file is left intact).
    fn save_at_shutdown(&self, agent: Tes, learned: u64, failed_saves: &mut u64) -> LibraryFacts {
        let mut facts = LibraryFacts {
            path: self.path.display().to_string(),
            started_empty: self.started_empty,
            before: self.before,
            after: self.before,
            end: LibraryEnd::LeftAsItWas,
        };
        if learned == 0 {
            // Nothing was learned from a real motion (say, the link to the brick never came
            // up): the library on disk stays exactly as it was.
            tracing::info!(
                library = %self.path.display(),
                "nothing learned in this run; the library is left as it was"
            );
        } else {
            match save_library(agent, &self.path, &self.names) {
                Ok(after) => (facts.after, facts.end) = (after, LibraryEnd::Saved),
                Err(e) => {
                    *failed_saves += 1;
                    facts.end = LibraryEnd::NotSaved;
                    tracing::error!(error = %e, "the library was not saved at shutdown; the previous file is intact");
                }
            }
        }
        facts
    }
}

/// The parameters of the empty library a controller starts from when there is no library
/// file (a replay of such a run starts from the same).
pub fn empty_library_params(config: &ControllerConfig) -> LibraryParams {
    LibraryParams {
        max_views: config.max_views,
        mdagl: MdaglParams {
            lambda: config.lambda,
            alpha: config.alpha,
            intercept: false,
        },
        ..LibraryParams::default()
    }
}

/// The acting loop's settings for `config` (checked as `checked`): the controller's, and a
/// replay's of a run with that configuration.
pub fn acting_settings(config: &ControllerConfig, checked: &CheckedController) -> ActingSettings {
    let (strategy, planning) = (checked.wait(), checked.planning());
    ActingSettings {
        order: config.order,
        budget_us: config.budget_us,
        warmup_actions: config.warmup_actions,
        epsilon: config.epsilon,
        seed: config.seed,
        keepalive: (config.keepalive_ms > 0).then(|| Duration::from_millis(config.keepalive_ms)),
        save_interval: checked.save_interval(),
        // An inline plan before the command would be part of the decision.
        offer_before_command: offers_before_command(strategy) && planning != Planning::Inline,
        first_plan_timeout: Duration::from_secs(10),
    }
}

/// When to wake the planner with the new model: before the command when the bridge sleeps on
/// events, after it when the bridge busy-polls. A bridge woken while this CPU is busy goes to
/// the other, idle CPU, and in a VM whose idle vCPUs halt it runs there only once that vCPU is
/// back; waking the planner first gets that CPU out of halt while the command is sent, and the
/// `SCHED_IDLE` planner gives way to the bridge at once. A spinning bridge needs no wake-up.
fn offers_before_command(strategy: WaitStrategy) -> bool {
    strategy != WaitStrategy::Spin
}

fn log_refusal(obs: &Observation, why: Refusal) {
    match why {
        Refusal::UnknownState => {
            tracing::warn!(
                seq = obs.seq,
                x = obs.state.x,
                y = obs.state.y,
                orientation = obs.state.orientation,
                "observation of an unknown state refused"
            );
        }
        Refusal::Stale { last_seq } => {
            tracing::warn!(
                seq = obs.seq,
                last_seq,
                "stale or duplicate observation refused"
            );
        }
        Refusal::NonFiniteReward => {
            tracing::warn!(
                seq = obs.seq,
                "observation with a non-finite reward refused"
            );
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ThreadPlacement;
    use tes_runtime::channel::{LatestInbox, Outbox};
    use tes_runtime::clock::monotonic_ns;
    use tes_topics::StateAttributes;
    use tes_topics::observation_flags;

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
        assert_eq!(m.effect_between(s, at(&m, 1, 1, 0)), 0, "forward");
        assert_eq!(m.effect_between(s, s), 1, "stayed");
        assert_eq!(m.effect_between(s, at(&m, 0, 1, 1)), 2, "turned left");
        // Two cells forward: nearest to "forward".
        assert_eq!(m.effect_between(s, at(&m, 2, 1, 0)), 0);
        // Turned right (no such effect): "stay" and "turn left" are both one cell away (0),
        // then one turn each way; the lowest such effect wins.
        assert_eq!(m.effect_between(s, at(&m, 0, 1, 3)), 1);
        // Out of the area from the east edge going east.
        let edge = at(&m, 2, 1, 0);
        assert_eq!(m.effect_between(edge, m.out_state()), 0);
    }

    #[test]
    fn the_map_becomes_a_cmdp() {
        let m = map();
        let c = crate::acting::structure_from_map(&m).unwrap();
        assert_eq!((c.n_states(), c.n_actions(), c.n_effects()), (37, 2, 3));
        let s = at(&m, 1, 1, 2);
        assert_eq!(c.features(s), &[2]);
        assert!(c.is_terminal(m.out_state()));
        let mut bad = map();
        bad.next_state[3][1] = 99;
        assert!(matches!(
            crate::acting::structure_from_map(&bad),
            Err(ActingError::BadMap(_))
        ));
    }

    /// `load_library` for the test map (2 actions, 3 effects, 4 features) and default settings.
    fn load_test_library(path: &std::path::Path) -> Result<StartingLibrary, ControllerError> {
        load_library(&ControllerConfig::default(), path, &map())
    }

    #[test]
    fn no_library_file_starts_empty_and_says_so_after_removing_dead_saves() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("library.tesl");
        // No process has a pid at the kernel's limit: a save by it is an interrupted one.
        let dead = std::fs::read_to_string("/proc/sys/kernel/pid_max")
            .ok()
            .and_then(|s| s.trim().parse::<u32>().ok())
            .map(|pid| dir.path().join(format!(".library.tesl.tmp-{pid}")));
        let live = dir
            .path()
            .join(format!(".library.tesl.tmp-{}", std::process::id()));
        for tmp in dead.iter().chain([&live]) {
            std::fs::write(tmp, b"half a library").unwrap();
        }
        let start = load_test_library(&path).unwrap();
        assert!(start.started_empty);
        assert!(start.library.is_empty());
        assert_eq!(start.library.n_actions(), 2);
        if let Some(dead) = dead {
            assert!(!dead.exists(), "the dead saver's file is removed");
        }
        assert!(live.exists(), "a live saver's file is kept");
        assert!(!path.exists(), "loading creates nothing");
    }

    #[test]
    fn an_existing_library_is_loaded_not_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("library.tesl");
        let mut library = ViewLibrary::new(2, 3, 4, LibraryParams::default()).unwrap();
        library.end_task(Vec::new()).unwrap();
        let stored = store::StoredLibrary {
            library,
            world: "arena 1".into(),
            action_names: Vec::new(),
            feature_names: Vec::new(),
        };
        store::save(&path, &stored).unwrap();
        let start = load_test_library(&path).unwrap();
        assert!(!start.started_empty);
        assert_eq!(start.library, stored.library);
    }

    /// Anything at the library path that is not a loadable library stops the controller with
    /// the path and the cause, and is left as it was.
    #[test]
    fn an_unusable_library_path_is_an_error_not_a_fresh_start() {
        let dir = tempfile::tempdir().unwrap();
        let expect_error = |path: &std::path::Path, cause: &str| {
            let err = load_test_library(path).unwrap_err();
            assert!(matches!(err, ControllerError::Store(_)), "{err}");
            let text = err.to_string();
            assert!(text.contains(&path.display().to_string()), "{text}");
            assert!(text.contains(cause), "{text}");
        };
        let dangling = dir.path().join("dangling.tesl");
        let target = dir.path().join("moved-away.tesl");
        std::os::unix::fs::symlink(&target, &dangling).unwrap();
        expect_error(&dangling, "which does not exist");
        expect_error(&dangling, &target.display().to_string());
        assert!(
            std::fs::symlink_metadata(&dangling)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert!(!target.exists());

        let directory = dir.path().join("directory.tesl");
        std::fs::create_dir(&directory).unwrap();
        expect_error(&directory, "is a directory, not a regular file");

        let device = dir.path().join("device.tesl");
        std::os::unix::fs::symlink("/dev/zero", &device).unwrap();
        expect_error(&device, "is a character device, not a regular file");

        let corrupt = dir.path().join("corrupt.tesl");
        std::fs::write(&corrupt, b"not a library at all").unwrap();
        expect_error(&corrupt, "not a TES view library");
        assert_eq!(std::fs::read(&corrupt).unwrap(), b"not a library at all");

        let other_world = dir.path().join("other-world.tesl");
        let stored = store::StoredLibrary {
            library: ViewLibrary::new(5, 3, 4, LibraryParams::default()).unwrap(),
            world: "arena 2".into(),
            action_names: Vec::new(),
            feature_names: Vec::new(),
        };
        store::save(&other_world, &stored).unwrap();
        expect_error(&other_world, "this world has 2, 3 and 4");
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
                channel::pubsub::<Observation, _>(&node, &names.observation, 0).unwrap();
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
        // Nothing was learned from a motion: the library is not written at all, and the
        // summary says so.
        let library = rig.config.library.as_ref().unwrap();
        assert!(
            !library.exists(),
            "nothing learned, yet {} was saved",
            library.display()
        );
        let facts = summary.library.as_ref().expect("the library facts");
        assert_eq!(
            (facts.started_empty, facts.end, facts.after),
            (true, LibraryEnd::LeftAsItWas, LibraryCounts::default()),
            "{facts:?}"
        );
        assert_eq!(facts.path, library.display().to_string());
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
        // Learned from, so saved at shutdown: this run's task finished in it, the facts those
        // of the file, its actions named by their wheels (this map's features mean nothing
        // known, so they are not named).
        let facts = summary.library.as_ref().expect("the library facts");
        let stored = store::load(rig.config.library.as_ref().unwrap()).unwrap();
        assert_eq!(
            (facts.started_empty, facts.end, facts.before),
            (true, LibraryEnd::Saved, LibraryCounts::default()),
            "{facts:?}"
        );
        assert_eq!(facts.after, LibraryCounts::of(&stored.library), "{facts:?}");
        assert_eq!(facts.after.tasks, 1, "{facts:?}");
        assert_eq!(stored.action_names, ["stay (both wheels 0°)"; 2]);
        assert!(stored.feature_names.is_empty());
        rig.close();
    }

    /// Spinning, the controller plans between its polls (no planner thread): every learned
    /// step gets a plan in the pause before the next observation, and the loop still answers
    /// each observation once.
    #[test]
    fn a_spinning_controller_plans_between_polls() {
        use std::sync::atomic::Ordering;

        let mut rig = Rig::new("controller-between-polls");
        rig.config.wait = WaitStrategy::Spin;
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
