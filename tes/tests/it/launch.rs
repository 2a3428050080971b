//! `tes launch` with its real child processes: a clean run, a child killed under
//! `restart = "never"`, and a child killed and respawned under `restart = "on-failure"`.
//!
//! Every test runs its group under its own iceoryx2 service prefix and data directory, and a
//! guard kills the launcher (whose children die with it by their parent-death signal) and
//! removes dead processes' iceoryx2 resources even when the test fails.

use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

use crate::common::*;

/// A bad launch file — an unknown key or table, a value of the wrong type or out of range,
/// text that is not TOML, bytes that are not UTF-8, no file at all — makes `tes launch` exit
/// non-zero at once with an error naming the file and the line and key (or the reason), and
/// start no process: no child's settings file, which is written just before the child starts,
/// exists, and the launcher never announces the group.
#[test]
fn a_bad_launch_file_is_refused_naming_the_file_and_key_and_starts_nothing() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cases: [(Option<&[u8]>, &[&str]); 15] = [
        (
            Some(b"[launch]\nepisodez = 3\n"),
            &[":2:1: [launch] episodez: unknown field `episodez`"],
        ),
        (
            Some(b"[launch]\nepisodes = \"many\"\n"),
            &[":2:12: [launch] episodes: invalid type: string \"many\", expected u32"],
        ),
        (
            Some(b"[controller]\nepsilon = 0.1\nbudjet_us = 5\n"),
            &[":3:1: [controller] budjet_us: unknown field `budjet_us`"],
        ),
        (
            Some(b"[perception]\narena = \"three\"\n"),
            &[":2:9: [perception] arena: invalid type: string \"three\""],
        ),
        (
            Some(b"[launch]\nepisodes = 2\n[monitor]\nrate = 5\n"),
            &[":3:2: monitor: unknown field `monitor`"],
        ),
        (Some(b"this is { not toml\n"), &[":1:6: not valid TOML"]),
        (
            Some(b"[launch]\narena = 4\n"),
            &[":2:1: [launch] arena: must be 1, 2 or 3, got 4"],
        ),
        (
            Some(b"[controller]\nbudget_us = 0\n"),
            &[":2:1: [controller] budget_us: must be at least 1"],
        ),
        (
            Some(b"[controller]\nseed = 4\nwait = \"nap\"\n"),
            &[":3:8: [controller] wait: unknown wait strategy \"nap\""],
        ),
        (
            Some(b"[bridge]\nwatchdogg = 1\n"),
            &[":2:1: [bridge] watchdogg: unknown field `watchdogg`"],
        ),
        // Reported at the user's line, not at one of the settings files the launcher writes.
        (
            Some(
                b"[launch]\nepisodes = 2\n\n[bridge]\nseed = 4\n\
                   [bridge.watchdog]\ndeadline_ms = 10\n",
            ),
            &[":7:1: [bridge] watchdog.deadline_ms: must be at least 50, got 10"],
        ),
        (
            Some(b"[bridge]\ntransport = \"usb:\"\n"),
            &[":2:13: [bridge] transport: expected \"sim\", \"serial:PATH\", \"bluetooth:"],
        ),
        // A value the launcher sets (the brick's speed-up from the real-time factor).
        (
            Some(b"[launch]\nreal_time_factor = 0.00001\n"),
            &[
                "[bridge] brick.time_scale (not in the file: a default or a launch-wide value): ",
                "must be in 0.001..=10000",
            ],
        ),
        (
            Some(b"[launch]\nepisodes = 3\n\xff\xfe\n"),
            &["cannot read the launch file", "UTF-8"],
        ),
        (None, &["cannot read the launch file", "No such file"]),
    ];
    let run = dir.path().join("data/run");
    for (i, (bytes, expected)) in cases.into_iter().enumerate() {
        let name = format!("bad{i}.toml");
        let path = dir.path().join(&name);
        if let Some(bytes) = bytes {
            std::fs::write(&path, bytes).expect("launch file");
        }
        let mut group = Group::start_with(dir.path(), &path, 1);
        let (ok, out, err) = group.finish(Duration::from_secs(30));
        let err = err.join("\n");
        assert!(!ok, "case {i} should fail: {err}");
        assert!(out.is_empty(), "case {i}: nothing on stdout: {out:?}");
        let first = err.lines().next().unwrap_or("");
        assert!(
            first.starts_with("error: ") && first.contains(&name),
            "case {i}: the file is named: {err}"
        );
        for text in expected {
            assert!(err.contains(text), "case {i}: {text:?} in {err}");
        }
        assert!(
            err.trim_end().ends_with("; nothing was started"),
            "case {i}: {err}"
        );
        assert!(!err.contains("launch: arena"), "case {i}: announced: {err}");
        for role in ["bridge", "controller", "perception-sim"] {
            assert!(
                !run.join(format!("{role}.toml")).exists(),
                "case {i}: {role} was prepared"
            );
        }
    }
}

#[test]
fn a_launched_group_runs_its_episodes_and_saves_the_library() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut group = Group::start(dir.path(), &launch_file(dir.path(), ""), 4);
    let (ok, out, err) = group.finish(Duration::from_secs(60));
    assert!(ok, "stdout {out:?}\nstderr {err:?}");
    let episodes: Vec<&String> = out.iter().filter(|l| l.starts_with("episode ")).collect();
    assert_eq!(episodes.len(), 4, "{out:?}");
    assert!(episodes[0].contains("decision latency p50"), "{out:?}");
    assert!(
        out.iter().any(|l| l.starts_with("controller: 4 episodes")),
        "{out:?}"
    );
    assert!(
        out.last()
            .is_some_and(|l| l.contains("all processes stopped cleanly"))
    );
    // The library is on disk and loads, for the arena's shape.
    let library = dir.path().join("data/library.tesl");
    let stored = load_library(&library).expect("the saved library loads");
    assert!(!stored.library.is_empty());
    assert!(!group.children_alive());
}

/// The group learns: over the same seeded budget of 80 episodes on Env 3, the learner's
/// reward over its last 40 episodes beats a random policy's (the same processes with
/// `epsilon = 1`) by a wide margin.
#[test]
fn the_group_learns_against_a_random_policy() {
    let run = |epsilon: f64| {
        let dir = tempfile::tempdir().expect("temp dir");
        let extra = format!(
            "seed = 1\n[controller]\nepsilon = {epsilon}\nlibrary = \"{}\"\n",
            dir.path().join("library.tesl").display()
        );
        let mut group = Group::start(dir.path(), &launch_file(dir.path(), &extra), 80);
        let (ok, out, err) = group.finish(Duration::from_secs(600));
        assert!(ok, "stdout {out:?}\nstderr {err:?}");
        (mean_reward(&out, 0, 40), mean_reward(&out, 40, 80))
    };
    // (Its own first 40 are no baseline: it often learns within a few episodes — measured
    // first 40 at +0.94 once — so only the random policy is.)
    let (_, learner_last) = run(0.05);
    let (_, random_last) = run(1.0);
    assert!(
        learner_last > random_last + 1.0,
        "learner {learner_last:.2} vs random {random_last:.2} per episode (last 40)"
    );
}

#[test]
fn a_killed_child_stops_the_group_when_restarts_are_off() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut group = Group::start(
        dir.path(),
        &launch_file(dir.path(), "restart = \"never\"\nreal_time_factor = 0.01\n"),
        10_000,
    );
    group.wait_for_episodes(1, Duration::from_secs(60));
    kill(group.child("controller"), Signal::SIGKILL).expect("kill the controller");
    let (ok, _, err) = group.finish(Duration::from_secs(30));
    assert!(!ok, "the launcher must fail");
    let err = err.join("\n");
    assert!(
        err.contains("controller was killed by SIGKILL; stopping the others"),
        "{err}"
    );
    assert!(!group.children_alive(), "no child outlives the launcher");
}

#[test]
fn a_killed_child_is_respawned_and_the_run_goes_on() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut group = Group::start(
        dir.path(),
        &launch_file(
            dir.path(),
            "restart = \"on-failure\"\nreal_time_factor = 0.01\n",
        ),
        6,
    );
    group.wait_for_episodes(1, Duration::from_secs(60));
    kill(group.child("bridge"), Signal::SIGKILL).expect("kill the bridge");
    let (ok, out, err) = group.finish(Duration::from_secs(120));
    let err = err.join("\n");
    assert!(
        err.contains("bridge was killed by SIGKILL; respawning it (restart 1/3)"),
        "{err}"
    );
    assert!(ok, "stdout {out:?}\nstderr {err}");
    assert!(
        out.iter()
            .any(|l| l.contains("all processes stopped cleanly")),
        "{out:?}"
    );
}

/// At the robot's pace (real-time factor 1) behind a Bluetooth-like link (30 ± 10 ms a
/// reply), the bridge times every exchange: the launch's last lines and `bridge-report.json`
/// give the round trip (at least the 20 ms floor of the delay) and each command's time on the
/// link.
#[test]
fn the_links_round_trips_are_measured_and_reported() {
    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(
        dir.path(),
        "real_time_factor = 1.0\n[bridge.link_delay]\nenabled = true\nmean_ms = 30\njitter_ms = 10\n",
    );
    let mut group = Group::start(dir.path(), &toml, 1);
    let (ok, out, err) = group.finish(Duration::from_secs(120));
    assert!(ok, "stdout {out:?}\nstderr {err:?}");
    let line = out
        .iter()
        .find(|l| l.starts_with("launch: link sim (seed "))
        .unwrap_or_else(|| panic!("no link line: {out:?}"));
    assert!(line.contains("+ link delay 30ms ± 10ms: "), "{line}");
    assert!(line.contains(" of it on the link"), "{line}");
    let report =
        tes_bridge::process::BridgeReport::load(&dir.path().join("run/bridge-report.json"))
            .expect("the bridge's report");
    assert!(
        report.link.exchanges > 0 && report.link.failed == 0,
        "{report:?}"
    );
    assert!(report.link.p50_us >= 20_000, "{report:?}");
    let (_, on_link) = report.per_command_us().expect("commands were carried out");
    assert!(
        on_link >= 20_000,
        "each command waits for at least one reply: {report:?}"
    );
}

#[test]
fn ctrl_c_stops_the_group_cleanly_leaving_no_child_or_service() {
    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(dir.path(), "real_time_factor = 0.01\n");
    let prefix = service_prefix(dir.path());
    let mut group = Group::start(dir.path(), &toml, 10_000);
    group.wait_for_episodes(2, Duration::from_secs(60));
    assert!(
        !tes_runtime::channel::services_with_prefix(&prefix)
            .expect("list")
            .is_empty(),
        "the group's services exist while it runs"
    );
    kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGINT).expect("Ctrl-C");
    let (ok, out, err) = group.finish(Duration::from_secs(30));
    assert!(ok, "stdout {out:?}\nstderr {err:?}");
    assert!(err.iter().any(|l| l.contains("stop requested")), "{err:?}");
    assert!(
        out.iter()
            .any(|l| l.contains("all processes stopped cleanly")),
        "{out:?}"
    );
    assert!(!group.children_alive(), "no child outlives the launcher");
    let left = tes_runtime::channel::services_with_prefix(&prefix).expect("list");
    assert!(left.is_empty(), "services left behind: {left:?}");
    // The controller saved the library on its way out.
    load_library(&dir.path().join("data/library.tesl")).expect("the library loads");
    the_verdict_counts_what_the_controller_did(&out);
}

/// The launch's last line counts the episodes the controller's summary counts and, when the
/// stop came mid-episode, the actions of the unfinished one.
fn the_verdict_counts_what_the_controller_did(out: &[String]) {
    let summary = out
        .iter()
        .find_map(|l| l.strip_prefix("controller: "))
        .unwrap_or_else(|| panic!("no controller summary: {out:?}"));
    let episode_lines = summary
        .split_once(" episodes, ")
        .and_then(|(n, _)| n.parse::<u64>().ok())
        .unwrap_or_else(|| panic!("no episode count: {summary}"));
    let unfinished = summary
        .split_once(" actions (")
        .and_then(|(_, rest)| rest.split_once(" in the unfinished episode)"))
        .map(|(n, _)| n.parse::<u64>().expect("a count"));
    let episodes = if episode_lines == 1 {
        "1 episode".to_owned()
    } else {
        format!("{episode_lines} episodes")
    };
    let expected = match unfinished {
        None => format!("launch: {episodes}; all processes stopped cleanly"),
        Some(1) => format!(
            "launch: {episodes} and 1 action of an unfinished one; all processes stopped cleanly"
        ),
        Some(n) => format!(
            "launch: {episodes} and {n} actions of an unfinished one; all processes stopped \
             cleanly"
        ),
    };
    assert_eq!(out.last(), Some(&expected), "{out:?}");
}

/// Process faults: each of the three processes is SIGKILLed 20 times at seeded
/// random moments of one launched run under `restart = "on-failure"`. Every kill is reported
/// and the process respawned (its stale iceoryx2 resources cleaned by the launcher); after
/// every controller kill the library file on disk loads (saved after every episode here, so
/// kills land in the middle of saves too); after all 60 the group still finishes episodes and
/// stops cleanly on Ctrl-C.
#[test]
fn every_process_survives_twenty_kills_and_the_library_always_loads() {
    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(
        dir.path(),
        "restart = \"on-failure\"\nmax_restarts = 1000\n[controller]\nsave_interval_s = 0.0\n",
    );
    let mut group = Group::start(dir.path(), &toml, 1_000_000);
    group.wait_for_episodes(1, Duration::from_secs(60));
    let library = dir.path().join("data/library.tesl");
    let mut state = 0x9e37_79b9_7f4a_7c15u64; // xorshift, seeded: the kill moments
    let mut random_ms = |lo: u64, hi: u64| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        lo + state % (hi - lo)
    };
    let mut kills = std::collections::BTreeMap::new();
    for round in 0..20 {
        for role in ["controller", "bridge", "perception-sim"] {
            std::thread::sleep(Duration::from_millis(random_ms(20, 400)));
            let deadline = Instant::now() + Duration::from_secs(30);
            let pid = loop {
                if let Some(pid) = group.find_child(role) {
                    break pid;
                }
                assert!(
                    Instant::now() < deadline,
                    "round {round}: no {role} to kill"
                );
                std::thread::sleep(Duration::from_millis(10));
            };
            kill(pid, Signal::SIGKILL).expect("kill");
            *kills.entry(role).or_insert(0) += 1;
            let n = kills[role];
            group.wait_for_stderr(
                &format!("{role} was killed by SIGKILL; respawning it (restart {n}/1000)"),
                Duration::from_secs(30),
            );
            if role == "controller" && library.exists() {
                load_library(&library).unwrap_or_else(|e| {
                    panic!("round {round}: the library on disk does not load: {e}")
                });
            }
        }
    }
    // Still running: new episodes arrive after the last kill.
    while group.stdout.try_recv().is_ok() {}
    group.wait_for_episodes(2, Duration::from_secs(120));
    kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGINT).expect("Ctrl-C");
    let (_, out, err) = group.finish(Duration::from_secs(60));
    assert!(
        err.iter().any(|l| l.contains("stop requested")),
        "{out:?}\n{err:?}"
    );
    load_library(&library).expect("the library saved at shutdown loads");
    assert!(!group.children_alive());
}

/// The bridge's watchdog is a dead man's switch with the real processes: while the controller
/// lives, its keep-alives hold the watchdog off through a move far longer than the deadline;
/// once the controller is SIGKILLed mid-move, the bridge brakes within its deadline.
#[test]
fn the_bridge_brakes_within_its_deadline_when_the_controller_vanishes_mid_move() {
    use std::sync::atomic::AtomicBool;
    use tes_runtime::channel::{Inbox, WaitStrategy};
    use tes_topics::{MotorState, ServiceNames, motor_flags};

    let dir = tempfile::tempdir().expect("temp dir");
    // Physical time (the watchdog's deadline is then 1 s of wall time), and every action a
    // long move: 20 000° a wheel, about 30 s at the default power. (Perception re-publishes
    // its observation after its 5 s motion timeout; the controller then commands again.)
    let extra = format!(
        "restart = \"on-failure\"\nreal_time_factor = 1.0\n\
         [bridge]\nuse_command_degrees = false\n{}",
        long_move_actions()
    );
    let group = Group::start(dir.path(), &launch_file(dir.path(), &extra), 1000);
    let prefix = service_prefix(dir.path());
    let names = ServiceNames::with_prefix(&prefix);
    let node = tes_runtime::channel::node(false).expect("node");
    let states = Inbox::<MotorState>::open(
        &node,
        &names.motor_state,
        &names.motor_state_event,
        0,
        WaitStrategy::Block,
    )
    .expect("subscribe to the motor states");
    let stop = AtomicBool::new(false);
    let next = |limit: Duration| -> Option<MotorState> {
        let until = Instant::now() + limit;
        while Instant::now() < until {
            if let Ok(s) = states
                .next(Duration::from_millis(100), &stop)
                .expect("receive")
            {
                return Some(s);
            }
        }
        None
    };

    // A move under way for 2.5 s, two and a half deadlines: the keep-alives hold it.
    let mut moving_since: Option<Instant> = None;
    let started = Instant::now();
    let (mut seen, mut last) = (0u32, None);
    loop {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "no long move under way within 60 s; {seen} motor states, the last {last:?}"
        );
        let Some(s) = next(Duration::from_secs(1)) else {
            continue;
        };
        (seen, last) = (seen + 1, Some(s));
        assert_eq!(
            s.flags & motor_flags::WATCHDOG_BRAKED,
            0,
            "braked while the controller lives: {s:?}"
        );
        if s.after_command > 0 && s.flags & motor_flags::SETTLED == 0 {
            let since = *moving_since.get_or_insert_with(Instant::now);
            if since.elapsed() > Duration::from_millis(2500) {
                break;
            }
        }
    }

    kill(group.child("controller"), Signal::SIGKILL).expect("kill the controller");
    let killed = Instant::now();
    let braked = loop {
        let s = next(Duration::from_secs(10)).expect("motor states keep coming");
        if s.flags & motor_flags::WATCHDOG_BRAKED != 0 {
            break s;
        }
        assert!(
            killed.elapsed() < Duration::from_secs(10),
            "no watchdog brake 10 s after the controller died"
        );
    };
    let took = killed.elapsed();
    // The bound is the deadline (1 s) after the last keep-alive, which came before the kill;
    // the slack absorbs a descheduled bridge on a loaded machine.
    assert!(
        took <= Duration::from_millis(1500),
        "braked {took:?} after the kill"
    );
    let lines = group.wait_for_stderr(
        "watchdog: no command within the deadline",
        Duration::from_secs(10),
    );
    assert_braked_at_the_deadline(&lines);
    // The wheels stop: the bridge reports them settled, and they stay where they stopped.
    let settled = loop {
        let s = next(Duration::from_secs(10)).expect("motor states keep coming");
        if s.flags & motor_flags::SETTLED != 0 {
            break s;
        }
    };
    assert!(
        settled.tacho_count[1] < 20_000 && settled.tacho_count[2] < 20_000,
        "the move was cut short: {settled:?} (braked at {braked:?})"
    );
}
