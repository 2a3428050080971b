//! `tes status`: the TES process groups of this machine, so that nobody needs `pgrep`.
//!
//! Every process of a group names its iceoryx2 node after the group's service prefix and its
//! role (`tes-41-0badcafe/tes/controller`, see [`channel::group_node_name`]), and so does the
//! launcher. This command lists iceoryx2's node registry, groups the nodes by prefix, and for
//! each process shows its pid, whether it is alive or died leaving stale resources behind, its
//! uptime (from `/proc/<pid>/stat`), and how far it got (episodes and steps, from its progress
//! reports). `--clean` first removes what dead processes left behind; `--json` prints one
//! JSON object for machines.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use serde::Serialize;
use tes_runtime::channel::{self, Member as GroupMember, NodeEntry, NodeLiveness};
use tes_runtime::progress::ProgressWatch;
use tes_topics::{Role, ServiceNames};

/// Arguments of `tes status`.
#[derive(Debug, Args)]
pub struct StatusArgs {
    /// Print one JSON object (for machines) instead of the table.
    #[arg(long)]
    json: bool,
    /// First remove the iceoryx2 resources that dead processes (crashed groups) left behind.
    #[arg(long)]
    clean: bool,
    /// How long to wait for the processes' progress reports, ms (each process reports a few
    /// times a second; 0 takes only what is there).
    #[arg(long, default_value_t = 1000)]
    wait_ms: u64,
}

/// What `tes status` found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Status {
    /// The groups, by service prefix.
    pub(crate) groups: Vec<GroupStatus>,
    /// Dead processes whose resources `--clean` removed (`None` without `--clean`).
    pub(crate) cleaned: Option<usize>,
}

/// One group: the nodes sharing a service prefix.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct GroupStatus {
    /// The group's service prefix (may be empty for processes started by hand).
    pub(crate) prefix: String,
    /// Running, incomplete or stale.
    pub(crate) state: GroupState,
    /// The launcher, if the group has one (processes started by hand have none).
    pub(crate) launcher: Option<Member>,
    /// The processes: perception-sim, controller, bridge order; alive before dead.
    pub(crate) processes: Vec<Member>,
    /// Why the group's progress could not be read, if it could not.
    pub(crate) progress_error: Option<String>,
}

/// How a group is, from its processes' states.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub(crate) enum GroupState {
    /// Every role has a live process.
    Running,
    /// Something lives, but a role has no live process (starting, stopping, respawning, or
    /// started by hand).
    Incomplete,
    /// Nothing lives: the group crashed and left its resources behind.
    Stale,
}

/// A process (or the launcher) of a group.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Member {
    /// A process of the group (`perception-sim`, `controller`, `bridge`) or `launcher`.
    #[serde(serialize_with = "by_name")]
    pub(crate) role: GroupMember,
    /// Its process id.
    pub(crate) pid: i32,
    /// Alive, or dead with stale resources.
    pub(crate) state: MemberState,
    /// How long it has run, s (alive processes whose start time is readable).
    pub(crate) uptime_s: Option<f64>,
    /// Episodes finished, from its latest progress report.
    pub(crate) episodes: Option<u64>,
    /// Steps done, from its latest progress report (observations published, commands sent or
    /// executed).
    pub(crate) steps: Option<u64>,
}

/// A member as its name.
fn by_name<S: serde::Serializer>(member: &GroupMember, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(member.name())
}

/// Whether a group member's process runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub(crate) enum MemberState {
    /// Its process runs.
    Alive,
    /// Its process died without cleaning up: its iceoryx2 resources are stale.
    DeadStale,
}

/// What is printed when no group exists.
pub(crate) const NONE_RUNNING: &str = "no TES group is running";

/// Runs `tes status`.
pub fn run(args: &StatusArgs) -> Result<()> {
    let cleaned = if args.clean {
        Some(channel::clean_stale_resources().context("cannot remove stale resources")?)
    } else {
        None
    };
    let nodes = channel::list_nodes().context("cannot list the iceoryx2 nodes")?;
    let mut groups = group_nodes(&nodes);
    for group in &mut groups {
        for member in group.launcher.iter_mut().chain(group.processes.iter_mut()) {
            if member.state == MemberState::Alive {
                member.uptime_s = uptime(member.pid).map(|d| d.as_secs_f64());
            }
        }
    }
    read_progress(&mut groups, Duration::from_millis(args.wait_ms))?;
    let status = Status { groups, cleaned };
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&status).context("cannot write the status as JSON")?
        );
    } else {
        print!("{}", render(&status));
    }
    Ok(())
}

/// The groups the nodes `nodes` make up: nodes named by [`channel::group_node_name`], alive
/// or dead, by prefix (other nodes are not TES groups' and are left out).
pub(crate) fn group_nodes(nodes: &[NodeEntry]) -> Vec<GroupStatus> {
    let mut by_prefix: BTreeMap<&str, (Vec<Member>, Vec<Member>)> = BTreeMap::new();
    for node in nodes {
        let state = match node.liveness {
            NodeLiveness::Alive => MemberState::Alive,
            NodeLiveness::Dead => MemberState::DeadStale,
            NodeLiveness::Inaccessible | NodeLiveness::Undefined => continue,
        };
        let (Some(name), Some(pid)) = (node.name.as_deref(), node.pid) else {
            continue;
        };
        let Some((prefix, role)) = channel::parse_group_node_name(name) else {
            continue;
        };
        let member = Member {
            role,
            pid,
            state,
            uptime_s: None,
            episodes: None,
            steps: None,
        };
        let (launchers, processes) = by_prefix.entry(prefix).or_default();
        if role == GroupMember::Launcher {
            launchers.push(member);
        } else {
            processes.push(member);
        }
    }
    by_prefix
        .into_iter()
        .map(|(prefix, (mut launchers, mut processes))| {
            let order = |m: &Member| {
                (
                    GroupMember::ALL.iter().position(|r| *r == m.role),
                    m.state != MemberState::Alive,
                    m.pid,
                )
            };
            processes.sort_by_key(order);
            launchers.sort_by_key(order);
            let alive = |m: &Member| m.state == MemberState::Alive;
            let state = if Role::ALL.iter().all(|r| {
                processes
                    .iter()
                    .any(|m| m.role == GroupMember::Process(*r) && alive(m))
            }) {
                GroupState::Running
            } else if processes.iter().chain(&launchers).any(alive) {
                GroupState::Incomplete
            } else {
                GroupState::Stale
            };
            GroupStatus {
                prefix: prefix.to_owned(),
                state,
                launcher: launchers.into_iter().next(),
                processes,
                progress_error: None,
            }
        })
        .collect()
}

/// Fills in each live process's episodes and steps from its group's progress reports,
/// waiting at most `wait` for every live process to have reported.
fn read_progress(groups: &mut [GroupStatus], wait: Duration) -> Result<()> {
    let wanted = |g: &GroupStatus| {
        g.processes
            .iter()
            .any(|m| m.state == MemberState::Alive && m.role != GroupMember::Launcher)
    };
    if !groups.iter().any(wanted) {
        return Ok(());
    }
    let node = channel::node(false)?;
    let mut watches: Vec<(usize, ProgressWatch)> = Vec::new();
    for (i, group) in groups.iter_mut().enumerate() {
        if !wanted(group) {
            continue;
        }
        // Only a group whose progress services exist is watched: opening would create them.
        let progress = format!("{}{}", group.prefix, tes_topics::service::PROGRESS);
        match channel::services_with_prefix(&progress) {
            Ok(found) if found.is_empty() => continue,
            Ok(_) => {}
            Err(e) => {
                group.progress_error = Some(e.to_string());
                continue;
            }
        }
        match ProgressWatch::open(&node, &ServiceNames::with_prefix(&group.prefix)) {
            Ok(watch) => watches.push((i, watch)),
            Err(e) => group.progress_error = Some(e.to_string()),
        }
    }
    let deadline = Instant::now() + wait;
    loop {
        let mut missing = false;
        for (i, watch) in &mut watches {
            let group = &mut groups[*i];
            if let Err(e) = watch.poll() {
                group.progress_error = Some(e.to_string());
                continue;
            }
            for member in &mut group.processes {
                if member.state != MemberState::Alive {
                    continue;
                }
                let report = member
                    .role
                    .role()
                    .and_then(|r| watch.latest(r))
                    .filter(|p| i64::from(p.pid) == i64::from(member.pid));
                match report {
                    Some(p) => {
                        member.episodes = Some(p.episodes);
                        member.steps = Some(p.steps);
                        if member.uptime_s.is_none() {
                            let since =
                                tes_runtime::clock::monotonic_ns().saturating_sub(p.started_ns);
                            member.uptime_s = Some(Duration::from_nanos(since).as_secs_f64());
                        }
                    }
                    None => missing = true,
                }
            }
        }
        if !missing || Instant::now() >= deadline {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// How long process `pid` has run, from its start time in `/proc/<pid>/stat` and the time
/// since boot in `/proc/uptime`; `None` when either cannot be read.
fn uptime(pid: i32) -> Option<Duration> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let boot = std::fs::read_to_string("/proc/uptime").ok()?;
    let ticks_per_s = nix::unistd::sysconf(nix::unistd::SysconfVar::CLK_TCK)
        .ok()
        .flatten()
        .and_then(|t| u64::try_from(t).ok())?;
    process_uptime(&stat, &boot, ticks_per_s)
}

/// A process's uptime from its `/proc/<pid>/stat` text (start time in clock ticks after
/// boot, field 22), `/proc/uptime`'s text (seconds since boot first) and the ticks per
/// second; `None` for text that is not of that form.
pub(crate) fn process_uptime(stat: &str, boot: &str, ticks_per_s: u64) -> Option<Duration> {
    if ticks_per_s == 0 {
        return None;
    }
    // `pid (comm) state …`: comm may hold spaces and parentheses, so count after the last
    // ')'; the first field there is the 3rd.
    let (_, rest) = stat.rsplit_once(')')?;
    let start_ticks: u64 = rest.split_whitespace().nth(22 - 3)?.parse().ok()?;
    let since_boot: f64 = boot.split_whitespace().next()?.parse().ok()?;
    if !since_boot.is_finite() || since_boot < 0.0 {
        return None;
    }
    let started = Duration::from_secs(start_ticks / ticks_per_s)
        + Duration::from_secs_f64((start_ticks % ticks_per_s) as f64 / ticks_per_s as f64);
    Some(Duration::from_secs_f64(since_boot).saturating_sub(started))
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
    use proptest::prelude::*;

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

    use NodeLiveness::{Alive, Dead, Inaccessible, Undefined};

    /// Nodes make groups by prefix; their roles come in loop order, alive before dead; other
    /// programs' nodes, unnamed nodes and unreadable nodes are left out.
    #[test]
    fn nodes_are_grouped_by_prefix_in_role_order() {
        let a = "tes-41-0badcafe/";
        let nodes = [
            named(a, BRIDGE, 44, Alive),
            entry("", 7, Alive),
            entry("someone/else", 8, Alive),
            named(a, CONTROLLER, 43, Alive),
            named("b/", CONTROLLER, 50, Dead),
            named(a, CONTROLLER, 40, Dead),
            named(a, PERCEPTION, 42, Alive),
            named(a, LAUNCHER, 41, Alive),
            named("c/", BRIDGE, 60, Inaccessible),
            named("c/", BRIDGE, 61, Undefined),
            NodeEntry {
                name: None,
                pid: None,
                liveness: Alive,
            },
        ];
        let groups = group_nodes(&nodes);
        type Row = (GroupMember, i32, MemberState);
        let summary: Vec<(&str, GroupState, Option<i32>, Vec<Row>)> = groups
            .iter()
            .map(|g| {
                (
                    g.prefix.as_str(),
                    g.state,
                    g.launcher.as_ref().map(|l| l.pid),
                    g.processes
                        .iter()
                        .map(|p| (p.role, p.pid, p.state))
                        .collect(),
                )
            })
            .collect();
        assert_eq!(
            summary,
            [
                (
                    "b/",
                    GroupState::Stale,
                    None,
                    vec![(CONTROLLER, 50, MemberState::DeadStale)]
                ),
                (
                    a,
                    GroupState::Running,
                    Some(41),
                    vec![
                        (PERCEPTION, 42, MemberState::Alive),
                        (CONTROLLER, 43, MemberState::Alive),
                        (CONTROLLER, 40, MemberState::DeadStale),
                        (BRIDGE, 44, MemberState::Alive),
                    ]
                ),
            ]
        );
    }

    /// A group with a role missing or dead but something alive is incomplete; one with only
    /// a live launcher too; with nothing alive, stale.
    #[test]
    fn a_group_is_running_incomplete_or_stale() {
        let p = "g/";
        let state = |nodes: &[NodeEntry]| group_nodes(nodes)[0].state;
        let all = |l: NodeLiveness| {
            vec![
                named(p, PERCEPTION, 1, l),
                named(p, CONTROLLER, 2, l),
                named(p, BRIDGE, 3, l),
            ]
        };
        assert_eq!(state(&all(Alive)), GroupState::Running);
        assert_eq!(state(&all(Dead)), GroupState::Stale);
        let mut one_dead = all(Alive);
        one_dead[1].liveness = Dead;
        assert_eq!(state(&one_dead), GroupState::Incomplete);
        assert_eq!(state(&all(Alive)[..2]), GroupState::Incomplete);
        assert_eq!(
            state(&[named(p, LAUNCHER, 9, Alive)]),
            GroupState::Incomplete
        );
        let mut dead_with_launcher = all(Dead);
        dead_with_launcher.push(named(p, LAUNCHER, 9, Dead));
        assert_eq!(state(&dead_with_launcher), GroupState::Stale);
    }

    #[test]
    fn no_group_says_so() {
        let status = Status {
            groups: group_nodes(&[entry("other", 3, Alive)]),
            cleaned: None,
        };
        assert_eq!(render(&status), format!("{NONE_RUNNING}\n"));
        let cleaned = Status {
            groups: Vec::new(),
            cleaned: Some(2),
        };
        assert_eq!(
            render(&cleaned),
            format!("removed the stale iceoryx2 resources of 2 dead processes\n{NONE_RUNNING}\n")
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
        running.processes[2].steps = None;
        running.processes[2].episodes = None;
        let text = render(&Status {
            groups,
            cleaned: None,
        });
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines,
            [
                "tes-41-0badcafe/  running",
                "  launcher        pid 41       alive  up 1 min 05 s",
                "  perception-sim  pid 42       alive  up 1 min 04 s  episodes 3  steps 410",
                "  controller      pid 43       alive  up 1 min 04 s  episodes 3  steps 410",
                "  bridge          pid 44       alive  up 1 min 04 s  no progress report yet",
                "",
                "tes-9-deadbeef/  stale: every process is dead",
                "  controller      pid 12       dead (stale)",
                "  hint: dead processes left iceoryx2 resources behind; `tes status --clean` \
                 removes them (so does the next `tes launch`)",
            ]
        );
    }

    #[test]
    fn the_json_names_states_in_kebab_case() {
        let status = Status {
            groups: group_nodes(&[named("g/", BRIDGE, 5, Dead)]),
            cleaned: Some(0),
        };
        let json: serde_json::Value =
            serde_json::from_str(&serde_json::to_string(&status).expect("json")).expect("parse");
        assert_eq!(json["cleaned"], 0);
        let g = &json["groups"][0];
        assert_eq!(g["prefix"], "g/");
        assert_eq!(g["state"], "stale");
        assert_eq!(g["launcher"], serde_json::Value::Null);
        assert_eq!(g["processes"][0]["role"], "bridge");
        assert_eq!(g["processes"][0]["pid"], 5);
        assert_eq!(g["processes"][0]["state"], "dead-stale");
    }

    #[test]
    fn a_process_uptime_comes_from_its_start_ticks() {
        // Started 250 ticks (2.5 s at 100 Hz) after boot; the machine is up 12.75 s.
        let stat = "4242 (tes child (x) y) S 41 4242 41 0 -1 4194560 100 0 0 0 5 1 0 0 20 0 \
                    3 0 250 123456 789 18446744073709551615";
        let up = process_uptime(stat, "12.75 34.00\n", 100).expect("parsed");
        assert!((up.as_secs_f64() - 10.25).abs() < 1e-9, "{up:?}");
        for (stat, boot, hz) in [
            (stat, "12.75 34.00\n", 0),
            (stat, "soon", 100),
            (stat, "-1 0", 100),
            ("4242 (tes) S 41", "12.75 1", 100),
            ("no parenthesis", "12.75 1", 100),
            (
                "1 (x) S 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 later 0",
                "12.75 1",
                100,
            ),
        ] {
            assert_eq!(
                process_uptime(stat, boot, hz),
                None,
                "{stat:?} {boot:?} {hz}"
            );
        }
        // A start after the boot clock (clock skew) is no negative uptime.
        assert_eq!(process_uptime(stat, "1.0 1", 100), Some(Duration::ZERO));
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

    proptest! {
        /// Any prefix a group may have (ASCII, up to 64 bytes) and any member make a node
        /// name that groups back under that prefix and member.
        #[test]
        fn any_group_node_name_groups_back_under_its_prefix_and_role(
            prefix in "[ -~]{0,64}",
            member in 0usize..4,
            pid in 1i32..i32::MAX,
            alive in any::<bool>(),
        ) {
            let member = GroupMember::ALL[member];
            let name = channel::group_node_name(&prefix, member);
            prop_assert!(name.len() <= channel::NODE_NAME_MAX);
            prop_assert_eq!(channel::parse_group_node_name(&name), Some((prefix.as_str(), member)));
            let liveness = if alive { Alive } else { Dead };
            let groups = group_nodes(&[entry(&name, pid, liveness)]);
            prop_assert_eq!(groups.len(), 1);
            prop_assert_eq!(&groups[0].prefix, &prefix);
            let m = if member == LAUNCHER {
                groups[0].launcher.clone()
            } else {
                groups[0].processes.first().cloned()
            };
            prop_assert_eq!(m.map(|m| (m.role, m.pid)), Some((member, pid)));
        }

        /// Parsing never panics and whatever it accepts is a member's name behind a prefix.
        #[test]
        fn parsing_any_name_is_total(name in "\\PC{0,80}") {
            if let Some((prefix, member)) = channel::parse_group_node_name(&name) {
                prop_assert_eq!(channel::group_node_name(prefix, member), name);
            }
        }
    }
}
