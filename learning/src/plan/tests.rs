use super::*;
use crate::cmdp::CmdpError;
use crate::cmdp::EffectTable;
use crate::cmdp::examples::{corridor, two_state_structure};
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

/// A random CMDP for the sweep tests: any successors, rewards and terminal states;
/// probabilities of any sign pattern a model can hold, zeros (of both signs) included.
fn random_cmdp(
    rng: &mut rand_chacha::ChaCha8Rng,
    n: usize,
    actions: usize,
    effects: usize,
) -> crate::cmdp::CmdpStructure {
    use rand::RngExt;
    let next: Vec<usize> = (0..n * effects).map(|_| rng.random_range(0..n)).collect();
    let reward = (0..n)
        .map(|_| [-0.01, 1.0, -1.0, 0.0, -0.0][rng.random_range(0..5)])
        .collect();
    let terminal = (0..n).map(|_| rng.random::<f64>() < 0.15).collect();
    let none: [u32; 0] = [];
    crate::cmdp::CmdpStructure::new(
        n,
        actions,
        effects,
        1,
        |s, e| next[s * effects + e],
        reward,
        terminal,
        |_| &none,
    )
    .unwrap()
}

/// A random effect distribution; sometimes with zeros or a one-hot row.
fn random_row(rng: &mut rand_chacha::ChaCha8Rng, effects: usize) -> Vec<f64> {
    use rand::RngExt;
    let mut row: Vec<f64> = (0..effects)
        .map(|_| match rng.random_range(0..6) {
            0 => 0.0,
            1 => -0.0,
            _ => rng.random::<f64>(),
        })
        .collect();
    let total: f64 = row.iter().sum();
    if total > 0.0 {
        row.iter_mut().for_each(|p| *p /= total);
    } else {
        row[rng.random_range(0..effects)] = 1.0;
    }
    row
}

/// The sweep as it was written before it was vectorised and tracked: every state, every
/// action's sum of products in effect order. What the faster sweeps must equal bit for bit.
fn reference_sweep(
    values: &mut [f64],
    policy: &mut [u32],
    c: &crate::cmdp::CmdpStructure,
    table: &EffectTable,
    gamma: f64,
    optimism: Option<Optimism<'_>>,
) -> SweepTally {
    let mut tally = SweepTally::new();
    for s in 0..c.n_states() {
        let terminal = c.is_terminal(s);
        if !terminal {
            let backup: Vec<f64> = c
                .successors(s)
                .iter()
                .map(|&next| {
                    let next = next as usize;
                    let future = if c.is_terminal(next) {
                        0.0
                    } else {
                        gamma * values[next]
                    };
                    c.reward(next) + future
                })
                .collect();
            let mut best = (0, f64::NEG_INFINITY);
            for a in 0..c.n_actions() {
                let q = match optimism {
                    Some(o) if o.unknown[a * c.n_states() + s] => o.value,
                    _ => table
                        .probs(a, s)
                        .iter()
                        .zip(&backup)
                        .map(|(&p, &b)| p * b)
                        .sum(),
                };
                if q > best.1 {
                    best = (a, q);
                }
            }
            tally.residual = tally.residual.max((best.1 - values[s]).abs());
            values[s] = best.1;
            policy[s] = best.0 as u32;
        }
        let b = c.reward(s) + if terminal { 0.0 } else { gamma * values[s] };
        tally.lo = tally.lo.min(b);
        tally.hi = tally.hi.max(b);
    }
    tally
}

fn bits(values: &[f64]) -> Vec<u64> {
    values.iter().map(|v| v.to_bits()).collect()
}

proptest::proptest! {
    /// One sweep from the same values gives the reference's bits — values, policy, residual
    /// and span — built for the default target or for AVX2, with or without optimism,
    /// tracked (from scratch) or not, for 1 to 6 actions (by lanes up to 4) and 3, 5 or 20
    /// effects (specialised and generic code).
    #[test]
    fn every_sweep_equals_the_scalar_reference(
        seed in 0u64..10_000,
        n in 1usize..40,
        actions in 1usize..7,
        effects in proptest::sample::select(vec![3usize, 5, 20]),
        optimistic in proptest::bool::ANY,
    ) {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let c = random_cmdp(&mut rng, n, actions, effects);
        let mut table = EffectTable::uniform(&c);
        for a in 0..actions {
            for s in 0..n {
                table.set(a, s, &random_row(&mut rng, effects));
            }
        }
        let unknown: Vec<bool> = (0..actions * n).map(|_| rng.random::<f64>() < 0.3).collect();
        let optimism = optimistic.then_some(Optimism { unknown: &unknown, value: 20.0 });
        let mut start = ValueIteration::new(&c, PlannerParams::default()).unwrap();
        for v in &mut start.values {
            *v = rng.random::<f64>() * 4.0 - 2.0;
        }
        let (mut values, mut policy) = (start.values.clone(), start.policy.clone());
        let want = reference_sweep(&mut values, &mut policy, &c, &table, 0.95, optimism);
        let mut runs: Vec<(&str, ValueIteration, SweepTally)> = Vec::new();
        let mut untracked = start.clone();
        let mut t = SweepTally::new();
        untracked.sweep_states(&c, &table, optimism, 0..n, &mut t);
        runs.push(("dispatched", untracked, t));
        let (probs, lanes) = table.layouts();
        let parts = || crate::cmdp::TableParts { probs, lanes, fresh: &mut [] };
        let mut portable = start.clone();
        let mut t = SweepTally::new();
        portable.sweep_portable::<false>(&c, parts(), optimism, 0..n, &mut t);
        runs.push(("portable", portable, t));
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let mut avx2 = start.clone();
            let mut t = SweepTally::new();
            // SAFETY: the CPU has AVX2.
            unsafe { avx2.sweep_avx2::<false>(&c, parts(), optimism, 0..n, &mut t) };
            runs.push(("avx2", avx2, t));
        }
        if !optimistic {
            let mut tracked = start.clone();
            let mut t = SweepTally::new();
            tracked.sweep_tracked(&c, &mut table.clone(), 0..n, &mut t);
            runs.push(("tracked", tracked, t));
        }
        for (name, vi, t) in runs {
            proptest::prop_assert_eq!(bits(&vi.values), bits(&values), "{}", name);
            proptest::prop_assert_eq!(&vi.policy, &policy, "{}", name);
            proptest::prop_assert_eq!(t.residual.to_bits(), want.residual.to_bits(), "{}", name);
            proptest::prop_assert_eq!(t.lo.to_bits(), want.lo.to_bits(), "{}", name);
            proptest::prop_assert_eq!(t.hi.to_bits(), want.hi.to_bits(), "{}", name);
        }
    }

    /// A planned model that keeps changing — rows rewritten (some to the bits they had), a
    /// plan adopted, pieces of any size — plans exactly as the reference would: the same
    /// sweeps, values, policy, statistics and span after every re-plan, though its tracked
    /// sweeps skip the states nothing reached.
    #[test]
    fn tracked_replans_equal_the_reference_plans(
        seed in 0u64..10_000,
        n in 2usize..40,
        actions in proptest::sample::select(vec![2usize, 4, 5]),
        effects in proptest::sample::select(vec![3usize, 5, 20]),
        stop_at_drift in proptest::bool::ANY,
        piece in 1usize..50,
    ) {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let c = Arc::new(random_cmdp(&mut rng, n, actions, effects));
        let params = PlannerParams { max_sweeps: 4, stop_at_drift, ..PlannerParams::default() };
        let mut model = PlannedModel::new(c.clone(), params).unwrap();
        let (mut values, mut policy) = (vec![0.0; n], vec![0u32; n]);
        let reference_plan = |model: &PlannedModel, values: &mut Vec<f64>,
                                  policy: &mut Vec<u32>, good_enough: f64| {
            let mut stats = PlanStats::NONE;
            loop {
                let t = reference_sweep(values, policy, &c, model.table(), params.gamma, None);
                stats.sweeps += 1;
                stats.residual = t.residual;
                if t.residual <= params.tolerance {
                    stats.converged = true;
                }
                if stats.converged || t.residual <= good_enough || stats.sweeps >= params.max_sweeps {
                    return (stats, t.hi - t.lo);
                }
            }
        };
        for step in 0..40 {
            // A few rows change; some are written again with the bits they hold.
            for _ in 0..rng.random_range(0..4) {
                let (a, s) = (rng.random_range(0..actions), rng.random_range(0..n));
                let row = if rng.random::<f64>() < 0.3 {
                    model.table().probs(a, s).to_vec()
                } else {
                    random_row(&mut rng, effects)
                };
                model.set(a, s, &row);
            }
            if step == 20 {
                // An adopted plan: the next tracked sweep must back up every state.
                let adopted: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
                let stats = model.last_plan();
                model.adopt(&adopted, &policy, stats, model.plan_span()).unwrap();
                values.clone_from(&adopted);
            }
            let good_enough = model.good_enough();
            let needed = model.needs_plan();
            let planned = if step % 3 == 0 {
                // In pieces, as a planner between polls makes it.
                let changes = crate::plan::ModelChanges::new(&c);
                let mut pieces = model.begin_pieces(&changes);
                while !model.advance(&changes, &mut pieces, piece).unwrap() {}
                needed.then(|| model.last_plan())
            } else {
                model.replan()
            };
            proptest::prop_assert_eq!(planned.is_some(), needed);
            if let Some(stats) = planned {
                let (want, span) = reference_plan(&model, &mut values, &mut policy, good_enough);
                proptest::prop_assert_eq!(stats.sweeps, want.sweeps);
                proptest::prop_assert_eq!(stats.converged, want.converged);
                proptest::prop_assert_eq!(stats.residual.to_bits(), want.residual.to_bits());
                proptest::prop_assert_eq!(model.plan_span().to_bits(), span.to_bits());
            }
            proptest::prop_assert_eq!(bits(model.planner().values()), bits(&values));
            proptest::prop_assert_eq!(model.planner().policy(), &policy[..]);
        }
    }
}

/// The tracking does skip: once a plan has converged to the bit (values no longer move), a
/// further tracked sweep finds no state to back up; changing one row flags that state
/// alone.
#[test]
fn a_sweep_over_an_unchanged_model_backs_up_nothing() {
    let c = Arc::new(corridor(20, &[]));
    let mut model = PlannedModel::new(c.clone(), tight()).unwrap();
    for s in 0..20 {
        model.set(0, s, &[0.7, 0.2, 0.1]);
        model.set(1, s, &[0.2, 0.7, 0.1]);
    }
    model.replan().unwrap();
    // Sweep until no value changes bit for bit (Gauss–Seidel on a chain gets there).
    for _ in 0..10_000 {
        let mut tally = SweepTally::new();
        model
            .planner
            .sweep_tracked(&c, &mut model.table, 0..20, &mut tally);
        if tally.residual == 0.0 {
            break;
        }
    }
    assert!(model.planner.tracking);
    // (Terminal states are never backed up, so their flags do not matter.)
    let stale = (0..20).filter(|&s| !c.is_terminal(s) && model.planner.stale[s]);
    assert_eq!(stale.count(), 0, "no successor moved");
    let fresh = (0..20).filter(|&s| !c.is_terminal(s) && model.table.parts().fresh[s]);
    assert_eq!(fresh.count(), 0, "no row moved");
    model.set(1, 7, &[0.2, 0.6, 0.2]);
    let fresh: Vec<usize> = (1..19).filter(|&s| model.table.parts().fresh[s]).collect();
    assert_eq!(fresh, [7]);
    // Writing a row's own bits again flags nothing.
    let row = model.table().probs(0, 3).to_vec();
    model.set(0, 3, &row);
    assert!(!model.table.parts().fresh[3]);
}

/// Two effects that enter the same state with different step rewards: the planner
/// backs up each step's own reward and takes the action whose effect pays.
#[test]
fn step_rewards_are_what_the_planner_backs_up() {
    let c = two_state_structure();
    assert_eq!(c.step_reward(0, 0, 1), c.reward(1));
    let paid = c
        .clone()
        .with_step_rewards(|s, _, e| if (s, e) == (0, 1) { 1.0 } else { -1.0 })
        .unwrap();
    assert_eq!(
        (paid.step_reward(0, 0, 0), paid.step_reward(0, 0, 1)),
        (-1.0, 1.0)
    );
    assert_eq!(paid.reward(1), 0.0);
    let mut table = EffectTable::uniform(&paid);
    table.set(0, 0, &[1.0, 0.0]);
    table.set(1, 0, &[0.0, 1.0]);
    let mut planner = ValueIteration::new(&paid, PlannerParams::default()).unwrap();
    planner.plan(&paid, &table);
    assert_eq!(planner.policy()[0], 1);
    assert_eq!(planner.q_value(&paid, &table, 0, 1), 1.0);
    assert_eq!(planner.q_value(&paid, &table, 0, 0), -1.0);
    let refused = c.with_step_rewards(|_, a, _| if a == 1 { f64::NAN } else { 0.0 });
    assert_eq!(
        refused.unwrap_err(),
        CmdpError::BadStepReward {
            state: 0,
            action: 1,
            effect: 0
        }
    );
}

/// Both actions have the same effect with the same chances, from the same state to the
/// same next state; only what they cost differs (−5 for action 0, −1 for action 1). The
/// plan takes the cheaper one, and its value is what that action pays.
#[test]
fn a_reward_that_depends_on_the_action_alone_is_planned_on() {
    let c = two_state_structure()
        .with_step_rewards(|_, a, _| if a == 0 { -5.0 } else { -1.0 })
        .unwrap();
    // Each action has each effect half the time (the uniform table): the cost is all
    // that tells them apart.
    let table = EffectTable::uniform(&c);
    assert_eq!(table.probs(0, 0), table.probs(1, 0));
    let mut planner = ValueIteration::new(&c, PlannerParams::default()).unwrap();
    let stats = planner.plan(&c, &table);
    assert!(stats.converged);
    assert_eq!(planner.policy()[0], 1);
    assert_eq!(planner.value(0), -1.0);
    assert_eq!(planner.q_value(&c, &table, 0, 0), -5.0);
    assert_eq!(planner.q_value(&c, &table, 0, 1), -1.0);
}
