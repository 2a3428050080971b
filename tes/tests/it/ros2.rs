//! `tes launch --ros2` and `--rosbag` (docs/ros2.md). A `tes` built without the `ros2`
//! feature refuses them before anything starts; one built with it (`cargo test -p tes
//! --features ros2 --test it ros2::`) publishes the group's topics to an independent ROS 2
//! peer (Eclipse Cyclone DDS from PyPI) and writes a bag PyPI's `rosbags` reads.

use std::time::Duration;

use crate::common::{Group, launch_file};

/// A `tes` without the feature says how to build it in, and starts nothing: no process, no
/// bag directory.
#[cfg(not(feature = "ros2"))]
#[test]
fn ros2_is_refused_by_a_tes_built_without_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    let bag = dir.path().join("bag");
    let bag_arg = bag.display().to_string();
    for args in [vec!["--ros2"], vec!["--rosbag", bag_arg.as_str()]] {
        let toml = launch_file(dir.path(), "");
        let mut group = Group::start_in(dir.path(), &toml, 1, &args, &[]);
        let (ok, _, stderr) = group.finish(Duration::from_secs(120));
        assert!(!ok, "{args:?} was accepted: {stderr:?}");
        let said = stderr.join("\n");
        assert!(
            said.contains("built without ROS 2")
                && said.contains("--features ros2")
                && said.contains("nothing was started"),
            "{said}"
        );
        assert!(!said.contains("started controller"), "{said}");
        assert!(!bag.exists());
    }
}

/// The whole group on ROS 2: a Cyclone DDS peer, in a domain of this test's own, decodes
/// every topic with ROS 2's names and types while the group runs; the bag of the same run
/// reads back in `rosbags` topic by topic.
#[cfg(feature = "ros2")]
#[test]
fn a_launch_on_ros2_reaches_a_cyclone_dds_peer_and_writes_a_bag_rosbags_reads() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};

    let peers = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../ros2/tests/peers");
    let python = std::env::var("TES_ROS2_PYTHON").unwrap_or_else(|_| {
        let venv =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/ros2-venv/bin/python");
        if venv.exists() {
            venv.display().to_string()
        } else {
            "python3".into()
        }
    });
    let domain = (1 + std::process::id() % 200 + 20).to_string();
    let mut listener = crate::common::Killed(
        Command::new(&python)
            .arg(peers.join("listen.py"))
            .args([domain.as_str(), "90"])
            .current_dir(&peers)
            .stdout(Stdio::piped())
            .spawn()
            .expect("the Cyclone DDS peer starts"),
    );
    let mut out = BufReader::new(listener.0.stdout.take().expect("its output"));
    let mut line = String::new();
    out.read_line(&mut line).expect("the peer says it is ready");
    assert_eq!(line.trim(), "ready");

    let dir = tempfile::tempdir().expect("temp dir");
    let bag = dir.path().join("bag");
    let bag_arg = bag.display().to_string();
    // Slow enough for DDS discovery (a few seconds) to happen while the group runs.
    let toml = launch_file(dir.path(), "real_time_factor = 0.05\n");
    let env = [("ROS_DOMAIN_ID", domain.as_str())];
    let mut group = Group::start_in(
        dir.path(),
        &toml,
        4,
        &["--ros2", "--rosbag", bag_arg.as_str()],
        &env,
    );
    line.clear();
    out.read_line(&mut line).expect("the peer's report");
    let (ok, _, stderr) = group.finish(Duration::from_secs(300));
    assert!(ok, "{stderr:?}");
    let said = stderr.join("\n");
    assert!(
        said.contains("on ROS 2 as node /tes/group, ROS 2 domain"),
        "{said}"
    );
    assert!(said.contains("to the rosbag2 bag"), "{said}");
    let report: serde_json::Value = serde_json::from_str(line.trim()).expect("JSON");
    for topic in [
        "/tf",
        "/tes/arena",
        "/tes/path",
        "/tes/decision/action",
        "/tes/decision/latency_us",
        "/tes/episode/reward",
        "/tes/episode/end",
        "/rosout",
    ] {
        assert!(
            report[topic]["count"].as_u64() > Some(0),
            "nothing on {topic}: {report}"
        );
    }
    assert_eq!(report["/tes/arena"]["last"]["markers"], 7);

    let read = Command::new(&python)
        .arg(peers.join("read_bag.py"))
        .arg(&bag)
        .current_dir(&peers)
        .output()
        .expect("rosbags runs");
    assert!(
        read.status.success(),
        "{}",
        String::from_utf8_lossy(&read.stderr)
    );
    let bag: serde_json::Value = serde_json::from_slice(&read.stdout).expect("JSON");
    assert_eq!(bag["/tes/episode/end"]["count"], 4, "{bag}");
    assert_eq!(bag["/tes/episode/reward"]["count"], 4, "{bag}");
    assert!(bag["/rosout"]["count"].as_u64() > Some(0), "{bag}");
}
