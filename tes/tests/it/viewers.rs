//! A run where robotics people look: `tes launch --record` draws the arena and the robot in
//! Foxglove's own schemas, which PyPI's `mcap` with Foxglove's Protobuf classes reads and
//! Rerun converts; `tes launch --foxglove` serves the same channels live to a WebSocket
//! client (PyPI's `websockets`), which also tries bad requests and leaves a second client
//! unread, and to a client offering each name of the protocol (`foxglove.sdk.v1`, and the
//! published `foxglove.websocket.v1`). The clients are driven by `viewers.py` beside this file; each test is ignored, with
//! how to install them, where they cannot be imported, and always runs under CI (`build.rs`).

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;

use crate::common::*;

const LIMIT: Duration = Duration::from_secs(180);

/// `viewers.py MODE ARGS…`: the facts it prints.
fn client_facts(args: &[&str]) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/it/viewers.py");
    let out = Command::new("python3")
        .arg(script)
        .args(args)
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "viewers.py {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("viewers.py prints JSON")
}

/// Records `episodes` episodes with the processes logging at `info` (so `/log` has lines).
fn record(dir: &Path, episodes: u32) -> (std::path::PathBuf, Vec<String>) {
    let file = dir.join("run.mcap");
    let toml = launch_file(dir, &format!("record = \"{}\"\n", file.display()));
    let mut group = Group::start_in(dir, &toml, episodes, &[], &[("RUST_LOG", "info")]);
    let (ok, out, err) = group.finish(LIMIT);
    assert!(ok, "the launch failed: {out:?} {err:?}");
    (file, out)
}

fn count(v: &Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("a count: {v}"))
}

#[test]
#[cfg_attr(
    not(tes_viewer_clients),
    ignore = "the viewers' clients are not installed: python3 -m pip install 'rerun-sdk==0.41.*' \
              'foxglove-schemas-protobuf==0.4.*' 'mcap-protobuf-support==0.6.*' 'websockets==17.*'"
)]
fn a_recording_draws_the_arena_the_robot_its_decisions_rewards_and_logs() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (file, out) = record(dir.path(), 4);
    let f = client_facts(&["mcap", file.to_str().expect("utf-8")]);
    let channel = |topic: &str| f["channels"][topic].clone();
    for (topic, schema) in [
        ("/arena", "foxglove.SceneUpdate"),
        ("/arena/points", "foxglove.PointCloud"),
        ("/tf", "foxglove.FrameTransform"),
        ("/robot", "foxglove.SceneUpdate"),
        ("/robot/pose", "foxglove.PoseInFrame"),
        ("/robot/path", "foxglove.PosesInFrame"),
        ("/log", "foxglove.Log"),
        ("/tes/decision", "decision.Decision"),
        ("/tes/episode", "episodeend.EpisodeEnd"),
    ] {
        let c = channel(topic);
        assert_eq!(c[0], schema, "{topic}: {c}");
        assert_eq!(
            (c[1].as_str(), c[2].as_str()),
            (Some("protobuf"), Some("protobuf"))
        );
        assert!(f["ordered"][topic] == true, "{topic}: log times go back");
    }
    // The latency and reward again as ROS 2 number arrays (what Rerun plots), one a decision
    // and one an episode.
    for (topic, of) in [
        ("/tes/decision/latency_us", "/tes/decision"),
        ("/tes/episode/reward", "/tes/episode"),
    ] {
        let c = channel(topic);
        assert_eq!(c[0], "std_msgs/msg/Float64MultiArray", "{topic}: {c}");
        assert_eq!(
            (c[1].as_str(), c[2].as_str()),
            (Some("ros2msg"), Some("cdr"))
        );
        assert_eq!(count(&c[3]), count(&channel(of)[3]), "{topic}");
    }
    // Our own channels are still there, unchanged.
    assert_eq!(channel("/tes/observation")[0], "tes.Observation");
    // The arena once, to scale: Env 3 is 6 ft (1.8288 m) square.
    assert_eq!(count(&channel("/arena")[3]), 1);
    assert_eq!(f["arena"]["frame"], "arena");
    assert!((f["arena"]["floor_m"].as_f64().expect("a size") - 1.8288).abs() < 1e-9);
    assert!(count(&f["arena"]["cylinders"]) >= 10 && count(&f["arena"]["spheres"]) == 1);
    // The robot: a transform at each observation and more while it moves.
    let observations = count(&channel("/tes/observation")[3]);
    let tf = f["tf"].as_array().expect("transforms");
    assert!(tf.len() as u64 > observations, "{} transforms", tf.len());
    assert!(tf.iter().all(|t| t[0] == "arena" && t[1] == "robot"));
    assert!(
        tf.iter()
            .all(|t| (0.0..=1.83).contains(&t[2].as_f64().unwrap_or(-1.0)))
    );
    assert_eq!(
        f["robot_entities"],
        serde_json::json!(["decision", "path", "robot"])
    );
    // A decision per action the run reported, each with its latency; an end per episode.
    let actions = reported_actions(&out);
    let decisions = f["decisions"].as_array().expect("decisions");
    assert_eq!(decisions.len() as u64, actions, "{out:?}");
    assert!(
        decisions
            .iter()
            .all(|d| d[1].as_f64().is_some_and(|us| us > 0.0))
    );
    assert_eq!(f["episodes"].as_array().expect("episodes").len(), 4);
    // The processes' log lines, named by process.
    let logs = f["logs"].as_array().expect("logs");
    for role in ["perception-sim", "controller", "bridge"] {
        assert!(
            logs.iter().any(|l| l[0] == role),
            "no {role} line in {logs:?}"
        );
    }
}

#[test]
#[cfg_attr(
    not(tes_viewer_clients),
    ignore = "the viewers' clients are not installed: python3 -m pip install 'rerun-sdk==0.41.*' \
              'foxglove-schemas-protobuf==0.4.*' 'mcap-protobuf-support==0.6.*' 'websockets==17.*'"
)]
fn rerun_turns_a_recording_into_a_transform_points_text_and_numbers() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (file, _) = record(dir.path(), 3);
    let rrd = dir.path().join("run.rrd");
    let f = client_facts(&[
        "rerun",
        file.to_str().expect("utf-8"),
        rrd.to_str().expect("utf-8"),
    ]);
    assert_eq!(
        (f["convert_status"].as_i64(), f["check_status"].as_i64()),
        (Some(0), Some(0))
    );
    assert_eq!(
        f["check_problems"],
        serde_json::json!([]),
        "rerun mcap check: {f}"
    );
    let rows = |key: &str| f["rows"][key].as_u64().unwrap_or(0);
    assert!(rows("/tf Transform3D:translation") > 10, "{f}");
    assert_eq!(
        rows("/tf Transform3D:child_frame"),
        rows("/tf Transform3D:translation")
    );
    assert_eq!(rows("/arena/points Points3D:positions"), 1);
    assert!(rows("/robot/pose InstancePoses3D:translations") > 0);
    assert!(rows("/log TextLog:text") > 0);
    // The arena's 100 cells, its marks, the ball and 4 corners, in more than one colour.
    let points = &f["arena_points"][0];
    assert!(
        count(&points[0]) > 100 && count(&points[1]) >= 4,
        "{points}"
    );
    // Rerun's own scalars: a latency per decision, a reward per episode.
    let decisions = f["latencies"].as_array().expect("latencies").len() as u64;
    assert_eq!(
        rows("/tes/decision/latency_us Scalars:scalars"),
        decisions,
        "{f}"
    );
    assert_eq!(rows("/tes/episode/reward Scalars:scalars"), 3, "{f}");
    let latencies = f["latencies"].as_array().expect("latencies");
    assert!(
        !latencies.is_empty()
            && latencies
                .iter()
                .all(|l| l.as_f64().is_some_and(|us| us > 0.0))
    );
}

#[test]
#[cfg_attr(
    not(tes_viewer_clients),
    ignore = "the viewers' clients are not installed: python3 -m pip install 'rerun-sdk==0.41.*' \
              'foxglove-schemas-protobuf==0.4.*' 'mcap-protobuf-support==0.6.*' 'websockets==17.*'"
)]
fn a_live_group_is_served_to_foxglove_clients_that_cannot_slow_or_break_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    // Slow enough that a client joins while episodes are still to come.
    let toml = launch_file(
        dir.path(),
        "real_time_factor = 0.1\nfoxglove = \"127.0.0.1:0\"\n",
    );
    let mut group = Group::start(dir.path(), &toml, 400);
    let said = wait_for_lines(&group.stderr, LIMIT, "the live server's address", |seen| {
        seen.iter().any(|l| l.contains("live in Foxglove at ws://"))
    });
    let addr = said
        .iter()
        .find_map(|l| l.split("ws://").nth(1)?.split_whitespace().next())
        .expect("an address")
        .to_owned();
    assert!(
        addr.starts_with("127.0.0.1:"),
        "loopback by default: {addr}"
    );
    let f = client_facts(&["live", &addr, "5"]);
    let names = client_facts(&["names", &addr]);
    kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGINT).expect("SIGINT");
    let (ok, out, err) = group.finish(LIMIT);
    assert!(ok, "the group stopped cleanly on Ctrl-C: {out:?} {err:?}");

    for (topic, schema) in [
        ("/arena", "foxglove.SceneUpdate"),
        ("/tf", "foxglove.FrameTransform"),
        ("/tes/episode", "episodeend.EpisodeEnd"),
        ("/log", "foxglove.Log"),
        ("/tes/decision/latency_us", "std_msgs/msg/Float64MultiArray"),
    ] {
        assert_eq!(f["advertised"][topic][0], schema, "{f}");
    }
    // The arena, drawn again for the client that joined late; the robot moving; episodes.
    assert_eq!(count(&f["arena_entities"]), 1);
    assert!(count(&f["tf"]) > 10);
    assert!(f["episodes"].as_array().expect("episodes").len() >= 5);
    // Bad requests are answered with a status and change nothing else: the episodes go on
    // reaching this client, beside a second client that never reads.
    let statuses = f["statuses"].as_object().expect("statuses");
    let said = |what: &str| statuses.keys().any(|k| k.contains(what));
    assert!(said("Invalid message"), "{statuses:?}");
    assert!(said("Unknown channel ID"), "{statuses:?}");
    assert!(said("already subscribed"), "{statuses:?}");
    assert!(count(&f["after_bad_requests"]) >= 1);
    assert_eq!(f["slow_client"], "OPEN");
    // A client offering only the protocol's published name (Lichtblick, Foxglove Studio
    // before the SDK) is answered in that name and given what an SDK client is given.
    let (sdk, published) = (&names["foxglove.sdk.v1"], &names["foxglove.websocket.v1"]);
    assert_eq!(sdk["subprotocol"], "foxglove.sdk.v1", "{names}");
    assert_eq!(published["subprotocol"], "foxglove.websocket.v1", "{names}");
    assert_eq!(sdk["channels"], published["channels"], "{names}");
    assert_eq!(sdk["channels"].as_object().map(|c| c.len()), Some(11));
    assert!(
        count(&sdk["tf"]) >= 3 && count(&published["tf"]) >= 3,
        "{names}"
    );
}
