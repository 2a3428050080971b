//! `tes experiment grid --draw`: a grid run drawn for Foxglove and Rerun is the study's run
//! (the same episodes for the same method, task and seed), in a complete MCAP file whose
//! channels are the drawn scene's.

use tes_experiments::episode::{AgentSettings, run_agent};
use tes_experiments::grid::{GridConfig, GridEnv, draw_run};
use tes_experiments::method::Method;
use tes_learning::plan::PlannerParams;
use tes_perception_sim::grid::GridSuite;

#[test]
fn the_drawn_grid_run_is_the_studys_run_in_a_complete_file() {
    let config = GridConfig::quick();
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("grid.mcap");
    let drawn = draw_run(&config, &path, 3).expect("draws");
    assert_eq!(
        (drawn.method, drawn.seed, drawn.episodes.len()),
        (Method::LoreRl, 1, 3)
    );

    let task = GridSuite::paper(config.world_seed, drawn.irrelevant)
        .into_iter()
        .nth(config.task_index)
        .expect("the task");
    let env = GridEnv::new(task).expect("an environment");
    let settings = AgentSettings {
        planner: PlannerParams {
            stop_at_drift: config.stop_at_drift,
            ..PlannerParams::default()
        },
        ..AgentSettings::default()
    };
    let unwatched = run_agent(Method::LoreRl, &env, 3, 1, settings, |_| {}).expect("runs");
    let rewards = |e: &[tes_experiments::episode::Episode]| -> Vec<(f64, u32)> {
        e.iter().map(|e| (e.reward, e.steps)).collect()
    };
    assert_eq!(rewards(&drawn.episodes), rewards(&unwatched));

    let bytes = std::fs::read(&path).expect("the file");
    let summary = mcap::Summary::read(&bytes)
        .expect("a complete file")
        .expect("with a summary");
    let mut topics: Vec<&str> = summary
        .channels
        .values()
        .map(|c| c.topic.as_str())
        .collect();
    topics.sort_unstable();
    assert_eq!(
        topics,
        [
            "/arena",
            "/arena/points",
            "/robot",
            "/tes/decision",
            "/tes/decision/latency_us",
            "/tes/episode",
            "/tes/episode/reward",
            "/tf"
        ]
    );
    let steps: u32 = drawn.episodes.iter().map(|e| e.steps).sum();
    // Per step a decision and its latency, a transform and a robot update; per episode a
    // start's transform and robot update, an end and its reward; the arena, its points and
    // the agent's body once. A step that moves the agent glides there: 3 transforms more.
    let fixed = u64::from(4 * steps) + 3 * 4 + 3;
    let glides = drawn
        .messages
        .checked_sub(fixed)
        .expect("at least the fixed messages");
    assert_eq!(
        glides % 3,
        0,
        "{} messages: whole glides beyond {fixed}",
        drawn.messages
    );
    assert!(
        glides / 3 <= u64::from(steps),
        "{} glides in {steps} steps",
        glides / 3
    );
}
