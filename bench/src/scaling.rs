//! How the cost of one decision grows with the feature count and the library size.
//!
//! One decision is what the controller does per observation, in process: score and update the
//! taken action's working views (TES), hand the changed view to the planner thread, adopt its
//! latest plan and pick the next action. Each point runs `actions` decisions on an
//! arena-shaped CMDP ([`crate::fixtures::arena_like`]) with a trained library
//! ([`crate::fixtures::library_for`]) and records every decision's time.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use tes_controller::realtime::PlannerThread;
use tes_learning::agents::{Agent, Tes, TesParams};
use tes_learning::plan::PlannerParams;
use tes_runtime::latency::{LatencyRecorder, LatencyReport};

use crate::fixtures;
use tes_experiments::svg::{BandPoint, LineChart, Series};

/// The feature counts of the sweep (the arena has 312).
pub const FEATURES: [usize; 4] = [52, 312, 1000, 5000];
/// The library sizes of the sweep.
pub const VIEWS: [usize; 3] = [1, 9, 20];

/// One point of the sweep.
#[derive(Debug, Clone, Serialize)]
pub struct ScalingPoint {
    /// Binary features per state vector.
    pub features: usize,
    /// Views in the library.
    pub views: usize,
    /// Decision time (observation → action), µs.
    pub latency: LatencyReport,
}

/// Runs `actions` decisions (after `warmup` more) for `features` features and `views` views.
pub fn measure(
    features: usize,
    views: usize,
    actions: u64,
    warmup: u64,
    seed: u64,
) -> Result<ScalingPoint> {
    let structure = Arc::new(fixtures::arena_like(features, seed)?);
    let library = fixtures::library_for(&structure, views, seed)?;
    let mut agent = Tes::new(structure.clone(), library, TesParams::default(), seed)?;
    agent.model_mut().plan_elsewhere();
    let mut planner = PlannerThread::spawn(
        structure.clone(),
        PlannerParams {
            max_sweeps: 500,
            ..PlannerParams::default()
        },
    )?;
    planner.offer(agent.model_mut())?;
    planner.wait(agent.model_mut(), std::time::Duration::from_secs(10))?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(1));
    let mut latency = LatencyRecorder::new(1000, warmup);
    let mut state = 0usize;
    let mut action = agent.act(state)?;
    for _ in 0..actions + warmup {
        // A seeded stand-in world: an effect skewed by the state's first feature.
        let first = structure.features(state).first().copied().unwrap_or(0) as usize;
        let effect = (first + rng.random_range(0..3)) % structure.n_effects();
        let mut next = structure.next_state(state, effect);
        if structure.is_terminal(next) {
            next = rng.random_range(0..structure.n_states());
        }
        let started = Instant::now();
        agent.observe(state, action, effect)?;
        planner.collect(agent.model_mut())?;
        planner.offer(agent.model_mut())?;
        action = agent.act(next)?;
        latency.record_ns(started.elapsed().as_nanos() as u64);
        state = next;
    }
    Ok(ScalingPoint {
        features,
        views,
        latency: latency.report(),
    })
}

/// The whole sweep: every feature count at 9 views, every library size at 312 features.
pub fn sweep(
    actions: u64,
    warmup: u64,
    seed: u64,
    mut progress: impl FnMut(&ScalingPoint),
) -> Result<Vec<ScalingPoint>> {
    let mut points = Vec::new();
    let grid = FEATURES
        .iter()
        .map(|&d| (d, 9))
        .chain(VIEWS.iter().filter(|&&v| v != 9).map(|&v| (312, v)));
    for (d, v) in grid {
        let p = measure(d, v, actions, warmup, seed)
            .with_context(|| format!("{d} features, {v} views"))?;
        progress(&p);
        points.push(p);
    }
    Ok(points)
}

/// The two charts: latency against features (9 views) and against views (312 features).
pub fn charts(points: &[ScalingPoint]) -> [LineChart; 2] {
    let series = |filter: &dyn Fn(&ScalingPoint) -> Option<f64>| {
        let mut p50 = Vec::new();
        let mut p99 = Vec::new();
        for p in points {
            if let Some(x) = filter(p) {
                let l = &p.latency;
                p50.push(BandPoint {
                    x,
                    y: l.p50_us as f64,
                    lo: l.p50_us as f64,
                    hi: l.p90_us as f64,
                });
                p99.push(BandPoint {
                    x,
                    y: l.p99_us as f64,
                    lo: l.p99_us as f64,
                    hi: l.p99_us as f64,
                });
            }
        }
        vec![
            Series {
                name: "p50 (band to p90)".into(),
                points: p50,
                colour: Some(0),
            },
            Series {
                name: "p99".into(),
                points: p99,
                colour: Some(1),
            },
        ]
    };
    [
        LineChart {
            title: "Decision time vs feature count (9 views)".into(),
            x_label: "binary features".into(),
            y_label: "µs per decision".into(),
            series: series(&|p| (p.views == 9).then_some(p.features as f64)),
            markers: true,
        },
        LineChart {
            title: "Decision time vs library size (312 features)".into(),
            x_label: "views in the library".into(),
            y_label: "µs per decision".into(),
            series: series(&|p| (p.features == 312).then_some(p.views as f64)),
            markers: true,
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_point_measures_every_decision() {
        let p = measure(52, 1, 200, 20, 3).unwrap();
        assert_eq!(p.latency.count, 200);
        assert!(p.latency.p50_us <= p.latency.p99_us);
        let charts = charts(&[p.clone(), ScalingPoint { views: 9, ..p }]);
        assert_eq!(charts[0].series[0].points.len(), 1);
        assert!(charts[1].to_svg().contains("<svg"));
    }
}
