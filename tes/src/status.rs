//! `tes status`: the TES process groups of this machine, so that nobody needs `pgrep`.
//!
//! The command line over [`tes_launch::status`], which finds the groups (iceoryx2's node
//! registry grouped by service prefix), each process's pid, whether it is alive or died
//! leaving stale resources behind, its uptime and how far it got. This file prints them:
//! the table, or with `--json` one JSON object for machines. `--clean` first removes what
//! dead processes left behind.

use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use tes_launch::status::{GroupMember, GroupState, MemberState, Status};

/// Arguments of `tes status`.
#[derive(Debug, Args)]
pub struct StatusArgs {
    /// Print one JSON object (for machines) instead of the table.
    #[arg(long)]
    json: bool,
    /// First remove what dead processes (crashed groups) left behind: iceoryx2 resources,
    /// and the lock files of ended launches in the default data directory.
    #[arg(long)]
    clean: bool,
    /// How long to wait for the processes' progress reports, ms (each process reports a few
    /// times a second; 0 takes only what is there).
    #[arg(long, default_value_t = 1000)]
    wait_ms: u64,
}

/// What is printed when no group exists.
pub(crate) const NONE_RUNNING: &str = "no TES group is running";

/// Runs `tes status`.
pub fn run(args: &StatusArgs) -> Result<()> {
    let status = Status::read(args.clean, Duration::from_millis(args.wait_ms))?;
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&status).context("cannot write the status as JSON")?
        );
    } else {
        print!("{}", render(&status));
    }
    match status.not_cleaned.len() {
        0 => Ok(()),
        n => anyhow::bail!(
            "--clean removed what it could; {} could not be removed (named above)",
            if n == 1 {
                "1 stale resource".to_owned()
            } else {
                format!("{n} stale resources")
            }
        ),
    }
}

/// `12.3 s`, `4 min 05 s`, `2 h 03 min`, `3 d 04 h`.
pub(crate) fn human_duration(d: Duration) -> String {
    let s = d.as_secs();
    match s {
        0..60 => format!("{:.1} s", d.as_secs_f64()),
        60..3600 => format!("{} min {:02} s", s / 60, s % 60),
        3600..86_400 => format!("{} h {:02} min", s / 3600, s % 3600 / 60),
        _ => format!("{} d {:02} h", s / 86_400, s % 86_400 / 3600),
    }
}

/// The table `tes status` prints.
pub(crate) fn render(status: &Status) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    if let Some(n) = status.cleaned {
        let _ = writeln!(
            out,
            "removed the stale iceoryx2 resources of {n} dead process{}",
            if n == 1 { "" } else { "es" }
        );
    }
    if let Some(n) = status.domains_cleaned.filter(|&n| n > 0) {
        let _ = writeln!(
            out,
            "removed {n} iceoryx2 domain{} whose processes had all ended",
            if n == 1 { "" } else { "s" }
        );
    }
    if let Some(n) = status.locks_cleaned.filter(|&n| n > 0) {
        let _ = writeln!(
            out,
            "removed {n} lock file{} of ended launches",
            if n == 1 { "" } else { "s" }
        );
    }
    for what in &status.not_cleaned {
        let _ = writeln!(out, "could not remove {what}");
    }
    if status.groups.is_empty() {
        let _ = writeln!(out, "{NONE_RUNNING}");
        return out;
    }
    for (i, group) in status.groups.iter().enumerate() {
        if i > 0 {
            out.push('\n');
        }
        let prefix = if group.prefix.is_empty() {
            "(no service prefix)"
        } else {
            &group.prefix
        };
        let state = match group.state {
            GroupState::Running => "running",
            GroupState::Incomplete => "incomplete",
            GroupState::Stale => "stale: every process is dead",
        };
        let _ = writeln!(out, "{prefix}  {state}");
        for p in group.launcher.iter().chain(&group.processes) {
            let mut line = format!(
                "  {:<14}  pid {:<7}  {}",
                p.role,
                p.pid,
                state_word(p.state)
            );
            if let Some(s) = p.uptime_s {
                let _ = write!(line, "  up {}", human_duration(Duration::from_secs_f64(s)));
            }
            match (p.episodes, p.steps) {
                (Some(e), Some(s)) => {
                    let _ = write!(line, "  episodes {e}  steps {s}");
                }
                (None, Some(s)) => {
                    let _ = write!(line, "  commands {s}");
                }
                _ if p.state == MemberState::Alive && p.role != GroupMember::Launcher => {
                    line.push_str("  no progress report yet");
                }
                _ => {}
            }
            let _ = writeln!(out, "{line}");
        }
        if let Some(e) = &group.progress_error {
            let _ = writeln!(out, "  (progress unavailable: {e})");
        }
        let dead = group
            .processes
            .iter()
            .chain(&group.launcher)
            .any(|m| m.state == MemberState::DeadStale);
        if dead {
            let _ = writeln!(
                out,
                "  hint: dead processes left iceoryx2 resources behind; `tes status --clean` \
                 removes them (so does the next `tes launch`)"
            );
        }
    }
    out
}

fn state_word(state: MemberState) -> &'static str {
    match state {
        MemberState::Alive => "alive",
        MemberState::DeadStale => "dead (stale)",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_launch::status::group_nodes;
    use tes_runtime::channel::{self, NodeEntry, NodeLiveness};
    use tes_topics::Role;

    fn entry(name: &str, pid: i32, liveness: NodeLiveness) -> NodeEntry {
        NodeEntry {
            name: Some(name.to_owned()),
            pid: Some(pid),
            liveness,
        }
    }

    const PERCEPTION: GroupMember = GroupMember::Process(Role::Perception);
    const CONTROLLER: GroupMember = GroupMember::Process(Role::Controller);
    const BRIDGE: GroupMember = GroupMember::Process(Role::Bridge);
    const LAUNCHER: GroupMember = GroupMember::Launcher;

    fn named(prefix: &str, member: GroupMember, pid: i32, liveness: NodeLiveness) -> NodeEntry {
        entry(&channel::group_node_name(prefix, member), pid, liveness)
    }

    use NodeLiveness::{Alive, Dead};

    #[test]
    fn no_group_says_so() {
        let status = Status {
            groups: group_nodes(&[entry("other", 3, Alive)]),
            cleaned: None,
            domains_cleaned: None,
            locks_cleaned: None,
            not_cleaned: Vec::new(),
        };
        assert_eq!(render(&status), format!("{NONE_RUNNING}\n"));
        let cleaned = Status {
            groups: Vec::new(),
            cleaned: Some(2),
            domains_cleaned: Some(0),
            locks_cleaned: Some(0),
            not_cleaned: Vec::new(),
        };
        assert_eq!(
            render(&cleaned),
            format!("removed the stale iceoryx2 resources of 2 dead processes\n{NONE_RUNNING}\n")
        );
    }

    /// A clean-up that could not remove everything says what it removed and names each
    /// thing it could not, with why.
    #[test]
    fn what_a_clean_up_could_not_remove_is_named() {
        let status = Status {
            groups: Vec::new(),
            cleaned: Some(1),
            domains_cleaned: Some(0),
            locks_cleaned: Some(0),
            not_cleaned: vec!["node \"x/controller\" (pid 7): InternalError".into()],
        };
        assert_eq!(
            render(&status),
            format!(
                "removed the stale iceoryx2 resources of 1 dead process\n\
                 could not remove node \"x/controller\" (pid 7): InternalError\n{NONE_RUNNING}\n"
            )
        );
    }

    /// A running group shows its prefix, launcher and each process with its pid, uptime and
    /// progress; a crashed one is marked stale with the hint to clean it.
    #[test]
    fn the_table_shows_each_process_and_the_stale_hint() {
        let mut groups = group_nodes(&[
            named("tes-41-0badcafe/", LAUNCHER, 41, Alive),
            named("tes-41-0badcafe/", PERCEPTION, 42, Alive),
            named("tes-41-0badcafe/", CONTROLLER, 43, Alive),
            named("tes-41-0badcafe/", BRIDGE, 44, Alive),
            named("tes-9-deadbeef/", CONTROLLER, 12, Dead),
        ]);
        let running = &mut groups[0];
        running.launcher.as_mut().expect("launcher").uptime_s = Some(65.0);
        for p in &mut running.processes {
            p.uptime_s = Some(64.5);
            p.episodes = Some(3);
            p.steps = Some(410);
        }
        running.processes[2].episodes = None;
        let mut silent = running.clone();
        silent.processes[2].steps = None;
        let text = render(&Status {
            groups,
            cleaned: None,
            domains_cleaned: None,
            locks_cleaned: None,
            not_cleaned: Vec::new(),
        });
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines,
            [
                "tes-41-0badcafe/  running",
                "  launcher        pid 41       alive  up 1 min 05 s",
                "  perception-sim  pid 42       alive  up 1 min 04 s  episodes 3  steps 410",
                "  controller      pid 43       alive  up 1 min 04 s  episodes 3  steps 410",
                "  bridge          pid 44       alive  up 1 min 04 s  commands 410",
                "",
                "tes-9-deadbeef/  stale: every process is dead",
                "  controller      pid 12       dead (stale)",
                "  hint: dead processes left iceoryx2 resources behind; `tes status --clean` \
                 removes them (so does the next `tes launch`)",
            ]
        );
        // A process that has not reported yet says so.
        let text = render(&Status {
            groups: vec![silent],
            cleaned: None,
            domains_cleaned: None,
            locks_cleaned: None,
            not_cleaned: Vec::new(),
        });
        assert!(
            text.contains(
                "  bridge          pid 44       alive  up 1 min 04 s  no progress report yet"
            ),
            "{text}"
        );
    }

    #[test]
    fn durations_read_as_people_say_them() {
        let cases = [
            (0.0, "0.0 s"),
            (12.34, "12.3 s"),
            (65.0, "1 min 05 s"),
            (7380.0, "2 h 03 min"),
            (3.0 * 86_400.0 + 4.0 * 3600.0, "3 d 04 h"),
        ];
        for (s, shown) in cases {
            assert_eq!(human_duration(Duration::from_secs_f64(s)), shown);
        }
    }
}
