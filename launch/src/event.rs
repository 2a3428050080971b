//! What a launch tells: the [`Event`]s a [`crate::Supervisor`] emits, in order, to an
//! [`Observer`] (the command line's printer, its live view, a recorder of events in a test).

use std::path::PathBuf;
use std::time::Duration;
pub use tes_bridge::process::BridgeReport;
pub use tes_bridge::transport::in_words;

use tes_controller::summary::EpisodeLine;
use tes_link::{LinkCounts, Mode, Topic};
use tes_topics::wire::Refusal;
use tes_topics::{Progress, Role};

use crate::children::{Escalation, SaveWait};
use crate::file::Restart;
use crate::library::LibraryOutcome;
use crate::recording::Recorded;
use crate::run_record::{EpisodeRow, RobotAt};

/// Something that happened in a launch.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Resources of crashed processes were removed before the start.
    StaleResourcesRemoved {
        /// How many dead processes' resources.
        processes: usize,
    },
    /// Something went wrong that does not stop the launch.
    Warning(String),
    /// The launch is about to start: what it runs and where.
    Planned {
        /// The world: `arena Env 3`, or a ROS 2 robot's.
        world: String,
        /// Episodes to run.
        episodes: u32,
        /// The real-time factor (0: as fast as possible).
        real_time_factor: f64,
        /// How the processes wait: `[launch] wait`, and what `auto` chose.
        wait: crate::file::ChosenWait,
        /// What happens when a child dies.
        restart: Restart,
        /// The group's iceoryx2 service prefix.
        service_prefix: String,
        /// The run folder.
        run_dir: PathBuf,
    },
    /// Old run folders were removed to keep `[launch] keep_runs`.
    RunFoldersPruned {
        /// How many.
        removed: usize,
        /// How many are kept.
        keep: u32,
    },
    /// The link to the other hosts is open.
    LinkOpened {
        /// The roles this launch plays.
        local: Vec<Role>,
        /// The group's name on Zenoh.
        group: String,
        /// Zenoh's mode.
        mode: Mode,
        /// This launch's Zenoh session id.
        zid: String,
        /// Endpoints listened on.
        listen: Vec<String>,
        /// Endpoints connected to.
        connect: Vec<String>,
        /// How the link is protected.
        security: tes_link::Security,
    },
    /// The launch waits for the launches playing `missing` (said every few seconds).
    LinkWaiting {
        /// The roles no launch plays yet.
        missing: Vec<Role>,
        /// The group's name on Zenoh.
        group: String,
        /// How long it has waited so far (zero the first time it says so).
        waited: Duration,
        /// When the launch gives up.
        timeout: Duration,
    },
    /// A peer launch playing `role` is there (`again`: it joined again during the run).
    LinkUp {
        /// The role.
        role: Role,
        /// Whether it came back during the run.
        again: bool,
    },
    /// A peer's sample was refused (the first of its kind, then every 100th).
    LinkRefused {
        /// The service.
        topic: Topic,
        /// Why.
        why: Refusal,
        /// Samples of this service refused so far.
        count: u64,
    },
    /// Zenoh refused a connection (it failed the group's TLS) or a peer's message (its
    /// certificate does not allow it).
    LinkDenied(tes_link::refusals::Denial),
    /// The launch playing `role` left the group (its host stopped, was killed or cannot be
    /// reached): the group stops.
    LinkDown {
        /// The role.
        role: Role,
    },
    /// Another launch of the group plays `role` too: the group stops.
    LinkTwice {
        /// The group's name on Zenoh.
        group: String,
        /// The role.
        role: Role,
    },
    /// A peer stopped the group.
    PeerStopped {
        /// Whether it stopped as planned.
        clean: bool,
        /// What it said.
        reason: String,
    },
    /// The view library the controller starts from.
    LibraryAtStart {
        /// The file.
        path: PathBuf,
        /// Whether there is one (else the controller starts from an empty library).
        exists: bool,
    },
    /// The run is being recorded to `path`.
    Recording {
        /// The MCAP file.
        path: PathBuf,
    },
    /// The run is served live to Foxglove at `addr`.
    Foxglove {
        /// Where the server listens.
        addr: std::net::SocketAddr,
        /// Whether that is beyond loopback: anyone who reaches it sees the run.
        exposed: bool,
    },
    /// The run is on ROS 2, or written to a rosbag2 bag, or both.
    Ros2(crate::ros2::Ros2Started),
    /// A child started.
    ProcessStarted {
        /// Its role.
        role: Role,
        /// Its pid.
        pid: u32,
    },
    /// The controller ended an episode: its line, parsed and as written.
    EpisodeEnded {
        /// The line's values.
        line: EpisodeLine,
        /// The line.
        text: String,
    },
    /// A child wrote a line on its standard output that is not an episode line (the
    /// controller's summary).
    Output {
        /// Its role.
        role: Role,
        /// The line.
        text: String,
    },
    /// A child logged a line (its standard error).
    Log {
        /// Its role.
        role: Role,
        /// The line.
        text: String,
    },
    /// An episode joined with its end in the run folder's `episodes.csv`.
    EpisodeRecorded(EpisodeRow),
    /// Where the robot is now.
    RobotMoved(RobotAt),
    /// A process's progress report (a few times a second).
    Progress {
        /// Its role.
        role: Role,
        /// Its report.
        progress: Progress,
    },
    /// A stop was asked (Ctrl-C, SIGTERM, the caller).
    StopRequested,
    /// A child exited on its own.
    ProcessExited {
        /// Its role.
        role: Role,
        /// How ("exited with status 3", "was killed by SIGKILL").
        how: String,
        /// What it said last (its last error line).
        said: Option<String>,
        /// What the supervisor does about it.
        then: ExitConsequence,
    },
    /// A child was started again after it failed or stalled.
    ProcessRestarted {
        /// Its role.
        role: Role,
        /// This restart's number.
        restart: u32,
        /// Restarts allowed.
        max: u32,
    },
    /// The group made no progress for `silent_for`.
    Stalled {
        /// How long.
        silent_for: Duration,
        /// The process holding it up.
        holder: Role,
        /// What it has not done.
        why: String,
        /// Whether the holder is restarted (else the group stops).
        restarting: bool,
    },
    /// A child needed a harder signal to stop.
    Escalated(Escalation),
    /// A child still saving (the controller's final library save) was waited for before
    /// SIGKILL.
    WaitedForSave(SaveWait),
    /// The link is closed: what passed through it.
    LinkClosed(LinkCounts),
    /// The recording is complete.
    Recorded(Recorded),
    /// The ROS 2 side stopped: what it published and wrote.
    Ros2Done(crate::ros2::Ros2Done),
    /// The run folder is complete (`drawn`: its pictures) or not (why).
    RunFolder {
        /// The folder.
        dir: PathBuf,
        /// Its pictures, or why they could not be drawn.
        drawn: Result<Vec<PathBuf>, String>,
    },
    /// The bridge's link to the brick: its round trips (from the bridge's report).
    LinkTimed(BridgeReport),
    /// What became of the view library.
    LibraryAtEnd {
        /// The file.
        path: PathBuf,
        /// What became of it.
        outcome: LibraryOutcome,
    },
    /// How the launch went.
    Verdict(Verdict),
}

/// What the supervisor does about a child that exited on its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExitConsequence {
    /// It finished its work (perception, its episodes): the group stops cleanly.
    Finished,
    /// It is respawned: this is restart `restart` of `max`.
    Restart {
        /// This restart's number.
        restart: u32,
        /// Restarts allowed.
        max: u32,
    },
    /// It failed: the group stops.
    StopGroup,
    /// The bridge's link to the brick is down: the group stops (respawning cannot help).
    LinkDown,
}

/// How a launch went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Verdict {
    /// Episodes the controller reported.
    pub episodes: u32,
    /// Commands of an episode the group stopped before it ended (a stop requested
    /// mid-episode), as the controller reported them: the library learned from them.
    pub unfinished_steps: u64,
    /// What failed, if anything (a process, the link, the recorder).
    pub failures: Vec<String>,
}

impl Verdict {
    /// The run's length in words: `20 episodes`, `1 episode`, or with a stop mid-episode
    /// `0 episodes and 3 actions of an unfinished one` (the library learned from those too).
    ///
    /// ```
    /// let verdict = tes_launch::event::Verdict {
    ///     episodes: 0,
    ///     unfinished_steps: 3,
    ///     failures: Vec::new(),
    /// };
    /// assert_eq!(verdict.length(), "0 episodes and 3 actions of an unfinished one");
    /// ```
    pub fn length(&self) -> String {
        let plural = |n: u64| if n == 1 { "" } else { "s" };
        let episodes = u64::from(self.episodes);
        let mut said = format!("{episodes} episode{}", plural(episodes));
        if self.unfinished_steps > 0 {
            let n = self.unfinished_steps;
            said.push_str(&format!(
                " and {n} action{} of an unfinished one",
                plural(n)
            ));
        }
        said
    }

    /// Whether everything stopped cleanly.
    pub fn success(&self) -> bool {
        self.failures.is_empty()
    }
}

/// What a launch tells its events to.
pub trait Observer {
    /// Takes one event (called on the supervisor's thread, in order).
    fn event(&mut self, event: &Event);
}

impl<F: FnMut(&Event)> Observer for F {
    fn event(&mut self, event: &Event) {
        self(event)
    }
}

impl Observer for Vec<Event> {
    fn event(&mut self, event: &Event) {
        self.push(event.clone());
    }
}
