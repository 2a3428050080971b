//! How the cost of one decision grows with the feature count and the library size.
//!
//! What the controller does per observation, in process, in its acting loop's order (decide
//! first, learn after): the *decision* — adopt the planner thread's latest plan and pick the
//! next action — and then the *learning* — score and update the taken action's working views
//! (TES) and hand the changed view to the planner thread. Each point runs `actions` steps on
//! an arena-shaped CMDP ([`crate::fixtures::arena_like`]) with a trained library
//! ([`crate::fixtures::library_for`]) and records each part's time and their sum.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use tes_controller::acting::Order;
use tes_controller::config::ControllerConfig;
use tes_controller::realtime::{PlannerThread, PlannerThreadOptions};
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
    /// The whole step (decision and learning), µs.
    pub latency: LatencyReport,
    /// The decision: adopt a finished plan, pick the action, µs.
    pub decision: LatencyReport,
    /// The learning after it: score and update the views, hand over the model, µs.
    pub learn: LatencyReport,
}

/// Runs `actions` steps (after `warmup` more) for `features` features and `views` views, in
/// `order`: deciding first, the decision and the learning are timed apart; learning first,
/// the decision includes the learning and none is timed apart (the acting loop's older order,
/// for a before/after comparison).
pub fn measure(
    features: usize,
    views: usize,
    actions: u64,
    warmup: u64,
    seed: u64,
    order: Order,
) -> Result<ScalingPoint> {
    let structure = Arc::new(fixtures::arena_like(features, seed)?);
    let library = fixtures::library_for(&structure, views, seed)?;
    let mut agent = Tes::new(structure.clone(), library, TesParams::default(), seed)?;
    agent.model_mut().plan_elsewhere();
    // As the controller runs it by default: polling between jobs.
    let defaults = ControllerConfig::default();
    let mut planner = PlannerThread::spawn_with(
        structure.clone(),
        PlannerParams {
            max_sweeps: defaults.plan_sweeps,
            ..PlannerParams::default()
        },
        PlannerThreadOptions {
            cpu: None,
            idle_spin: defaults.planner_idle_spin(defaults.wait),
        },
    )?;
    planner.offer(agent.model_mut())?;
    planner.wait(agent.model_mut(), std::time::Duration::from_secs(10))?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(1));
    let mut latency = LatencyRecorder::new(1000, warmup);
    let mut decision = LatencyRecorder::new(1000, warmup);
    let mut learn = LatencyRecorder::new(1000, warmup);
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
        let next_action = match order {
            Order::DecideFirst => {
                planner.collect(agent.model_mut())?;
                let next_action = agent.act(next)?;
                let decided = Instant::now();
                agent.observe(state, action, effect)?;
                planner.offer(agent.model_mut())?;
                let learned = Instant::now();
                decision.record_ns((decided - started).as_nanos() as u64);
                learn.record_ns((learned - decided).as_nanos() as u64);
                latency.record_ns((learned - started).as_nanos() as u64);
                next_action
            }
            Order::LearnFirst => {
                agent.observe(state, action, effect)?;
                planner.collect(agent.model_mut())?;
                planner.offer(agent.model_mut())?;
                let next_action = agent.act(next)?;
                let ns = started.elapsed().as_nanos() as u64;
                decision.record_ns(ns);
                latency.record_ns(ns);
                next_action
            }
        };
        (state, action) = (next, next_action);
    }
    Ok(ScalingPoint {
        features,
        views,
        latency: latency.report(),
        decision: decision.report(),
        learn: learn.report(),
    })
}

/// The settings of a sweep: `tes bench scaling`'s flags, each defined here once (its help
/// from its doc, its default from [`ScalingSettings::default`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::Args)]
pub struct ScalingSettings {
    /// Decisions measured per point (after the warm-up).
    #[arg(long, default_value_t = ScalingSettings::default().actions)]
    pub actions: u64,
    /// Decisions run first at each point and left out.
    #[arg(long, default_value_t = ScalingSettings::default().warmup)]
    pub warmup: u64,
    /// Seed of the structures, libraries and steps.
    #[arg(long, default_value_t = ScalingSettings::default().seed)]
    pub seed: u64,
    /// The acting loop's order: decide-first (the decision and the learning timed apart) or
    /// learn-first (the older order: the decision includes the learning).
    #[arg(long, default_value_t = ScalingSettings::default().order)]
    pub order: Order,
}

impl Default for ScalingSettings {
    fn default() -> Self {
        Self {
            actions: 5000,
            warmup: 500,
            seed: 1,
            order: Order::DecideFirst,
        }
    }
}

impl ScalingSettings {
    /// [`sweep`] with these settings; refuses a sweep that measures nothing.
    pub fn sweep(&self, progress: impl FnMut(&ScalingPoint)) -> Result<Vec<ScalingPoint>> {
        if self.actions == 0 {
            anyhow::bail!("--actions must be at least 1");
        }
        sweep(self.actions, self.warmup, self.seed, self.order, progress)
    }
}

/// The whole sweep in `order`: every feature count at 9 views, every library size at 312
/// features.
pub fn sweep(
    actions: u64,
    warmup: u64,
    seed: u64,
    order: Order,
    mut progress: impl FnMut(&ScalingPoint),
) -> Result<Vec<ScalingPoint>> {
    let mut points = Vec::new();
    let grid = FEATURES
        .iter()
        .map(|&d| (d, 9))
        .chain(VIEWS.iter().filter(|&&v| v != 9).map(|&v| (312, v)));
    for (d, v) in grid {
        let p = measure(d, v, actions, warmup, seed, order)
            .with_context(|| format!("{d} features, {v} views"))?;
        progress(&p);
        points.push(p);
    }
    Ok(points)
}

/// The two charts: the decision's and the learning's time against features (9 views) and
/// against views (312 features), p50 (with a band to p90) and p99 of each.
pub fn charts(points: &[ScalingPoint]) -> [LineChart; 2] {
    let series = |filter: &dyn Fn(&ScalingPoint) -> Option<f64>| {
        let mut all = Vec::new();
        for (i, part) in ["decision", "learning"].into_iter().enumerate() {
            let report = |p: &ScalingPoint| if i == 0 { p.decision } else { p.learn };
            let mut p50 = Vec::new();
            let mut p99 = Vec::new();
            for p in points {
                if let Some(x) = filter(p) {
                    let l = report(p);
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
            all.push(Series {
                name: format!("{part} p50 (band to p90)"),
                points: p50,
                colour: Some(2 * i),
            });
            all.push(Series {
                name: format!("{part} p99"),
                points: p99,
                colour: Some(2 * i + 1),
            });
        }
        all
    };
    [
        LineChart {
            title: "Time per observation vs feature count (9 views)".into(),
            x_label: "binary features".into(),
            y_label: "µs per observation".into(),
            series: series(&|p| (p.views == 9).then_some(p.features as f64)),
            markers: true,
        },
        LineChart {
            title: "Time per observation vs library size (312 features)".into(),
            x_label: "views in the library".into(),
            y_label: "µs per observation".into(),
            series: series(&|p| (p.features == 312).then_some(p.views as f64)),
            markers: true,
        },
    ]
}

/// The files [`write()`] makes, in order.
pub const OUTPUTS: [&str; 4] = [
    "scaling.csv",
    "scaling.json",
    "scaling-features.svg",
    "scaling-views.svg",
];

/// Writes the sweep's `points` into `dir` (made if missing): a CSV row and a JSON object per
/// point, and the two [`charts`] as SVG ([`OUTPUTS`]).
pub fn write(dir: &Path, points: &[ScalingPoint]) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let [by_features, by_views] = charts(points);
    let texts = [
        csv(points),
        serde_json::to_string_pretty(points)? + "\n",
        by_features.to_svg(),
        by_views.to_svg(),
    ];
    for (name, text) in OUTPUTS.into_iter().zip(texts) {
        let path = dir.join(name);
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// The points as CSV: the whole step's figures, then the decision's and the learning's.
fn csv(points: &[ScalingPoint]) -> String {
    let mut csv = String::from(
        "features,views,count,p50_us,p90_us,p99_us,p999_us,max_us,\
         decision_p50_us,decision_p99_us,decision_max_us,learn_p50_us,learn_p99_us,learn_max_us\n",
    );
    for p in points {
        let (l, d, n) = (&p.latency, &p.decision, &p.learn);
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            p.features,
            p.views,
            l.count,
            l.p50_us,
            l.p90_us,
            l.p99_us,
            l.p999_us,
            l.max_us,
            d.p50_us,
            d.p99_us,
            d.max_us,
            n.p50_us,
            n.p99_us,
            n.max_us
        );
    }
    csv
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_point_measures_every_decision() {
        let p = measure(52, 1, 200, 20, 3, Order::DecideFirst).unwrap();
        assert_eq!(p.latency.count, 200);
        assert_eq!((p.decision.count, p.learn.count), (200, 200));
        assert!(p.latency.p50_us <= p.latency.p99_us);
        // The whole step is its two parts.
        assert!(p.latency.max_us <= p.decision.max_us + p.learn.max_us + 1);
        let charts = charts(&[p.clone(), ScalingPoint { views: 9, ..p }]);
        assert_eq!(charts[0].series.len(), 4);
        assert_eq!(charts[0].series[0].points.len(), 1);
        assert!(charts[1].to_svg().contains("<svg"));
        // Learning first, the decision is the whole step and no learning is timed apart.
        let p = measure(52, 1, 200, 20, 3, Order::LearnFirst).unwrap();
        assert_eq!(
            (p.decision.count, p.learn.count, p.latency.count),
            (200, 0, 200)
        );
    }
}
