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
        serde_json::json!(["belief", "decision", "path", "robot"])
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
    assert_eq!(sdk["channels"].as_object().map(|c| c.len()), Some(12));
    assert!(
        count(&sdk["tf"]) >= 3 && count(&published["tf"]) >= 3,
        "{names}"
    );
}

/// Every message of an MCAP file: its topic, publish time and bytes, in file order.
fn messages(file: &Path) -> Vec<(String, u64, Vec<u8>)> {
    let bytes = std::fs::read(file).expect("the recording reads");
    mcap::MessageStream::new(&bytes)
        .expect("an MCAP file")
        .map(|m| {
            let m = m.expect("a whole message");
            (m.channel.topic.clone(), m.publish_time, m.data.into_owned())
        })
        .collect()
}

/// The messages on `topic`, decoded by `decode`, with their publish times.
fn on<T>(
    all: &[(String, u64, Vec<u8>)],
    topic: &str,
    decode: impl Fn(&[u8]) -> T,
) -> Vec<(u64, T)> {
    all.iter()
        .filter(|(t, ..)| t == topic)
        .map(|(_, at, data)| (*at, decode(data)))
        .collect()
}

/// `/tes/decision` as the file holds it (the derived schema numbers the fields 1..=n).
#[derive(Clone, PartialEq, prost::Message)]
struct DecisionTwin {
    #[prost(uint32, tag = "1")]
    episode: u32,
    #[prost(uint32, tag = "2")]
    step: u32,
    #[prost(uint32, tag = "3")]
    action: u32,
    #[prost(string, tag = "4")]
    action_name: String,
    #[prost(double, tag = "5")]
    latency_us: f64,
}

/// `/tes/episode` as the file holds it.
#[derive(Clone, PartialEq, prost::Message)]
struct EpisodeTwin {
    #[prost(uint32, tag = "1")]
    episode: u32,
    #[prost(double, tag = "2")]
    reward: f64,
    #[prost(uint32, tag = "3")]
    actions: u32,
    #[prost(string, tag = "4")]
    outcome: String,
}

/// Records `episodes` episodes with the launch's defaults (the fastest pace, no `RUST_LOG`).
fn record_by_default(dir: &Path, episodes: u32) -> std::path::PathBuf {
    let file = dir.join("run.mcap");
    let toml = launch_file(dir, &format!("record = \"{}\"\n", file.display()));
    let mut group = Group::start_in(dir, &toml, episodes, &[], &[]);
    let (ok, out, err) = group.finish(LIMIT);
    assert!(ok, "the launch failed: {out:?} {err:?}");
    file
}

/// At the fastest pace the recorder takes observations and commands in batches; each drawn
/// decision still names the observation it answered (observation ↔ command by their stamps
/// in the same file's `tes.*` channels), and each text over the robot pairs the action whose
/// motion led to its observation with the effect that motion had.
#[test]
fn every_drawn_decision_names_the_observation_it_answered_and_the_effect_of_its_action() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = record_by_default(dir.path(), 12);
    every_label_is_true(&messages(&file));
}

/// Each drawn decision against the command and observation it answered, and each text over
/// the robot against the action that led to its observation and the effect it had.
fn every_label_is_true(all: &[(String, u64, Vec<u8>)]) {
    use prost::Message;
    use tes_perception_sim::arena::{ACTION_NAMES, Arena, ArenaId, Effect};
    use tes_recorder::schema::{decode_command, decode_observation};
    use tes_topics::observation_flags;
    let observations = on(all, "/tes/observation", |b| {
        decode_observation(b).expect("an observation")
    });
    let commands = on(all, "/tes/command", |b| {
        decode_command(b).expect("a command")
    });
    let by_stamp: std::collections::HashMap<u64, &tes_topics::Observation> =
        observations.iter().map(|(_, o)| (o.stamp_ns, o)).collect();
    let decisions = on(all, "/tes/decision", |b| {
        DecisionTwin::decode(b).expect("a decision")
    });
    assert_eq!(decisions.len(), commands.len(), "a decision per command");
    assert!(decisions.len() > 40, "{} decisions", decisions.len());
    let mut wrong = Vec::new();
    for (at, d) in &decisions {
        let c = commands
            .iter()
            .map(|(_, c)| c)
            .find(|c| c.stamp_ns == *at)
            .expect("the decision's command is recorded");
        let o = by_stamp
            .get(&c.observed_ns)
            .expect("the command's observation is recorded");
        if (d.episode, d.step, d.action) != (o.episode, o.step, c.action) {
            wrong.push(format!("{d:?} answered {o:?}"));
        }
    }
    assert!(
        wrong.is_empty(),
        "{} of {} decisions mislabelled: {wrong:#?}",
        wrong.len(),
        decisions.len()
    );

    // The text over the robot at each observation.
    let arena = Arena::new(ArenaId::Env3);
    let texts = on(all, "/robot", |b| {
        foxglove::messages::SceneUpdate::decode(b).expect("a scene update")
    });
    let mut checked = 0;
    let mut previous: Option<&tes_topics::Observation> = None;
    for (_, o) in &observations {
        let (_, update) = texts
            .iter()
            .find(|(at, u)| *at == o.stamp_ns && u.entities.iter().any(|e| e.id == "decision"))
            .expect("a text at each observation");
        let text = &update
            .entities
            .iter()
            .find(|e| e.id == "decision")
            .expect("a text")
            .texts[0]
            .text;
        let head = format!("episode {} step {}", o.episode, o.step);
        let action = commands
            .iter()
            .map(|(_, c)| c)
            .find(|c| o.after_command != 0 && c.seq == o.after_command)
            .map(|c| ACTION_NAMES[c.action as usize]);
        let effect = previous
            .filter(|p| p.episode == o.episode && o.flags & observation_flags::RESYNC == 0)
            .and_then(|p| {
                let (from, to) = (arena.state_index(p.state)?, arena.state_index(o.state)?);
                (from < arena.out_state())
                    .then(|| Effect::from_index(arena.effect_between(from, to)))?
            });
        let expected = match (action, effect) {
            (Some(a), Some(e)) => format!("{head}: {a} → {e}"),
            _ => head,
        };
        assert_eq!(text, &expected, "{o:?}");
        checked += 1;
        previous = Some(o);
    }
    assert_eq!(checked, observations.len());
}

/// Without `RUST_LOG` the processes log only warnings, yet `/log` holds the launch's own
/// lines (the group's start, its end), and every panel of the layout the docs hand out has
/// data in a default recording.
#[test]
fn a_default_recording_has_a_log_and_data_for_every_panel_of_the_layout() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = record_by_default(dir.path(), 3);
    let all = messages(&file);
    let logs = on(&all, "/log", |b| {
        <foxglove::messages::Log as prost::Message>::decode(b).expect("a log line")
    });
    let said: Vec<&str> = logs.iter().map(|(_, l)| l.message.as_str()).collect();
    assert!(
        said.iter()
            .any(|l| l.contains("launch: the group") && l.contains("started")),
        "{said:?}"
    );
    assert!(
        said.last().is_some_and(|l| l.contains("3 episodes")),
        "{said:?}"
    );
    assert!(logs.iter().all(|(_, l)| l.name == "launch"
        || ["perception-sim", "controller", "bridge"].contains(&l.name.as_str())));

    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/foxglove/tes-layout.json");
    let layout: Value =
        serde_json::from_str(&std::fs::read_to_string(path).expect("the layout")).expect("JSON");
    let mut topics: Vec<String> = Vec::new();
    for (id, config) in layout["configById"].as_object().expect("panels") {
        if let Some(shown) = config["topics"].as_object() {
            topics.extend(
                shown
                    .iter()
                    .filter(|(_, v)| v["visible"] == true)
                    .map(|(t, _)| t.clone()),
            );
        }
        for p in config["paths"].as_array().into_iter().flatten() {
            let path = p["value"].as_str().expect("a message path");
            topics.push(path.split('.').next().expect("a topic").to_owned());
        }
        if let Some(t) = config["topicToRender"].as_str() {
            topics.push(t.to_owned());
        }
        assert!(!topics.is_empty(), "{id} shows nothing");
    }
    for frame in layout["configById"]["3D!arena"]["transforms"]
        .as_object()
        .expect("frames")
        .keys()
    {
        let frame = frame.strip_prefix("frame:").expect("a frame");
        let tf = on(
            &all,
            if frame == "belief" {
                "/tf/belief"
            } else {
                "/tf"
            },
            |b| {
                <foxglove::messages::FrameTransform as prost::Message>::decode(b)
                    .expect("a transform")
            },
        );
        assert!(
            frame == "arena" || tf.iter().any(|(_, t)| t.child_frame_id == frame),
            "no transform to {frame}"
        );
    }
    for topic in &topics {
        assert!(
            all.iter().any(|(t, ..)| t == topic),
            "the layout shows {topic}, which has no message"
        );
    }
}

/// The true pose (`arena → robot`, from the simulated world) never jumps: within an episode
/// each transform is at most as far from the last as the wheels turned between them could
/// carry the robot (the most a surface lets a wheel's turn carry it, plus a slope's slide),
/// where the observed cell snapped it by up to 0.26 m.
/// The belief (`arena → belief`) is drawn beside it.
#[test]
fn the_robot_moves_as_far_as_its_wheels_turned() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = record_by_default(dir.path(), 6);
    the_robot_moves_as_its_wheels_allow(&messages(&file));
}

/// Each step of `arena → robot` within an episode against the wheels' turn between its two
/// transforms; the belief drawn beside it.
fn the_robot_moves_as_its_wheels_allow(all: &[(String, u64, Vec<u8>)]) {
    use prost::Message;
    use tes_recorder::schema::{decode_motor_state, decode_observation};
    use tes_topics::observation_flags;
    let tf = on(all, "/tf", |b| {
        foxglove::messages::FrameTransform::decode(b).expect("a transform")
    });
    assert!(tf.iter().all(|(_, t)| t.child_frame_id == "robot"));
    let belief = on(all, "/tf/belief", |b| {
        foxglove::messages::FrameTransform::decode(b).expect("a transform")
    });
    assert!(!belief.is_empty() && belief.iter().all(|(_, t)| t.child_frame_id == "belief"));
    let starts: Vec<u64> = on(all, "/tes/observation", |b| {
        decode_observation(b).expect("an observation")
    })
    .into_iter()
    .filter(|(_, o)| o.flags & observation_flags::EPISODE_START != 0)
    .map(|(_, o)| o.stamp_ns)
    .collect();
    let wheels: Vec<(u64, [i32; 2])> = on(all, "/tes/motor-state", |b| {
        decode_motor_state(b).expect("a motor state")
    })
    .into_iter()
    .map(|(_, m)| (m.stamp_ns, [m.tacho_count[1], m.tacho_count[2]]))
    .collect();
    // The counts at time `t`: the last report at or before it.
    let at = |t: u64| {
        wheels
            .iter()
            .rev()
            .find(|(s, _)| *s <= t)
            .map_or([0, 0], |w| w.1)
    };
    let cm_per_deg = std::f64::consts::PI * tes_perception_sim::arena::WHEEL_DIAMETER_CM / 360.0;
    let (mut steps, mut largest) = (0, 0.0f64);
    for pair in tf.windows(2) {
        let ((t0, a), (t1, b)) = (&pair[0], &pair[1]);
        if starts.iter().any(|s| t0 < s && s <= t1) {
            continue; // a new episode puts the robot at its start
        }
        let (p, q) = (a.translation.expect("at"), b.translation.expect("at"));
        let moved_cm = ((q.x - p.x).powi(2) + (q.y - p.y).powi(2)).sqrt() * 100.0;
        let (w0, w1) = (at(*t0), at(*t1));
        let turned_deg = f64::from((w1[0] - w0[0]).abs().max((w1[1] - w0[1]).abs()));
        // A wheel's turn carries the robot at most 1.26 times its arc (on the beans); the
        // slope slides it up to 3.75 cm a motion.
        let bound_cm = 1.3 * turned_deg * cm_per_deg + 4.0;
        assert!(
            moved_cm <= bound_cm,
            "moved {moved_cm:.2} cm with {turned_deg}° of wheel turn ({t0} → {t1})"
        );
        largest = largest.max(moved_cm);
        steps += 1;
    }
    assert!(steps > 100, "{steps} steps");
    assert!(largest > 0.0);
}

/// On a machine whose every core is busy with other work, a recording at the fastest pace
/// still has every channel in time order (a sample read late from one service is drawn after
/// the older ones of another), every label true and the robot moving as its wheels allow.
#[test]
fn under_a_cpu_hog_every_channel_stays_in_time_order_and_every_drawing_true() {
    let dir = tempfile::tempdir().expect("temp dir");
    let hog = CpuHogs::two_per_core();
    let file = record_by_default(dir.path(), 12);
    drop(hog);
    let bytes = std::fs::read(&file).expect("the recording reads");
    let mut last: std::collections::HashMap<String, u64> = std::collections::HashMap::new();
    let mut back = Vec::new();
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("a whole message");
        let previous = last.insert(m.channel.topic.clone(), m.log_time);
        if previous.is_some_and(|p| p > m.log_time) {
            back.push(format!("{} {previous:?} → {}", m.channel.topic, m.log_time));
        }
    }
    assert!(back.is_empty(), "log times go back: {back:#?}");
    assert!(last.contains_key("/tf/belief") && last.contains_key("/tf"));
    let all = messages(&file);
    every_label_is_true(&all);
    the_robot_moves_as_its_wheels_allow(&all);
}

/// The key of a column of the `.rrd` a client read back: `entity archetype:component`.
fn rrd_rows(f: &Value, key: &str) -> u64 {
    f["rows"][key].as_u64().unwrap_or(0)
}

#[test]
#[cfg_attr(
    not(tes_viewer_clients),
    ignore = "the viewers' clients are not installed: python3 -m pip install \
              'rerun-sdk[catalog]==0.41.*' 'mcap==1.*' 'websockets==17.*'"
)]
fn rerun_draws_a_recording_natively_shapes_path_robot_texts_and_plots() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (file, out) = record(dir.path(), 3);
    let rrd = dir.path().join("native.rrd");
    let f = client_facts(&[
        "native",
        file.to_str().expect("utf-8"),
        rrd.to_str().expect("utf-8"),
    ]);
    let rows = |key: &str| rrd_rows(&f, key);
    // The arena as shapes to scale: its cubes (floor, cells, death spots, walls) as boxes, the
    // floor Env 3's 6 ft (1.8288 m) across, the marks as cylinders, the ball as a sphere.
    assert_eq!(rows("/arena/arena/boxes Boxes3D:half_sizes"), 1, "{f}");
    assert!(count(&f["arena_boxes"]) > 4 + 1, "{f}");
    let side = f["largest_box_m"].as_f64().expect("a size");
    assert!((side - (1.8288 + 2.0 * 0.02)).abs() < 1e-6, "{side}");
    assert_eq!(rows("/arena/arena/cylinders Cylinders3D:lengths"), 1, "{f}");
    assert_eq!(
        rows("/arena/arena/spheres Ellipsoids3D:half_sizes"),
        1,
        "{f}"
    );
    assert_eq!(rows("/arena/arena/lines0 LineStrips3D:strips"), 1, "{f}");
    // The robot's body in its frame, moving; the belief beside it; the path as a line.
    assert_eq!(
        rows("/arena/robot/robot/boxes Boxes3D:half_sizes"),
        1,
        "{f}"
    );
    assert_eq!(
        rows("/arena/belief/belief/boxes Boxes3D:half_sizes"),
        1,
        "{f}"
    );
    assert!(rows("/arena/robot Transform3D:translation") > 20, "{f}");
    assert!(rows("/arena/belief Transform3D:translation") > 20, "{f}");
    assert!(rows("/arena/path LineStrips3D:strips") > 10, "{f}");
    // Each decision as text, the text over the robot, the log; the two plots.
    let decisions = reported_actions(&out);
    assert_eq!(rows("/decisions TextLog:text"), decisions, "{f}");
    assert_eq!(rows("/plots/latency_us Scalars:scalars"), decisions, "{f}");
    assert_eq!(rows("/plots/reward Scalars:scalars"), 3, "{f}");
    assert_eq!(rows("/episodes TextLog:text"), 3, "{f}");
    assert!(rows("/log TextLog:text") >= 2, "{f}");
    assert!(rows("/arena/robot/said Points3D:labels") > 10, "{f}");
    let said = f["said"][0].as_str().expect("a text over the robot");
    assert!(said.starts_with("episode 0 step "), "{said}");
}

#[test]
#[cfg_attr(
    not(tes_viewer_clients),
    ignore = "the viewers' clients are not installed: python3 -m pip install \
              'rerun-sdk[catalog]==0.41.*' 'mcap==1.*' 'websockets==17.*'"
)]
fn rerun_draws_a_live_group_natively() {
    let dir = tempfile::tempdir().expect("temp dir");
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
    let rrd = dir.path().join("live.rrd");
    let f = client_facts(&["native-live", &addr, rrd.to_str().expect("utf-8"), "8"]);
    kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGINT).expect("SIGINT");
    let (ok, out, err) = group.finish(LIMIT);
    assert!(ok, "the group stopped cleanly on Ctrl-C: {out:?} {err:?}");
    let rows = |key: &str| rrd_rows(&f, key);
    // The arena drawn again for the client that joined, the robot moving, decisions.
    assert_eq!(rows("/arena/arena/boxes Boxes3D:half_sizes"), 1, "{f}");
    assert_eq!(
        rows("/arena/robot/robot/boxes Boxes3D:half_sizes"),
        1,
        "{f}"
    );
    assert!(rows("/arena/robot Transform3D:translation") > 5, "{f}");
    assert!(rows("/decisions TextLog:text") > 5, "{f}");
    assert!(rows("/plots/latency_us Scalars:scalars") > 5, "{f}");
}

/// A drawn grid run names each episode's end by the cell the agent ended on: the green exit
/// tile is `exit`, the orange fire tile `fire`, any other `cut short`, whatever the sign of the
/// episode's total reward (read from the drawing alone: the tiles' colours, the last
/// transform before each end).
#[test]
fn a_drawn_grid_run_ends_each_episode_as_the_cell_it_ended_on() {
    use prost::Message;
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("grid");
    let out_s = out.to_string_lossy().into_owned();
    let drawn = format!("{out_s}/run.mcap");
    let run = tes(&[
        "experiment",
        "grid",
        "--quick",
        "--runs",
        "1",
        "--episodes",
        "1",
        "--out",
        &out_s,
        "--draw",
        &drawn,
        "--draw-episodes",
        "25",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let all = messages(Path::new(&drawn));
    let arena = on(&all, "/arena", |b| {
        foxglove::messages::SceneUpdate::decode(b).expect("the grid")
    });
    let tiles: Vec<([f64; 2], [f64; 3])> = arena[0].1.entities[0]
        .cubes
        .iter()
        .filter(|c| c.size.is_some_and(|s| s.z < 0.005))
        .map(|c| {
            let (p, k) = (
                c.pose.expect("placed").position.expect("at"),
                c.color.expect("coloured"),
            );
            ([p.x, p.y], [k.r, k.g, k.b])
        })
        .collect();
    let tf = on(&all, "/tf", |b| {
        foxglove::messages::FrameTransform::decode(b).expect("a transform")
    });
    let ends = on(&all, "/tes/episode", |b| {
        EpisodeTwin::decode(b).expect("an end")
    });
    assert_eq!(ends.len(), 25);
    let near = |a: f64, b: f64| (a - b).abs() < 1e-6;
    let mut finished = 0;
    for (at, end) in &ends {
        let (_, last) = tf
            .iter()
            .rev()
            .find(|(t, _)| t <= at)
            .expect("the agent was drawn");
        let p = last.translation.expect("at");
        let (_, colour) = tiles
            .iter()
            .find(|(c, _)| near(c[0], p.x) && near(c[1], p.y))
            .expect("the agent ends on a cell's centre");
        let cell = match colour {
            [r, g, b] if near(*r, 0.10) && near(*g, 0.85) && near(*b, 0.30) => "exit",
            [r, g, b] if near(*r, 1.0) && near(*g, 0.40) && near(*b, 0.0) => "fire",
            _ => "cut short",
        };
        assert_eq!(end.outcome, cell, "{end:?}");
        finished += usize::from(cell != "cut short");
    }
    assert!(finished > 0, "no episode reached an exit or fire: {ends:?}");
}
