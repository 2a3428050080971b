//! The learning path's costs, piece by piece:
//!
//! * `planner/full` — value iteration from scratch to convergence (tolerance 1e-4);
//! * `planner/incremental` — what one step costs the planner: a view learns one step, its
//!   action's model rows are refreshed, and the anytime re-plan runs (≤ 10 warm sweeps);
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

use criterion::{BatchSize, BenchmarkId, Criterion, criterion_group, criterion_main};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tes_bench::experiment::EpisodicTask;
use tes_bench::experiment::grid::GridEnv;
use tes_controller::agents::{Agent, Tes, TesParams};
use tes_controller::cmdp::CmdpStructure;
use tes_controller::library::{ActionOutcome, LibraryParams, ViewLibrary, Winner};
use tes_controller::mdagl::{Features, Mdagl, MdaglParams};
use tes_controller::plan::{PlannedModel, PlannerParams, ValueIteration};
use tes_controller::realtime::PlannerThread;
use tes_perception_sim::grid::GridSuite;

const SEED: u64 = 2017;

/// An arena-shaped CMDP: a 10×10 grid × 8 headings, 20 effects (4 moves × 5 turns relative
/// to the heading), 312 binary features with ~15 on per state, a ball (+2) and death spots.
fn arena_like() -> CmdpStructure {
    let (w, o) = (10i32, 8i32);
    let n = (w * w * o) as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let features: Vec<Vec<u32>> = (0..n)
        .map(|s| {
            let mut f: Vec<u32> = (0..312u32)
                .filter(|_| rng.random::<f64>() < 0.045)
                .collect();
            f.push(300 + (s % 8) as u32);
            f.sort_unstable();
            f.dedup();
            f
        })
        .collect();
    let dirs = [
        (1, 0),
        (1, 1),
        (0, 1),
        (-1, 1),
        (-1, 0),
        (-1, -1),
        (0, -1),
        (1, -1),
    ];
    let next = |s: usize, e: usize| -> usize {
        let s = s as i32;
        let (cell, h) = (s / o, s % o);
        let (x, y) = (cell % w, cell / w);
        let (m, t) = (e as i32 / 5, e as i32 % 5);
        let dir = match m {
            0 => Some(h),
            1 => Some((h + 1) % o),
            2 => Some((h + o - 1) % o),
            _ => None,
        };
        let (nx, ny) = dir.map_or((x, y), |d| (x + dirs[d as usize].0, y + dirs[d as usize].1));
        let nh = (h + [0, 1, 2, -1, -2][t as usize] + o) % o;
        if (0..w).contains(&nx) && (0..w).contains(&ny) {
            ((ny * w + nx) * o + nh) as usize
        } else {
            s as usize // pushed against the border: stays
        }
    };
    let mut reward = vec![-0.05; n];
    let mut terminal = vec![false; n];
    for cell in [55usize, 12, 87, 33] {
        for h in 0..8 {
            let s = cell * 8 + h;
            reward[s] = if cell == 55 { 2.0 } else { -1.0 };
            terminal[s] = true;
        }
    }
    CmdpStructure::new(n, 3, 20, 312, next, reward, terminal, |s| &features[s])
        .expect("a valid arena-like CMDP")
}

fn grid() -> CmdpStructure {
    let task = GridSuite::paper(SEED, 200).remove(0);
    let env = GridEnv::new(task).expect("the suite's task 0 is valid");
    (*env.structure()).clone()
}

/// Views that have learned `rows` steps of a seeded random policy in `structure`.
fn trained_views(structure: &CmdpStructure, rows: usize, seed: u64) -> Vec<Mdagl> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut views: Vec<Mdagl> = (0..structure.n_actions())
        .map(|_| {
            Mdagl::new(
                structure.n_effects(),
                structure.n_features(),
                MdaglParams::default(),
            )
            .expect("valid settings")
        })
        .collect();
    for _ in 0..rows {
        let s = rng.random_range(0..structure.n_states());
        let a = rng.random_range(0..structure.n_actions());
        // Effects skewed towards the first few, depending on the first feature.
        let first = structure.features(s).first().copied().unwrap_or(0) as usize;
        let e = (first + rng.random_range(0..3)) % structure.n_effects();
        views[a]
            .update(Features::SparseBinary(structure.features(s)), e)
            .expect("valid rows");
    }
    views
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
    }
    group.finish();
}

/// A library with `n` views spread over the actions, trained on different seeds.
fn library(structure: &CmdpStructure, n: usize) -> ViewLibrary {
    let params = LibraryParams {
        max_views: n.max(1),
        ..LibraryParams::default()
    };
    let mut lib = ViewLibrary::new(
        structure.n_actions(),
        structure.n_effects(),
        structure.n_features(),
        params,
    )
    .expect("valid settings");
    let mut task = 0;
    while lib.len() < n {
        let views = trained_views(structure, 500, SEED + task);
        let outcomes = views
            .into_iter()
            .enumerate()
            .take(n - lib.len())
            .map(|(action, model)| ActionOutcome {
                action,
                observations: 500,
                winner: Winner::Fresh,
                model,
                score: -100.0,
                library_scores: vec![],
            })
            .collect();
        lib.end_task(outcomes).expect("valid outcomes");
        task += 1;
    }
    lib
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
    agent.model_mut().set_inline_planning(false);
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
    agent.model_mut().set_inline_planning(false);
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
