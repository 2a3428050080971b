//! The supervisor: starts the group's children, relays their lines, watches their progress,
//! respawns or stops them, and says how the launch went — all as [`Event`]s.
//!
//! It is a plain type driven by its caller: [`Supervisor::start`], then
//! [`Supervisor::step`] until it says the group is stopping (a few times a second is
//! enough: [`TICK`]), then [`Supervisor::stop`]; [`run`] does all three.

use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use tes_bridge::config::TransportKind;
use tes_controller::summary::ControllerSummary;
use tes_link::{Link, LinkError, LinkEvent};
use tes_recorder::live::Recorder;
use tes_runtime::channel::{self, IpcError};
use tes_runtime::progress::{ProgressWatch, holdup};
use tes_topics::{Role, ServiceNames, progress_flags};

use crate::IoError;
use crate::children::{self, ChildCommand, Running, SpawnError};
use crate::event::{Event, ExitConsequence, Observer, Verdict};
use crate::file::{LaunchFile, LaunchFileError, Prepared, Restart, prepare};
use crate::library::{self, Fingerprint, LibraryOutcome};
use crate::logs::{self, ChildLine, Stream};
use crate::recording::{self, RecordingError};
use crate::run_record::{RobotAt, RunRecord};

/// How long the group may take to start (the controller loads its library and plans)
/// before the stall watch applies, on top of `stall_timeout_ms`.
pub const START_ALLOWANCE: Duration = Duration::from_secs(20);

/// How often [`run`] steps the supervisor.
pub const TICK: Duration = Duration::from_millis(20);

/// How many of a child's last log lines the supervisor keeps, to say why it died.
const LAST_WORDS: usize = 3;

/// How often the supervisor reads the trajectory perception writes.
const RECORD_POLL: Duration = Duration::from_millis(250);

/// How often a launch waiting for its peers reminds that it still waits (said once at
/// first, then this often, with the time waited).
const WAITING_SAID_EVERY: Duration = Duration::from_secs(10);

/// A launch that cannot start or cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    /// The launch file or the run folder.
    #[error(transparent)]
    File(#[from] LaunchFileError),
    /// iceoryx2 refused something (listing services, the progress watch).
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// Another running group uses the service prefix.
    #[error(
        "the service prefix {0:?} is in use by another running group; give this launch \
         another [launch] service_prefix, or leave it unset for one of its own; nothing was \
         started"
    )]
    PrefixInUse(String),
    /// The link cannot open.
    #[error("nothing was started")]
    Link(#[source] LinkError),
    /// The peers are not all there, or refused this launch.
    #[error("{0}; nothing was started")]
    Peers(String),
    /// A file of the run folder.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A child cannot be started.
    #[error(transparent)]
    Spawn(#[from] SpawnError),
    /// The recording cannot start.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// The group's ROS 2 side cannot start.
    #[error(transparent)]
    Ros2(#[from] crate::ros2::Ros2Error),
    /// A child cannot be polled.
    #[error("cannot poll a child")]
    Poll(#[source] std::io::Error),
    /// The bridge's link cannot exist here: a serial device missing or no terminal, no USB
    /// bus, no Bluetooth.
    #[error("[bridge] transport: {0}; nothing was started")]
    NoBrick(tes_bridge::config::DeviceError),
    /// The view library file cannot be used (corrupt, foreign, for another world).
    #[error("{0}; nothing was started (move the file away to start from an empty library)")]
    Library(tes_learning::library::store::StoreError),
}

/// How a supervisor starts children and when it stops.
#[derive(Debug, Clone)]
pub struct Options {
    /// The program and arguments a child is started with (the supervisor adds `ROLE
    /// --config FILE`).
    pub command: ChildCommand,
    /// Raised (by a signal handler, a live view, the caller), the group stops.
    pub stop: Arc<AtomicBool>,
    /// How long the group may take to start before the stall watch applies, on top of
    /// `[launch] stall_timeout_ms` (default [`START_ALLOWANCE`]).
    pub start_allowance: Duration,
}

impl Options {
    /// Children started with `command`, stopped when `stop` is raised.
    pub fn new(command: ChildCommand, stop: Arc<AtomicBool>) -> Self {
        Self {
            command,
            stop,
            start_allowance: START_ALLOWANCE,
        }
    }
}

/// What the group does after a [`Supervisor::step`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// It runs on.
    Running,
    /// It is to stop: call [`Supervisor::stop`].
    Stopping,
}

/// Why the group stops.
#[derive(Debug, Default)]
struct Ending {
    /// What failed, if anything.
    failure: Option<String>,
    /// Why, for the peers; `None` when a peer stopped it.
    reason: Option<String>,
}

/// The group's supervisor: owns its children, its link, its recording and run folder.
pub struct Supervisor {
    file: LaunchFile,
    options: Options,
    prepared: Prepared,
    watch: ProgressWatch,
    link: Option<Link>,
    recorder: Option<Recorder>,
    ros2: Option<crate::ros2::Running>,
    record: RunRecord,
    children: Vec<Running>,
    lines: mpsc::Receiver<ChildLine>,
    following: Arc<AtomicBool>,
    relay: Relay,
    library: PathBuf,
    library_at_start: Option<Fingerprint>,
    report: Option<PathBuf>,
    record_polled: Instant,
    last_steps: Option<u64>,
    stall_deadline: Instant,
    /// The payloads the link has delivered from peers (observations, commands, motor
    /// states), and when the group stalls if that does not grow.
    link_delivered: u64,
    link_deadline: Instant,
    progress_seen: [u64; 3],
    /// The most episodes the episode-counting roles (perception, controller) reported,
    /// the count of a group side that plays neither.
    reported_episodes: u64,
    ending: Option<Ending>,
    // Declared last: dropped after the ports of the watch and the link.
    _node: iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
}

impl Supervisor {
    /// Prepares the launch `file` (its run folder, the children's settings), opens its link
    /// and waits for its peers (a launch with roles), starts its recording and its children.
    pub fn start(
        file: &LaunchFile,
        options: Options,
        observer: &mut dyn Observer,
    ) -> Result<Self, LaunchError> {
        refuse_a_missing_brick(file)?;
        refuse_a_bad_library(file)?;
        // A refusal from here until the children run removes the new run folder (`prepared`'s
        // drop) and leaves `runs/latest` as it was.
        let mut prepared = prepare(file)?;
        crate::reference::write_resolved(file, &prepared.run_dir)?;
        clean_stale_resources(observer);
        let prefix = prepared.service_prefix.clone();
        refuse_a_prefix_in_use(&prefix)?;
        let node = channel::node_named(
            &channel::group_node_name(&prefix, channel::Member::Launcher),
            false,
        )?;
        let names = ServiceNames::with_prefix(&prefix);
        let watch = ProgressWatch::open(&node, &names)?;
        say_the_plan(file, &prepared, observer);
        let link = match file.roles() {
            Some(local) => Some(open_link(file, &local, &names, &options.stop, observer)?),
            None => None,
        };
        let record = RunRecord::create(&prepared.run_dir, file.controller.budget_us, file.arena())?;
        let library = file.controller.library_path();
        let report = fresh_reports(&prepared, &library, observer)?;
        let library_at_start = Fingerprint::of(&library);
        // Subscribed before any child starts, so it misses nothing.
        let recorder = start_recording(file, &prepared, &library, observer)?;
        let log_to = recorder.as_ref().map(Recorder::log_lines);
        let ros2 = crate::ros2::start(file, &prefix)?.map(|(running, started)| {
            observer.event(&Event::Ros2(started));
            running
        });
        let ros2_lines = ros2.as_ref().map(crate::ros2::lines);
        let (lines_tx, lines) = mpsc::channel::<ChildLine>();
        let following = Arc::new(AtomicBool::new(false));
        let children = start_children(&options.command, &prepared, &lines_tx, &following)?;
        for c in &children {
            observer.event(&Event::ProcessStarted {
                role: c.spec.role,
                pid: c.process.child.id(),
            });
        }
        if let Some(log) = &log_to {
            log.send(LAUNCH_LOG, &started_line(&children, &prefix));
        }
        let pruned = prepared.commit();
        if !pruned.is_empty() {
            observer.event(&Event::RunFoldersPruned {
                removed: pruned.len(),
                keep: file.launch.keep_runs,
            });
        }
        let stall_deadline = Instant::now() + options.start_allowance + stall_timeout(file);
        Ok(Self {
            file: file.clone(),
            options,
            prepared,
            watch,
            link,
            recorder,
            ros2,
            record,
            children,
            lines,
            following,
            relay: Relay {
                log_to,
                ros2_lines,
                ..Relay::default()
            },
            library,
            library_at_start,
            report,
            record_polled: Instant::now(),
            last_steps: None,
            stall_deadline,
            link_delivered: 0,
            link_deadline: stall_deadline,
            progress_seen: [0; 3],
            reported_episodes: 0,
            ending: None,
            _node: node,
        })
    }

    /// The run folder.
    pub fn run_dir(&self) -> &Path {
        &self.prepared.run_dir
    }

    /// The group's iceoryx2 service prefix.
    pub fn service_prefix(&self) -> &str {
        &self.prepared.service_prefix
    }

    /// Asks the group to stop (as Ctrl-C does).
    pub fn request_stop(&self) {
        self.options.stop.store(true, Ordering::Relaxed);
    }

    /// One look at the group: the children's new lines, a stop asked for, the link's news,
    /// the children that exited, the run folder's records, the stall watch.
    pub fn step(&mut self, observer: &mut dyn Observer) -> Result<Step, LaunchError> {
        if self.ending.is_some() {
            return Ok(Step::Stopping);
        }
        self.relay_lines(observer);
        self.check_stop_request(observer);
        self.follow_link(observer);
        self.tend_children(observer)?;
        self.poll_run_record(observer);
        self.watch_progress(observer)?;
        Ok(match self.ending {
            Some(_) => Step::Stopping,
            None => Step::Running,
        })
    }

    /// Stops the group (peers told why, children signalled), takes their last lines, closes
    /// the link, completes the run folder and the recording, and says what became of the
    /// library and the launch.
    pub fn stop(mut self, observer: &mut dyn Observer) -> Verdict {
        let ending = self.ending.take().unwrap_or_else(|| Ending {
            failure: None,
            reason: Some("the group stopped".into()),
        });
        self.tell_peers(&ending);
        // The last reports before the group goes: a side without the controller counts its
        // episodes from them.
        if self.watch.poll().is_ok() {
            self.emit_progress(observer);
        }
        let grace = Duration::from_millis(self.file.launch.grace_ms);
        let mut processes: Vec<&mut children::Process> =
            self.children.iter_mut().map(|c| &mut c.process).collect();
        // A controller still saving the library (its marker beside its report) is waited
        // for before SIGKILL.
        let marker = self
            .report
            .as_deref()
            .map(tes_controller::process::saving_marker);
        let saving = |p: &children::Process| {
            p.name == Role::Controller.name() && marker.as_deref().is_some_and(Path::exists)
        };
        let shutdown = children::shutdown_saving(&mut processes, grace, &saving);
        for escalation in shutdown.escalations {
            observer.event(&Event::Escalated(escalation));
        }
        for wait in shutdown.save_waits {
            observer.event(&Event::WaitedForSave(wait));
        }
        self.take_last_lines(observer);
        if let Some(mut link) = self.link.take() {
            observer.event(&Event::LinkClosed(link.counts()));
            link.close();
        }
        let drawn = self.record.finish();
        self.relay.emit_records(&self.record, observer);
        let mut failures: Vec<String> = ending.failure.into_iter().collect();
        if let Some(log) = &self.relay.log_to {
            // The recording's last line: how the group went (the recorder's own end is in
            // the file's end record).
            let mut so_far = failures.clone();
            self.add_failed_children(&mut so_far);
            let line = ended_line(&so_far, ending.reason.as_deref(), self.relay.episodes);
            log.send(LAUNCH_LOG, &line);
        }
        self.finish_recording(&mut failures, observer);
        self.finish_ros2(&mut failures, observer);
        self.add_failed_children(&mut failures);
        self.relay
            .held_errors
            .retain(|_, error| !failures.iter().any(|f| f.contains(error.as_str())));
        self.relay.tell_held_errors(observer);
        observer.event(&Event::RunFolder {
            dir: self.prepared.run_dir.clone(),
            drawn: drawn.map_err(|e| error_chain(&e)),
        });
        self.say_how_the_link_went(observer);
        let summary = self
            .report
            .as_deref()
            .and_then(|report| library::read_report(Some(report)));
        self.say_what_became_of_the_library(summary.as_ref(), observer);
        let verdict = Verdict {
            episodes: self.episodes_taken_part_in(),
            unfinished_steps: summary.map_or(0, |s| s.unfinished_steps),
            failures,
        };
        observer.event(&Event::Verdict(verdict.clone()));
        verdict
    }

    /// The episodes this side of the group took part in: the controller's lines where it
    /// plays the controller, else the most its peers' progress reports counted.
    fn episodes_taken_part_in(&self) -> u32 {
        if self.plays(Role::Controller) {
            self.relay.episodes
        } else {
            u32::try_from(self.reported_episodes).unwrap_or(u32::MAX)
        }
    }

    /// Takes every line the children wrote since the last step.
    fn relay_lines(&mut self, observer: &mut dyn Observer) {
        for line in self.lines.try_iter() {
            self.relay.take(line, &mut self.record, observer);
        }
    }

    /// Takes lines until none has come for a moment (a child that just died may still have
    /// its last words on their way from its files).
    fn relay_until_quiet(&mut self, observer: &mut dyn Observer) {
        while let Ok(line) = self.lines.recv_timeout(Duration::from_millis(50)) {
            self.relay.take(line, &mut self.record, observer);
        }
    }

    fn check_stop_request(&mut self, observer: &mut dyn Observer) {
        if self.ending.is_none() && self.options.stop.load(Ordering::Relaxed) {
            observer.event(&Event::StopRequested);
            self.end(
                None,
                Some("stop requested (Ctrl-C or SIGTERM) on a peer".into()),
            );
        }
    }

    /// Acts on what the link saw: a peer back, a refused sample, connection or message, a
    /// peer gone or twice, a peer's stop.
    fn follow_link(&mut self, observer: &mut dyn Observer) {
        let Some(link) = &self.link else { return };
        for event in link.events() {
            if self.ending.is_some() {
                return;
            }
            match event {
                LinkEvent::Joined(role) => observer.event(&Event::LinkUp { role, again: true }),
                LinkEvent::Refused { topic, why, count } => {
                    observer.event(&Event::LinkRefused { topic, why, count })
                }
                LinkEvent::Denied(denial) => observer.event(&Event::LinkDenied(denial)),
                LinkEvent::Left(role) => self.peer_left(role, observer),
                LinkEvent::Twice(role) => {
                    let group = self.file.launch.link.group.clone();
                    let twice = format!(
                        "link: another launch of group {group:?} plays the {} too",
                        role.name()
                    );
                    observer.event(&Event::LinkTwice { group, role });
                    self.end(Some(twice.clone()), Some(twice));
                }
                LinkEvent::Stop { clean, reason } => {
                    observer.event(&Event::PeerStopped {
                        clean,
                        reason: reason.clone(),
                    });
                    let failure = (!clean).then(|| format!("a peer failed: {reason}"));
                    self.end(failure, None);
                }
            }
        }
    }

    /// The launch playing `role` is gone: the group stops, non-zero.
    fn peer_left(&mut self, role: Role, observer: &mut dyn Observer) {
        let lost = format!(
            "link: the {}'s launch left the group (its host stopped, was killed or cannot be \
             reached)",
            role.name()
        );
        observer.event(&Event::LinkDown { role });
        if role == Role::Controller && self.plays(Role::Bridge) {
            // As with a controller that dies on this host: a motion under way is braked by
            // the bridge's watchdog, not cut short by the stop.
            std::thread::sleep(watchdog_wall(&self.file));
        }
        self.end(Some(lost.clone()), Some(lost));
    }

    /// Looks at each child that exited: perception done, a bridge whose link is down, a
    /// failure to respawn or to stop the group for.
    fn tend_children(&mut self, observer: &mut dyn Observer) -> Result<(), LaunchError> {
        let mut respawned = Vec::new();
        for i in 0..self.children.len() {
            if self.ending.is_some() {
                break;
            }
            let Some(status) = self.children[i]
                .process
                .child
                .try_wait()
                .map_err(LaunchError::Poll)?
            else {
                continue;
            };
            let role = self.children[i].spec.role;
            match self.consequence_of(i, status) {
                ExitConsequence::Restart { .. } => {
                    self.respawn(i, status, observer)?;
                    respawned.push(role);
                }
                then => self.child_ended(i, status, then, observer),
            }
        }
        for role in respawned {
            self.watch.forget(role);
            self.stall_deadline =
                Instant::now() + self.options.start_allowance + stall_timeout(&self.file);
            self.link_deadline = self.stall_deadline;
        }
        Ok(())
    }

    /// What an exit of child `i` with `status` means for the group.
    fn consequence_of(&self, i: usize, status: std::process::ExitStatus) -> ExitConsequence {
        let launch = &self.file.launch;
        let child = &self.children[i];
        if child.spec.role == Role::Perception && status.success() {
            ExitConsequence::Finished
        } else if child.spec.role == Role::Bridge
            && status.code() == Some(tes_bridge::process::LINK_DOWN_EXIT_STATUS)
        {
            ExitConsequence::LinkDown
        } else if launch.restart == Restart::OnFailure
            && !status.success()
            && child.restarts < launch.max_restarts
        {
            ExitConsequence::Restart {
                restart: child.restarts + 1,
                max: launch.max_restarts,
            }
        } else {
            ExitConsequence::StopGroup
        }
    }

    /// Child `i` ended and the group stops for it (`then` says why).
    fn child_ended(
        &mut self,
        i: usize,
        status: std::process::ExitStatus,
        then: ExitConsequence,
        observer: &mut dyn Observer,
    ) {
        let role = self.children[i].spec.role;
        self.children[i].process.status = Some(status);
        let how = children::describe(status);
        if then != ExitConsequence::Finished {
            self.relay_until_quiet(observer);
        }
        let said = self.relay.last_error(role);
        self.relay.take_held_error(role);
        observer.event(&Event::ProcessExited {
            role,
            how: how.clone(),
            said,
            then,
        });
        // The cause was said with the exit just now: the verdict names the failure only.
        match then {
            ExitConsequence::Finished => {
                self.end(None, Some("perception-sim finished its episodes".into()));
            }
            ExitConsequence::LinkDown => {
                self.end(
                    Some("bridge: its link to the brick".to_owned()),
                    Some("the group stopped".into()),
                );
            }
            _ => {
                let failure = format!("{role} {how}");
                self.end(Some(failure), Some("the group stopped".into()));
            }
        }
    }

    /// Child `i` failed and may be respawned: it is, after its stale resources are cleaned.
    fn respawn(
        &mut self,
        i: usize,
        status: std::process::ExitStatus,
        observer: &mut dyn Observer,
    ) -> Result<(), LaunchError> {
        let role = self.children[i].spec.role;
        self.children[i].restarts += 1;
        self.relay_until_quiet(observer);
        let said = self.relay.take_held_error(role);
        observer.event(&Event::ProcessExited {
            role,
            how: children::describe(status),
            said,
            then: ExitConsequence::Restart {
                restart: self.children[i].restarts,
                max: self.file.launch.max_restarts,
            },
        });
        observer.event(&Event::ProcessRestarted {
            role,
            restart: self.children[i].restarts,
            max: self.file.launch.max_restarts,
        });
        if let Some(log) = &self.relay.log_to {
            let how = children::describe(status);
            let text = format!(
                "WARN launch: {} {how}; restart {} of {}",
                role.name(),
                self.children[i].restarts,
                self.file.launch.max_restarts
            );
            log.send(LAUNCH_LOG, &text);
        }
        if let Err(e) = channel::clean_stale_resources() {
            observer.event(&Event::Warning(e.to_string()));
        }
        let child = children::respawn(&self.options.command, &self.children[i].spec)?;
        observer.event(&Event::ProcessStarted {
            role,
            pid: child.id(),
        });
        self.children[i].process.child = child;
        Ok(())
    }

    /// Reads perception's trajectory now and then: the episodes now complete and where the
    /// robot is.
    fn poll_run_record(&mut self, observer: &mut dyn Observer) {
        if self.record_polled.elapsed() < RECORD_POLL && self.ending.is_none() {
            return;
        }
        self.record_polled = Instant::now();
        self.record.poll();
        self.relay.emit_records(&self.record, observer);
    }

    /// The stall watch: the controller's commands are the group's progress; a group without
    /// a new one for `stall_timeout_ms` names the process holding it up, and restarts it or
    /// stops.
    fn watch_progress(&mut self, observer: &mut dyn Observer) -> Result<(), LaunchError> {
        if self.ending.is_some() {
            return Ok(());
        }
        self.watch.poll()?;
        self.emit_progress(observer);
        let steps = self.watch.latest(Role::Controller).map(|p| p.steps);
        let timeout = stall_timeout(&self.file);
        // A ROS 2 robot takes the time it takes (a real base moves for seconds, a reset
        // between episodes for longer): the ROS 2 world says so while it waits for it.
        let awaiting_peer = self
            .watch
            .latest(Role::Perception)
            .is_some_and(|p| p.flags & progress_flags::AWAITING_PEER != 0);
        if awaiting_peer || (steps.is_some() && steps != self.last_steps) {
            self.last_steps = steps;
            self.stall_deadline = Instant::now() + timeout;
        } else if Instant::now() > self.stall_deadline {
            self.stalled(timeout, observer);
        }
        self.watch_link(timeout, observer);
        Ok(())
    }

    /// The stall watch of a split group's link: the controller may go on deciding (its
    /// steps grow) while what it sends stops reaching the robot's host — every command
    /// refused, or the link wedged — and the robot's observations stop reaching it. A link
    /// that delivers no observation, command or motor state for `stall_timeout_ms` stops
    /// the group, saying what it refused; restarting a process would not mend it.
    fn watch_link(&mut self, timeout: Duration, observer: &mut dyn Observer) {
        let Some(link) = &self.link else { return };
        let counts = link.counts();
        let data = |t: &tes_link::Topic| {
            !matches!(t, tes_link::Topic::Progress(_) | tes_link::Topic::WorldMap)
                && t.comes_in(&self.file.launch.roles)
        };
        let delivered: u64 = counts
            .by_topic
            .iter()
            .filter(|(t, _, _)| data(t))
            .map(|(_, taken, _)| taken)
            .sum();
        if delivered != self.link_delivered {
            self.link_delivered = delivered;
            self.link_deadline = Instant::now() + timeout;
            return;
        }
        if self.ending.is_some() || Instant::now() <= self.link_deadline {
            return;
        }
        let Some((topic, _, _)) = counts.by_topic.iter().find(|(t, _, _)| data(t)) else {
            return;
        };
        let why = format!(
            "sent no {topic} that this host took for {:.1} s (link: {counts})",
            timeout.as_secs_f64()
        );
        observer.event(&Event::Stalled {
            silent_for: timeout,
            holder: topic.writer(),
            why: why.clone(),
            restarting: false,
        });
        let silent = format!("the link stalled: the {} {why}", topic.writer().name());
        self.end(Some(silent.clone()), Some(silent));
    }

    /// Tells each new progress report.
    fn emit_progress(&mut self, observer: &mut dyn Observer) {
        for (i, role) in Role::ALL.into_iter().enumerate() {
            if let Some(p) = self.watch.latest(role)
                && p.stamp_ns != self.progress_seen[i]
            {
                self.progress_seen[i] = p.stamp_ns;
                if role != Role::Bridge {
                    self.reported_episodes = self.reported_episodes.max(p.episodes);
                }
                observer.event(&Event::Progress { role, progress: *p });
            }
        }
    }

    /// The group made no progress for `timeout`: the holder is restarted (killed here,
    /// respawned by the next step like any failed child) or the group stops.
    fn stalled(&mut self, timeout: Duration, observer: &mut dyn Observer) {
        let latest = Role::ALL.map(|r| self.watch.latest(r).copied());
        // Reports come every quarter second: a process silent for half the stall is the one.
        let quiet = (timeout / 2).max(Duration::from_millis(600));
        let holdup = holdup(&latest, tes_runtime::clock::monotonic_ns(), quiet);
        let index = self
            .children
            .iter()
            .position(|c| c.spec.role == holdup.role);
        let launch = &self.file.launch;
        let restarting = launch.restart == Restart::OnFailure
            && index.is_some_and(|i| self.children[i].restarts < launch.max_restarts);
        observer.event(&Event::Stalled {
            silent_for: timeout,
            holder: holdup.role,
            why: holdup.why.clone(),
            restarting,
        });
        match index {
            Some(i) if restarting => {
                let _ = self.children[i].process.child.kill();
                self.stall_deadline = Instant::now() + self.options.start_allowance + timeout;
            }
            _ => {
                let silent = format!(
                    "the group made no progress for {:.1} s: {holdup}",
                    timeout.as_secs_f64()
                );
                self.end(Some(silent.clone()), Some(silent));
            }
        }
    }

    /// The peers stop too, told why: cleanly unless something failed here.
    fn tell_peers(&self, ending: &Ending) {
        if let (Some(link), Some(reason)) = (&self.link, &ending.reason) {
            match &ending.failure {
                Some(f) => link.send_stop(false, f),
                None => link.send_stop(true, reason),
            }
        }
    }

    /// Every child has exited: takes what they wrote last (the controller reports its last
    /// episode and its summary on the way out).
    fn take_last_lines(&mut self, observer: &mut dyn Observer) {
        self.following.store(true, Ordering::Release);
        let deadline = Instant::now() + Duration::from_secs(2);
        while let Ok(line) = self
            .lines
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
        {
            self.relay.take(line, &mut self.record, observer);
        }
    }

    fn finish_ros2(&mut self, failures: &mut Vec<String>, observer: &mut dyn Observer) {
        if let Some(r) = self.ros2.take() {
            match crate::ros2::finish(r) {
                Ok(done) => observer.event(&Event::Ros2Done(done)),
                Err(e) => failures.push(format!("ROS 2: {}", error_chain(&e))),
            }
        }
    }

    fn finish_recording(&mut self, failures: &mut Vec<String>, observer: &mut dyn Observer) {
        if let Some(r) = self.recorder.take() {
            match recording::finish(r) {
                Ok(Some(recorded)) => observer.event(&Event::Recorded(recorded)),
                Ok(None) => {}
                Err(e) => failures.push(format!("recorder: {}", error_chain(&e))),
            }
        }
    }

    /// Adds each child that failed (and is not named yet) to `failures`.
    fn add_failed_children(&self, failures: &mut Vec<String>) {
        for c in &self.children {
            let Some(s) = c.process.status else { continue };
            if s.success() || children::stopped_by_us(s) {
                continue;
            }
            let role = c.spec.role.name();
            let said = self
                .relay
                .held_errors
                .get(&c.spec.role)
                .map(|e| format!(" ({e})"))
                .unwrap_or_default();
            let line = format!("{role} {}{said}", children::describe(s));
            if !failures.iter().any(|f| f.starts_with(role) || *f == line) {
                failures.push(line);
            }
        }
    }

    /// The bridge's round trips to the brick, from its report (when this launch played the
    /// bridge and it wrote one).
    fn say_how_the_link_went(&self, observer: &mut dyn Observer) {
        let report = self
            .prepared
            .bridge_report
            .as_deref()
            .and_then(|path| tes_bridge::process::BridgeReport::load(path).ok());
        if let Some(report) = report.filter(|r| !r.link.transport.is_empty()) {
            observer.event(&Event::LinkTimed(report));
        }
    }

    /// The library is the controller's: a launch without it says nothing of it.
    fn say_what_became_of_the_library(
        &self,
        summary: Option<&ControllerSummary>,
        observer: &mut dyn Observer,
    ) {
        if self.report.is_some() {
            let outcome = LibraryOutcome::of(summary, &self.library, self.library_at_start);
            observer.event(&Event::LibraryAtEnd {
                path: self.library.clone(),
                outcome,
            });
        }
    }

    /// Whether this launch starts `role`.
    fn plays(&self, role: Role) -> bool {
        self.children.iter().any(|c| c.spec.role == role)
    }

    /// The group is to stop: the first reason given is the one.
    fn end(&mut self, failure: Option<String>, reason: Option<String>) {
        self.ending.get_or_insert(Ending { failure, reason });
    }
}

/// The name the launcher's own lines carry in a recording's `/log`.
const LAUNCH_LOG: &str = "launch";

/// The `/log` line of the group's start: each process and its pid.
fn started_line(children: &[Running], prefix: &str) -> String {
    let who: Vec<String> = children
        .iter()
        .map(|c| format!("{} (pid {})", c.spec.role.name(), c.process.child.id()))
        .collect();
    format!(
        "INFO launch: the group {prefix} started: {}",
        who.join(", ")
    )
}

/// The `/log` line of the group's end: how it went, at the level it deserves.
fn ended_line(failures: &[String], reason: Option<&str>, episodes: u32) -> String {
    if failures.is_empty() {
        let why = reason.unwrap_or("the group stopped");
        format!("INFO launch: {why}; {episodes} episodes")
    } else {
        format!(
            "ERROR launch: the group failed after {episodes} episodes: {}",
            failures.join("; ")
        )
    }
}

/// Runs the launch `file` to its end: [`Supervisor::start`], [`Supervisor::step`] every
/// [`TICK`] until the group stops, [`Supervisor::stop`].
pub fn run(
    file: &LaunchFile,
    options: Options,
    observer: &mut dyn Observer,
) -> Result<Verdict, LaunchError> {
    let mut supervisor = Supervisor::start(file, options, observer)?;
    while supervisor.step(observer)? == Step::Running {
        std::thread::sleep(TICK);
    }
    Ok(supervisor.stop(observer))
}

/// The children's lines, relayed as events; each child's last log lines; the episodes.
#[derive(Default)]
struct Relay {
    last_words: BTreeMap<Role, VecDeque<String>>,
    /// Each child's closing `error: …` line, held back from the relayed lines: the launch
    /// says it once, with the child's role, where it tells how the child ended.
    held_errors: BTreeMap<Role, String>,
    /// Episode lines seen.
    episodes: u32,
    /// Episodes of the run record told so far.
    rows_told: usize,
    /// Where the robot was last told to be.
    robot_told: Option<RobotAt>,
    /// The recorder's `/log`, when a recording or a live view draws the run.
    log_to: Option<tes_recorder::live::LogLines>,
    /// The ROS 2 side's `/rosout`, when the run is on ROS 2.
    ros2_lines: Option<crate::ros2::Lines>,
}

impl Relay {
    fn take(&mut self, line: ChildLine, record: &mut RunRecord, observer: &mut dyn Observer) {
        let ChildLine { role, stream, text } = line;
        match stream {
            Stream::Out => {
                let episode = (role == Role::Controller)
                    .then(|| tes_controller::summary::EpisodeLine::parse(&text))
                    .flatten();
                match episode {
                    Some(line) => {
                        self.episodes += 1;
                        record.controller_line(&text);
                        observer.event(&Event::EpisodeEnded { line, text });
                    }
                    None => observer.event(&Event::Output { role, text }),
                }
            }
            Stream::Log => {
                let kept = self.last_words.entry(role).or_default();
                if kept.len() == LAST_WORDS {
                    kept.pop_front();
                }
                kept.push_back(text.clone());
                if let Some(log) = &self.log_to {
                    log.send(role.name(), &text);
                }
                if let Some(lines) = &self.ros2_lines {
                    crate::ros2::send_line(lines, role, &text);
                }
                match text.trim().strip_prefix("error: ") {
                    Some(error) => {
                        self.held_errors.insert(role, error.to_owned());
                    }
                    None => observer.event(&Event::Log { role, text }),
                }
            }
        }
    }

    /// Tells the episodes the run record completed and where the robot is, if it moved.
    fn emit_records(&mut self, record: &RunRecord, observer: &mut dyn Observer) {
        for row in &record.episodes()[self.rows_told..] {
            observer.event(&Event::EpisodeRecorded(row.clone()));
        }
        self.rows_told = record.episodes().len();
        if let Some(at) = record.robot()
            && self.robot_told != Some(at)
        {
            self.robot_told = Some(at);
            observer.event(&Event::RobotMoved(at));
        }
    }

    /// The closing error `role` said and the launch has not told yet, now told.
    fn take_held_error(&mut self, role: Role) -> Option<String> {
        self.held_errors.remove(&role)
    }

    /// Tells every closing error not told with its child's end (a child that failed while
    /// the group stopped), as that child's log line.
    fn tell_held_errors(&mut self, observer: &mut dyn Observer) {
        for (role, error) in std::mem::take(&mut self.held_errors) {
            observer.event(&Event::Log {
                role,
                text: format!("error: {error}"),
            });
        }
    }

    /// The last error line `role` logged (else its last line), without a log line's
    /// timestamp and level.
    fn last_error(&self, role: Role) -> Option<String> {
        let kept = self.last_words.get(&role)?;
        kept.iter()
            .rev()
            .find(|l| l.contains(" ERROR ") || l.starts_with("error"))
            .or_else(|| kept.back())
            .map(|l| {
                let l = l.trim();
                l.split_once(" ERROR ")
                    .map(|(_, rest)| rest.trim_start())
                    .or_else(|| l.strip_prefix("error: "))
                    .unwrap_or(l)
                    .to_owned()
            })
    }
}

/// Removes the iceoryx2 resources crashed runs left.
fn clean_stale_resources(observer: &mut dyn Observer) {
    match channel::clean_stale_resources() {
        Ok(0) => {}
        Ok(processes) => observer.event(&Event::StaleResourcesRemoved { processes }),
        Err(e) => observer.event(&Event::Warning(e.to_string())),
    }
}

/// Refuses a library file the controller would refuse, before anything starts: a launch
/// that plays the controller checks the file (if there is one) as the controller will load
/// it, for the world perception publishes.
fn refuse_a_bad_library(file: &LaunchFile) -> Result<(), LaunchError> {
    if file
        .roles()
        .is_some_and(|local| !local.contains(&Role::Controller))
    {
        return Ok(());
    }
    let path = file.controller.library_path();
    if std::fs::symlink_metadata(&path).is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound) {
        return Ok(());
    }
    let checked = match tes_perception_sim::arena::ArenaId::from_number(file.arena()) {
        Ok(id) => {
            let arena = tes_perception_sim::arena::Arena::new(id);
            match tes_perception_sim::process::world_map(&arena) {
                Ok(map) => tes_learning::library::store::load_for(
                    &path,
                    map.n_actions as usize,
                    map.n_effects as usize,
                    map.n_features as usize,
                ),
                Err(_) => tes_learning::library::store::load(&path),
            }
        }
        // A bad arena number is the launch file's error, said by its own check.
        Err(_) => tes_learning::library::store::load(&path),
    };
    checked.map(|_| ()).map_err(LaunchError::Library)
}

/// Refuses a prefix a running group uses. A group is there if its processes' progress
/// services are (a watcher of other services, such as a test subscribing early, is not a
/// group).
fn refuse_a_prefix_in_use(prefix: &str) -> Result<(), LaunchError> {
    let progress = format!("{prefix}{}", tes_topics::service::PROGRESS);
    if channel::services_with_prefix(&progress)?.is_empty() {
        Ok(())
    } else {
        Err(LaunchError::PrefixInUse(prefix.to_owned()))
    }
}

/// Refuses a launch whose bridge would talk to a serial device that is not there, or is no
/// terminal (`/dev/null`, a FIFO, a file), or to a USB or Bluetooth brick on a machine with
/// no USB bus or no Bluetooth: the link could never come up, and a run that cannot happen
/// must not start (said once, before any process could say it again).
fn refuse_a_missing_brick(file: &LaunchFile) -> Result<(), LaunchError> {
    let plays_bridge = file.launch.roles.is_empty() || file.launch.roles.contains(&Role::Bridge);
    if plays_bridge {
        file.bridge
            .transport
            .check_device()
            .map_err(LaunchError::NoBrick)?;
    }
    Ok(())
}

/// Tells what the launch runs.
fn say_the_plan(file: &LaunchFile, prepared: &Prepared, observer: &mut dyn Observer) {
    let launch = &file.launch;
    observer.event(&Event::Planned {
        world: file.world_name(),
        episodes: launch.episodes,
        real_time_factor: launch.real_time_factor,
        wait: file.chosen_wait(),
        restart: launch.restart,
        service_prefix: prepared.service_prefix.clone(),
        run_dir: prepared.run_dir.clone(),
    });
}

/// The controller's report file of this run (if it writes one), with any stale report of
/// the controller and the bridge removed; says the library the controller starts from.
fn fresh_reports(
    prepared: &Prepared,
    library: &Path,
    observer: &mut dyn Observer,
) -> Result<Option<PathBuf>, LaunchError> {
    let report = controller_report(prepared)?;
    if let Some(path) = &prepared.bridge_report {
        library::remove_stale_report(path, "bridge")?;
    }
    if report.is_some() {
        observer.event(&Event::LibraryAtStart {
            path: library.to_owned(),
            exists: std::fs::symlink_metadata(library).is_ok(),
        });
    }
    Ok(report)
}

/// Starts the run's recorder, if the launch file asks for one, and says where it records
/// and serves.
fn start_recording(
    file: &LaunchFile,
    prepared: &Prepared,
    library: &Path,
    observer: &mut dyn Observer,
) -> Result<Option<Recorder>, LaunchError> {
    let recorder = recording::start(file, &prepared.specs, &prepared.service_prefix, library)?;
    if let Some(path) = recorder.as_ref().and_then(Recorder::path) {
        observer.event(&Event::Recording {
            path: path.to_owned(),
        });
    }
    if let Some(addr) = recorder.as_ref().and_then(Recorder::foxglove_addr) {
        observer.event(&Event::Foxglove {
            addr,
            exposed: !addr.ip().is_loopback(),
        });
    }
    Ok(recorder)
}

/// The controller's report path, when this launch plays the controller (an old report
/// removed).
fn controller_report(prepared: &Prepared) -> Result<Option<PathBuf>, LaunchError> {
    let Some(spec) = prepared.specs.iter().find(|s| s.role == Role::Controller) else {
        return Ok(None);
    };
    let path = library::controller_report(spec, &prepared.run_dir)?;
    library::remove_stale_report(&path, "controller")?;
    Ok(Some(path))
}

/// Starts every child of `prepared` with its output files followed; if one cannot start,
/// the ones started are stopped.
fn start_children(
    command: &ChildCommand,
    prepared: &Prepared,
    lines: &mpsc::Sender<ChildLine>,
    following: &Arc<AtomicBool>,
) -> Result<Vec<Running>, LaunchError> {
    let mut children = Vec::new();
    for spec in &prepared.specs {
        let started = follow_outputs(spec, lines, following)
            .map_err(LaunchError::from)
            .and_then(|()| children::spawn(command, spec).map_err(LaunchError::from));
        match started {
            Ok(child) => children.push(Running {
                spec: spec.clone(),
                process: children::Process::new(spec.role.name(), child),
                restarts: 0,
            }),
            Err(e) => {
                let mut started: Vec<&mut children::Process> =
                    children.iter_mut().map(|c| &mut c.process).collect();
                children::shutdown(&mut started, Duration::from_secs(1));
                return Err(e);
            }
        }
    }
    Ok(children)
}

/// Starts `spec`'s output files afresh and follows them.
fn follow_outputs(
    spec: &crate::children::ChildSpec,
    lines: &mpsc::Sender<ChildLine>,
    following: &Arc<AtomicBool>,
) -> Result<(), IoError> {
    let dir = spec.run_dir();
    let role = spec.role;
    logs::reset(&dir, role.name())?;
    for (stream, path) in logs::paths(&dir, role.name()) {
        logs::follow(path, role, stream, lines.clone(), following.clone())?;
    }
    Ok(())
}

/// `[launch] stall_timeout_ms`.
fn stall_timeout(file: &LaunchFile) -> Duration {
    Duration::from_millis(file.launch.stall_timeout_ms)
}

/// The bridge's watchdog deadline in wall time (its settings are in brick time).
fn watchdog_wall(file: &LaunchFile) -> Duration {
    match file.children() {
        Ok(c) => {
            let scale = if c.bridge.transport == TransportKind::Sim {
                c.bridge.brick.time_scale.max(1e-3)
            } else {
                1.0
            };
            Duration::from_secs_f64(c.bridge.watchdog.deadline_ms as f64 / 1000.0 / scale)
                + Duration::from_millis(200)
        }
        Err(_) => Duration::from_secs(1),
    }
}

/// An error and its causes, as one line ("what: why: deeper why").
pub fn error_chain(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(e) = source {
        text.push_str(": ");
        text.push_str(&e.to_string());
        source = e.source();
    }
    text
}

/// Opens the link of a launch playing `local` and waits until every other role's launch is
/// there (at most `[launch.link] peer_timeout_ms`), saying whom it waits for.
fn open_link(
    file: &LaunchFile,
    local: &[Role],
    names: &ServiceNames,
    stop: &AtomicBool,
    observer: &mut dyn Observer,
) -> Result<Link, LaunchError> {
    let settings = &file.launch.link;
    let link = Link::open(settings, local, names).map_err(LaunchError::Link)?;
    observer.event(&Event::LinkOpened {
        local: local.to_vec(),
        group: settings.group.clone(),
        mode: settings.mode,
        zid: link.zid().to_owned(),
        listen: link.endpoints().listen.clone(),
        connect: link.endpoints().connect.clone(),
        security: settings.security(),
    });
    wait_for_peers(&link, file, stop, observer)?;
    Ok(link)
}

/// Waits until a launch plays each role this one does not.
fn wait_for_peers(
    link: &Link,
    file: &LaunchFile,
    stop: &AtomicBool,
    observer: &mut dyn Observer,
) -> Result<(), LaunchError> {
    let settings = &file.launch.link;
    let timeout = Duration::from_millis(settings.peer_timeout_ms);
    let start = Instant::now();
    let mut said: Option<Instant> = None;
    loop {
        take_events_while_waiting(link, &settings.group, observer)?;
        let missing = link.missing();
        if missing.is_empty() {
            return Ok(());
        }
        if stop.load(Ordering::Relaxed) {
            return Err(LaunchError::Peers(format!(
                "stop requested while waiting for the {}",
                role_list(&missing)
            )));
        }
        if start.elapsed() >= timeout {
            return Err(LaunchError::Peers(format!(
                "no launch of group {:?} playing the {} was reached within {:.1} s \
                 ([launch.link] peer_timeout_ms): is it started, with the same group, and can \
                 this host reach it (listen {:?}, connect {:?})?",
                settings.group,
                role_list(&missing),
                timeout.as_secs_f64(),
                settings.listen,
                settings.connect
            )));
        }
        if said.is_none_or(|at| at.elapsed() >= WAITING_SAID_EVERY) {
            // Zero the first time: the launch says whom it waits for; then how long.
            let waited = said.map_or(Duration::ZERO, |_| start.elapsed());
            said = Some(Instant::now());
            observer.event(&Event::LinkWaiting {
                missing,
                group: settings.group.clone(),
                waited,
                timeout,
            });
        }
        std::thread::sleep(TICK);
    }
}

/// The link's events while the launch waits: a role played twice or a peer's stop ends the
/// wait; a peer that joins is told.
fn take_events_while_waiting(
    link: &Link,
    group: &str,
    observer: &mut dyn Observer,
) -> Result<(), LaunchError> {
    for event in link.events() {
        match event {
            LinkEvent::Twice(role) => {
                return Err(LaunchError::Peers(format!(
                    "two launches of group {group:?} play the {}: give each role to one launch",
                    role.name()
                )));
            }
            LinkEvent::Stop { reason, .. } => {
                return Err(LaunchError::Peers(format!(
                    "a peer stopped the group while this launch waited ({reason})"
                )));
            }
            LinkEvent::Joined(role) => observer.event(&Event::LinkUp { role, again: false }),
            LinkEvent::Denied(denial) => observer.event(&Event::LinkDenied(denial)),
            _ => {}
        }
    }
    Ok(())
}

/// "perception-sim, bridge".
pub fn role_list(roles: &[Role]) -> String {
    roles
        .iter()
        .map(|r| r.name())
        .collect::<Vec<_>>()
        .join(", ")
}
