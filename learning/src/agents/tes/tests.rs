use super::*;
use crate::agents::tests::assert_refuses_bad_steps;
use crate::cmdp::examples::corridor;
use crate::library::{LibraryParams, Winner};

/// The corridor of `cmdp::tests` (2 actions, 3 effects, features: 0 bias, 1 slippery).
fn structure() -> Arc<CmdpStructure> {
    Arc::new(corridor(6, &[2, 3]))
}

fn empty_library(c: &CmdpStructure) -> ViewLibrary {
    ViewLibrary::new(
        c.n_actions(),
        c.n_effects(),
        c.n_features(),
        LibraryParams::default(),
    )
    .unwrap()
}

/// A model for `c` that has learned `n` times that the bias feature gives `effect`.
fn trained(lib: &ViewLibrary, effect: usize, n: usize) -> Mdagl {
    let mut m = lib.fresh_model();
    for _ in 0..n {
        m.update(Features::SparseBinary(&[0]), effect).unwrap();
    }
    m
}

/// Adds a view for `action` that believes `effect` always happens, as a newbie of a task.
fn add_view(lib: &mut ViewLibrary, action: usize, effect: usize) {
    let model = trained(lib, effect, 60);
    lib.end_task(vec![crate::library::ActionOutcome {
        action,
        observations: 60,
        winner: Winner::Fresh,
        model,
        score: -1.0,
        library_scores: vec![],
    }])
    .unwrap();
}

const STEPS: [(usize, usize, usize); 6] = [
    (1, 1, 1),
    (2, 1, 0),
    (3, 0, 0),
    (4, 1, 1),
    (1, 0, 2),
    (3, 1, 0),
];

#[test]
fn every_view_of_the_taken_action_is_scored_before_it_learns() {
    let c = structure();
    let mut lib = empty_library(&c);
    add_view(&mut lib, 1, 1); // action 1 moves right: right, as believed
    let library_model = lib.views()[0].model().clone();
    let mut agent = Tes::new(c.clone(), lib.clone(), TesParams::default(), 1).unwrap();

    // The hand computation: a learning copy of the library view, its frozen original, and a
    // fresh view, each scored on the step before (for the learners) learning from it.
    let (mut copy, mut frozen, mut fresh) =
        (library_model.clone(), library_model, lib.fresh_model());
    let (mut s_copy, mut s_frozen, mut s_fresh) = (0.0, 0.0, 0.0);
    for &(s, a, e) in &STEPS {
        agent.observe(s, a, e).unwrap();
        if a == 1 {
            let x = Features::SparseBinary(c.features(s));
            s_copy += copy.log_prob(x, e).unwrap();
            copy.update(x, e).unwrap();
            s_frozen += frozen.log_prob(x, e).unwrap();
            s_fresh += fresh.log_prob(x, e).unwrap();
            fresh.update(x, e).unwrap();
        }
    }
    let views = agent.working_views(1);
    assert_eq!(views.len(), 2);
    assert_eq!(views[0].origin(), Origin::Library(0));
    assert_eq!(views[0].score(), s_copy);
    assert_eq!(views[0].original_score(), Some(s_frozen));
    assert_eq!(views[0].model(), &copy);
    assert_eq!(views[1].origin(), Origin::Fresh);
    assert_eq!(views[1].score(), s_fresh);
    assert_eq!(views[1].model(), &fresh);
    // Action 0 has only its fresh view, scored over its 2 steps: ln(1/3) each at first.
    assert!(agent.working_views(0)[0].score() < 0.0);
}

#[test]
fn starts_with_the_best_track_record_and_switches_to_the_best_score() {
    let c = structure();
    let mut lib = empty_library(&c);
    add_view(&mut lib, 0, 2); // view 0: action 0 "stays"
    add_view(&mut lib, 0, 0); // view 1: action 0 moves left
    // View 1 wins another task (adjusted within c): Φ = 2 > Φ(view 0) = 1.
    let model = lib.views()[1].model().clone();
    lib.end_task(vec![crate::library::ActionOutcome {
        action: 0,
        observations: 5,
        winner: Winner::Adjusted {
            id: 1,
            original_score: -1.0,
        },
        model,
        score: -1.0,
        library_scores: vec![(0, -9.0), (1, -1.0)],
    }])
    .unwrap();
    let mut agent = Tes::new(c.clone(), lib, TesParams::default(), 1).unwrap();
    assert_eq!(agent.selected(0).unwrap().origin(), Origin::Library(1));
    assert_eq!(
        agent.selected(1).unwrap().origin(),
        Origin::Fresh,
        "nothing for action 1"
    );
    // The world says action 0 stays put: view 0 predicts that, so it takes over.
    for _ in 0..5 {
        agent.observe(3, 0, 2).unwrap();
    }
    assert_eq!(agent.selected(0).unwrap().origin(), Origin::Library(0));
}

#[test]
fn finishing_a_task_grows_the_library_from_the_winners() {
    let c = structure();
    let mut lib = empty_library(&c);
    add_view(&mut lib, 1, 0); // believes "right" moves left: wrong
    let mut agent = Tes::new(c.clone(), lib, TesParams::default(), 3).unwrap();
    for _ in 0..40 {
        agent.observe(2, 1, 1).unwrap(); // right moves right
    }
    // The fresh view learned the truth faster than the wrong view could unlearn.
    assert_eq!(agent.selected(1).unwrap().origin(), Origin::Fresh);
    let (lib, report) = agent.finish_task().unwrap();
    assert_eq!(report.task, 1);
    assert_eq!(report.added, vec![1]);
    assert_eq!(lib.len(), 2);
    assert_eq!(lib.views()[1].action(), 1);
    assert_eq!(lib.views()[0].history().last().map(|h| h.won), Some(false));
}

#[test]
fn lwt_keeps_its_view_frozen_and_random_views_learn_without_switching() {
    let c = structure();
    let mut lib = empty_library(&c);
    add_view(&mut lib, 1, 0);
    add_view(&mut lib, 1, 1);
    let lwt_params = TesParams {
        policy: ViewPolicy::Lwt,
        ..TesParams::default()
    };
    let mut lwt = Tes::new(c.clone(), lib.clone(), lwt_params, 1).unwrap();
    assert_eq!(lwt.name(), "LWT");
    let chosen = lwt.selected(1).unwrap().model().clone();
    for &(s, a, e) in &STEPS {
        lwt.observe(s, a, e).unwrap();
    }
    assert_eq!(
        lwt.selected(1).unwrap().model(),
        &chosen,
        "LWT never updates"
    );
    assert!(lwt.selected(1).unwrap().score() < 0.0, "but it is scored");
    let (same, report) = lwt.finish_task().unwrap();
    assert_eq!((same, report), (lib.clone(), TaskReport::default()));

    let rands = TesParams {
        policy: ViewPolicy::RandomFixed,
        ..TesParams::default()
    };
    let mut picks = std::collections::BTreeSet::new();
    for seed in 0..16 {
        let mut agent = Tes::new(c.clone(), lib.clone(), rands, seed).unwrap();
        let first = agent.selected(1).unwrap().origin();
        assert!(matches!(first, Origin::Library(_)));
        picks.insert(format!("{first:?}"));
        for _ in 0..30 {
            agent.observe(2, 1, 2).unwrap();
        }
        assert_eq!(agent.selected(1).unwrap().origin(), first, "never switches");
        assert_eq!(agent.selected(1).unwrap().model().n_updates(), 60 + 30);
    }
    assert_eq!(picks.len(), 2, "the draw covers both views");
}

#[test]
fn bad_steps_and_libraries_are_refused() {
    let c = Arc::new(corridor(5, &[]));
    let mut agent = Tes::new(c.clone(), empty_library(&c), TesParams::default(), 1).unwrap();
    assert_refuses_bad_steps(&mut agent);
    assert_eq!(agent.working_views(0)[0].model().n_updates(), 0);
    let other = ViewLibrary::new(3, 3, 2, LibraryParams::default()).unwrap();
    assert!(matches!(
        Tes::new(c.clone(), other, TesParams::default(), 1),
        Err(AgentError::LibraryShape { actions: 3, .. })
    ));
    let bad = TesParams {
        epsilon: -0.1,
        ..TesParams::default()
    };
    assert!(Tes::new(c.clone(), empty_library(&c), bad, 1).is_err());
}

#[test]
fn with_an_empty_library_tes_learns_like_lore_rl() {
    let c = Arc::new(corridor(8, &[]));
    let mut agent = Tes::new(c.clone(), empty_library(&c), TesParams::default(), 5).unwrap();
    let mut world = ChaCha8Rng::seed_from_u64(9);
    let mut late = 0.0;
    for episode in 0..60 {
        let mut s = 4;
        for _ in 0..60 {
            let a = agent.act(s).unwrap();
            let e = if world.random::<f64>() < 0.9 { a } else { 2 };
            agent.observe(s, a, e).unwrap();
            s = c.next_state(s, e);
            if episode >= 40 {
                late += c.reward(s);
            }
            if c.is_terminal(s) {
                break;
            }
        }
    }
    assert!(late / 20.0 > 0.9, "mean late return {}", late / 20.0);
    assert_eq!(agent.planner().action(5), 1);
}
