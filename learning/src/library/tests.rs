use super::*;
use crate::mdagl::Features;

const ACTIONS: usize = 2;
const EFFECTS: usize = 3;
const FEATURES: usize = 4;

fn library(max_views: usize) -> ViewLibrary {
    let params = LibraryParams {
        max_views,
        ..LibraryParams::default()
    };
    ViewLibrary::new(ACTIONS, EFFECTS, FEATURES, params).unwrap()
}

/// A model that has learned `n` rows of "feature 1 on → effect `effect`".
fn trained(lib: &ViewLibrary, effect: usize, n: usize) -> Mdagl {
    let mut m = lib.fresh_model();
    for _ in 0..n {
        m.update(Features::SparseBinary(&[0, 1]), effect).unwrap();
    }
    m
}

fn fresh_win(lib: &ViewLibrary, action: usize, effect: usize) -> ActionOutcome {
    ActionOutcome {
        action,
        observations: 10,
        winner: Winner::Fresh,
        model: trained(lib, effect, 10),
        score: -3.0,
        library_scores: vec![],
    }
}

#[test]
fn a_winning_newbie_is_added_with_the_task_in_its_history() {
    let mut lib = library(20);
    let outcome = fresh_win(&lib, 1, 2);
    let model = outcome.model.clone();
    let report = lib.end_task(vec![outcome]).unwrap();
    assert_eq!(report.task, 0);
    assert_eq!(report.added, vec![0]);
    assert_eq!(lib.len(), 1);
    let v = &lib.views()[0];
    assert_eq!((v.id(), v.action(), v.wins()), (0, 1, &[0][..]));
    assert_eq!(v.model(), &model);
    assert_eq!(
        v.history(),
        &[TaskScore {
            task: 0,
            score: -3.0,
            observations: 10,
            won: true
        }]
    );
    assert_eq!(lib.tasks_seen(), 1);
    assert_eq!(lib.track_record(v), 1.0);
}

/// A library with one view (id 0) for action 0, won in task 0.
fn library_with_one_view() -> ViewLibrary {
    let mut lib = library(20);
    let outcome = fresh_win(&lib, 0, 0);
    lib.end_task(vec![outcome]).unwrap();
    lib
}

fn adjusted(lib: &ViewLibrary, score: f64, original_score: f64) -> ActionOutcome {
    ActionOutcome {
        action: 0,
        observations: 40,
        winner: Winner::Adjusted {
            id: 0,
            original_score,
        },
        model: trained(lib, 2, 40),
        score,
        library_scores: vec![(0, score)],
    }
}

#[test]
fn an_adjusted_copy_beating_its_original_by_more_than_c_becomes_a_new_view() {
    let mut lib = library_with_one_view();
    let before = lib.views()[0].model().clone();
    let c = LibraryParams::default().growth_threshold;
    let outcome = adjusted(&lib, -10.0, -10.0 - c - 0.01);
    let winner = outcome.model.clone();
    let report = lib.end_task(vec![outcome]).unwrap();
    assert_eq!(
        (report.added.clone(), report.updated.clone()),
        (vec![1], vec![])
    );
    assert_eq!(lib.len(), 2);
    let (old, new) = (&lib.views()[0], &lib.views()[1]);
    assert_eq!(old.model(), &before, "the original keeps its parameters");
    assert_eq!(old.wins(), &[0]);
    assert_eq!(
        old.history().last().map(|h| (h.task, h.won)),
        Some((1, false))
    );
    assert_eq!(new.model(), &winner);
    assert_eq!(new.wins(), &[1]);
}

#[test]
fn an_adjusted_copy_within_c_updates_its_original() {
    let mut lib = library_with_one_view();
    let c = LibraryParams::default().growth_threshold;
    let outcome = adjusted(&lib, -10.0, -10.0 - c + 0.01);
    let winner = outcome.model.clone();
    let report = lib.end_task(vec![outcome]).unwrap();
    assert_eq!(
        (report.added.clone(), report.updated.clone()),
        (vec![], vec![0])
    );
    assert_eq!(lib.len(), 1);
    let v = &lib.views()[0];
    assert_eq!(v.model(), &winner);
    assert_eq!(v.wins(), &[0, 1]);
    assert_eq!(
        v.history().last(),
        Some(&TaskScore {
            task: 1,
            score: -10.0,
            observations: 40,
            won: true
        })
    );
    assert_eq!(lib.track_record(v), 2.0);
}

#[test]
fn past_m_views_the_lowest_track_record_goes_first() {
    let mut lib = library(3);
    // Task 0: views 0 (action 0) and 1 (action 1).
    let (a, b) = (fresh_win(&lib, 0, 0), fresh_win(&lib, 1, 1));
    lib.end_task(vec![a, b]).unwrap();
    // Task 1: view 0 wins again (adjusted within c), so Φ(view 0) = 2.
    let outcome = adjusted(&lib, -1.0, -1.0);
    lib.end_task(vec![outcome]).unwrap();
    // Task 2: two newbies → 4 views > M = 3. Views 1, 2, 3 all have Φ = 1; view 1's last win
    // (task 0) is the oldest, so it goes.
    let (a, b) = (fresh_win(&lib, 0, 2), fresh_win(&lib, 1, 2));
    let report = lib.end_task(vec![a, b]).unwrap();
    assert_eq!(report.added, vec![2, 3]);
    assert_eq!(report.removed, vec![1]);
    let ids: Vec<u64> = lib.views().iter().map(View::id).collect();
    assert_eq!(ids, vec![0, 2, 3]);
    // Ids are never reused.
    let a = fresh_win(&lib, 1, 0);
    let report = lib.end_task(vec![a]).unwrap();
    assert_eq!(report.added, vec![4]);
    assert_eq!(lib.len(), 3);
}

#[test]
fn recency_weighting_decays_old_wins() {
    let params = LibraryParams {
        recency: 0.5,
        max_views: 1,
        ..LibraryParams::default()
    };
    let mut lib = ViewLibrary::new(ACTIONS, EFFECTS, FEATURES, params).unwrap();
    let a = fresh_win(&lib, 0, 0);
    lib.end_task(vec![a]).unwrap();
    let outcome = adjusted(&lib, -1.0, -1.0);
    lib.end_task(vec![outcome]).unwrap();
    // Wins in tasks 0 and 1, next task 2: e^{-0.5·2} + e^{-0.5·1}.
    let v = &lib.views()[0];
    let expected = (-1.0f64).exp() + (-0.5f64).exp();
    assert!((lib.track_record(v) - expected).abs() < 1e-15);
    // Task 2's newbie overflows M = 1. Pruning weighs at task 2: the old view has
    // e^{-1} + e^{-0.5} ≈ 0.97, the newbie e^0 = 1, so the old view goes.
    let newbie = fresh_win(&lib, 1, 1);
    let report = lib.end_task(vec![newbie]).unwrap();
    assert_eq!(report.removed, vec![0]);
    assert_eq!(lib.views()[0].id(), 1);
}

#[test]
fn actions_without_observations_change_nothing_and_bad_outcomes_are_refused() {
    let mut lib = library_with_one_view();
    let mut idle = fresh_win(&lib, 1, 1);
    idle.observations = 0;
    let report = lib.end_task(vec![idle]).unwrap();
    assert!(report.added.is_empty() && report.updated.is_empty());
    assert_eq!(lib.len(), 1);
    assert_eq!(lib.tasks_seen(), 2);

    let before = lib.clone();
    let mut unknown = adjusted(&lib, -1.0, -1.0);
    unknown.winner = Winner::Adjusted {
        id: 7,
        original_score: 0.0,
    };
    assert_eq!(
        lib.end_task(vec![unknown]),
        Err(LibraryError::UnknownView(7))
    );
    let twice = vec![fresh_win(&lib, 1, 0), fresh_win(&lib, 1, 1)];
    assert_eq!(lib.end_task(twice), Err(LibraryError::DuplicateAction(1)));
    let mut wrong = fresh_win(&lib, 0, 0);
    wrong.model = Mdagl::new(EFFECTS, FEATURES + 1, LibraryParams::default().mdagl).unwrap();
    assert!(matches!(
        lib.end_task(vec![wrong]),
        Err(LibraryError::WrongShape { .. })
    ));
    let mut no_action = fresh_win(&lib, 0, 0);
    no_action.action = ACTIONS;
    assert!(matches!(
        lib.end_task(vec![no_action]),
        Err(LibraryError::WrongShape { .. })
    ));
    assert_eq!(lib, before, "a refused outcome changes nothing");
}

#[test]
fn settings_are_checked() {
    for params in [
        LibraryParams {
            max_views: 0,
            ..LibraryParams::default()
        },
        LibraryParams {
            recency: -1.0,
            ..LibraryParams::default()
        },
        LibraryParams {
            growth_threshold: f64::NAN,
            ..LibraryParams::default()
        },
    ] {
        assert!(matches!(
            ViewLibrary::new(2, 3, 4, params),
            Err(LibraryError::Invalid { .. })
        ));
    }
    assert!(ViewLibrary::new(0, 3, 4, LibraryParams::default()).is_err());
    assert!(matches!(
        ViewLibrary::new(2, 1, 4, LibraryParams::default()),
        Err(LibraryError::View(_))
    ));
}

#[test]
fn algorithm_2_prunes_one_view_per_task_and_ours_prunes_to_the_limit() {
    for (pruning, left) in [(Pruning::ToLimit, 1), (Pruning::OnePerTask, 2)] {
        let params = LibraryParams {
            max_views: 1,
            pruning,
            ..LibraryParams::default()
        };
        let mut lib = ViewLibrary::new(3, EFFECTS, FEATURES, params).unwrap();
        // One task adds a view per action (three), over M = 1.
        let wins: Vec<ActionOutcome> = (0..3).map(|a| fresh_win(&lib, a, a % EFFECTS)).collect();
        let report = lib.end_task(wins).unwrap();
        assert_eq!(report.added.len(), 3);
        assert_eq!(lib.len(), left, "{pruning:?}");
        assert_eq!(report.removed.len(), 3 - left, "{pruning:?}");
    }
}
