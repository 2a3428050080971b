//! How the launcher speaks: the line printer, an [`Observer`] of the supervisor's events that
//! prints each as the line `tes launch` has always printed, on standard output (episode
//! lines, the summary, the end) or standard error (notes, warnings, the children's logs).

use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use tes_launch::event::{Event, ExitConsequence, Observer};
use tes_launch::supervisor::role_list;
use tes_link::Security;

/// Which of the launcher's outputs a line goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum To {
    /// Standard output.
    Out,
    /// Standard error.
    Err,
}

/// One line of the launcher: where it goes, and whether it is said even when not echoing
/// (warnings, failures, the children's logs).
struct Said {
    to: To,
    line: String,
    always: bool,
}

/// A note on standard error, said only when echoing.
fn note(line: String) -> Option<Said> {
    Some(Said {
        to: To::Err,
        line,
        always: false,
    })
}

/// A warning or failure on standard error, always said.
fn warn(line: String) -> Option<Said> {
    Some(Said {
        to: To::Err,
        line,
        always: true,
    })
}

/// A line on standard output, said only when echoing.
fn out(line: String) -> Option<Said> {
    Some(Said {
        to: To::Out,
        line,
        always: false,
    })
}

/// The lines `event` is said as; `echo` off (a launch run for its files, as the benchmark
/// does) keeps only warnings, failures and the children's logs.
pub(crate) fn lines_of(event: &Event, echo: bool) -> Vec<(To, String)> {
    let said = match event {
        Event::RunFolder { dir, drawn } => return run_folder_lines(dir, drawn, echo),
        Event::LinkTimed(report) => out(brick_link_line(report)),
        Event::LibraryAtEnd { path, outcome } => {
            let default = tes_controller::config::default_library_path();
            return match echo {
                true => outcome
                    .lines(path, &default)
                    .into_iter()
                    .map(|l| (To::Out, l))
                    .collect(),
                false => Vec::new(),
            };
        }
        Event::LinkOpened { .. }
        | Event::LinkWaiting { .. }
        | Event::LinkUp { .. }
        | Event::LinkRefused { .. }
        | Event::LinkDenied(_)
        | Event::LinkDown { .. }
        | Event::LinkTwice { .. }
        | Event::PeerStopped { .. }
        | Event::LinkClosed(_) => link_line(event),
        Event::ProcessExited { .. }
        | Event::Stalled { .. }
        | Event::Escalated(_)
        | Event::WaitedForSave(_)
        | Event::StopRequested
        | Event::Log { .. } => process_line(event),
        _ => run_line(event),
    };
    match said {
        Some(s) if echo || s.always => vec![(s.to, s.line)],
        _ => Vec::new(),
    }
}

/// The group on ROS 2: where its node is reachable (a warning beyond this host) and its bag.
fn ros2_line(started: &tes_launch::ros2::Ros2Started) -> Option<Said> {
    let mut line = match &started.reach {
        Some(reach) => format!("launch: on ROS 2 as node /tes/group, {reach}"),
        None => "launch: not on ROS 2 (no --ros2)".to_owned(),
    };
    if let Some(bag) = &started.bag {
        line.push_str(&format!(
            "; writing its topics to the rosbag2 bag {}",
            bag.display()
        ));
    }
    if started.beyond_this_host {
        warn(format!("{line}; WARNING: peers on the network see the run"))
    } else {
        note(line)
    }
}

/// The lines of the run as a whole: its plan, its library and recording, its episodes and
/// its end.
fn run_line(event: &Event) -> Option<Said> {
    match event {
        Event::StaleResourcesRemoved { processes } => note(format!(
            "launch: removed the stale iceoryx2 resources of {processes} dead processes"
        )),
        Event::Warning(w) => warn(format!("launch: warning: {w}")),
        Event::Planned {
            world,
            episodes,
            real_time_factor,
            wait,
            restart,
            service_prefix,
            run_dir,
        } => note(format!(
            "launch: {world}, {}, real-time factor {real_time_factor}, wait {wait}, \
             restart {restart}, services {service_prefix}*, run folder {}",
            count(u64::from(*episodes), "episode"),
            run_dir.display()
        )),
        Event::RunFoldersPruned { removed, keep } => note(format!(
            "launch: removed the {removed} oldest run folders (keep_runs = {keep})"
        )),
        Event::LibraryAtStart { path, exists: true } => {
            note(format!("launch: view library {}", path.display()))
        }
        Event::LibraryAtStart {
            path,
            exists: false,
        } => note(format!(
            "launch: no view library at {}; the controller starts from an empty one",
            path.display()
        )),
        Event::Recording { path } => note(format!("launch: recording to {}", path.display())),
        Event::Foxglove { addr, exposed } => {
            let line = format!(
                "launch: live in Foxglove at ws://{addr} (Open connection → Foxglove WebSocket)"
            );
            if *exposed {
                warn(format!(
                    "{line}; WARNING: {} is not loopback: anyone who reaches it sees the run",
                    addr.ip()
                ))
            } else {
                note(line)
            }
        }
        Event::Ros2(started) => ros2_line(started),
        Event::Ros2Done(done) => note(format!("launch: {done}")),
        Event::EpisodeEnded { text, .. } | Event::Output { text, .. } => out(text.clone()),
        Event::Recorded(recorded) => note(format!("launch: {recorded}")),
        Event::Verdict(v) if v.failures.is_empty() => out(format!(
            "launch: {}; all processes stopped cleanly",
            v.length()
        )),
        Event::Verdict(v) => out(format!(
            "launch: {}; failed: {}",
            v.length(),
            v.failures.join("; ")
        )),
        _ => None,
    }
}

/// The bridge's link: its round trips, and what each command took of the run and of the link.
fn brick_link_line(report: &tes_launch::event::BridgeReport) -> String {
    let mut line = format!("launch: {}", report.link);
    if let Some((each, on_link)) = report.per_command_us() {
        use tes_launch::event::in_words;
        line += &format!(
            "; per command {} of the run, {} of it on the link",
            in_words(each),
            in_words(on_link)
        );
    }
    line
}

/// `n` and `noun`, plural unless `n` is 1: "1 episode", "20 episodes".
fn count(n: u64, noun: &str) -> String {
    format!("{n} {noun}{}", if n == 1 { "" } else { "s" })
}

/// The lines of the processes' lives: their logs, exits, stalls and stops.
fn process_line(event: &Event) -> Option<Said> {
    match event {
        Event::Log { text, .. } => warn(text.clone()),
        Event::StopRequested => warn("launch: stop requested; stopping the group".into()),
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
        } => warn(format!(
            "launch: the group made no progress for {:.1} s: {holder} {why}; {}",
            silent_for.as_secs_f64(),
            if *restarting {
                "restarting it"
            } else {
                "stopping the group"
            }
        )),
        Event::Escalated(e) => warn(format!(
            "launch: {} did not stop within {:?} of {}; escalating",
            e.process, e.grace, e.signal
        )),
        Event::WaitedForSave(w) if w.done => note(format!(
            "launch: waited {:.1} s for the {} to save the library (at most {} s)",
            w.waited.as_secs_f64(),
            w.process,
            w.bound.as_secs()
        )),
        Event::WaitedForSave(w) => warn(format!(
            "launch: the {} was still saving the library after {} s; killed (the previous \
             library file is intact)",
            w.process,
            w.bound.as_secs()
        )),
        _ => None,
    }
}

/// The line of a child that exited on its own, by what the supervisor does about it.
fn exit_line(
    role: tes_topics::Role,
    how: &str,
    said: Option<&str>,
    then: ExitConsequence,
) -> Option<Said> {
    match then {
        ExitConsequence::Finished => {
            note("launch: perception-sim finished its episodes; the group stopped".into())
        }
        ExitConsequence::Restart { restart, max } => {
            let said = said.map(|e| format!(" ({e})")).unwrap_or_default();
            warn(format!(
                "launch: {role} {how}{said}; respawning it (restart {restart}/{max})"
            ))
        }
        ExitConsequence::LinkDown => warn(format!(
            "launch: bridge stopped: {}; stopping the others",
            said.unwrap_or("the link to the brick is down")
        )),
        ExitConsequence::StopGroup => {
            let said = said.map(|e| format!(" ({e})")).unwrap_or_default();
            warn(format!("launch: {role} {how}{said}; stopping the others"))
        }
    }
}

/// How the link is protected, in a few words.
fn security_words(security: &Security) -> String {
    match security {
        Security::Private { socket } => format!(
            "this host only: a Unix socket only this user can reach ({})",
            socket.display()
        ),
        Security::Tls { common_name } => {
            format!("mutual TLS, this host's certificate {common_name:?}")
        }
        Security::Insecure { .. } => "no authentication, INSECURE".into(),
    }
}

/// The lines of the link's events.
fn link_line(event: &Event) -> Option<Said> {
    match event {
        Event::LinkOpened {
            local,
            group,
            mode,
            zid,
            listen,
            connect,
            security,
        } => {
            let opened = format!(
                "launch: link: this launch plays {} in group {group:?} (Zenoh {mode:?}, id {zid}, \
                 listen {listen:?}, connect {connect:?}, {})",
                role_list(local),
                security_words(security)
            );
            match security {
                Security::Insecure { exposed } => warn(format!(
                    "{opened}\nlaunch: link: INSECURE: no authentication on {}: anyone who \
                     reaches it (on loopback, every user of this host) can join the group, read \
                     its observations and drive the robot ([launch.link] insecure = true; \
                     `tes link keygen DIR` makes TLS keys)",
                    exposed.join(", ")
                )),
                _ => note(opened),
            }
        }
        Event::LinkWaiting {
            missing,
            group,
            waited,
            timeout,
        } if waited.is_zero() => note(format!(
            "launch: link: waiting for the {} (group {group:?}; gives up after {:.0} s)",
            role_list(missing),
            timeout.as_secs_f64()
        )),
        Event::LinkWaiting {
            missing,
            waited,
            timeout,
            ..
        } => note(format!(
            "launch: link: no {} yet after {:.0} s (gives up after {:.0} s)",
            role_list(missing),
            waited.as_secs_f64(),
            timeout.as_secs_f64()
        )),
        Event::LinkUp { role, again: false } => note(format!("launch: link: the {role} is there")),
        Event::LinkUp { role, again: true } => {
            note(format!("launch: link: the {role} joined again"))
        }
        Event::LinkDenied(denial) => warn(format!("launch: link: {denial}")),
        Event::LinkRefused { topic, why, count } => warn(format!(
            "launch: link: warning: refused a {topic} sample from a peer: {why} ({count} \
             refused so far)"
        )),
        Event::LinkDown { role } => warn(format!(
            "launch: link: the {role}'s launch left the group (its host stopped, was killed or \
             cannot be reached); stopping the group"
        )),
        Event::LinkTwice { group, role } => warn(format!(
            "launch: link: another launch of group {group:?} plays the {role} too; stopping \
             the group"
        )),
        Event::PeerStopped { reason, .. } => warn(format!(
            "launch: link: a peer stopped the group ({reason}); stopping"
        )),
        Event::LinkClosed(counts) => note(format!("launch: link: from peers {counts}")),
        _ => None,
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
            // Only the files the run wrote are named (a run that failed at once has no
            // trajectory).
            let mut what: Vec<String> = Vec::new();
            if !names.is_empty() {
                what.push(format!("{} (pictures)", names.join(", ")));
            }
            for (table, rows) in [
                ("episodes.csv", "one row per episode"),
                ("trajectory.csv", "one row per action"),
            ] {
                if dir.join(table).exists() {
                    what.push(format!("{table} ({rows})"));
                }
            }
            let mut lines = vec![(To::Out, format!("launch: run folder {}", dir.display()))];
            if !what.is_empty() {
                lines.push((
                    To::Out,
                    format!("launch: see the run in {} there", what.join(", ")),
                ));
            }
            lines
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
    /// Lines held back until the group has stopped: perception-sim ends first, so its
    /// "finished" line would come before the controller's last episode line.
    pub(crate) deferred: Vec<(To, String)>,
}

impl Observer for Printer {
    fn event(&mut self, event: &Event) {
        let lines = lines_of(event, self.echo);
        match event {
            Event::ProcessExited {
                then: ExitConsequence::Finished,
                ..
            } => {
                self.deferred.extend(lines);
                return;
            }
            Event::RunFolder { .. }
            | Event::LinkTimed(_)
            | Event::LibraryAtEnd { .. }
            | Event::Verdict(_) => {
                for (to, line) in std::mem::take(&mut self.deferred) {
                    self.say_line(to, &line);
                }
            }
            _ => {}
        }
        for (to, line) in lines {
            self.say_line(to, &line);
        }
    }
}

impl Printer {
    fn say_line(&self, to: To, line: &str) {
        match to {
            To::Out => self.say.out(line),
            To::Err => self.say.err(line),
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

#[cfg(test)]
mod tests;
