//! The Foxglove layout the docs hand users (`docs/foxglove/tes-layout.json`) opens on what the
//! scene draws: every panel of its tree is configured, the 3D panel follows the robot's frame
//! and shows the scene's topics, the plots read fields the scene's messages have, the log
//! panel reads `/log`.

use serde_json::Value;
use tes_viewer::robot::ROBOT_FRAME;
use tes_viewer::scene::{DECISION, Decision, EPISODE, EpisodeEnd, LOG, Scene, SceneSettings};

fn layout() -> Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../docs/foxglove/tes-layout.json"
    );
    let text = std::fs::read_to_string(path).expect("the layout is in the docs");
    serde_json::from_str(&text).expect("the layout is JSON")
}

fn leaves(node: &Value, out: &mut Vec<String>) {
    match node {
        Value::String(id) => out.push(id.clone()),
        Value::Object(split) => {
            leaves(&split["first"], out);
            leaves(&split["second"], out);
        }
        other => panic!("not a layout node: {other}"),
    }
}

#[test]
fn the_layout_opens_on_the_scenes_topics() {
    let layout = layout();
    let configs = layout["configById"].as_object().expect("panel configs");
    let mut panels = Vec::new();
    leaves(&layout["layout"], &mut panels);
    assert_eq!(panels.len(), configs.len());
    for id in &panels {
        assert!(configs.contains_key(id), "{id} has no config");
    }

    let scene = Scene::new(SceneSettings::default());
    let topics: Vec<&str> = scene.channels().map(|c| c.topic).collect();
    let three_d = &configs["3D!arena"];
    assert_eq!(three_d["followTf"], ROBOT_FRAME);
    for topic in three_d["topics"].as_object().expect("topics").keys() {
        assert!(topics.contains(&topic.as_str()), "{topic} is not drawn");
    }
    let plotted: Vec<String> = ["Plot!reward", "Plot!latency"]
        .iter()
        .flat_map(|id| configs[*id]["paths"].as_array().expect("paths").clone())
        .map(|p| p["value"].as_str().expect("a path").to_owned())
        .collect();
    // The fields plotted are the messages' own (named here, so a rename breaks this test).
    let _ = (Decision::default().latency_us, EpisodeEnd::default().reward);
    assert_eq!(
        plotted,
        [
            format!("{EPISODE}.reward"),
            format!("{DECISION}.latency_us")
        ]
    );
    assert_eq!(configs["RosOut!log"]["topicToRender"], LOG);
}
