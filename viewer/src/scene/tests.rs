use super::*;
use crate::canvas::Collected;
use foxglove::messages::FrameTransform;
use prost::Message;
use tes_topics::StateAttributes;

fn arena_map(world: u32) -> Box<WorldMap> {
    let mut map = Box::new(WorldMap::EMPTY);
    map.world = world;
    map
}

fn observation(seq: u64, episode: u32, step: u32, at: StateAttributes, flags: u32) -> Observation {
    Observation {
        seq,
        stamp_ns: seq * 1_000_000,
        episode,
        step,
        state: at,
        reward: if flags & observation_flags::TERMINAL != 0 {
            2.0
        } else {
            -0.05
        },
        flags,
        ..Observation::default()
    }
}

fn decoded<M: Message + Default>(drawn: &Collected, topic: &str) -> Vec<M> {
    drawn
        .on(topic)
        .map(|b| M::decode(b).expect("a well-formed message"))
        .collect()
}

#[test]
fn a_short_episode_draws_the_arena_the_robot_its_path_decisions_and_reward() {
    let mut scene = Scene::new(SceneSettings {
        wall_offset_ns: 1_700_000_000_000_000_000,
        ..SceneSettings::default()
    });
    let mut drawn = Collected::default();
    let ok = |r: Result<(), std::convert::Infallible>| r.unwrap_or_else(|e| match e {});
    ok(scene.world_map(&arena_map(3), 1, &mut drawn));
    ok(scene.observation(
        &observation(
            1,
            0,
            0,
            StateAttributes::at(2, 2, 0),
            observation_flags::EPISODE_START,
        ),
        &mut drawn,
    ));
    let forward = Command {
        seq: 1,
        answers: 1,
        stamp_ns: 1_000_000 + 12_000,
        observed_ns: 1_000_000,
        action: 0,
        ..Command::default()
    };
    ok(scene.command(&forward, &mut drawn));
    // The wheels turn (port 1 left, port 2 right): the robot is dead-reckoned east.
    for (i, deg) in [0, 120, 246].into_iter().enumerate() {
        let m = MotorState {
            seq: i as u64 + 1,
            stamp_ns: 1_500_000 + i as u64,
            tacho_count: [0, deg, deg],
            ..MotorState::default()
        };
        ok(scene.motor_state(&m, &mut drawn));
    }
    ok(scene.observation(
        &Observation {
            after_command: forward.seq,
            ..observation(
                2,
                0,
                1,
                StateAttributes::at(3, 2, 0),
                observation_flags::TERMINAL,
            )
        },
        &mut drawn,
    ));

    let arena: Vec<SceneUpdate> = decoded(&drawn, ARENA);
    assert_eq!(arena.len(), 1);
    assert_eq!(arena[0].entities[0].frame_id, "arena");
    assert_eq!(drawn.on(ARENA_POINTS).count(), 1);

    // No world pose came (and too few observations to give up on one): the belief alone.
    assert_eq!(drawn.on(TF).count(), 0);
    let tf: Vec<FrameTransform> = decoded(&drawn, TF_BELIEF);
    // At each observation (2) and as the wheels turned (2 reports after the baseline).
    assert_eq!(tf.len(), 4, "{tf:?}");
    let xs: Vec<f64> = tf.iter().map(|t| t.translation.expect("set").x).collect();
    assert!(xs.windows(2).all(|w| w[1] > w[0]), "moving east: {xs:?}");
    assert!(
        tf.iter()
            .all(|t| t.parent_frame_id == "arena" && t.child_frame_id == "belief")
    );
    let ts = tf[0].timestamp.expect("stamped");
    assert!(ts.sec() >= 1_700_000_000, "wall-clock time: {ts:?}");

    let robot: Vec<SceneUpdate> = decoded(&drawn, ROBOT);
    let last = robot.last().expect("drawn");
    let path = last
        .entities
        .iter()
        .find(|e| e.id == "path")
        .expect("a path");
    assert_eq!(path.lines[0].points.len(), 2);
    let text = &last
        .entities
        .iter()
        .find(|e| e.id == "decision")
        .expect("a decision")
        .texts[0];
    assert_eq!(text.text, "episode 0 step 1: forward → forward, no turn");
    assert!(
        robot
            .iter()
            .any(|u| u.entities.iter().any(|e| e.id == "robot" && e.frame_locked))
    );

    let decisions: Vec<DecisionTwin> = decoded(&drawn, DECISION);
    assert_eq!(decisions.len(), 1);
    assert_eq!(decisions[0].action_name, "forward");
    assert!((decisions[0].latency_us - 12.0).abs() < 1e-9);

    // The same numbers as plain series: one per decision, one per episode.
    assert_eq!(drawn.on(LATENCY_SERIES).count(), 1);
    assert_eq!(drawn.on(REWARD_SERIES).count(), 1);

    let ends: Vec<EpisodeTwin> = decoded(&drawn, EPISODE);
    assert_eq!(ends.len(), 1);
    assert_eq!(ends[0].outcome, "ball");
    assert!((ends[0].reward - 2.0).abs() < 1e-9 && ends[0].actions == 1);
}

/// Our derived messages read through hand-written prost twins: the derived schema numbers
/// the fields 1..=n in declaration order.
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

/// The recorder may hand over a command before the observation it answers (or several
/// observations before their commands): each decision is labelled with its own observation,
/// and each text with the action whose motion led to its observation.
#[test]
fn decisions_are_labelled_by_the_observation_they_answer_whatever_the_order() {
    let mut scene = Scene::new(SceneSettings::default());
    let mut drawn = Collected::default();
    let ok = |r: Result<(), std::convert::Infallible>| r.unwrap_or_else(|e| match e {});
    ok(scene.world_map(&arena_map(3), 1, &mut drawn));
    let at = |x| StateAttributes::at(x, 2, 0);
    let command = |seq, answers, action| Command {
        seq,
        answers,
        stamp_ns: answers * 1_000_000 + 500,
        observed_ns: answers * 1_000_000,
        action,
        ..Command::default()
    };
    // Observations 1 and 2 before the command answering 1; the one answering 3 before 3.
    ok(scene.observation(
        &observation(1, 4, 0, at(2), observation_flags::EPISODE_START),
        &mut drawn,
    ));
    let second = Observation {
        after_command: 1,
        ..observation(2, 4, 1, at(3), 0)
    };
    ok(scene.observation(&second, &mut drawn));
    ok(scene.command(&command(1, 1, 0), &mut drawn));
    ok(scene.command(&command(2, 2, 1), &mut drawn));
    ok(scene.command(&command(3, 3, 2), &mut drawn));
    let third = Observation {
        after_command: 2,
        ..observation(3, 4, 2, at(3), 0)
    };
    ok(scene.observation(&third, &mut drawn));
    let decisions: Vec<DecisionTwin> = decoded(&drawn, DECISION);
    let labels: Vec<(u32, u32, String)> = decisions
        .iter()
        .map(|d| (d.episode, d.step, d.action_name.clone()))
        .collect();
    assert_eq!(
        labels,
        [
            (4, 0, "forward".to_owned()),
            (4, 1, "spin".to_owned()),
            (4, 2, "pivot".to_owned())
        ]
    );
    let texts: Vec<String> = decoded::<SceneUpdate>(&drawn, ROBOT)
        .iter()
        .flat_map(|u| u.entities.iter())
        .filter(|e| e.id == "decision")
        .map(|e| e.texts[0].text.clone())
        .collect();
    // The second observation was drawn before its command was taken: its action is not
    // known yet, and no other action is put in its place; the third names the spin.
    assert_eq!(texts[0], "episode 4 step 0");
    assert!(
        texts[2].starts_with("episode 4 step 2: spin → "),
        "{texts:?}"
    );
}

#[test]
fn a_world_that_is_not_an_arena_draws_nothing_and_says_so_once() {
    let mut scene = Scene::new(SceneSettings::default());
    let mut drawn = Collected::default();
    let ok = |r: Result<(), std::convert::Infallible>| r.unwrap_or_else(|e| match e {});
    ok(scene.world_map(&arena_map(0), 1, &mut drawn));
    ok(scene.observation(
        &observation(1, 0, 0, StateAttributes::at(0, 0, 0), 0),
        &mut drawn,
    ));
    assert!(drawn.drawings.is_empty());
}

#[test]
fn log_levels_come_from_the_tracing_line() {
    assert_eq!(
        level_of("2026-12-05T23:23:02Z  WARN bridge: slow"),
        log::Level::Warning
    );
    assert_eq!(
        level_of("2026-12-05T23:23:02Z ERROR x: y"),
        log::Level::Error
    );
    assert_eq!(level_of("plain words"), log::Level::Info);
}

#[test]
fn every_channel_describes_its_messages() {
    let scene = Scene::new(SceneSettings::default());
    for c in scene.channels() {
        let (schema, message) = match c.topic {
            LATENCY_SERIES | REWARD_SERIES => ("ros2msg", "cdr"),
            _ => ("protobuf", "protobuf"),
        };
        assert_eq!(c.encoding, message, "{}", c.topic);
        assert_eq!(c.schema.encoding, schema, "{}", c.topic);
        assert!(!c.schema.data.is_empty(), "{}", c.topic);
    }
}

/// A straggler (an observation handed over after a motor report newer than it) is drawn at
/// its channels' last time, never before: each channel stays in time order.
#[test]
fn a_sample_older_than_the_last_drawn_is_drawn_at_its_channels_last_time() {
    let mut scene = Scene::new(SceneSettings::default());
    let mut drawn = Collected::default();
    let ok = |r: Result<(), std::convert::Infallible>| r.unwrap_or_else(|e| match e {});
    ok(scene.world_map(&arena_map(3), 1, &mut drawn));
    let start = observation(
        1,
        0,
        0,
        StateAttributes::at(2, 2, 0),
        observation_flags::EPISODE_START,
    );
    ok(scene.observation(&start, &mut drawn));
    for (i, deg) in [0, 90, 180].into_iter().enumerate() {
        let m = MotorState {
            seq: i as u64 + 1,
            stamp_ns: 5_000_000 + i as u64,
            tacho_count: [0, deg, deg],
            ..MotorState::default()
        };
        ok(scene.motor_state(&m, &mut drawn));
    }
    // Published at 3 ms, before the reports above, but handed over after them.
    ok(scene.observation(
        &observation(3, 0, 1, StateAttributes::at(3, 2, 0), 0),
        &mut drawn,
    ));
    let mut last: std::collections::HashMap<&str, u64> = std::collections::HashMap::new();
    for (topic, _, wall_ns) in &drawn.drawings {
        let before = last.insert(topic, *wall_ns).unwrap_or(0);
        assert!(before <= *wall_ns, "{topic}: {before} then {wall_ns}");
    }
    let beliefs: Vec<u64> = drawn
        .drawings
        .iter()
        .filter(|(t, ..)| *t == TF_BELIEF)
        .map(|(.., w)| *w)
        .collect();
    assert_eq!(beliefs.len(), 4, "{beliefs:?}");
    assert_eq!(beliefs[3], 5_000_002, "drawn at the last report's time");
}
