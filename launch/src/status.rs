//! The TES process groups running on this machine, as data a program can read without the
//! command line (`tes status` prints them; a live viewer or a script can call [`Status::read`]
//! or [`running_groups`] itself).
//!
//! Every process of a group names its iceoryx2 node after the group's service prefix and its
//! role (`tes-41-0badcafe/tes/controller`, see [`channel::group_node_name`]), and so does the
//! launcher. This module lists iceoryx2's node registry, groups the nodes by prefix
//! ([`group_nodes`]), and for each process finds its pid, whether it is alive or died leaving
//! stale resources behind, its uptime (from `/proc/<pid>/stat`, [`uptime`]), and how far it
//! got (episodes and steps, from its progress reports, [`read_progress`]). Looking never
//! creates a group's services.
//!
//! ```no_run
//! use std::time::Duration;
//!
//! for group in tes_launch::status::running_groups(Duration::from_secs(1))? {
//!     println!("{} {:?}", group.prefix, group.state);
//!     for process in &group.processes {
//!         println!("  {} pid {} steps {:?}", process.role, process.pid, process.steps);
//!     }
//! }
//! # Ok::<(), tes_launch::status::StatusError>(())
//! ```
//!
//! Every type serialises (serde) to the JSON `tes status --json` prints.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use serde::Serialize;
use tes_runtime::channel::{self, IpcError, NodeEntry, NodeLiveness};
use tes_runtime::progress::ProgressWatch;
use tes_topics::{Role, ServiceNames};

/// A member of a group as its node's name says it: one of the three processes, or the
/// launcher (re-exported from [`tes_runtime::channel::Member`]).
pub use tes_runtime::channel::Member as GroupMember;

/// Why the groups of this machine could not be read.
#[derive(Debug, thiserror::Error)]
pub enum StatusError {
    /// Removing the resources dead processes left behind failed.
    #[error("cannot remove stale resources")]
    Clean(#[source] IpcError),
    /// iceoryx2's node registry could not be listed.
    #[error("cannot list the iceoryx2 nodes")]
    ListNodes(#[source] IpcError),
    /// This process's own iceoryx2 node, which reads the groups' progress, could not be
    /// created.
    #[error(transparent)]
    Node(IpcError),
}

/// What a look at this machine found: its groups, and what a clean-up removed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Status {
    /// The groups, by service prefix.
    pub groups: Vec<GroupStatus>,
    /// Dead processes whose resources were removed first (`None` when nothing was cleaned).
    pub cleaned: Option<usize>,
    /// iceoryx2 domains other than the default (a latency bench's, a test host's) removed
    /// first because every process in them had ended (`None` when nothing was cleaned).
    pub domains_cleaned: Option<usize>,
    /// Lock files ended launches left in the default data directory (a killed launcher's
    /// role locks, a killed controller's library lock), removed first (`None` when nothing
    /// was cleaned).
    pub locks_cleaned: Option<usize>,
    /// What the clean-up could not remove, each named with why (empty when it removed
    /// everything, or nothing was cleaned).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub not_cleaned: Vec<String>,
}

impl Status {
    /// Looks at this machine: with `clean`, first removes the resources dead processes left
    /// behind ([`clean_stale_resources`]); then reads the groups ([`running_groups`]),
    /// waiting at most `wait` for their progress reports.
    ///
    /// # Errors
    ///
    /// [`StatusError`] when the clean-up, the node registry or this process's own node fails.
    pub fn read(clean: bool, wait: Duration) -> Result<Self, StatusError> {
        let (mut cleaned, mut domains_cleaned, mut not_cleaned) = (None, None, Vec::new());
        let mut locks_cleaned = None;
        if clean {
            let locks = clean_stale_locks(&tes_controller::config::default_data_dir());
            locks_cleaned = Some(locks.removed);
            not_cleaned.extend(locks.not_removed);
            // Everything that can be removed is, whatever could not be: each failure is
            // named, not the first one made the end of the clean-up.
            let nodes = channel::clean_every_stale_resource().map_err(StatusError::Clean)?;
            let domains = channel::clean_every_stale_domain();
            cleaned = Some(nodes.removed);
            domains_cleaned = Some(domains.removed);
            not_cleaned = nodes.not_removed;
            not_cleaned.extend(domains.not_removed);
        }
        let groups = running_groups(wait)?;
        Ok(Self {
            groups,
            cleaned,
            domains_cleaned,
            locks_cleaned,
            not_cleaned,
        })
    }
}

/// What a clean-up of lock files did.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct LocksCleaned {
    /// Lock files removed (their holders had ended).
    pub removed: usize,
    /// Those that could not be looked at or removed, each named with why.
    pub not_removed: Vec<String>,
}

/// Removes the lock files of `data_dir` no live process holds: `*.lock` in it (the view
/// library's) and in its `runs/` (each role's), and each run folder's in-use lock. A lock is
/// free exactly when its holder has ended (the kernel releases a `flock` with its process),
/// so taking it tells, and letting it go removes the file; a held one stays.
pub fn clean_stale_locks(data_dir: &std::path::Path) -> LocksCleaned {
    let runs = data_dir.join(crate::run_folder::RUNS);
    let folders = crate::run_folder::list(&runs);
    let candidates = lock_files_in(data_dir)
        .into_iter()
        .chain(lock_files_in(&runs))
        .chain(folders.iter().flat_map(|f| lock_files_in(f)));
    let mut done = LocksCleaned::default();
    for path in candidates {
        match tes_runtime::lock::Lock::acquire(&path, "lock file") {
            Ok(lock) => {
                drop(lock);
                match std::fs::symlink_metadata(&path) {
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => done.removed += 1,
                    _ => done
                        .not_removed
                        .push(format!("the lock file {}", path.display())),
                }
            }
            Err(tes_runtime::lock::LockError::Held { .. }) => {}
            Err(e) => done.not_removed.push(e.to_string()),
        }
    }
    done
}

/// The regular `*.lock` files directly in `dir` (none when it cannot be read).
fn lock_files_in(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .filter_map(Result::ok)
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "lock"))
        .collect()
}

/// One group: the nodes sharing a service prefix.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroupStatus {
    /// The group's service prefix (may be empty for processes started by hand).
    pub prefix: String,
    /// Running, incomplete or stale.
    pub state: GroupState,
    /// The launcher, if the group has one (processes started by hand have none).
    pub launcher: Option<MemberStatus>,
    /// The processes: perception-sim, controller, bridge order; alive before dead.
    pub processes: Vec<MemberStatus>,
    /// Why the group's progress could not be read, if it could not.
    pub progress_error: Option<String>,
}

/// How a group is, from its processes' states.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum GroupState {
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
pub struct MemberStatus {
    /// A process of the group (`perception-sim`, `controller`, `bridge`) or `launcher`;
    /// serialised as that name.
    #[serde(serialize_with = "by_name")]
    pub role: GroupMember,
    /// Its process id.
    pub pid: i32,
    /// Alive, or dead with stale resources.
    pub state: MemberState,
    /// How long it has run, s (alive processes whose start time is readable).
    pub uptime_s: Option<f64>,
    /// Episodes finished, from its latest progress report (`None` for the bridge, which sees
    /// commands, not episodes).
    pub episodes: Option<u64>,
    /// Steps done, from its latest progress report (observations published, commands sent or
    /// executed).
    pub steps: Option<u64>,
}

/// A member as its name.
fn by_name<S: serde::Serializer>(member: &GroupMember, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(member.name())
}

/// Whether a group member's process runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum MemberState {
    /// Its process runs.
    Alive,
    /// Its process died without cleaning up: its iceoryx2 resources are stale.
    DeadStale,
}

/// Removes the iceoryx2 resources that dead processes (crashed groups) left behind; how many
/// dead processes' resources it removed.
///
/// # Errors
///
/// [`StatusError::Clean`] when iceoryx2 cannot list or remove them.
pub fn clean_stale_resources() -> Result<usize, StatusError> {
    channel::clean_stale_resources().map_err(StatusError::Clean)
}

/// Removes the iceoryx2 domains other than the default whose processes have all ended (what
/// a latency bench or a test host in a domain of its own left, the segment iceoryx2 keeps per
/// domain included); how many it removed.
///
/// # Errors
///
/// [`StatusError::Clean`] when iceoryx2 cannot list a domain's nodes or a file cannot be
/// removed.
pub fn clean_stale_domains() -> Result<usize, StatusError> {
    channel::clean_stale_domains().map_err(StatusError::Clean)
}

/// The groups of this machine, alive or stale, by service prefix: each member with its
/// uptime, and each live process with its episodes and steps, waiting at most `wait` for
/// every live process to have reported (a process reports a few times a second;
/// [`Duration::ZERO`] takes only what is there).
///
/// # Errors
///
/// [`StatusError::ListNodes`] when the node registry cannot be listed,
/// [`StatusError::Node`] when this process's node cannot be created. A group whose progress
/// cannot be read is no error: its [`GroupStatus::progress_error`] says why.
pub fn running_groups(wait: Duration) -> Result<Vec<GroupStatus>, StatusError> {
    let nodes = channel::list_nodes().map_err(StatusError::ListNodes)?;
    let mut groups = group_nodes(&nodes);
    for group in &mut groups {
        for member in group.launcher.iter_mut().chain(group.processes.iter_mut()) {
            if member.state == MemberState::Alive {
                member.uptime_s = uptime(member.pid).map(|d| d.as_secs_f64());
            }
        }
    }
    read_progress(&mut groups, wait)?;
    Ok(groups)
}

/// The groups the nodes `nodes` make up: nodes named by [`channel::group_node_name`], alive
/// or dead, by prefix (other nodes are not TES groups' and are left out). Uptimes and
/// progress are not filled in.
pub fn group_nodes(nodes: &[NodeEntry]) -> Vec<GroupStatus> {
    let mut by_prefix: BTreeMap<&str, (Vec<MemberStatus>, Vec<MemberStatus>)> = BTreeMap::new();
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
        let member = MemberStatus {
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
            let order = |m: &MemberStatus| {
                (
                    GroupMember::ALL.iter().position(|r| *r == m.role),
                    m.state != MemberState::Alive,
                    m.pid,
                )
            };
            processes.sort_by_key(order);
            launchers.sort_by_key(order);
            let alive = |m: &MemberStatus| m.state == MemberState::Alive;
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
/// waiting at most `wait` for every live process to have reported. Only groups whose
/// progress services exist are watched (opening would create them); a group whose progress
/// cannot be read gets its [`GroupStatus::progress_error`]. A live process without an uptime
/// gets the one its report says.
///
/// # Errors
///
/// [`StatusError::Node`] when this process's iceoryx2 node cannot be created (only when
/// some group has a live process).
pub fn read_progress(groups: &mut [GroupStatus], wait: Duration) -> Result<(), StatusError> {
    let wanted = |g: &GroupStatus| {
        g.processes
            .iter()
            .any(|m| m.state == MemberState::Alive && m.role != GroupMember::Launcher)
    };
    if !groups.iter().any(wanted) {
        return Ok(());
    }
    let node = channel::node(false).map_err(StatusError::Node)?;
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
            let Some(group) = groups.get_mut(*i) else {
                continue;
            };
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
                        // The bridge sees commands, not episodes: it has no count to give.
                        member.episodes =
                            (member.role.role() != Some(Role::Bridge)).then_some(p.episodes);
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
pub fn uptime(pid: i32) -> Option<Duration> {
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
pub fn process_uptime(stat: &str, boot: &str, ticks_per_s: u64) -> Option<Duration> {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Lock files whose holders ended are removed (the library's, each role's, a run
    /// folder's); a held one stays; nothing else is touched.
    #[test]
    fn stale_lock_files_are_removed_and_held_ones_kept() {
        let data = tempfile::tempdir().expect("temp dir");
        let runs = data.path().join(crate::run_folder::RUNS);
        let folder = runs.join("2026-11-30T00-53-20Z");
        std::fs::create_dir_all(&folder).expect("run folder");
        let stale = [
            data.path().join("library.tesl.lock"),
            runs.join("controller.lock"),
            folder.join(crate::run_folder::IN_USE),
        ];
        for path in &stale {
            std::fs::write(path, "4194304\n").expect("a dead holder's lock file");
        }
        let kept = data.path().join("library.tesl");
        std::fs::write(&kept, "not a lock").expect("a file");
        let held = tes_runtime::lock::Lock::acquire(&runs.join("bridge.lock"), "bridge")
            .expect("a live lock");
        let done = clean_stale_locks(data.path());
        assert_eq!(done.removed, 3, "{done:?}");
        assert!(done.not_removed.is_empty(), "{done:?}");
        assert!(stale.iter().all(|p| !p.exists()));
        assert!(held.path().exists() && kept.exists());
        assert_eq!(clean_stale_locks(data.path()).removed, 0);
    }
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

    /// Nodes of no TES group make no group.
    #[test]
    fn other_nodes_make_no_group() {
        assert_eq!(group_nodes(&[entry("other", 3, Alive)]), []);
    }

    #[test]
    fn the_json_names_states_in_kebab_case() {
        let status = Status {
            groups: group_nodes(&[named("g/", BRIDGE, 5, Dead)]),
            cleaned: Some(0),
            domains_cleaned: Some(0),
            locks_cleaned: None,
            not_cleaned: Vec::new(),
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

    /// The JSON's keys, in their order, are the ones `tes status --json` has always printed.
    #[test]
    fn the_json_keeps_its_keys_and_order() {
        let mut groups = group_nodes(&[
            named("g/", LAUNCHER, 4, Alive),
            named("g/", CONTROLLER, 5, Alive),
        ]);
        groups[0].processes[0].uptime_s = Some(1.5);
        groups[0].processes[0].episodes = Some(2);
        groups[0].processes[0].steps = Some(30);
        let status = Status {
            groups,
            cleaned: None,
            domains_cleaned: None,
            locks_cleaned: None,
            not_cleaned: Vec::new(),
        };
        assert_eq!(
            serde_json::to_string(&status).expect("json"),
            "{\"groups\":[{\"prefix\":\"g/\",\"state\":\"incomplete\",\
             \"launcher\":{\"role\":\"launcher\",\"pid\":4,\"state\":\"alive\",\
             \"uptime_s\":null,\"episodes\":null,\"steps\":null},\
             \"processes\":[{\"role\":\"controller\",\"pid\":5,\"state\":\"alive\",\
             \"uptime_s\":1.5,\"episodes\":2,\"steps\":30}],\"progress_error\":null}],\
             \"cleaned\":null,\"domains_cleaned\":null,\"locks_cleaned\":null}"
        );
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

    /// This very process has an uptime, and it is short of the machine's.
    #[test]
    fn this_process_has_an_uptime() {
        let pid = i32::try_from(std::process::id()).expect("pid fits");
        let up = uptime(pid).expect("this process's /proc entry is readable");
        assert!(up < Duration::from_secs(365 * 86_400), "{up:?}");
    }

    /// The errors say what failed, as `tes status` has always said it.
    #[test]
    fn the_errors_say_what_failed() {
        let ipc = || IpcError {
            context: "list the nodes",
            message: "denied".to_owned(),
        };
        let chain = |e: &dyn std::error::Error| {
            let mut text = e.to_string();
            let mut source = e.source();
            while let Some(s) = source {
                text = format!("{text}: {s}");
                source = s.source();
            }
            text
        };
        assert_eq!(
            chain(&StatusError::ListNodes(ipc())),
            "cannot list the iceoryx2 nodes: iceoryx2: cannot list the nodes: denied"
        );
        assert_eq!(
            chain(&StatusError::Clean(ipc())),
            "cannot remove stale resources: iceoryx2: cannot list the nodes: denied"
        );
        assert_eq!(
            chain(&StatusError::Node(ipc())),
            "iceoryx2: cannot list the nodes: denied"
        );
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
