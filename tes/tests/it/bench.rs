//! `tes bench latency` and `tes bench scaling` as a user runs them, on a small budget: the
//! real processes and the floor's relay start, measure and stop, and the report holds the
//! documented keys with consistent values. (Figures are for the benchmarks to judge, not
//! for tests.) A guard kills the bench and its process group if the test fails.

use std::io::Read;
use std::process::Stdio;
use std::time::Duration;

use serde_json::json;

use crate::common::*;

fn run(args: &[&str], data: &std::path::Path, limit: Duration) -> (bool, String, String) {
    let _sharing = sharing_the_machine();
    let child = tes_command()
        .args(args)
        .env("TES_DATA_DIR", data)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("tes starts");
    let mut guard = Killed(child);
    let status = wait_exit(&mut guard.0, limit, &format!("tes {args:?}"));
    let mut out = String::new();
    let mut err = String::new();
    if let Some(mut o) = guard.0.stdout.take() {
        o.read_to_string(&mut out).expect("stdout");
    }
    if let Some(mut e) = guard.0.stderr.take() {
        e.read_to_string(&mut err).expect("stderr");
    }
    (status.success(), out, err)
}

/// The floor measured something, its first hop lies inside its round trip, and the p50
/// ratio is the run's p50 over the floor's.
fn assert_floor_consistent(v: &serde_json::Value) {
    let floor_p50 = v["floor_p50_us"].as_u64().expect("floor p50");
    assert!(floor_p50 > 0, "{v}");
    assert!(
        v["floor_decision"]["p50_us"].as_u64().unwrap() <= floor_p50,
        "{v}"
    );
    let ratio = v["ratio_p50"].as_f64().unwrap();
    let p50 = v["p50_us"].as_f64().unwrap();
    assert!((ratio - p50 / floor_p50 as f64).abs() < 1e-9, "{v}");
}

/// Each process of the group, and of the floor, reports its CPU over the measured actions: a
/// share of a core and µs per action, consistent with its CPU and wall times.
fn assert_cpu_reported(v: &serde_json::Value) {
    let measured = v["actions"].as_u64().expect("actions");
    let processes = [
        "perception-sim",
        "controller",
        "controller/acting",
        "bridge",
    ];
    let floor = ["source", "hop", "sink"];
    let all = processes
        .iter()
        .map(|p| (p, &v["cpu"][p]))
        .chain(floor.iter().map(|r| (r, &v["floor_cpu"][r])));
    for (who, used) in all {
        let share = used["core_share"].as_f64().expect("core_share");
        let per_action = used["us_per_action"].as_f64().expect("us_per_action");
        let (cpu_us, wall_us, actions) = (
            used["cpu_us"].as_f64().unwrap(),
            used["wall_us"].as_f64().unwrap(),
            used["actions"].as_u64().unwrap(),
        );
        // Counted from the end of the warm-up to the last action.
        assert!(
            actions + 2 >= measured && actions <= measured + 2,
            "{who}: {v}"
        );
        assert!(wall_us > 0.0 && share >= 0.0, "{who}: {v}");
        assert!(
            (per_action * actions as f64 - cpu_us).abs() <= 1.0 + 0.01 * cpu_us,
            "{who}: {v}"
        );
        assert!(
            (share * wall_us - cpu_us).abs() <= 1.0 + 0.01 * cpu_us,
            "{who}: {v}"
        );
    }
    // The acting thread is part of the controller.
    assert!(
        v["cpu"]["controller/acting"]["cpu_us"].as_u64()
            <= v["cpu"]["controller"]["cpu_us"].as_u64(),
        "{v}"
    );
}

/// Every one of `files` was kept in the `--out` folder.
fn assert_kept(out: &std::path::Path, files: &[&str]) {
    for file in files {
        assert!(out.join(file).exists(), "{file} kept with --out");
    }
}

/// The decision splits into its wake-up and its compute; deciding first (the default), the
/// learning follows each command and is timed on its own; each second hop is timed too.
fn assert_parts_timed(v: &serde_json::Value, actions: u64) {
    let awake = &v["floor_awake"];
    for part in [
        "decision",
        "wake",
        "compute",
        "learn",
        "floor_decision",
        "command_hop",
        "floor_second_hop",
    ] {
        assert_eq!(v[part]["count"], actions, "{part}: {v}");
    }
    // The second hops (command published → received) are parts of the round trips: never
    // longer than them, sample by sample, so neither at the median.
    for (hop, whole) in [
        ("command_hop", "p50_us"),
        ("floor_second_hop", "floor_p50_us"),
    ] {
        assert!(v[hop]["p50_us"].as_u64() <= v[whole].as_u64(), "{hop}: {v}");
    }
    assert_eq!(awake["second_hop"]["count"], actions, "{v}");
}

/// No --wait: auto, which blocks at the fastest pace (nothing is announced there).
fn assert_auto_blocked(v: &serde_json::Value, stderr: &str) {
    assert_eq!(
        (v["wait"].as_str(), v["wait_chosen"].as_str()),
        (Some("auto"), Some("block")),
        "{v}"
    );
    assert!(
        v["catches"].as_object().is_some_and(|c| c.is_empty()),
        "{v}"
    );
    assert!(stderr.contains("wait auto: block"), "{stderr}");
}

#[test]
fn latency_runs_both_paths_and_reports_every_key() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // The default placement, as a user gets it: blocking, on two or more CPUs, the acting
    // thread (and the floor's hop) on the last allowed CPU and the planner on the first.
    let allowed = tes_runtime::affinity::allowed_cpus();
    let (acting, planner) = match (allowed.first(), allowed.last()) {
        (Some(&first), Some(&last)) if first != last => (json!(last), json!(first)),
        _ => (json!(null), json!(null)),
    };
    let (ok, stdout, stderr) = run(
        &[
            "bench",
            "latency",
            "--actions",
            "150",
            "--warmup",
            "30",
            "--views",
            "3",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ],
        &dir.path().join("data"),
        Duration::from_secs(300),
    );
    assert!(ok, "bench failed:\n{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    for key in [
        "wait",
        "actions",
        "p50_us",
        "p99_us",
        "p999_us",
        "max_us",
        "misses",
        "allocations",
        "floor_p50_us",
        "floor_p99_us",
        "floor_misses",
        "floor_decision",
        "ratio_p50",
        "ratio_p99",
        "decision",
        "wake",
        "compute",
        "order",
        "learn",
        "learning_overran",
        "floor_comparable",
        "pace",
        "cpu",
        "floor_cpu",
        "planner_idle_spin_us",
    ] {
        assert!(v.get(key).is_some(), "missing {key} in {v}");
    }
    assert_eq!(v["pace"], "fastest", "{v}");
    // Blocking, the planner thread sleeps at once after a plan (no core kept busy).
    assert_eq!(v["planner_idle_spin_us"], 0, "{v}");
    let comparable =
        v["ratio_p50"].as_f64().unwrap() >= 0.9 && v["ratio_p99"].as_f64().unwrap() >= 0.9;
    assert_eq!(v["floor_comparable"], comparable, "{v}");
    // At the fastest pace the floor runs again with every CPU kept awake.
    let awake = &v["floor_awake"];
    assert_eq!(awake["round_trip"]["count"], 150, "{v}");
    assert_eq!(awake["first_hop"]["count"], 150, "{v}");
    let awake_comparable =
        awake["ratio_p50"].as_f64().unwrap() >= 0.9 && awake["ratio_p99"].as_f64().unwrap() >= 0.9;
    assert_eq!(awake["comparable"], awake_comparable, "{v}");
    assert_cpu_reported(&v);
    assert_eq!(v["acting_cpu"], acting, "{v}");
    assert_eq!(v["planner_cpu"], planner, "{v}");
    assert_parts_timed(&v, 150);
    assert_eq!(v["order"], "decide-first", "{v}");
    let overran = v["learning_overran"].as_u64().expect("a count");
    assert!(overran <= 150, "{v}");
    assert_auto_blocked(&v, &stderr);
    assert_eq!(v["planning"], "thread", "{v}");
    assert_eq!(v["actions"], 150);
    // The planner thread planned (at least the first plan, before the first action) and the
    // acting loop adopted its plans: at most one per observation (180 actions, plus each
    // episode's last observation).
    let plans = v["plans"].as_u64().expect("plans is a count");
    assert!((1..=360).contains(&plans), "{v}");
    let (p50, p99, max) = (
        v["p50_us"].as_u64().unwrap(),
        v["p99_us"].as_u64().unwrap(),
        v["max_us"].as_u64().unwrap(),
    );
    assert!(0 < p50 && p50 <= p99 && p99 <= max, "{v}");
    assert_floor_consistent(&v);
    // The controller counts its acting path's allocations (the tes binary installs the
    // counting allocator): none, its command included (a blackboard store, not a loan).
    assert_eq!(v["allocations"], 0, "{v}");
    assert_eq!(v["ipc_allocations"], 0, "{v}");
    assert_kept(
        &out,
        &[
            "floor.json",
            "floor-first-hop.json",
            "floor-second-hop.json",
            "bridge.json",
            "controller.json",
            "library.tesl",
        ],
    );
}

/// At the robot's pace (the settle time, the brick in real time, a Bluetooth-like link
/// delay) with no `--wait`, the controller and the bridge anticipate the observations and
/// commands that perception announces and catch them inside their poll windows; the floor
/// runs at the same cadence with the same help, and the CPU is reported for both.
#[test]
fn latency_at_the_robots_pace_anticipates_by_default_and_catches_in_the_windows() {
    // No other test's group beside it: their wake-ups land in its windows.
    let _alone = alone_on_the_machine();
    let dir = tempfile::tempdir().unwrap();
    let (ok, stdout, stderr) = run(
        &[
            "bench",
            "latency",
            "--pace",
            "real",
            "--actions",
            "20",
            "--warmup",
            "5",
            "--views",
            "3",
            "--json",
        ],
        &dir.path().join("data"),
        Duration::from_secs(300),
    );
    assert!(ok, "bench failed:\n{stderr}");
    assert!(stderr.contains("at the robot's pace"), "{stderr}");
    assert!(
        stderr.contains("wait auto: anticipate for the controller and the bridge"),
        "the choice is said at start: {stderr}"
    );
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(
        (
            v["pace"].as_str(),
            v["wait"].as_str(),
            v["wait_chosen"].as_str()
        ),
        (Some("real"), Some("auto"), Some("anticipate")),
        "{v}"
    );
    // The settle time alone is 200 ms an action.
    assert!(v["cycle_us"].as_u64().unwrap() >= 200_000, "{v}");
    for part in ["decision", "floor_decision"] {
        assert_eq!(v[part]["count"], 20, "{part}: {v}");
    }
    // At this pace both sides wake from the same idleness: no floor kept awake.
    assert!(v["floor_awake"].is_null(), "{v}");
    assert_floor_consistent(&v);
    assert_cpu_reported(&v);
    // Both anticipating receivers took every message (25, warm-up included), and caught
    // many inside their poll windows: a window that opens too late or closes too early
    // leaves its message to a blocking wake-up, counted as woken, and its window as missed.
    // A window broken so misses nearly every message; a quiet machine catches nearly all,
    // and a compiler running beside the test on this 2-core machine was seen to make the
    // controller miss 14 of 27. So the bound is a quarter, not a timing target (that is
    // `tes bench latency`'s, over 1 000 actions).
    for who in ["controller", "bridge"] {
        let c = &v["catches"][who];
        let count = |key: &str| {
            c[key]
                .as_u64()
                .unwrap_or_else(|| panic!("{who} {key}: {v}"))
        };
        let (caught, woken, missed) = (count("polled"), count("woken"), count("missed_windows"));
        assert!(caught + woken >= 25, "{who}: {v}");
        // Of the 25 announced messages (the bridge also wakes for keep-alives, unannounced).
        assert!(caught >= 25 / 4, "{who}: windows caught: {v}");
        assert!(missed <= 25 * 3 / 4, "{who}: {v}");
    }
    // The floor's hop anticipates as the controller does, alone on its CPU as the acting
    // thread is: both poll under SCHED_FIFO where the system lets them (every window caught
    // polling was polled so), neither where it does not.
    let allowed =
        std::thread::spawn(|| tes_runtime::affinity::set_this_thread_realtime(true).is_ok())
            .join()
            .unwrap();
    for who in ["controller", "floor hop"] {
        let c = &v["catches"][who];
        let (fifo, caught) = (c["realtime_windows"].as_u64(), c["polled"].as_u64());
        assert!(fifo.is_some() && caught.is_some(), "{who}'s catches: {v}");
        if allowed {
            assert!(fifo >= caught, "{who} polls alone under SCHED_FIFO: {v}");
        } else {
            assert_eq!(fifo, Some(0), "{who}: {v}");
        }
    }
    assert_eq!(v["allocations"], 0, "{v}");
}

#[test]
fn latency_via_zenoh_runs_the_split_group_and_its_floor_in_one_invocation() {
    split_group_and_its_floor("zenoh", &[]);
}

/// The same over QUIC with the run's own keys (made in the run directory), group and floor
/// alike.
#[test]
fn latency_via_zenoh_tls_runs_both_over_quic_with_the_runs_keys() {
    split_group_and_its_floor(
        "zenoh-tls",
        &[
            "keys/ca.pem",
            "floor/keys/ca.pem",
            "floor-awake/floor/keys/ca.pem",
        ],
    );
}

/// `tes bench latency --via VIA` measures the split group and its floor in one invocation;
/// `kept` are files the run leaves in its directory besides the usual ones.
fn split_group_and_its_floor(via: &str, kept: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let (ok, stdout, stderr) = run(
        &[
            "bench",
            "latency",
            "--via",
            via,
            "--actions",
            "100",
            "--warmup",
            "20",
            "--views",
            "3",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ],
        &dir.path().join("data"),
        Duration::from_secs(300),
    );
    assert!(ok, "bench failed:\n{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(v["via"], via, "{v}");
    assert_eq!(v["actions"], 100, "{v}");
    // The split run and its floor both measured every action, the floor's first hop timed
    // in the floor's controller process.
    for part in ["decision", "floor_decision"] {
        assert_eq!(v[part]["count"], 100, "{part}: {v}");
    }
    // And the floor again with every CPU kept awake, in a folder of its own.
    assert_eq!(v["floor_awake"]["round_trip"]["count"], 100, "{v}");
    assert_eq!(v["floor_awake"]["first_hop"]["count"], 100, "{v}");
    assert_floor_consistent(&v);
    // Across the link the acting path still allocates nothing.
    assert_eq!(v["allocations"], 0, "{v}");
    assert_kept(
        &out,
        &[
            "floor-first-hop.json",
            "floor-hop.log",
            "controller.json",
            "bridge.json",
            "controller-launch.log",
            "floor-awake/floor-first-hop.json",
        ],
    );
    assert_kept(&out, kept);
}

#[test]
fn bad_bench_arguments_are_refused_before_anything_starts() {
    let dir = tempfile::tempdir().unwrap();
    // Each bad argument, and what its message must name. Planning between polls needs a
    // spinning wait.
    let cases: [(&[&str], &[&str]); 6] = [
        (&["--wait", "nap"], &["--wait"]),
        (&["--actions", "0"], &["--actions"]),
        (
            &["--acting-cpu", "100000"],
            &["--acting-cpu", "CPU 100000", "allowed"],
        ),
        (&["--acting-cpu", "fast"], &["--acting-cpu", "none"]),
        (&["--planning", "between-polls"], &["--planning", "spin"]),
        (&["--order", "later"], &["--order", "decide-first"]),
    ];
    for (bad, named) in cases {
        let args: Vec<&str> = ["bench", "latency"].iter().chain(bad).copied().collect();
        let (ok, _, stderr) = run(&args, dir.path(), Duration::from_secs(30));
        assert!(!ok, "{bad:?} was accepted");
        for word in named {
            assert!(stderr.contains(word), "{bad:?}: no {word:?} in\n{stderr}");
        }
    }
}

/// `--record --foxglove`: blocks with and without each observer alternate; the recorder's
/// blocks say what they wrote, the Foxglove server's what its viewer received, and the acting
/// path allocates nothing with either.
#[test]
fn latency_compares_the_recorder_and_the_foxglove_server_in_blocks() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, stdout, stderr) = run(
        &[
            "bench",
            "latency",
            "--actions",
            "60",
            "--warmup",
            "20",
            "--views",
            "3",
            "--record",
            "--foxglove",
            "--record-blocks",
            "1",
            "--json",
        ],
        &dir.path().join("data"),
        Duration::from_secs(300),
    );
    assert!(ok, "bench failed:\n{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    for (key, watcher) in [("recorder", "recorder"), ("foxglove", "foxglove")] {
        let c = &v[key];
        assert_eq!(c["watcher"], watcher, "{v}");
        let blocks = c["blocks"].as_array().expect("blocks");
        let kinds: Vec<bool> = blocks.iter().map(|b| b["recorded"] == true).collect();
        assert_eq!(kinds, [false, true], "{c}");
        assert_eq!(c["allocations_with"], 0, "{c}");
        assert!(c["with_p50_us"].as_f64().is_some_and(|us| us > 0.0), "{c}");
    }
    let with_viewer = &v["foxglove"]["blocks"][1];
    assert!(
        with_viewer["viewer_messages"]
            .as_u64()
            .is_some_and(|n| n > 60),
        "{with_viewer}"
    );
    assert!(
        v["recorder"]["blocks"][1]["written"][1]
            .as_u64()
            .is_some_and(|n| n >= 60)
    );
}
