//! The process group: starting the children, relaying their lines, respawning or stopping
//! them.

use super::*;
use crate::link::{Link, LinkEvent};

/// The roles this executable plays as a child.
pub const ROLES: [&str; 3] = ["bridge", "controller", "perception-sim"];

/// One child's launch recipe.
#[derive(Debug)]
pub(crate) struct ChildSpec {
    pub(crate) role: &'static str,
    pub(crate) config: PathBuf,
}

/// A running (or finished) child.
pub(crate) struct Running {
    pub(crate) spec: ChildSpec,
    pub(crate) child: Child,
    pub(crate) restarts: u32,
    pub(crate) status: Option<ExitStatus>,
}

/// How a group run went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct GroupOutcome {
    /// Episodes the controller reported.
    pub(crate) episodes: u32,
}

/// How long the group may take to start (the controller loads its library and plans) before
/// the stall watch applies, on top of `stall_timeout_ms`.
const START_ALLOWANCE: Duration = Duration::from_secs(20);

/// How many of a child's last log lines the launcher keeps, to say why it died.
const LAST_WORDS: usize = 3;

/// [`run_file`] with the children already prepared.
/// `tui` shows the group in a live view ([`tui`]) while it runs.
pub(crate) fn run_group(
    file: &LaunchFile,
    prepared: Prepared,
    echo: bool,
    tui: bool,
) -> Result<GroupOutcome> {
    let launch = &file.launch;
    let say = logs::Say::default();
    let note = |text: String| {
        if echo {
            say.err(&text);
        }
    };

    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone())
            .context("cannot install the signal handlers")?;
    }
    match channel::clean_stale_resources() {
        Ok(0) => {}
        Ok(n) => note(format!(
            "launch: removed the stale iceoryx2 resources of {n} dead processes"
        )),
        Err(e) => say.err(&format!("launch: warning: {e}")),
    }
    let prefix = &prepared.service_prefix;
    // A group is there if its processes' progress services are (a watcher of other services,
    // such as a test subscribing early, is not a group).
    let progress = format!("{prefix}{}", tes_topics::service::PROGRESS);
    let taken =
        channel::services_with_prefix(&progress).context("cannot list iceoryx2 services")?;
    if !taken.is_empty() {
        bail!(
            "the service prefix {prefix:?} is in use by another running group; give this \
             launch another [launch] service_prefix, or leave it unset for one of its own; \
             nothing was started"
        );
    }
    let node = channel::node_named(&channel::group_node_name(prefix, channel::LAUNCHER), false)?;
    let names = ServiceNames::with_prefix(prefix);
    let mut watch = ProgressWatch::open(&node, &names)?;
    note(format!(
        "launch: arena Env {}, {} episodes, real-time factor {}, wait {}, restart {:?}, \
         services {prefix}*, run folder {}",
        launch.arena,
        launch.episodes,
        launch.real_time_factor,
        launch.wait,
        launch.restart,
        prepared.run_dir.display()
    ));
    if !prepared.pruned.is_empty() {
        note(format!(
            "launch: removed the {} oldest run folders (keep_runs = {})",
            prepared.pruned.len(),
            launch.keep_runs
        ));
    }
    // A launch of some roles reaches the others over its link, and starts nothing before
    // they are all there.
    let mut link = match file.roles() {
        Some(local) => Some(open_link(file, &local, &names, &stop, &say, echo)?),
        None => None,
    };
    let record =
        run_record::RunRecord::create(&prepared.run_dir, file.controller.budget_us, file.arena())?;
    let run_dir = prepared.run_dir.clone();
    let library = file.controller.library_path();
    let plays_controller = prepared.specs.iter().any(|s| s.role == "controller");
    match std::fs::symlink_metadata(&library) {
        _ if !plays_controller => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => note(format!(
            "launch: no view library at {}; the controller starts from an empty one",
            library.display()
        )),
        _ => note(format!("launch: view library {}", library.display())),
    }
    // The library's facts at the end come from the controller's report; what the file was
    // at the start tells, if the controller cannot report, whether it was left as it was.
    let library_at_start = Fingerprint::of(&library);
    let mut report = None;
    for spec in prepared.specs.iter().filter(|s| s.role == "controller") {
        let path = controller_report(spec, &prepared.run_dir)?;
        // A previous run's report would say what that run did.
        match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                bail!(
                    "cannot remove the previous controller report {}: {e}",
                    path.display()
                )
            }
            _ => {}
        }
        report = Some(path);
    }
    // Subscribed before any child starts, so it misses nothing.
    let recorder = crate::record::start(file, &prepared.specs, prefix, &library)?;
    if let Some(r) = &recorder {
        note(format!("launch: recording to {}", r.path().display()));
    }
    let title = format!(
        "TES launch: arena Env {}, services {prefix}*, run folder {}",
        file.arena(),
        run_dir.display()
    );
    // The terminal is the view's from here until the group stops.
    let mut view = if tui {
        say.hold();
        match tui::LiveView::open() {
            Ok(view) => Some(view),
            Err(e) => {
                say.release();
                return Err(e.context("--tui: cannot show the live view; nothing was started"));
            }
        }
    } else {
        None
    };
    let (lines_tx, lines) = mpsc::channel::<ChildLine>();
    let following = Arc::new(AtomicBool::new(false));
    let mut children = Vec::new();
    for spec in prepared.specs {
        let dir = run_dir_of(&spec);
        logs::reset(&dir, spec.role)?;
        for (stream, path) in logs::paths(&dir, spec.role) {
            logs::follow(path, spec.role, stream, lines_tx.clone(), following.clone())?;
        }
        let child = spawn(&spec)?;
        children.push(Running {
            spec,
            child,
            restarts: 0,
            status: None,
        });
    }
    drop(lines_tx);
    let grace = Duration::from_millis(launch.grace_ms);
    let stall_timeout = Duration::from_millis(launch.stall_timeout_ms);
    let mut relay = Relay {
        echo,
        say: &say,
        last_words: BTreeMap::new(),
        episodes: 0,
        record,
    };
    let mut record_polled = Instant::now();
    let mut failure: Option<String> = None;
    // The controller's commands are the group's progress: its last count, and until when the
    // group may go without a new one.
    let mut last_steps = None;
    let mut stall_deadline = Instant::now() + START_ALLOWANCE + stall_timeout;
    // Why this launch stopped, for its peers; `None` when a peer stopped it.
    let mut stop_reason = Some("the group stopped".to_owned());
    'supervise: loop {
        relay.drain(&lines);
        if stop.load(Ordering::Relaxed) {
            say.err("launch: stop requested; stopping the group");
            stop_reason = Some("stop requested (Ctrl-C or SIGTERM) on a peer".into());
            break;
        }
        if let Some(l) = &link {
            for event in l.events() {
                match event {
                    LinkEvent::Joined(role) => {
                        note(format!("launch: link: the {} joined again", role.name()))
                    }
                    LinkEvent::Refused { topic, why, count } => say.err(&format!(
                        "launch: link: warning: refused a {topic} sample from a peer: {why} \
                         ({count} refused so far)"
                    )),
                    LinkEvent::Left(role) => {
                        let lost = format!(
                            "link: the {}'s launch left the group (its host stopped, was killed \
                             or cannot be reached)",
                            role.name()
                        );
                        say.err(&format!("launch: {lost}; stopping the group"));
                        if role == Role::Controller
                            && children.iter().any(|c| c.spec.role == "bridge")
                        {
                            // As with a controller that dies on this host: a motion under way
                            // is braked by the bridge's watchdog, not cut short by the stop.
                            std::thread::sleep(watchdog_wall(file));
                        }
                        stop_reason = Some(lost.clone());
                        failure = Some(lost);
                        break 'supervise;
                    }
                    LinkEvent::Twice(role) => {
                        let twice = format!(
                            "link: another launch of group {:?} plays the {} too",
                            launch.link.group,
                            role.name()
                        );
                        say.err(&format!("launch: {twice}; stopping the group"));
                        stop_reason = Some(twice.clone());
                        failure = Some(twice);
                        break 'supervise;
                    }
                    LinkEvent::Stop { clean, reason } => {
                        say.err(&format!(
                            "launch: link: a peer stopped the group ({reason}); stopping"
                        ));
                        if !clean {
                            failure = Some(format!("a peer failed: {reason}"));
                        }
                        stop_reason = None;
                        break 'supervise;
                    }
                }
            }
        }
        let mut respawned = Vec::new();
        for i in 0..children.len() {
            let Some(status) = children[i]
                .child
                .try_wait()
                .context("cannot poll a child")?
            else {
                continue;
            };
            let role = children[i].spec.role;
            if role == "perception-sim" && status.success() {
                note("launch: perception-sim finished its episodes; stopping the group".into());
                children[i].status = Some(status);
                stop_reason = Some("perception-sim finished its episodes".into());
                break 'supervise;
            }
            let why = describe(status);
            if role == "bridge" && status.code() == Some(tes_bridge::process::LINK_DOWN_EXIT_STATUS)
            {
                // Respawning cannot bring a link back: the launch ends here.
                relay.drain_until_quiet(&lines);
                let cause = relay
                    .last_error(role)
                    .unwrap_or_else(|| "the link to the brick is down".to_owned());
                say.err(&format!(
                    "launch: bridge stopped: {cause}; stopping the others"
                ));
                children[i].status = Some(status);
                failure = Some(format!("bridge: {cause}"));
                break 'supervise;
            }
            let may_restart = launch.restart == Restart::OnFailure
                && !status.success()
                && children[i].restarts < launch.max_restarts;
            if !may_restart {
                relay.drain_until_quiet(&lines);
                let said = relay
                    .last_error(role)
                    .map(|e| format!(" ({e})"))
                    .unwrap_or_default();
                say.err(&format!("launch: {role} {why}{said}; stopping the others"));
                children[i].status = Some(status);
                failure = Some(format!("{role} {why}{said}"));
                break 'supervise;
            }
            children[i].restarts += 1;
            say.err(&format!(
                "launch: {role} {why}; respawning it (restart {}/{})",
                children[i].restarts, launch.max_restarts
            ));
            if let Err(e) = channel::clean_stale_resources() {
                say.err(&format!("launch: warning: {e}"));
            }
            children[i].child = spawn(&children[i].spec)?;
            respawned.push(role);
        }
        if record_polled.elapsed() >= RECORD_POLL {
            record_polled = Instant::now();
            relay.record.poll();
        }
        if let Some(v) = &mut view {
            if v.stop_asked() {
                stop.store(true, Ordering::Relaxed);
            }
            let processes: Vec<tui::ProcessRow> = children
                .iter()
                .map(|c| tui::ProcessRow {
                    role: c.spec.role,
                    pid: c.child.id(),
                    state: c.status.map_or("running".to_owned(), describe),
                    restarts: c.restarts,
                })
                .collect();
            let log = say.held_lines(50);
            let frame = tui::Frame {
                title: &title,
                episodes_planned: launch.episodes,
                budget_us: file.controller.budget_us,
                processes: &processes,
                record: &relay.record,
                log: &log,
                status: "",
            };
            if let Err(e) = v.draw_due(&frame) {
                view = None;
                say.release();
                say.err(&format!("launch: warning: the live view stopped: {e:#}"));
            }
        }
        // The stall watch: the controller's commands are the group's progress.
        watch.poll()?;
        for role in respawned {
            if let Some(r) = Role::ALL.into_iter().find(|r| r.name() == role) {
                watch.forget(r);
            }
            stall_deadline = Instant::now() + START_ALLOWANCE + stall_timeout;
        }
        let steps = watch.latest(Role::Controller).map(|p| p.steps);
        if steps.is_some() && steps != last_steps {
            last_steps = steps;
            stall_deadline = Instant::now() + stall_timeout;
        } else if Instant::now() > stall_deadline {
            let latest = Role::ALL.map(|r| watch.latest(r).copied());
            // Reports come every quarter second: a process silent for half the stall is the one.
            let quiet = (stall_timeout / 2).max(Duration::from_millis(600));
            let holdup = holdup(&latest, tes_runtime::clock::monotonic_ns(), quiet);
            let silent = format!(
                "the group made no progress for {:.1} s: {holdup}",
                stall_timeout.as_secs_f64()
            );
            let index = children
                .iter()
                .position(|c| c.spec.role == holdup.role.name());
            let may_restart = launch.restart == Restart::OnFailure
                && index.is_some_and(|i| children[i].restarts < launch.max_restarts);
            match index {
                Some(i) if may_restart => {
                    say.err(&format!("launch: {silent}; restarting it"));
                    // Killed here, respawned by the loop above like any failed child.
                    let _ = children[i].child.kill();
                    stall_deadline = Instant::now() + START_ALLOWANCE + stall_timeout;
                }
                _ => {
                    say.err(&format!("launch: {silent}; stopping the group"));
                    failure = Some(silent);
                    break 'supervise;
                }
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // The terminal is the user's again: the shutdown and the summary are printed.
    drop(view);
    say.release();
    // The peers stop too, told why: cleanly unless something failed here.
    if let (Some(l), Some(reason)) = (&link, &stop_reason) {
        match &failure {
            Some(f) => l.send_stop(false, f),
            None => l.send_stop(true, reason),
        }
    }
    shutdown(&mut children, grace);
    // Every child has exited; take what they wrote last (the controller reports its last
    // episode and its summary on the way out).
    following.store(true, Ordering::Release);
    let deadline = Instant::now() + Duration::from_secs(2);
    while let Ok(line) = lines.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        relay.take(line);
    }
    let episodes = relay.episodes;
    if let Some(mut l) = link.take() {
        note(format!("launch: link: from peers {}", l.counts()));
        l.close();
    }
    let drawn = relay.record.finish();
    let mut failed: Vec<String> = failure.into_iter().collect();
    if let Some(r) = recorder {
        match crate::record::finish(r) {
            Ok(line) => note(line),
            Err(e) => failed.push(format!("recorder: {e:#}")),
        }
    }
    for c in &children {
        match c.status {
            Some(s) if !s.success() && !stopped_by_us(s) => {
                let line = format!("{} {}", c.spec.role, describe(s));
                if !failed
                    .iter()
                    .any(|f| f.starts_with(c.spec.role) || *f == line)
                {
                    failed.push(line);
                }
            }
            _ => {}
        }
    }
    if echo {
        let default_library = tes_controller::config::default_library_path();
        match &drawn {
            Ok(pictures) => {
                say.out(&format!("launch: run folder {}", run_dir.display()));
                let names: Vec<String> = pictures
                    .iter()
                    .filter_map(|p| p.file_name())
                    .map(|n| n.to_string_lossy().into_owned())
                    .collect();
                say.out(&format!(
                    "launch: see the run in {} there (pictures), and episodes.csv and \
                     trajectory.csv (one row per episode, per action)",
                    names.join(", ")
                ));
            }
            Err(e) => say.err(&format!(
                "launch: warning: the run folder {} is incomplete: {e:#}",
                run_dir.display()
            )),
        }
        // The library is the controller's: a launch without it says nothing of it.
        if report.is_some() {
            let end = LibraryOutcome::read(report.as_deref(), &library, library_at_start);
            for line in end.lines(&library, &default_library) {
                say.out(&line);
            }
        }

        say.out(&format!(
            "launch: {episodes} episodes; {}",
            if failed.is_empty() {
                "all processes stopped cleanly".to_owned()
            } else {
                format!("failed: {}", failed.join("; "))
            }
        ));
    }
    if !failed.is_empty() {
        bail!("a process failed: {}", failed.join("; "));
    }
    Ok(GroupOutcome { episodes })
}

/// Relays the children's lines: standard output (episode lines, summaries) to the launcher's
/// standard output when echoing, logs to its standard error; keeps each child's last log lines.
struct Relay<'a> {
    echo: bool,
    say: &'a logs::Say,
    last_words: BTreeMap<&'static str, VecDeque<String>>,
    /// Episode lines seen.
    episodes: u32,
    /// The run folder's records, fed the controller's lines.
    record: run_record::RunRecord,
}

/// How often the launcher reads the trajectory perception writes.
const RECORD_POLL: Duration = Duration::from_millis(250);

impl Relay<'_> {
    fn take(&mut self, line: ChildLine) {
        match line.stream {
            logs::Stream::Out => {
                if line.role == "controller" && line.text.starts_with("episode ") {
                    self.episodes += 1;
                    self.record.controller_line(&line.text);
                }
                if self.echo {
                    self.say.out(&line.text);
                }
            }
            logs::Stream::Log => {
                self.say.err(&line.text);
                let kept = self.last_words.entry(line.role).or_default();
                if kept.len() == LAST_WORDS {
                    kept.pop_front();
                }
                kept.push_back(line.text);
            }
        }
    }

    /// Takes every line that has arrived.
    fn drain(&mut self, lines: &mpsc::Receiver<ChildLine>) {
        for line in lines.try_iter() {
            self.take(line);
        }
    }

    /// Takes lines until none has come for a moment (a child that just died may still have
    /// its last words on their way from its files).
    fn drain_until_quiet(&mut self, lines: &mpsc::Receiver<ChildLine>) {
        while let Ok(line) = lines.recv_timeout(Duration::from_millis(50)) {
            self.take(line);
        }
    }

    /// The last error line `role` logged (else its last line), without a log line's
    /// timestamp and level.
    fn last_error(&self, role: &str) -> Option<String> {
        let kept = self.last_words.get(role)?;
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

/// The controller's report in the run directory, when the launch file sets none.
pub(crate) const CONTROLLER_REPORT: &str = "controller-report.json";

/// Where the controller of `spec` writes its summary (as JSON) at exit: the `report` its
/// settings set, else [`CONTROLLER_REPORT`] in `run_dir`, which is then added to its
/// settings file.
fn controller_report(spec: &ChildSpec, run_dir: &Path) -> Result<PathBuf> {
    let text = std::fs::read_to_string(&spec.config)
        .with_context(|| format!("cannot read {}", spec.config.display()))?;
    let mut config = ControllerConfig::from_toml_in(&text, Origin::File(spec.config.clone()))?;
    if let Some(path) = &config.report {
        return Ok(path.clone());
    }
    let path = run_dir.join(CONTROLLER_REPORT);
    config.report = Some(path.clone());
    let text = toml::to_string(&config).context("cannot write the controller's settings")?;
    std::fs::write(&spec.config, text)
        .with_context(|| format!("cannot write {}", spec.config.display()))?;
    Ok(path)
}

/// Which file is at a path: its inode, length and modification time (an atomic save
/// replaces the inode).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Fingerprint {
    inode: u64,
    len: u64,
    modified: Option<std::time::SystemTime>,
}

impl Fingerprint {
    /// The file at `path`, or `None` if there is none (or it cannot be looked at).
    pub(crate) fn of(path: &Path) -> Option<Self> {
        use std::os::unix::fs::MetadataExt;
        let meta = std::fs::metadata(path).ok()?;
        Some(Self {
            inode: meta.ino(),
            len: meta.len(),
            modified: meta.modified().ok(),
        })
    }
}

/// What the end of a launch says about the view library.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum LibraryOutcome {
    /// The controller reported what it loaded and what became of the file.
    Reported(tes_controller::summary::LibraryFacts),
    /// The controller ended before it loaded the library (before the world map came).
    NotLoaded,
    /// The controller did not report (it failed or was killed): what the file is now against
    /// what it was at the start.
    Unreported {
        /// The file's fingerprint at the start.
        at_start: Option<Fingerprint>,
        /// Its fingerprint now.
        now: Option<Fingerprint>,
        /// What it holds now, if it changed and loads (else why not).
        holds: Option<std::result::Result<tes_controller::summary::LibraryCounts, String>>,
    },
}

impl LibraryOutcome {
    /// Reads the controller's report at `report` (if the launcher knows one), falling back on
    /// comparing the library file at `library` with its fingerprint at the start.
    pub(crate) fn read(
        report: Option<&Path>,
        library: &Path,
        at_start: Option<Fingerprint>,
    ) -> Self {
        let summary = report
            .and_then(|p| std::fs::read_to_string(p).ok())
            .and_then(|t| {
                serde_json::from_str::<tes_controller::summary::ControllerSummary>(&t).ok()
            });
        match summary {
            Some(s) => s.library.map_or(Self::NotLoaded, Self::Reported),
            None => {
                let now = Fingerprint::of(library);
                let holds = (now.is_some() && now != at_start).then(|| {
                    tes_learning::library::store::load(library)
                        .map(|s| tes_controller::summary::LibraryCounts::of(&s.library))
                        .map_err(|e| e.to_string())
                });
                Self::Unreported {
                    at_start,
                    now,
                    holds,
                }
            }
        }
    }

    /// The launcher's lines: the library's facts, then how to see its views (when there is a
    /// file to see; `tes library show` alone when it is the `default` library).
    pub(crate) fn lines(&self, library: &Path, default: &Path) -> Vec<String> {
        let shown = library.display();
        let not_saved = "not saved (the controller did not finish)";
        let mut lines = vec![match self {
            Self::Reported(facts) => format!("launch: {facts}"),
            Self::NotLoaded => format!(
                "launch: library {shown}: not loaded (the controller stopped before the world \
                 map came); left as it was"
            ),
            Self::Unreported {
                at_start,
                now,
                holds,
            } => match (at_start, now, holds) {
                (None, None, _) => {
                    format!("launch: library {shown}: {not_saved}; there is still no library file")
                }
                (_, None, _) => format!("launch: library {shown}: {not_saved}; the file is gone"),
                (a, b, _) if a == b => {
                    format!("launch: library {shown}: {not_saved}; left as it was")
                }
                (_, _, Some(Ok(counts))) => format!(
                    "launch: library {shown}: {not_saved}; saved after an episode of the run, \
                     it holds {counts}"
                ),
                (_, _, Some(Err(e))) => {
                    format!(
                        "launch: library {shown}: {not_saved}; it changed and does not load: {e}"
                    )
                }
                (_, _, None) => format!("launch: library {shown}: {not_saved}"),
            },
        }];
        if std::fs::metadata(library).is_ok_and(|m| m.is_file()) {
            lines.push(if library == default {
                "launch: see its views with `tes library show`".to_owned()
            } else {
                format!("launch: see its views with `tes library show {shown}`")
            });
        }
        lines
    }
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

/// Opens the link of a launch playing `local` and waits until every other role's launch is
/// there (at most `[launch.link] peer_timeout_ms`), saying whom it waits for.
fn open_link(
    file: &LaunchFile,
    local: &[Role],
    names: &ServiceNames,
    stop: &AtomicBool,
    say: &logs::Say,
    echo: bool,
) -> Result<Link> {
    let settings = &file.launch.link;
    let link = Link::open(settings, local, names).context("nothing was started")?;
    let list = |roles: &[Role]| {
        roles
            .iter()
            .map(|r| r.name())
            .collect::<Vec<_>>()
            .join(", ")
    };
    if echo {
        say.err(&format!(
            "launch: link: this launch plays {} in group {:?} (Zenoh {:?}, id {}, listen {:?}, \
             connect {:?})",
            list(local),
            settings.group,
            settings.mode,
            link.zid(),
            settings.listen,
            settings.connect
        ));
    }
    let timeout = Duration::from_millis(settings.peer_timeout_ms);
    let start = Instant::now();
    let mut said = Instant::now() - Duration::from_secs(10);
    loop {
        for event in link.events() {
            match event {
                LinkEvent::Twice(role) => bail!(
                    "two launches of group {:?} play the {}: give each role to one launch; \
                     nothing was started",
                    settings.group,
                    role.name()
                ),
                LinkEvent::Stop { reason, .. } => bail!(
                    "a peer stopped the group while this launch waited ({reason}); nothing \
                     was started"
                ),
                LinkEvent::Joined(role) if echo => {
                    say.err(&format!("launch: link: the {} is there", role.name()))
                }
                _ => {}
            }
        }
        let missing = link.missing();
        if missing.is_empty() {
            return Ok(link);
        }
        if stop.load(Ordering::Relaxed) {
            bail!(
                "stop requested while waiting for the {}; nothing was started",
                list(&missing)
            );
        }
        if start.elapsed() >= timeout {
            bail!(
                "no launch of group {:?} playing the {} was reached within {:.1} s \
                 ([launch.link] peer_timeout_ms): is it started, with the same group, and can \
                 this host reach it (listen {:?}, connect {:?})?; nothing was started",
                settings.group,
                list(&missing),
                timeout.as_secs_f64(),
                settings.listen,
                settings.connect
            );
        }
        if echo && said.elapsed() >= Duration::from_secs(5) {
            said = Instant::now();
            say.err(&format!(
                "launch: link: waiting for the {} (group {:?}; gives up after {:.0} s)",
                list(&missing),
                settings.group,
                timeout.as_secs_f64()
            ));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The run directory a child's settings are in (its output goes there too).
fn run_dir_of(spec: &ChildSpec) -> PathBuf {
    spec.config
        .parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
}

/// Starts one child: this executable in the child's role, dying with the launcher; its
/// output goes to its files in the run directory (see [`logs`]).
pub(crate) fn spawn(spec: &ChildSpec) -> Result<Child> {
    let exe = std::env::current_exe().context("cannot find the tes executable")?;
    let (out, log) = logs::open(&run_dir_of(spec), spec.role)?;
    let mut cmd = Command::new(exe);
    cmd.arg("child")
        .arg(spec.role)
        .arg("--config")
        .arg(&spec.config)
        .stdin(Stdio::null())
        .stdout(Stdio::from(out))
        .stderr(Stdio::from(log));
    // SAFETY: `pre_exec` runs in the forked child before exec; prctl(PR_SET_PDEATHSIG) is
    // async-signal-safe and touches no memory of the parent.
    unsafe {
        cmd.pre_exec(|| {
            nix::sys::prctl::set_pdeathsig(Signal::SIGTERM).map_err(std::io::Error::from)
        });
    }
    cmd.spawn().map_err(|e| {
        anyhow::anyhow!(
            "cannot start {}: {}",
            spec.role,
            tes_runtime::cause::explain(&e)
        )
    })
}

/// SIGINT, then SIGTERM after `grace`, then SIGKILL after `grace`; waits for every child.
pub(crate) fn shutdown(children: &mut [Running], grace: Duration) {
    for signal in [Signal::SIGINT, Signal::SIGTERM, Signal::SIGKILL] {
        let mut any = false;
        for c in children.iter_mut() {
            if c.status.is_none() {
                if let Ok(Some(s)) = c.child.try_wait() {
                    c.status = Some(s);
                    continue;
                }
                let pid = Pid::from_raw(c.child.id() as i32);
                if kill(pid, signal).is_ok() {
                    any = true;
                }
            }
        }
        if !any {
            break;
        }
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            let mut alive = false;
            for c in children.iter_mut() {
                if c.status.is_none() {
                    match c.child.try_wait() {
                        Ok(Some(s)) => c.status = Some(s),
                        _ => alive = true,
                    }
                }
            }
            if !alive {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        for c in children.iter() {
            if c.status.is_none() && signal != Signal::SIGKILL {
                eprintln!(
                    "launch: {} did not stop within {grace:?} of {signal}; escalating",
                    c.spec.role
                );
            }
        }
    }
    for c in children.iter_mut() {
        if c.status.is_none() {
            c.status = c.child.wait().ok();
        }
    }
}

/// Whether `status` is an exit the shutdown itself caused (SIGINT/SIGTERM handled by a
/// child that then exited by that signal).
pub(crate) fn stopped_by_us(status: ExitStatus) -> bool {
    use std::os::unix::process::ExitStatusExt;
    matches!(status.signal(), Some(s) if s == Signal::SIGINT as i32 || s == Signal::SIGTERM as i32)
}

/// "exited with status 3" / "was killed by SIGKILL".
pub(crate) fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(code), _) => format!("exited with status {code}"),
        (None, Some(sig)) => match Signal::try_from(sig) {
            Ok(s) => format!("was killed by {s}"),
            Err(_) => format!("was killed by signal {sig}"),
        },
        _ => "ended".to_owned(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_controller::summary::{ControllerSummary, LibraryCounts, LibraryEnd, LibraryFacts};
    use tes_learning::library::store::{self, StoredLibrary};
    use tes_learning::library::{LibraryParams, ViewLibrary};

    fn save_empty_library(path: &Path) {
        let stored = StoredLibrary {
            library: ViewLibrary::new(3, 20, 312, LibraryParams::default()).expect("library"),
            world: "arena 3".into(),
            action_names: Vec::new(),
            feature_names: Vec::new(),
        };
        store::save(path, &stored).expect("saved");
    }

    /// With the controller's report, the end says its facts and how to see the views (the
    /// short command for the default library).
    #[test]
    fn the_end_states_the_controllers_facts_and_what_to_look_at_next() {
        let dir = tempfile::tempdir().expect("temp dir");
        let library = dir.path().join("library.tesl");
        save_empty_library(&library);
        let report = dir.path().join(CONTROLLER_REPORT);
        let facts = LibraryFacts {
            path: library.display().to_string(),
            started_empty: false,
            before: LibraryCounts { views: 9, tasks: 3 },
            after: LibraryCounts {
                views: 11,
                tasks: 4,
            },
            end: LibraryEnd::Saved,
        };
        let summary = ControllerSummary {
            library: Some(facts.clone()),
            ..ControllerSummary::default()
        };
        std::fs::write(&report, serde_json::to_string(&summary).expect("json")).expect("report");
        let end = LibraryOutcome::read(Some(&report), &library, None);
        assert_eq!(end, LibraryOutcome::Reported(facts));
        let shown = library.display();
        assert_eq!(
            end.lines(&library, &library),
            [
                format!("launch: library {shown}: 9 views, 3 tasks -> 11 views, 4 tasks (saved)"),
                "launch: see its views with `tes library show`".to_owned()
            ]
        );
        let elsewhere = dir.path().join("default.tesl");
        assert_eq!(
            end.lines(&library, &elsewhere)[1],
            format!("launch: see its views with `tes library show {shown}`")
        );

        // A report of a controller that stopped before the map came.
        std::fs::write(
            &report,
            serde_json::to_string(&ControllerSummary::default()).expect("json"),
        )
        .expect("report");
        let end = LibraryOutcome::read(Some(&report), &library, None);
        assert_eq!(end, LibraryOutcome::NotLoaded);
        assert!(end.lines(&library, &library)[0].ends_with("left as it was"));
    }

    /// Without a report (the controller failed or was killed), the end still says only what
    /// is true: no file, the file as it was, or the file saved during the run, with its counts.
    #[test]
    fn without_a_report_the_end_compares_the_file_with_the_start() {
        let dir = tempfile::tempdir().expect("temp dir");
        let library = dir.path().join("library.tesl");
        let missing = dir.path().join(CONTROLLER_REPORT);
        let not_saved = "not saved (the controller did not finish)";

        let end = LibraryOutcome::read(Some(&missing), &library, None);
        let lines = end.lines(&library, &library);
        assert_eq!(lines.len(), 1, "no file, nothing to show: {lines:?}");
        assert!(
            lines[0].contains(not_saved) && lines[0].ends_with("there is still no library file"),
            "{lines:?}"
        );

        save_empty_library(&library);
        let at_start = Fingerprint::of(&library);
        let end = LibraryOutcome::read(None, &library, at_start);
        let lines = end.lines(&library, &library);
        assert!(
            lines[0].contains(not_saved) && lines[0].ends_with("left as it was"),
            "{lines:?}"
        );
        assert_eq!(lines.len(), 2, "{lines:?}");

        // Saved again (a new file replaces the old one): the run changed it.
        save_empty_library(&library);
        let end = LibraryOutcome::read(Some(&missing), &library, at_start);
        let lines = end.lines(&library, &library);
        assert!(
            lines[0].ends_with("saved after an episode of the run, it holds 0 views, 0 tasks"),
            "{lines:?}"
        );
        // Something that is not a file there: nothing to show.
        let directory = dir.path().join("directory.tesl");
        std::fs::create_dir(&directory).expect("dir");
        let at_start = Fingerprint::of(&directory);
        let lines = LibraryOutcome::read(None, &directory, at_start).lines(&directory, &directory);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].ends_with("left as it was"), "{lines:?}");
        // A report that is not one is no report.
        std::fs::write(&missing, "not json").expect("write");
        assert!(matches!(
            LibraryOutcome::read(Some(&missing), &library, None),
            LibraryOutcome::Unreported { .. }
        ));
    }

    /// The launcher adds the report to the controller's settings when they set none, and
    /// keeps one they set.
    #[test]
    fn the_controller_reports_into_the_run_directory_unless_told_elsewhere() {
        let dir = tempfile::tempdir().expect("temp dir");
        let config = dir.path().join("controller.toml");
        let write = |c: &ControllerConfig| {
            std::fs::write(&config, toml::to_string(c).expect("toml")).expect("settings");
        };
        let spec = ChildSpec {
            role: "controller",
            config: config.clone(),
        };
        let base = ControllerConfig {
            service_prefix: "x/".into(),
            ..ControllerConfig::default()
        };
        write(&base);
        let path = controller_report(&spec, dir.path()).expect("report path");
        assert_eq!(path, dir.path().join(CONTROLLER_REPORT));
        let text = std::fs::read_to_string(&config).expect("settings");
        let read = ControllerConfig::from_toml_in(&text, Origin::File(config.clone()))
            .expect("valid settings");
        assert_eq!(
            read,
            ControllerConfig {
                report: Some(path),
                ..base.clone()
            }
        );

        let own = dir.path().join("mine.json");
        write(&ControllerConfig {
            report: Some(own.clone()),
            ..base
        });
        assert_eq!(
            controller_report(&spec, dir.path()).expect("report path"),
            own
        );
    }
}
