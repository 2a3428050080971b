//! The learning path's costs, piece by piece:
//!
//! * `planner/full` — value iteration from scratch to convergence (tolerance 1e-4);
//! * `planner/incremental` — what one step costs the planner: a view learns one step, its
//!   action's model rows are refreshed, and the anytime re-plan runs (≤ 10 warm sweeps);
//! * `planner/slice` — one slice of that work as the controller does it between polls when
//!   it spins (`SlicedPlanner`, 32 states' worth): what an arriving observation may wait;
//! * `tes/score_update` — TES's per-step view work with a 9-view library: score every view
//!   of the taken action (working copies and frozen originals), update the working views,
//!   re-select, refresh the model;
//! * `tes/decision_step` — one whole in-process decision: the above, plus adopting the
//!   planner thread's latest policy, offering it the new model, and choosing the next action.
//!
//! Two shapes: the robot arena (800 states × 3 actions × 20 effects, 312 sparse binary
//! features) and the §5.1 grid (900 states × 4 actions × 5 effects, 210 features). Inputs are
//! built before timing with fixed seeds; parameters are in the benchmark ids.

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{BatchSize, BenchmarkId, Criterion, criterion_group, criterion_main};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tes_bench::fixtures;
use tes_controller::realtime::{PlannerThread, SlicedPlanner};
use tes_experiments::episode::EpisodicTask;
use tes_experiments::grid::GridEnv;
use tes_learning::agents::{Agent, Tes, TesParams};
use tes_learning::cmdp::CmdpStructure;
use tes_learning::library::ViewLibrary;
use tes_learning::mdagl::{Features, Mdagl};
use tes_learning::plan::{PlannedModel, PlannerParams, ValueIteration};
use tes_perception_sim::grid::GridSuite;

const SEED: u64 = 2017;

/// The arena-shaped CMDP (312 features) the benches share with `tes bench scaling`.
fn arena_like() -> CmdpStructure {
    fixtures::arena_like(312, SEED).expect("a valid arena-like CMDP")
}

fn grid() -> CmdpStructure {
    let task = GridSuite::paper(SEED, 200).remove(0);
    let env = GridEnv::new(task).expect("the suite's task 0 is valid");
    (*env.structure()).clone()
}

/// Views that have learned `rows` steps of a seeded random policy in `structure`.
fn trained_views(structure: &CmdpStructure, rows: usize, seed: u64) -> Vec<Mdagl> {
    fixtures::trained_views(structure, rows, seed).expect("valid rows")
}

fn shapes() -> Vec<(&'static str, Arc<CmdpStructure>)> {
    vec![
        ("arena_800x3x20", Arc::new(arena_like())),
        ("grid_900x4x5", Arc::new(grid())),
    ]
}

fn bench_planner(c: &mut Criterion) {
    let mut group = c.benchmark_group("planner");
    group.sample_size(20);
    for (name, structure) in shapes() {
        let views = trained_views(&structure, 3000, SEED);
        let mut model =
            PlannedModel::new(structure.clone(), PlannerParams::default()).expect("valid settings");
        for (a, v) in views.iter().enumerate() {
            model.refresh(a, v).expect("matching shapes");
        }
        let full = PlannerParams {
            max_sweeps: 100_000,
            ..PlannerParams::default()
        };
        group.bench_function(BenchmarkId::new("full", name), |b| {
            b.iter_batched(
                || ValueIteration::new(&structure, full).expect("valid settings"),
                |mut vi| black_box(vi.plan(&structure, model.table())),
                BatchSize::SmallInput,
            )
        });
        // Converge once, then time one learning step's worth of planning.
        let mut warm = model.clone();
        while warm.replan().is_some() {}
        let mut rng = ChaCha8Rng::seed_from_u64(SEED + 1);
        let steps: Vec<(usize, usize, usize)> = (0..256)
            .map(|_| {
                (
                    rng.random_range(0..structure.n_states()),
                    rng.random_range(0..structure.n_actions()),
                    rng.random_range(0..structure.n_effects()),
                )
            })
            .collect();
        let mut i = 0;
        group.bench_function(BenchmarkId::new("incremental", name), |b| {
            b.iter_batched(
                || {
                    i = (i + 1) % steps.len();
                    (warm.clone(), views[steps[i].1].clone(), steps[i])
                },
                |(mut m, mut view, (s, a, e))| {
                    view.update(Features::SparseBinary(structure.features(s)), e)
                        .expect("valid step");
                    m.refresh(a, &view).expect("matching shapes");
                    black_box(m.replan())
                },
                BatchSize::SmallInput,
            )
        });
        // One slice of planning between polls (32 states' worth, the controller's default):
        // what an observation arriving mid-slice waits at most. Each plan is one learning
        // step's (as above), offered untimed; every slice of it is timed, the adoption too.
        let mut acting = warm.clone();
        acting.plan_elsewhere();
        let mut planner = SlicedPlanner::new(structure.clone(), PlannerParams::default(), 32)
            .expect("valid settings");
        let mut views = views.clone();
        let mut i = 0;
        group.bench_function(BenchmarkId::new("slice/32_states", name), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    while !planner.busy() {
                        i = (i + 1) % steps.len();
                        let (s, a, e) = steps[i];
                        views[a]
                            .update(Features::SparseBinary(structure.features(s)), e)
                            .expect("valid step");
                        acting.refresh(a, &views[a]).expect("matching shapes");
                        planner.offer(&mut acting).expect("a plan");
                    }
                    let start = Instant::now();
                    black_box(planner.work_then_adopt(&mut acting));
                    total += start.elapsed();
                }
                total
            })
        });
    }
    group.finish();
}

/// A library with `n` views spread over the actions, trained on different seeds.
fn library(structure: &CmdpStructure, n: usize) -> ViewLibrary {
    fixtures::library_for(structure, n, SEED).expect("valid views")
}

fn bench_tes(c: &mut Criterion) {
    let mut group = c.benchmark_group("tes");
    let (name, structure) = shapes().remove(0);
    let lib = library(&structure, 9);
    let mut rng = ChaCha8Rng::seed_from_u64(SEED + 2);
    let steps: Vec<(usize, usize, usize)> = (0..4096)
        .map(|_| {
            (
                rng.random_range(0..structure.n_states()),
                rng.random_range(0..structure.n_actions()),
                rng.random_range(0..structure.n_effects()),
            )
        })
        .collect();

    let mut agent = Tes::new(structure.clone(), lib.clone(), TesParams::default(), SEED)
        .expect("a valid agent");
    agent.model_mut().plan_elsewhere();
    let mut i = 0;
    group.bench_function(
        BenchmarkId::new("score_update", format!("{name}/9_views")),
        |b| {
            b.iter(|| {
                i = (i + 1) % steps.len();
                let (s, a, e) = steps[i];
                agent.observe(s, a, e).expect("valid step");
            })
        },
    );

    let mut agent =
        Tes::new(structure.clone(), lib, TesParams::default(), SEED).expect("a valid agent");
    agent.model_mut().plan_elsewhere();
    let mut planner = PlannerThread::spawn(structure.clone(), PlannerParams::default())
        .expect("a planner thread");
    let mut i = 0;
    group.bench_function(
        BenchmarkId::new("decision_step", format!("{name}/9_views")),
        |b| {
            b.iter(|| {
                i = (i + 1) % steps.len();
                let (s, a, e) = steps[i];
                agent.observe(s, a, e).expect("valid step");
                planner.collect(agent.model_mut()).expect("planner alive");
                planner.offer(agent.model_mut()).expect("planner alive");
                black_box(agent.act(structure.next_state(s, e)).expect("valid state"))
            })
        },
    );
    group.finish();
}

criterion_group!(benches, bench_planner, bench_tes);
criterion_main!(benches);
