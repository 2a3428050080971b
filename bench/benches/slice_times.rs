//! How long one slice of between-polls planning takes (`SlicedPlanner::work_then_adopt`):
//! the wait an observation arriving mid-slice may see. On the arena-shaped CMDP (800 states
//! × 3 actions × 20 effects, 312 features, views trained on 3 000 seeded steps), 3 000
//! learning steps of a seeded random policy are each handed to the planner and planned in
//! slices; every slice is timed, and every plan from hand-over to adoption.
//!
//! ```sh
//! cargo bench -p tes-bench --bench slice_times -- 32   # states per slice
//! ```
//!
//! A measuring program rather than a criterion benchmark (`harness = false`): a bench target,
//! so that `cargo test` does not build it.

use std::sync::Arc;
use std::time::Instant;

use rand::{RngExt, SeedableRng};
use tes_controller::realtime::SlicedPlanner;
use tes_learning::mdagl::Features;
use tes_learning::plan::{PlannedModel, PlannerParams};

fn main() -> anyhow::Result<()> {
    // `cargo bench` adds `--bench`: the states per slice is the first other argument.
    let slice: usize = match std::env::args().skip(1).find(|a| !a.starts_with("--")) {
        Some(s) => s.parse()?,
        None => 32,
    };
    // The controller's default sweep cap per hand-over.
    let params = PlannerParams {
        max_sweeps: 500,
        ..PlannerParams::default()
    };
    let structure = Arc::new(tes_bench::fixtures::arena_like(312, 2017)?);
    let mut views = tes_bench::fixtures::trained_views(&structure, 3000, 2017)?;
    let mut acting = PlannedModel::new(structure.clone(), params)?;
    for (a, v) in views.iter().enumerate() {
        acting.refresh(a, v)?;
    }
    while acting.replan().is_some() {}
    acting.plan_elsewhere();
    let mut planner = SlicedPlanner::new(structure.clone(), params, slice)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let (mut slices, mut plans) = (Vec::new(), Vec::new());
    for _ in 0..3000 {
        let s = rng.random_range(0..structure.n_states());
        let a = rng.random_range(0..structure.n_actions());
        let e = rng.random_range(0..structure.n_effects());
        views[a].update(Features::SparseBinary(structure.features(s)), e)?;
        acting.refresh(a, &views[a])?;
        if !planner.offer(&mut acting)? {
            continue;
        }
        let plan_start = Instant::now();
        loop {
            let start = Instant::now();
            let more = planner.work_then_adopt(&mut acting);
            slices.push(start.elapsed().as_nanos() as u64);
            if !more {
                break;
            }
        }
        plans.push(plan_start.elapsed().as_nanos() as u64);
    }
    let show = |name: &str, mut v: Vec<u64>| {
        v.sort_unstable();
        let q = |p: f64| v[((v.len() - 1) as f64 * p) as usize];
        println!(
            "{name} ({}): p50 {} p90 {} p99 {} p99.9 {} max {} ns",
            v.len(),
            q(0.5),
            q(0.9),
            q(0.99),
            q(0.999),
            v[v.len() - 1]
        );
    };
    println!(
        "slices of {slice} states, {} plans adopted",
        planner.plans()
    );
    show("one slice", slices);
    show("one plan, hand-over to adoption", plans);
    Ok(())
}
