//! A group on ROS 2: a Cyclone DDS peer, knowing only ROS 2's names and types, receives and
//! decodes every topic the group's ROS 2 side publishes; `rosbags` reads its bag.

use std::time::{Duration, Instant};

use serde_json::Value;
use tes_ros2::group::{GroupOnRos2, Outputs};
use tes_ros2::scene::{SceneSettings, Topic};

use crate::common::{Peer, STEPS, StandIn, own_prefix_and_domain};

/// How long the peer listens at most: DDS discovery takes a few seconds here.
const LISTEN_S: u32 = 60;

/// Runs the stand-in group until the peer has printed its report (or the time is up).
fn run_until_the_peer_reports(group: &mut StandIn, side: &GroupOnRos2, peer: &mut Peer) -> Value {
    let deadline = Instant::now() + Duration::from_secs(u64::from(LISTEN_S) + 30);
    let lines = side.log_lines();
    let report = std::thread::scope(|s| {
        let reader = s.spawn(|| peer.line());
        while !reader.is_finished() && Instant::now() < deadline {
            group.act();
            lines.send(
                "controller",
                "2026-01-01T00:00:00Z  INFO tes_controller: acting",
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        reader.join().expect("the peer's reader")
    });
    serde_json::from_str(&report).unwrap_or_else(|e| panic!("the peer's report {report:?}: {e}"))
}

#[test]
#[cfg_attr(
    not(tes_cyclonedds),
    ignore = "PyPI's cyclonedds is not installed: python3 -m venv target/ros2-venv && target/ros2-venv/bin/pip install cyclonedds rosbags"
)]
fn a_cyclone_dds_peer_decodes_every_topic_with_ros2_names_and_types() {
    let (prefix, domain) = own_prefix_and_domain("publish");
    let side = GroupOnRos2::start(
        &prefix,
        Outputs {
            domain: Some(domain),
            bag: None,
            scene: SceneSettings::from_now([1, 2]),
            ..Outputs::default()
        },
    )
    .expect("the ROS 2 side starts");
    assert_eq!(side.reach().map(|r| r.domain), Some(domain));
    let mut group = StandIn::open(&prefix);
    group.world_map();
    let mut peer = Peer::start("listen.py", &[domain.to_string(), LISTEN_S.to_string()]);
    assert_eq!(peer.line(), "ready");
    let report = run_until_the_peer_reports(&mut group, &side, &mut peer);
    let published = side.stop().expect("the ROS 2 side stops cleanly");
    assert!(published.published > 0);
    for topic in Topic::ALL {
        let got = &report[topic.name()];
        assert!(
            got["count"].as_u64() > Some(0),
            "nothing on {}: {report}",
            topic.name()
        );
    }
    let tf = &report["/tf"]["last"];
    assert_eq!(
        (&tf["parent"], &tf["child"]),
        (&"arena".into(), &"robot".into())
    );
    assert!(
        tf["stamp_sec"].as_i64() > Some(1_700_000_000),
        "a wall-clock stamp: {tf}"
    );
    let arena = &report["/tes/arena"]["last"];
    assert_eq!(arena["markers"], 7, "{arena}");
    assert_eq!(arena["frames"], serde_json::json!(["arena", "robot"]));
    assert_eq!(report["/tes/path"]["last"]["frame"], "arena");
    assert!(report["/tes/path"]["last"]["poses"].as_u64() >= Some(1));
    let reward = report["/tes/episode/reward"]["last"]["data"].as_f64();
    assert!(
        reward.is_some_and(|r| (r - 3.0 * f64::from(-0.05f32)).abs() < 1e-9),
        "{reward:?}"
    );
    let end = report["/tes/episode/end"]["last"]["data"]
        .as_str()
        .unwrap_or("");
    assert!(
        end.starts_with("episode ") && end.ends_with(", cut short"),
        "{end}"
    );
    let latency = report["/tes/decision/latency_us"]["last"]["data"].as_f64();
    assert_eq!(latency, Some(40.0));
    let rosout = &report["/rosout"]["last"];
    assert_eq!(
        (&rosout["name"], &rosout["level"]),
        (&"controller".into(), &20.into())
    );
}

#[test]
#[cfg_attr(
    not(tes_rosbags),
    ignore = "PyPI's rosbags is not installed: python3 -m venv target/ros2-venv && target/ros2-venv/bin/pip install cyclonedds rosbags"
)]
fn rosbags_reads_the_bag_topic_by_topic_with_ros2_types() {
    let (prefix, _) = own_prefix_and_domain("bag");
    let dir = tempfile::tempdir().expect("a temporary directory");
    let bag = dir.path().join("run");
    // No ROS 2 node: a bag alone opens no socket.
    let side = GroupOnRos2::start(
        &prefix,
        Outputs {
            domain: None,
            bag: Some(bag.clone()),
            scene: SceneSettings::from_now([1, 2]),
            ..Outputs::default()
        },
    )
    .expect("the ROS 2 side starts");
    assert!(side.reach().is_none());
    let mut group = StandIn::open(&prefix);
    group.world_map();
    let lines = side.log_lines();
    // Two whole episodes, and a log line per action.
    for _ in 0..2 * STEPS {
        group.act();
        lines.send("bridge", "2026-01-01T00:00:00Z  WARN tes_bridge: slow");
        std::thread::sleep(Duration::from_millis(5));
    }
    // The side takes what is queued when it stops; give the log lines their time.
    std::thread::sleep(Duration::from_millis(100));
    let published = side.stop().expect("the ROS 2 side stops cleanly");
    let summary = published.bag.expect("a bag");
    let mut peer = Peer::start("read_bag.py", &[bag.display().to_string()]);
    let line = peer.line();
    let read: Value = serde_json::from_str(&line).unwrap_or_else(|e| panic!("{line:?}: {e}"));
    assert_eq!(read["message_count"].as_u64(), Some(summary.total()));
    for topic in Topic::ALL {
        let got = &read[topic.name()];
        assert_eq!(got["type"], topic.definition().full_name(), "{read}");
        assert_eq!(
            got["count"].as_u64(),
            summary.counts.get(&topic).copied(),
            "{read}"
        );
        let durability = if topic.qos().transient_local {
            "transient_local"
        } else {
            "volatile"
        };
        assert_eq!(got["durability"], durability, "{}", topic.name());
    }
    assert_eq!(read["/tes/episode/end"]["count"], 2);
    assert_eq!(read["/tes/episode/reward"]["count"], 2);
    assert_eq!(
        read["/tes/decision/action"]["count"].as_u64(),
        Some(2 * u64::from(STEPS - 1))
    );
    assert_eq!(read["/tes/arena"]["last"]["markers"], 7);
    assert_eq!(
        read["/rosout"]["count"].as_u64(),
        Some(2 * u64::from(STEPS))
    );
    assert_eq!(read["/rosout"]["last"]["name"], "bridge");
    assert_eq!(read["/tf"]["last"]["parent"], "arena");
}
