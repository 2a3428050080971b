//! How the launcher speaks: the line printer, an [`Observer`] of the supervisor's events that
//! prints each as the line `tes launch` has always printed, on standard output (episode
//! lines, the summary, the end) or standard error (notes, warnings, the children's logs).

use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use tes_launch::event::{Event, ExitConsequence, Observer};
use tes_launch::supervisor::role_list;

/// Which of the launcher's outputs a line goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum To {
    /// Standard output.
    Out,
    /// Standard error.
    Err,
}

/// The lines `event` is said as; `echo` off (a launch run for its files, as the benchmark
/// does) keeps only warnings, failures and the children's logs.
pub(crate) fn lines_of(event: &Event, echo: bool) -> Vec<(To, String)> {
    let (to, line, always) = match event {
        Event::StaleResourcesRemoved { processes } => (
            To::Err,
            format!("launch: removed the stale iceoryx2 resources of {processes} dead processes"),
            false,
        ),
        Event::Warning(w) => (To::Err, format!("launch: warning: {w}"), true),
        Event::Planned {
            arena,
            episodes,
            real_time_factor,
            wait,
            restart,
            service_prefix,
            run_dir,
        } => (
            To::Err,
            format!(
                "launch: arena Env {arena}, {episodes} episodes, real-time factor \
                 {real_time_factor}, wait {wait}, restart {restart:?}, services \
                 {service_prefix}*, run folder {}",
                run_dir.display()
            ),
            false,
        ),
        Event::RunFoldersPruned { removed, keep } => (
            To::Err,
            format!("launch: removed the {removed} oldest run folders (keep_runs = {keep})"),
            false,
        ),
        Event::LinkOpened { .. }
        | Event::LinkWaiting { .. }
        | Event::LinkUp { .. }
        | Event::LinkRefused { .. }
        | Event::LinkDown { .. }
        | Event::LinkTwice { .. }
        | Event::PeerStopped { .. }
        | Event::LinkClosed(_) => return link_lines(event, echo),
        Event::LibraryAtStart { path, exists } => (
            To::Err,
            if *exists {
                format!("launch: view library {}", path.display())
            } else {
                format!(
                    "launch: no view library at {}; the controller starts from an empty one",
                    path.display()
                )
            },
            false,
        ),
        Event::Recording { path } => (
            To::Err,
            format!("launch: recording to {}", path.display()),
            false,
        ),
        Event::EpisodeEnded { text, .. } | Event::Output { text, .. } => {
            (To::Out, text.clone(), false)
        }
        Event::Log { text, .. } => (To::Err, text.clone(), true),
        Event::StopRequested => (
            To::Err,
            "launch: stop requested; stopping the group".into(),
            true,
        ),
        Event::ProcessExited {
            role,
            how,
            said,
            then,
        } => exit_line(*role, how, said.as_deref(), *then),
        Event::Stalled {
            silent_for,
            holder,
            why,
            restarting,
        } => (
            To::Err,
            format!(
                "launch: the group made no progress for {:.1} s: {} {why}; {}",
                silent_for.as_secs_f64(),
                holder.name(),
                if *restarting {
                    "restarting it"
                } else {
                    "stopping the group"
                }
            ),
            true,
        ),
        Event::Escalated(e) => (
            To::Err,
            format!(
                "launch: {} did not stop within {:?} of {}; escalating",
                e.process, e.grace, e.signal
            ),
            true,
        ),
        Event::Recorded(recorded) => (To::Err, format!("launch: {recorded}"), false),
        Event::RunFolder { dir, drawn } => return run_folder_lines(dir, drawn, echo),
        Event::LibraryAtEnd { path, outcome } => {
            let default = tes_controller::config::default_library_path();
            let lines = outcome.lines(path, &default);
            return if echo {
                lines.into_iter().map(|l| (To::Out, l)).collect()
            } else {
                Vec::new()
            };
        }
        Event::Verdict(v) => (
            To::Out,
            format!(
                "launch: {} episodes; {}",
                v.episodes,
                if v.failures.is_empty() {
                    "all processes stopped cleanly".to_owned()
                } else {
                    format!("failed: {}", v.failures.join("; "))
                }
            ),
            false,
        ),
        Event::EpisodeRecorded(_)
        | Event::RobotMoved(_)
        | Event::Progress { .. }
        | Event::ProcessStarted { .. }
        | Event::ProcessRestarted { .. } => return Vec::new(),
    };
    if echo || always {
        vec![(to, line)]
    } else {
        Vec::new()
    }
}

/// The line of a child that exited on its own, by what the supervisor does about it.
fn exit_line(
    role: tes_topics::Role,
    how: &str,
    said: Option<&str>,
    then: ExitConsequence,
) -> (To, String, bool) {
    let line = match then {
        ExitConsequence::Finished => {
            return (
                To::Err,
                "launch: perception-sim finished its episodes; stopping the group".into(),
                false,
            );
        }
        ExitConsequence::Restart { restart, max } => {
            format!("launch: {role} {how}; respawning it (restart {restart}/{max})")
        }
        ExitConsequence::LinkDown => format!(
            "launch: bridge stopped: {}; stopping the others",
            said.unwrap_or("the link to the brick is down")
        ),
        ExitConsequence::StopGroup => {
            let said = said.map(|e| format!(" ({e})")).unwrap_or_default();
            format!("launch: {role} {how}{said}; stopping the others")
        }
    };
    (To::Err, line, true)
}

/// The lines of the link's events.
fn link_lines(event: &Event, echo: bool) -> Vec<(To, String)> {
    let (line, always) = match event {
        Event::LinkOpened {
            local,
            group,
            mode,
            zid,
            listen,
            connect,
        } => (
            format!(
                "launch: link: this launch plays {} in group {group:?} (Zenoh {mode:?}, id \
                 {zid}, listen {listen:?}, connect {connect:?})",
                role_list(local)
            ),
            false,
        ),
        Event::LinkWaiting {
            missing,
            group,
            timeout,
        } => (
            format!(
                "launch: link: waiting for the {} (group {group:?}; gives up after {:.0} s)",
                role_list(missing),
                timeout.as_secs_f64()
            ),
            false,
        ),
        Event::LinkUp { role, again: false } => {
            (format!("launch: link: the {role} is there"), false)
        }
        Event::LinkUp { role, again: true } => {
            (format!("launch: link: the {role} joined again"), false)
        }
        Event::LinkRefused { topic, why, count } => (
            format!(
                "launch: link: warning: refused a {topic} sample from a peer: {why} ({count} \
                 refused so far)"
            ),
            true,
        ),
        Event::LinkDown { role } => (
            format!(
                "launch: link: the {role}'s launch left the group (its host stopped, was \
                 killed or cannot be reached); stopping the group"
            ),
            true,
        ),
        Event::LinkTwice { group, role } => (
            format!(
                "launch: link: another launch of group {group:?} plays the {role} too; \
                 stopping the group"
            ),
            true,
        ),
        Event::PeerStopped { reason, .. } => (
            format!("launch: link: a peer stopped the group ({reason}); stopping"),
            true,
        ),
        Event::LinkClosed(counts) => (format!("launch: link: from peers {counts}"), false),
        _ => return Vec::new(),
    };
    if echo || always {
        vec![(To::Err, line)]
    } else {
        Vec::new()
    }
}

/// Where the run folder is and what to open in it, or why it is incomplete.
fn run_folder_lines(
    dir: &Path,
    drawn: &Result<Vec<std::path::PathBuf>, String>,
    echo: bool,
) -> Vec<(To, String)> {
    if !echo {
        return Vec::new();
    }
    match drawn {
        Ok(pictures) => {
            let names: Vec<String> = pictures
                .iter()
                .filter_map(|p| p.file_name())
                .map(|n| n.to_string_lossy().into_owned())
                .collect();
            vec![
                (To::Out, format!("launch: run folder {}", dir.display())),
                (
                    To::Out,
                    format!(
                        "launch: see the run in {} there (pictures), and episodes.csv and \
                         trajectory.csv (one row per episode, per action)",
                        names.join(", ")
                    ),
                ),
            ]
        }
        Err(e) => vec![(
            To::Err,
            format!(
                "launch: warning: the run folder {} is incomplete: {e}",
                dir.display()
            ),
        )],
    }
}

/// The line printer: says each event's lines through [`Say`].
#[derive(Debug, Default)]
pub(crate) struct Printer {
    /// Where the lines go.
    pub(crate) say: Say,
    /// Whether the launcher's own notes are printed (else only warnings and failures).
    pub(crate) echo: bool,
}

impl Observer for Printer {
    fn event(&mut self, event: &Event) {
        for (to, line) in lines_of(event, self.echo) {
            match to {
                To::Out => self.say.out(&line),
                To::Err => self.say.err(&line),
            }
        }
    }
}

/// The launcher's own output, which must never end the launch: a closed terminal or pipe
/// (`tes launch | head -2`) only silences it, and the group runs to its end.
#[derive(Debug, Default)]
pub(crate) struct Say {
    out_closed: AtomicBool,
    /// While a live view owns the terminal: the lines said, newest last, instead of printed.
    held: std::sync::Mutex<Option<std::collections::VecDeque<String>>>,
}

/// How many lines [`Say::hold`] keeps.
const HELD_LINES: usize = 500;

impl Say {
    /// Keeps what is said from now on (the last [`HELD_LINES`]) instead of printing it: the
    /// terminal belongs to the live view.
    pub(crate) fn hold(&self) {
        if let Ok(mut held) = self.held.lock() {
            held.get_or_insert_with(Default::default);
        }
    }

    /// Prints what is said again (the held lines are dropped: the run folder has them).
    pub(crate) fn release(&self) {
        if let Ok(mut held) = self.held.lock() {
            *held = None;
        }
    }

    /// The last `n` held lines, oldest first.
    pub(crate) fn held_lines(&self, n: usize) -> Vec<String> {
        match self.held.lock() {
            Ok(held) => held.as_ref().map_or_else(Vec::new, |h| {
                h.iter().skip(h.len().saturating_sub(n)).cloned().collect()
            }),
            Err(_) => Vec::new(),
        }
    }

    /// Whether `line` was held (and so must not be printed).
    fn held(&self, line: &str) -> bool {
        let Ok(mut held) = self.held.lock() else {
            return false;
        };
        let Some(held) = held.as_mut() else {
            return false;
        };
        if held.len() == HELD_LINES {
            held.pop_front();
        }
        held.push_back(line.to_owned());
        true
    }

    /// Prints `line` on standard output (nothing once that is closed).
    pub(crate) fn out(&self, line: &str) {
        if self.held(line) {
            return;
        }
        if !self.out_closed.load(Ordering::Relaxed) {
            let mut out = std::io::stdout().lock();
            if writeln!(out, "{line}").and_then(|()| out.flush()).is_err() {
                self.out_closed.store(true, Ordering::Relaxed);
            }
        }
    }

    /// Prints `line` on standard error (errors ignored: there is nowhere else to say them).
    pub(crate) fn err(&self, line: &str) {
        if self.held(line) {
            return;
        }
        let _ = writeln!(std::io::stderr().lock(), "{line}");
    }
}
