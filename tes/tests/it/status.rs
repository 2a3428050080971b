//! `tes status` against real launched groups: a running group is listed with its prefix, its
//! launcher and its three processes (their real pids, alive, with progress), and is gone once
//! it stops; a crashed group is listed as stale until `--clean` removes it.
//!
//! Each group runs under its own data directory and its own service prefix (the launcher's
//! default, `tes-<launcher pid>-…/`), and a guard kills it and removes dead processes'
//! resources even when a test fails. Other groups of the machine (other tests, other users)
//! may be listed too: the tests look only at their own.

use std::process::Output;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;

use crate::common::*;

const ROLES: [&str; 3] = ["perception-sim", "controller", "bridge"];

fn tes_status(args: &[&str]) -> Output {
    tes_command()
        .arg("status")
        .args(args)
        .output()
        .expect("tes status runs")
}

/// `tes status --json` (with `extra`), parsed.
fn status_json(extra: &[&str]) -> Value {
    let mut args = vec!["--json"];
    args.extend_from_slice(extra);
    let out = tes_status(&args);
    assert!(
        out.status.success(),
        "tes status failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).expect("utf-8");
    assert_eq!(text.trim().lines().count(), 1, "one JSON line: {text}");
    serde_json::from_str(&text).expect("one JSON object")
}

/// The group of `json` whose prefix is `prefix`.
fn group_with_prefix<'a>(json: &'a Value, prefix: &str) -> Option<&'a Value> {
    json["groups"]
        .as_array()
        .expect("groups")
        .iter()
        .find(|g| g["prefix"] == prefix)
}

/// The group whose launcher is `launcher`, once every process of it is listed alive with a
/// progress report of at least one controller episode (waits at most `limit`).
fn wait_until_listed(launcher: u32, limit: Duration) -> Value {
    let deadline = Instant::now() + limit;
    loop {
        let json = status_json(&[]);
        let found = json["groups"].as_array().and_then(|groups| {
            groups
                .iter()
                .find(|g| g["launcher"]["pid"] == launcher)
                .cloned()
        });
        if let Some(g) = &found {
            let processes = g["processes"].as_array().expect("processes");
            let ready = processes.len() == 3
                && processes
                    .iter()
                    .all(|p| p["state"] == "alive" && p["steps"].is_u64())
                && processes
                    .iter()
                    .any(|p| p["role"] == "controller" && p["episodes"].as_u64() >= Some(1));
            if ready {
                return g.clone();
            }
        }
        assert!(
            Instant::now() < deadline,
            "the group of launcher {launcher} was not listed running in {limit:?}: {json}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A default group started in `dir`, once it has finished an episode and `tes status` lists
/// it running: the group, and its entry in `tes status --json`.
fn listed_group(dir: &std::path::Path) -> (Group, Value) {
    let group = Group::start_default(dir, 100_000);
    group.wait_for_episodes(1, Duration::from_secs(60));
    let listed = wait_until_listed(group.launcher.id(), Duration::from_secs(30));
    (group, listed)
}

/// A running group: its prefix, launcher, and three processes with their real pids, alive,
/// with uptime and progress, in JSON and in the table; once stopped, it is not listed.
#[test]
fn a_running_group_is_listed_with_its_processes_and_gone_once_stopped() {
    // Alone: `tes status` opens every group's services (see `Alone`), and any launch removes
    // every dead node of the machine, which would take the crashed group away from under
    // this file's other test.
    let _alone = alone_on_the_machine();
    let dir = tempfile::tempdir().expect("temp dir");
    let (mut group, listed) = listed_group(dir.path());
    let launcher = group.launcher.id();
    let prefix = listed["prefix"].as_str().expect("prefix").to_owned();
    assert!(
        prefix.starts_with(&format!("tes-{launcher}-")) && prefix.ends_with('/'),
        "{listed}"
    );
    assert_eq!(listed["state"], "running", "{listed}");
    assert_eq!(listed["launcher"]["state"], "alive", "{listed}");
    let processes = listed["processes"].as_array().expect("processes");
    let roles: Vec<&str> = processes
        .iter()
        .map(|p| p["role"].as_str().expect("role"))
        .collect();
    assert_eq!(roles, ROLES, "{listed}");
    for p in processes {
        let role = p["role"].as_str().expect("role");
        assert_eq!(p["pid"], group.child(role).as_raw(), "{role}: {listed}");
        assert!(p["uptime_s"].as_f64().is_some_and(|s| s >= 0.0), "{listed}");
        assert!(p["steps"].as_u64().is_some_and(|s| s >= 1), "{listed}");
        // The bridge sees commands, not episodes.
        assert_eq!(p["episodes"].is_null(), role == "bridge", "{listed}");
    }

    // The table, as a user reads it.
    let out = tes_status(&[]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).expect("utf-8");
    let lines: Vec<&str> = text.lines().collect();
    let head = lines
        .iter()
        .position(|l| *l == format!("{prefix}  running"))
        .unwrap_or_else(|| panic!("no line for {prefix}: {text}"));
    let launcher_line = lines.get(head + 1).copied().unwrap_or_default();
    assert!(
        launcher_line.starts_with("  launcher ")
            && launcher_line.contains(&format!("pid {launcher} "))
            && launcher_line.contains(" alive"),
        "{text}"
    );
    for (i, role) in ROLES.iter().enumerate() {
        let line = lines.get(head + 2 + i).copied().unwrap_or_default();
        let pid = group.child(role).as_raw();
        assert!(
            line.starts_with(&format!("  {role} "))
                && line.contains(&format!("pid {pid} "))
                && line.contains(" alive  up ")
                && line.contains(if *role == "bridge" {
                    " commands "
                } else {
                    " steps "
                }),
            "{role}: {text}"
        );
    }

    // Stopped, the group is gone.
    kill(Pid::from_raw(launcher as i32), Signal::SIGINT).expect("Ctrl-C");
    let (ok, out, err) = group.finish(Duration::from_secs(30));
    assert!(ok, "stdout {out:?}\nstderr {err:?}");
    let json = status_json(&[]);
    assert!(group_with_prefix(&json, &prefix).is_none(), "{json}");
    let out = tes_status(&[]);
    let text = String::from_utf8(out.stdout).expect("utf-8");
    assert!(!text.contains(&prefix), "{text}");
}

/// A group whose processes all died by SIGKILL is listed stale, every process dead with the
/// pid it had, with the hint to clean; `--clean` removes it.
#[test]
fn a_crashed_group_is_listed_stale_until_cleaned() {
    // Alone: `tes status` opens every group's services (see `Alone`), and any launch removes
    // every dead node of the machine, which would take the crashed group away from under
    // this file's other test.
    let _alone = alone_on_the_machine();
    let dir = tempfile::tempdir().expect("temp dir");
    let (mut group, listed) = listed_group(dir.path());
    let launcher = group.launcher.id();
    let prefix = listed["prefix"].as_str().expect("prefix").to_owned();
    let pids: Vec<i32> = ROLES.iter().map(|r| group.child(r).as_raw()).collect();

    // The launcher frozen first, so that it neither stops nor respawns anything; then
    // everything killed.
    let launcher_pid = Pid::from_raw(launcher as i32);
    kill(launcher_pid, Signal::SIGSTOP).expect("stop the launcher");
    for pid in &pids {
        kill(Pid::from_raw(*pid), Signal::SIGKILL).expect("kill a child");
    }
    kill(launcher_pid, Signal::SIGKILL).expect("kill the launcher");
    let (ok, _, _) = group.finish(Duration::from_secs(10));
    assert!(!ok);
    let children: Vec<Pid> = pids.iter().map(|&p| Pid::from_raw(p)).collect();
    wait_gone(&children, Duration::from_secs(30));

    let json = status_json(&[]);
    // Any launch or clean-up elsewhere on the machine may have removed the dead nodes by
    // now; while they are there, they are shown dead.
    if let Some(g) = group_with_prefix(&json, &prefix) {
        assert_eq!(g["state"], "stale", "{g}");
        assert_eq!(g["launcher"]["state"], "dead-stale", "{g}");
        for p in g["processes"].as_array().expect("processes") {
            assert_eq!(p["state"], "dead-stale", "{g}");
            assert!(p["uptime_s"].is_null() && p["steps"].is_null(), "{g}");
            let pid = p["pid"].as_i64().and_then(|p| i32::try_from(p).ok());
            assert!(pid.is_some_and(|p| pids.contains(&p)), "{g}");
        }
        let text = String::from_utf8(tes_status(&[]).stdout).expect("utf-8");
        if text.contains(&prefix) {
            assert!(
                text.contains(&format!("{prefix}  stale: every process is dead"))
                    && text.contains("`tes status --clean` removes them"),
                "{text}"
            );
        }
    } else {
        eprintln!("the crashed group was cleaned up by someone else before it was listed");
    }

    let cleaned = status_json(&["--clean"]);
    assert!(cleaned["cleaned"].is_u64(), "{cleaned}");
    assert!(group_with_prefix(&cleaned, &prefix).is_none(), "{cleaned}");
}

/// A domain of its own (a latency bench's, a test host's) that a dead process left — here the
/// segment iceoryx2 keeps per domain — is removed by `--clean` once it has settled, and a
/// domain whose node lives is left alone.
#[test]
fn clean_removes_a_dead_domain_and_keeps_a_live_one() {
    use iceoryx2::prelude::*;
    let _alone = alone_on_the_machine();
    let node_in = |domain: &str| {
        let mut config = iceoryx2::config::Config::default();
        config.global.prefix =
            FileName::new(format!("iox2_{domain}_").as_bytes()).expect("a file name prefix");
        NodeBuilder::new()
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .expect("a node in the domain")
    };
    let files_of = |domain: &str| -> Vec<std::path::PathBuf> {
        let prefix = format!("iox2_{domain}_");
        std::fs::read_dir("/dev/shm")
            .expect("/dev/shm")
            .filter_map(Result::ok)
            .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
            .map(|e| e.path())
            .collect()
    };
    let dead = format!("tdead{}", std::process::id());
    let live = format!("tlive{}", std::process::id());
    drop(node_in(&dead));
    let keep = node_in(&live);
    // Settled: the clean-up leaves a domain whose files changed in the last 10 s.
    let settle = |domain: &str| {
        let old = std::time::SystemTime::now() - Duration::from_secs(60);
        for path in files_of(domain) {
            let file = std::fs::File::options()
                .write(true)
                .open(&path)
                .expect("open");
            file.set_modified(old).expect("backdate");
        }
    };
    settle(&dead);
    settle(&live);
    assert!(!files_of(&dead).is_empty());

    let json = status_json(&["--clean"]);
    assert!(json["domains_cleaned"].as_u64() >= Some(1), "{json}");
    assert_eq!(files_of(&dead), Vec::<std::path::PathBuf>::new());
    assert!(!files_of(&live).is_empty(), "a live domain is kept");
    drop(keep);
    settle(&live);
    let _ = status_json(&["--clean"]);
    assert_eq!(files_of(&live), Vec::<std::path::PathBuf>::new());
}
