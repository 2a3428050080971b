//! Deciding first makes the decisions learning first made, bit for bit.
//!
//! The command an observation gets comes from the last adopted plan, and that plan was made
//! from an earlier hand-over of the model, so moving the learning behind the command cannot
//! change it. These tests drive the acting loop over the paper's arena Env 3 both ways, with
//! each kind of planner, and compare every command, every working view and score, and the
//! library the task leaves. Each plan is made before the next observation (the planner is
//! settled between observations) so that the two runs adopt each plan at the same step, as
//! a fast enough planner does live. Adopting it before the observation comes (as an
//! anticipating wait's poll window does) decides the same too.

use std::time::Duration;

use crate::driver::ArenaDriver;
use tes_controller::acting::{ActingLoop, ActingSettings, Order};
use tes_controller::realtime::{Planner, PlannerThread, SlicedPlanner};
use tes_learning::library::store::{StoredLibrary, encode};
use tes_learning::library::{LibraryParams, ViewLibrary};
use tes_learning::plan::PlannerParams;
use tes_topics::Command;

/// Who plans in a run.
#[derive(Debug, Clone, Copy)]
enum Planning {
    Inline,
    Thread,
    BetweenPolls,
}

impl Planning {
    fn planner(
        self,
    ) -> impl FnOnce(
        std::sync::Arc<tes_learning::cmdp::CmdpStructure>,
    ) -> Result<Planner, tes_controller::realtime::PlannerThreadError> {
        move |s| {
            let params = PlannerParams::default();
            Ok(match self {
                Planning::Inline => Planner::Inline(Box::new(SlicedPlanner::new(s, params, 1)?)),
                Planning::Thread => Planner::Thread(PlannerThread::spawn(s, params)?),
                Planning::BetweenPolls => {
                    Planner::BetweenPolls(Box::new(SlicedPlanner::new(s, params, 32)?))
                }
            })
        }
    }
}

/// What a run did: its commands (without their stamps), the working views at its end, and
/// the library the task leaves.
struct Run {
    commands: Vec<Command>,
    views: String,
    library: Vec<u8>,
    plans: u64,
    learned: u64,
}

/// How a run waits between observations: `prepare` adopts the finished plan before the
/// next observation comes, as an anticipating wait's poll window does.
fn run(
    library: &ViewLibrary,
    planning: Planning,
    order: Order,
    offer_before: bool,
    prepare: bool,
) -> Run {
    let settings = ActingSettings {
        order,
        offer_before_command: offer_before,
        save_interval: Duration::ZERO,
        ..ActingSettings::default()
    };
    let mut driver = ArenaDriver::new(23);
    let mut acting = ActingLoop::new(
        driver.map.clone(),
        library.clone(),
        settings,
        planning.planner(),
    )
    .unwrap();
    let mut commands = Vec::new();
    for t in 0..12_000u64 {
        if prepare {
            acting.prepare();
        }
        if let Some(command) = driver.step(&mut acting) {
            // Stamps come from the shared fake clock, which other work may read more or
            // less often; what was decided is the rest.
            commands.push(Command {
                stamp_ns: 0,
                observed_ns: 0,
                ..command
            });
        }
        // Between polls, some slices now and then (adopting a finished plan early, as a
        // spinning loop does); then the plan in flight is finished before the next
        // observation either way.
        for _ in 0..t % 5 {
            acting.plan_between_polls();
        }
        assert!(
            acting.settle_planner(Duration::from_secs(30)).unwrap(),
            "{planning:?}: no plan within 30 s"
        );
    }
    let counts = acting.counts();
    let plans = acting.plans();
    let views = (0..driver.map.n_actions as usize)
        .map(|a| format!("{:?}", acting.agent().working_views(a)))
        .collect::<Vec<_>>()
        .join("\n");
    let (_, agent) = acting.finish();
    let (library, _) = agent.finish_task().unwrap();
    let library = encode(&StoredLibrary {
        library,
        world: "arena 3".into(),
        action_names: Vec::new(),
        feature_names: Vec::new(),
    });
    Run {
        commands,
        views,
        library,
        plans,
        learned: counts.learned,
    }
}

/// A library of views learned on Env 3 by a first task, so that scoring and selection have
/// something to choose from.
fn learned_library() -> ViewLibrary {
    let driver = ArenaDriver::new(5);
    let (actions, effects, features) = (
        driver.map.n_actions as usize,
        driver.map.n_effects as usize,
        driver.map.n_features as usize,
    );
    let empty = ViewLibrary::new(actions, effects, features, LibraryParams::default()).unwrap();
    let first = run_task(empty);
    assert!(!first.is_empty(), "the first task left no view");
    first
}

fn run_task(library: ViewLibrary) -> ViewLibrary {
    let mut driver = ArenaDriver::new(5);
    let settings = ActingSettings::default();
    let mut acting = ActingLoop::new(
        driver.map.clone(),
        library,
        settings,
        Planning::Inline.planner(),
    )
    .unwrap();
    for _ in 0..3_000 {
        driver.step(&mut acting);
    }
    acting.finish().1.finish_task().unwrap().0
}

fn same_run(planning: Planning) {
    let library = learned_library();
    let reference = run(&library, planning, Order::LearnFirst, true, false);
    assert!(
        reference.commands.len() >= 10_000,
        "{planning:?}: only {} commands",
        reference.commands.len()
    );
    assert!(
        reference.plans > 100,
        "{planning:?}: {} plans",
        reference.plans
    );
    assert!(reference.learned > 9_000, "{planning:?}");
    for (order, offer_before, prepare) in [
        (Order::LearnFirst, false, false),
        (Order::DecideFirst, true, false),
        (Order::DecideFirst, true, true),
    ] {
        let other = run(&library, planning, order, offer_before, prepare);
        let first_difference = reference
            .commands
            .iter()
            .zip(&other.commands)
            .position(|(a, b)| a != b);
        assert_eq!(
            first_difference, None,
            "{planning:?}, {order} (hand-over before the command: {offer_before}, \
             plan adopted before the observation: {prepare}): the commands differ"
        );
        assert_eq!(
            reference.commands.len(),
            other.commands.len(),
            "{planning:?}, {order}"
        );
        assert_eq!(reference.plans, other.plans, "{planning:?}, {order}");
        assert_eq!(reference.learned, other.learned, "{planning:?}, {order}");
        assert!(
            reference.views == other.views,
            "{planning:?}, {order}: the working views or their scores differ"
        );
        assert!(
            reference.library == other.library,
            "{planning:?}, {order}: the libraries differ"
        );
    }
}

#[test]
fn deciding_first_decides_the_same_with_inline_planning() {
    same_run(Planning::Inline);
}

#[test]
fn deciding_first_decides_the_same_with_a_planner_thread() {
    same_run(Planning::Thread);
}

#[test]
fn deciding_first_decides_the_same_planning_between_polls() {
    same_run(Planning::BetweenPolls);
}
