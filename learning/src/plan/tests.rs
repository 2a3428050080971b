use super::*;
use crate::cmdp::EffectTable;
use crate::cmdp::examples::corridor;
use std::sync::Arc;

fn tight() -> PlannerParams {
    PlannerParams {
        tolerance: 1e-9,
        max_sweeps: 100_000,
        ..PlannerParams::default()
    }
}

#[test]
fn deterministic_corridor_has_the_closed_form_values() {
    // Right always moves right: from cell s the exit is k = n−1−s moves away, paying −0.01
    // for each of the first k−1 and +1 for the last: V = −0.01·Σ_{i<k−1} γ^i + γ^{k−1}.
    let n = 8;
    let c = corridor(n, &[]);
    let mut table = EffectTable::uniform(&c);
    for s in 0..n {
        table.set(0, s, &[1.0, 0.0, 0.0]);
        table.set(1, s, &[0.0, 1.0, 0.0]);
    }
    let mut vi = ValueIteration::new(&c, tight()).unwrap();
    let stats = vi.plan(&c, &table);
    assert!(stats.converged);
    let g: f64 = 0.95;
    for s in 1..n - 1 {
        let k = (n - 1 - s) as i32;
        let expected = -0.01 * (0..k - 1).map(|i| g.powi(i)).sum::<f64>() + g.powi(k - 1);
        assert!((vi.value(s) - expected).abs() < 1e-6, "V({s})");
        assert_eq!(vi.action(s), 1);
    }
}

#[test]
fn stochastic_chain_matches_the_linear_solution() {
    // 3 cells: 0 is a −1 pit, 2 the +1 exit. In cell 1, "right" reaches the exit with
    // probability p and otherwise stays; "left" falls in the pit.
    // V = p·1 + (1−p)(−0.01 + γV)  ⇒  V = (p − 0.01(1−p)) / (1 − γ(1−p)).
    let c = corridor(3, &[]);
    let p = 0.3;
    let mut table = EffectTable::uniform(&c);
    table.set(0, 1, &[1.0, 0.0, 0.0]);
    table.set(1, 1, &[0.0, p, 1.0 - p]);
    let mut vi = ValueIteration::new(&c, tight()).unwrap();
    vi.plan(&c, &table);
    let expected = (p - 0.01 * (1.0 - p)) / (1.0 - 0.95 * (1.0 - p));
    assert!((vi.value(1) - expected).abs() < 1e-5);
    assert_eq!(vi.action(1), 1);
    assert_eq!(vi.value(0), 0.0, "terminal states keep V = 0");
}

/// The span a plan hands over with its values is the spread of `R + γV` under them, as a
/// pass over the states would find it, to the bit — whether the plan converged or
/// stopped at the sweep cap.
#[test]
fn the_plan_span_is_the_spread_of_the_backups_under_the_values() {
    let c = Arc::new(corridor(9, &[4]));
    for max_sweeps in [1, 3, 10_000] {
        let params = PlannerParams {
            max_sweeps,
            ..tight()
        };
        let mut model = PlannedModel::new(c.clone(), params).unwrap();
        for s in 0..9 {
            model.set(0, s, &[0.7, 0.2, 0.1]);
            model.set(1, s, &[0.1, 0.6, 0.3]);
        }
        model.replan().unwrap();
        let gamma = params.gamma;
        let backups = (0..9).map(|s| {
            let future = if c.is_terminal(s) {
                0.0
            } else {
                gamma * model.planner().value(s)
            };
            c.reward(s) + future
        });
        let lo = backups.clone().fold(f64::INFINITY, f64::min);
        let hi = backups.fold(f64::NEG_INFINITY, f64::max);
        assert_eq!(
            model.plan_span().to_bits(),
            (hi - lo).to_bits(),
            "{max_sweeps}"
        );
    }
}

#[test]
fn warm_start_replans_in_fewer_sweeps() {
    let n = 30;
    let c = corridor(n, &[]);
    let mut table = EffectTable::uniform(&c);
    for s in 0..n {
        table.set(0, s, &[0.8, 0.1, 0.1]);
        table.set(1, s, &[0.1, 0.8, 0.1]);
    }
    let mut vi = ValueIteration::new(&c, tight()).unwrap();
    let cold = vi.plan(&c, &table);
    table.set(1, 10, &[0.1, 0.75, 0.15]);
    let warm = vi.plan(&c, &table);
    assert!(cold.converged && warm.converged);
    assert!(warm.sweeps < cold.sweeps, "{warm:?} vs {cold:?}");
    let mut fresh = ValueIteration::new(&c, tight()).unwrap();
    fresh.plan(&c, &table);
    for s in 0..n {
        assert!((fresh.value(s) - vi.value(s)).abs() < 1e-4);
    }
}

#[test]
fn sweep_cap_is_respected_and_settings_checked() {
    let c = corridor(50, &[]);
    let table = EffectTable::uniform(&c);
    let params = PlannerParams {
        max_sweeps: 2,
        ..PlannerParams::default()
    };
    let stats = ValueIteration::new(&c, params).unwrap().plan(&c, &table);
    assert_eq!(stats.sweeps, 2);
    assert!(!stats.converged);
    let ok = PlannerParams::default();
    for bad in [
        PlannerParams { gamma: 1.0, ..ok },
        PlannerParams { gamma: -0.1, ..ok },
        PlannerParams {
            tolerance: 0.0,
            ..ok
        },
        PlannerParams {
            max_sweeps: 0,
            ..ok
        },
    ] {
        assert!(ValueIteration::new(&c, bad).is_err());
    }
}

#[test]
fn planned_model_replans_only_when_the_model_moved_enough() {
    let c = Arc::new(corridor(6, &[]));
    let params = PlannerParams {
        max_sweeps: 3,
        ..PlannerParams::default()
    };
    let mut model = PlannedModel::new(c.clone(), params).unwrap();
    for s in 0..6 {
        model.set(0, s, &[0.9, 0.05, 0.05]);
        model.set(1, s, &[0.05, 0.9, 0.05]);
    }
    // Not converged after 3 sweeps: re-plans continue, warm-started, until it is.
    let mut plans = 0;
    while model.replan().is_some() {
        plans += 1;
        assert!(plans < 1000);
    }
    assert!(
        plans > 1,
        "the sweep cap split the solve into {plans} plans"
    );
    let mut full = ValueIteration::new(&c, tight()).unwrap();
    full.plan(&c, model.table());
    for s in 0..6 {
        assert!((model.planner().value(s) - full.value(s)).abs() < 1e-3);
    }
    assert_eq!(model.action(3), 1);
    // A change far below the tolerance leaves the plan alone…
    model.set(1, 3, &[0.05 + 1e-6, 0.9 - 1e-6, 0.05]);
    assert!(model.replan().is_none());
    // …a real one re-plans, and so does an explicit invalidation.
    model.set(1, 3, &[0.5, 0.45, 0.05]);
    assert!(model.replan().is_some());
    while model.replan().is_some() {}
    model.invalidate();
    assert!(model.replan().is_some());
}

#[test]
fn a_replan_stops_at_the_drift_that_triggered_it_and_converges_once_the_model_holds_still() {
    let c = Arc::new(corridor(12, &[]));
    let params = PlannerParams {
        max_sweeps: 1000,
        stop_at_drift: true,
        ..PlannerParams::default()
    };
    let mut model = PlannedModel::new(c.clone(), params).unwrap();
    let set_all = |model: &mut PlannedModel, p: f64| {
        for s in 0..12 {
            model.set(0, s, &[p, 0.9 - p, 0.1]);
            model.set(1, s, &[0.9 - p, p, 0.1]);
        }
    };
    set_all(&mut model, 0.2);
    while model.replan().is_some() {}
    assert!(model.last_plan().converged);
    // Every row moves: the drift bound is far above the tolerance, so the re-plan stops
    // as soon as a sweep moves no value by more than that bound — one sweep here.
    set_all(&mut model, 0.25);
    let early = model.replan().expect("the model moved");
    assert!(!early.converged && early.residual > 1e-4, "{early:?}");
    assert_eq!(early.sweeps, 1);
    // Once the model holds still, planning continues to the tolerance…
    let mut plans = 0;
    while model.replan().is_some() {
        plans += 1;
        assert!(plans < 100);
    }
    assert!(model.last_plan().converged);
    let mut full = ValueIteration::new(&c, tight()).unwrap();
    full.plan(&c, model.table());
    for s in 0..12 {
        assert!((model.planner().value(s) - full.value(s)).abs() < 3e-3);
    }
    // …and a forced plan never stops early.
    set_all(&mut model, 0.3);
    model.invalidate();
    assert!(model.replan().expect("forced").converged);
    // Without stop_at_drift the same change is planned to the tolerance at once.
    let params = PlannerParams {
        stop_at_drift: false,
        ..params
    };
    let mut model = PlannedModel::new(c.clone(), params).unwrap();
    set_all(&mut model, 0.2);
    while model.replan().is_some() {}
    set_all(&mut model, 0.25);
    let full = model.replan().expect("the model moved");
    assert!(full.converged && full.sweeps > 1, "{full:?}");
}

/// Adopting by swapping gives the same plan as adopting by copying, hands back the previous
/// one, and refuses buffers of another size, changing nothing.
#[test]
fn adopting_by_swapping_equals_adopting_by_copying() {
    let c = corridor(9, &[]);
    let mut table = EffectTable::uniform(&c);
    for s in 0..9 {
        table.set(0, s, &[0.8, 0.1, 0.1]);
    }
    let mut made = ValueIteration::new(&c, tight()).unwrap();
    made.plan(&c, &table);
    let mut copied = ValueIteration::new(&c, tight()).unwrap();
    let mut swapped = ValueIteration::new(&c, tight()).unwrap();
    let previous = (swapped.values().to_vec(), swapped.policy().to_vec());
    copied.adopt(made.values(), made.policy()).unwrap();
    let (mut values, mut policy) = (made.values().to_vec(), made.policy().to_vec());
    swapped.adopt_swapping(&mut values, &mut policy).unwrap();
    assert_eq!(swapped.values(), copied.values());
    assert_eq!(swapped.policy(), copied.policy());
    assert_eq!((values, policy), previous, "the old plan comes back");
    let (mut short, mut policy) = (vec![0.0; 3], vec![0; 9]);
    assert!(swapped.adopt_swapping(&mut short, &mut policy).is_err());
    assert_eq!(
        swapped.values(),
        copied.values(),
        "a refused adoption changes nothing"
    );
    assert_eq!(short.len(), 3);
}
