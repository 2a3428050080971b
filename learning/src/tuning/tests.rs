//! The race on generated streams of several shapes, against every fixed setting of its grid
//! run afterwards on the same rows.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;

/// A stream's shape: classes, columns, the relevant columns and how often features are on.
#[derive(Debug, Clone, Copy)]
struct StreamShape {
    classes: usize,
    features: usize,
    relevant: usize,
    /// Probability a relevant feature is on in a row.
    relevant_on: f64,
    /// Probability an irrelevant feature is on in a row.
    noise_on: f64,
    rows: usize,
    seed: u64,
}

/// Rows (the indices of the features on, and the label) from a multinomial logistic model
/// over the relevant columns alone; returns the rows and the relevant set.
fn stream(shape: StreamShape) -> (Vec<(Vec<u32>, usize)>, Vec<usize>) {
    let mut rng = ChaCha8Rng::seed_from_u64(shape.seed);
    let mut relevant: Vec<usize> = Vec::new();
    while relevant.len() < shape.relevant {
        let i = rng.random_range(0..shape.features);
        if !relevant.contains(&i) {
            relevant.push(i);
        }
    }
    relevant.sort_unstable();
    // Strong weights, so each relevant feature moves the class distribution.
    let weights: Vec<Vec<f64>> = (0..shape.classes)
        .map(|_| {
            (0..shape.relevant)
                .map(|_| rng.random_range(-4.0..4.0))
                .collect()
        })
        .collect();
    let rows = (0..shape.rows)
        .map(|_| {
            let x: Vec<u32> = (0..shape.features)
                .filter(|i| {
                    let p = if relevant.binary_search(i).is_ok() {
                        shape.relevant_on
                    } else {
                        shape.noise_on
                    };
                    rng.random::<f64>() < p
                })
                .map(|i| i as u32)
                .collect();
            let scores: Vec<f64> = weights
                .iter()
                .map(|w| {
                    relevant
                        .iter()
                        .zip(w)
                        .filter(|(r, _)| x.binary_search(&(**r as u32)).is_ok())
                        .map(|(_, w)| w)
                        .sum()
                })
                .collect();
            let top = scores.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let odds: Vec<f64> = scores.iter().map(|s| (s - top).exp()).collect();
            let mut pick = rng.random::<f64>() * odds.iter().sum::<f64>();
            let mut label = shape.classes - 1;
            for (k, o) in odds.iter().enumerate() {
                if pick < *o {
                    label = k;
                    break;
                }
                pick -= o;
            }
            (x, label)
        })
        .collect();
    (rows, relevant)
}

/// Mean prequential log-loss of a fixed setting over `rows`, and the model.
fn fixed(shape: StreamShape, params: MdaglParams, rows: &[(Vec<u32>, usize)]) -> (f64, Mdagl) {
    let mut model = Mdagl::new(shape.classes, shape.features, params).expect("model");
    let loss: f64 = rows
        .iter()
        .map(|(x, y)| {
            -model
                .update(Features::SparseBinary(x), *y)
                .expect("row")
                .log_prob
        })
        .sum();
    (loss / rows.len() as f64, model)
}

/// Recall and precision of `selected` against `relevant`.
fn recall_precision(selected: &[usize], relevant: &[usize]) -> (f64, f64) {
    let hits = selected.iter().filter(|i| relevant.contains(i)).count() as f64;
    let recall = hits / relevant.len() as f64;
    let precision = if selected.is_empty() {
        0.0
    } else {
        hits / selected.len() as f64
    };
    (recall, precision)
}

/// The race's own prequential loss is within 2 % of the best fixed setting of its grid, chosen
/// afterwards; where the setting hindsight picks by the race's own rule — the sparsest of those
/// within [`TIE`] of the best loss — finds the relevant set (recall and precision ≥ 0.9), the
/// race's model does too; and the race cost a fraction of running the whole grid.
///
/// Hindsight applies the tie rule because the race does: a relevant feature too weak to move
/// the loss by [`TIE`] is one the sparser setting may drop, by design.
fn the_race_keeps_up_with_the_best_fixed_setting(shape: StreamShape) {
    let (rows, relevant) = stream(shape);
    let grid = auto_grid(None, None, true);
    let mut race = MdaglRace::new(
        shape.classes,
        shape.features,
        &grid,
        RaceSchedule::default(),
    )
    .expect("race");
    let raced: f64 = rows
        .iter()
        .map(|(x, y)| {
            -race
                .update(Features::SparseBinary(x), *y)
                .expect("row")
                .log_prob
        })
        .sum::<f64>()
        / rows.len() as f64;
    let fixed_runs: Vec<(f64, MdaglParams, Mdagl)> = grid
        .iter()
        .map(|&p| {
            let (loss, model) = fixed(shape, p, &rows);
            (loss, p, model)
        })
        .collect();
    let (best_loss, best_params) = fixed_runs
        .iter()
        .map(|(loss, params, _)| (*loss, *params))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .expect("a grid");
    let (_, hindsight_params, hindsight_model) = fixed_runs
        .iter()
        .filter(|(loss, _, _)| *loss <= best_loss * (1.0 + TIE))
        .max_by(|a, b| a.1.lambda.total_cmp(&b.1.lambda).then(b.0.total_cmp(&a.0)))
        .expect("the best is within the tie of itself");
    assert!(
        raced <= best_loss * 1.02,
        "{shape:?}: race {raced:.4} vs best fixed {best_loss:.4} ({best_params:?}); \
         the race chose {:?}",
        race.leader().params
    );
    let hindsight_selected: Vec<usize> = hindsight_model.selected_features().collect();
    let (r, p) = recall_precision(&hindsight_selected, &relevant);
    if r >= 0.9 && p >= 0.9 {
        let chosen: Vec<usize> = race.model().selected_features().collect();
        let (r, p) = recall_precision(&chosen, &relevant);
        assert!(
            r >= 0.9 && p >= 0.9,
            "{shape:?}: hindsight's setting ({hindsight_params:?}) found {relevant:?}, \
             the race's model ({:?}) {chosen:?}",
            race.leader().params
        );
    }
    // Some settings retired (the race cost less than the grid), never below the finalists.
    assert!(race.racing() < grid.len() && race.racing() >= RaceSchedule::default().finalists);
}

#[test]
fn rare_relevant_features_in_a_robot_sized_stream() {
    the_race_keeps_up_with_the_best_fixed_setting(StreamShape {
        classes: 20,
        features: 312,
        relevant: 12,
        relevant_on: 0.05,
        noise_on: 0.04,
        rows: 30_000,
        seed: 1,
    });
}

#[test]
fn common_relevant_features_few_classes_dense_rows() {
    the_race_keeps_up_with_the_best_fixed_setting(StreamShape {
        classes: 2,
        features: 50,
        relevant: 5,
        relevant_on: 0.5,
        noise_on: 0.5,
        rows: 20_000,
        seed: 2,
    });
}

#[test]
fn many_classes_many_columns_sparse_rows() {
    the_race_keeps_up_with_the_best_fixed_setting(StreamShape {
        classes: 50,
        features: 5_000,
        relevant: 10,
        relevant_on: 0.2,
        noise_on: 0.002,
        rows: 20_000,
        seed: 3,
    });
}

/// The field halves at 1×, 2×, 4× … the first cut, down to the finalists; every setting keeps
/// its standing.
#[test]
fn the_field_halves_on_schedule() {
    let grid = auto_grid(None, None, false);
    let schedule = RaceSchedule {
        first_cut: 100,
        finalists: 2,
    };
    let mut race = MdaglRace::new(3, 4, &grid, schedule).expect("race");
    let mut seen = Vec::new();
    for i in 0..1000u32 {
        let x = [i % 4];
        race.update(Features::SparseBinary(&x), (i % 3) as usize)
            .expect("row");
        if [98, 99, 198, 199, 398, 399, 999].contains(&i) {
            seen.push(race.racing());
        }
    }
    // 15 → 8 at row 100, → 4 at 200, → 2 at 400, and 2 to the end.
    assert_eq!(seen, [15, 8, 8, 4, 4, 2, 2]);
    let standings = race.standings();
    assert_eq!(standings.len(), 15);
    assert_eq!(standings.iter().filter(|s| s.racing).count(), 2);
    assert_eq!(standings[0].params, race.leader().params);
    assert!(standings[0].mean_log_loss <= standings[1].mean_log_loss);
}

/// A race of one setting is that setting: same predictions, same model.
#[test]
fn a_race_of_one_is_the_plain_model() {
    let params = MdaglParams {
        lambda: 0.01,
        alpha: 0.3,
        intercept: true,
    };
    let mut race = MdaglRace::new(2, 3, &[params], RaceSchedule::default()).expect("race");
    let mut plain = Mdagl::new(2, 3, params).expect("model");
    for i in 0..500u32 {
        let x = [i % 3];
        let label = usize::from(i % 3 == 0);
        let a = race.update(Features::SparseBinary(&x), label).expect("row");
        let b = plain
            .update(Features::SparseBinary(&x), label)
            .expect("row");
        assert_eq!(a, b);
    }
    assert_eq!(race.into_model().gradient_sums(), plain.gradient_sums());
}

/// A row the models would refuse is refused before any learns it.
#[test]
fn a_bad_row_changes_nothing() {
    let grid = auto_grid(None, Some(1.5), false);
    let mut race = MdaglRace::new(2, 3, &grid, RaceSchedule::default()).expect("race");
    assert!(race.update(Features::SparseBinary(&[5]), 0).is_err());
    assert!(race.update(Features::SparseBinary(&[1]), 2).is_err());
    assert_eq!(race.rows(), 0);
    assert!(race.standings().iter().all(|s| s.mean_log_loss == 0.0));
    assert!(matches!(
        MdaglRace::new(2, 3, &[], RaceSchedule::default()),
        Err(MdaglConfigError::EmptyGrid)
    ));
}

/// Two classes, one of four relevant features worth 0.14 % of the loss: the best fixed setting
/// (λ = 0.005) keeps it, the sparser λ = 0.015 ties with it and drops it, and the race, by its
/// tie rule, leads with the sparser — as hindsight by the same rule does.
#[test]
fn a_relevant_feature_too_weak_to_break_a_tie_may_be_dropped() {
    the_race_keeps_up_with_the_best_fixed_setting(StreamShape {
        classes: 2,
        features: 304,
        relevant: 4,
        relevant_on: 0.10459780814915477,
        noise_on: 0.2902631836959576,
        rows: 10_000,
        seed: 2656866498595117604,
    });
}

/// Four classes, three relevant features: the sparsest setting within the tie (λ = 0.005,
/// α = 1.5) leads at 8 000 rows but trails four denser settings by a hair over rows
/// 4 000–8 000. The cut there keeps it because it leads, and the race ends on it with the
/// three relevant columns rather than on λ = 0.0015's 24.
#[test]
fn the_cut_keeps_the_leader() {
    the_race_keeps_up_with_the_best_fixed_setting(StreamShape {
        classes: 4,
        features: 79,
        relevant: 3,
        relevant_on: 0.17447860359767325,
        noise_on: 0.29938700957800013,
        rows: 10_000,
        seed: 13376406431218011340,
    });
}

proptest::proptest! {
    // A fixed seed: the property is statistical (a race picks among near-ties), so every run
    // checks the same shapes rather than a new draw that may tie the other way.
    #![proptest_config(proptest::prelude::ProptestConfig {
        cases: 8,
        rng_seed: proptest::test_runner::RngSeed::Fixed(2017),
        ..proptest::prelude::ProptestConfig::default()
    })]

    /// On streams of shapes drawn at random — 2–10 classes, 20–400 columns, 2–8 relevant
    /// ones, rare to common features — the race keeps within 2 % of the best fixed setting
    /// and finds the relevant set wherever hindsight by its own rule does.
    #[test]
    fn the_race_keeps_up_on_any_shape(
        classes in 2usize..=10,
        features in 20usize..=400,
        relevant in 2usize..=8,
        relevant_on in 0.05f64..0.5,
        noise_on in 0.01f64..0.3,
        seed in proptest::prelude::any::<u64>(),
    ) {
        the_race_keeps_up_with_the_best_fixed_setting(StreamShape {
            classes,
            features,
            relevant,
            relevant_on,
            noise_on,
            rows: 10_000,
            seed,
        });
    }
}

/// A block learned by one thread or by several is the same, to the bit, as the rows learned
/// one by one: every prediction, every standing, the leader's model — across cuts that fall
/// inside blocks.
#[test]
fn blocks_on_any_number_of_threads_learn_as_rows_one_by_one() {
    let shape = StreamShape {
        classes: 5,
        features: 60,
        relevant: 4,
        relevant_on: 0.2,
        noise_on: 0.05,
        rows: 3000,
        seed: 11,
    };
    let (rows, _) = stream(shape);
    let grid = auto_grid(None, None, true);
    // Two finalists weigh every row as a mixture to the end; one predicts alone after 2 400
    // rows, on the race's shorter path.
    for finalists in [2, 1] {
        let schedule = RaceSchedule {
            first_cut: 300,
            finalists,
        };
        blocks_learn_as_rows_one_by_one(shape, &rows, &grid, schedule);
    }
}

fn blocks_learn_as_rows_one_by_one(
    shape: StreamShape,
    rows: &[(Vec<u32>, usize)],
    grid: &[MdaglParams],
    schedule: RaceSchedule,
) {
    let new_race = || MdaglRace::new(shape.classes, shape.features, grid, schedule).expect("race");
    let mut one_by_one = new_race();
    let expected: Vec<Prequential> = rows
        .iter()
        .map(|(x, y)| {
            one_by_one
                .update(Features::SparseBinary(x), *y)
                .expect("row")
        })
        .collect();
    for (threads, block) in [(1, 1000), (2, 257), (3, 3000), (16, 64)] {
        let mut race = new_race();
        race.set_threads(threads);
        let mut got = Vec::new();
        let mut out = Vec::new();
        for chunk in rows.chunks(block) {
            let batch: Vec<(Features<'_>, usize)> = chunk
                .iter()
                .map(|(x, y)| (Features::SparseBinary(x), *y))
                .collect();
            race.update_block(&batch, &mut out).expect("block");
            got.extend_from_slice(&out);
        }
        assert_eq!(
            got, expected,
            "{threads} threads, blocks of {block}, {schedule:?}"
        );
        assert_eq!(race.standings(), one_by_one.standings());
        assert_eq!(race.model(), one_by_one.model());
    }
}

/// A block with a refused row learns the rows before it and names it; nothing after it is
/// learned.
#[test]
fn a_block_stops_at_its_first_refused_row() {
    let grid = auto_grid(None, Some(1.5), false);
    let mut race = MdaglRace::new(2, 3, &grid, RaceSchedule::default()).expect("race");
    race.set_threads(2);
    let rows = [
        (Features::SparseBinary(&[0]), 0),
        (Features::SparseBinary(&[1, 2]), 1),
        (Features::SparseBinary(&[2, 1]), 0),
        (Features::SparseBinary(&[0]), 1),
    ];
    let mut out = Vec::new();
    let refused = race
        .update_block(&rows, &mut out)
        .expect_err("unsorted row");
    assert_eq!(refused.row, 2);
    assert!(matches!(
        refused.source,
        MdaglError::UnsortedIndices {
            previous: 2,
            index: 1
        }
    ));
    assert_eq!((out.len(), race.rows()), (2, 2));
    let label_out_of_range = [(Features::SparseBinary(&[0]), 2)];
    let refused = race
        .update_block(&label_out_of_range, &mut out)
        .expect_err("label");
    assert_eq!((refused.row, out.len(), race.rows()), (0, 0, 2));
}

/// A race saved mid-way — before and after its first cut — and restored from its state goes
/// on exactly as the original: the same prequential records, leader and standings.
#[test]
fn a_restored_race_goes_on_as_the_original() {
    let (rows, _) = stream(StreamShape {
        classes: 3,
        features: 12,
        relevant: 2,
        relevant_on: 0.2,
        noise_on: 0.1,
        rows: 900,
        seed: 5,
    });
    let schedule = RaceSchedule {
        first_cut: 300,
        finalists: 1,
    };
    for saved_at in [150, 450] {
        let mut race = MdaglRace::new(3, 12, &auto_grid(None, None, true), schedule).unwrap();
        for (x, label) in &rows[..saved_at] {
            race.update(Features::SparseBinary(x), *label).unwrap();
        }
        let mut restored = MdaglRace::from_state(race.state()).unwrap();
        assert_eq!(restored.state(), race.state());
        for (x, label) in &rows[saved_at..] {
            let a = race.update(Features::SparseBinary(x), *label).unwrap();
            let b = restored.update(Features::SparseBinary(x), *label).unwrap();
            assert_eq!(
                (a.log_prob.to_bits(), a.predicted),
                (b.log_prob.to_bits(), b.predicted)
            );
        }
        assert_eq!(restored.state(), race.state());
        assert_eq!(restored.standings(), race.standings());
    }
}

#[test]
fn a_corrupt_race_state_is_refused() {
    let race =
        MdaglRace::new(2, 3, &auto_grid(None, None, false), RaceSchedule::default()).unwrap();
    let mut no_entrants = race.state();
    no_entrants.entrants.clear();
    assert_eq!(
        MdaglRace::from_state(no_entrants).unwrap_err(),
        RaceStateError::NoEntrants
    );
    let mut bad_leader = race.state();
    bad_leader.leader = 99;
    assert!(matches!(
        MdaglRace::from_state(bad_leader),
        Err(RaceStateError::BadLeader { .. })
    ));
    let mut nan_loss = race.state();
    nan_loss.entrants[0].loss = f64::NAN;
    assert_eq!(
        MdaglRace::from_state(nan_loss).unwrap_err(),
        RaceStateError::Inconsistent
    );
}
