// The reference is a literal transcription of the paper's index notation (k, i); keep it that way.
#![allow(clippy::needless_range_loop)]

use super::synthetic::{SparseMultinomialStream, SyntheticSpec};
use super::*;
use proptest::prelude::*;

/// A plain, dense transcription of Algorithm 5: keeps `W` and `Ḡ` as full `K × d` matrices and
/// applies equation (2), the running average and rule (A.1) literally. Slow on purpose.
struct DenseReference {
    k: usize,
    d: usize,
    lambda: f64,
    alpha: f64,
    t: usize,
    w: Vec<Vec<f64>>,
    g_bar: Vec<Vec<f64>>,
}

impl DenseReference {
    fn new(k: usize, d: usize, lambda: f64, alpha: f64) -> Self {
        Self {
            k,
            d,
            lambda,
            alpha,
            t: 0,
            w: vec![vec![0.0; d]; k],
            g_bar: vec![vec![0.0; d]; k],
        }
    }

    fn probabilities(&self, x: &[f64]) -> Vec<f64> {
        let z: Vec<f64> = (0..self.k)
            .map(|k| (0..self.d).map(|i| self.w[k][i] * x[i]).sum())
            .collect();
        let max = z.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let e: Vec<f64> = z.iter().map(|v| (v - max).exp()).collect();
        let s: f64 = e.iter().sum();
        e.iter().map(|v| v / s).collect()
    }

    fn update(&mut self, x: &[f64], y: usize) {
        self.t += 1;
        let t = self.t as f64;
        let p = self.probabilities(x);
        for k in 0..self.k {
            for i in 0..self.d {
                let g = -x[i] * (f64::from(u8::from(y == k)) - p[k]);
                self.g_bar[k][i] = (t - 1.0) / t * self.g_bar[k][i] + g / t;
            }
        }
        let beta = self.alpha * t.sqrt();
        let thr = self.lambda * (self.k as f64).sqrt();
        for i in 0..self.d {
            let norm = (0..self.k)
                .map(|k| self.g_bar[k][i] * self.g_bar[k][i])
                .sum::<f64>()
                .sqrt();
            for k in 0..self.k {
                self.w[k][i] = if norm <= thr {
                    0.0
                } else {
                    t / beta * (thr / norm - 1.0) * self.g_bar[k][i]
                };
            }
        }
    }
}

fn dense(active: &[u32], d: usize) -> Vec<f64> {
    let mut x = vec![0.0; d];
    for &i in active {
        x[i as usize] = 1.0;
    }
    x
}

/// A random stream: `(K, d, rows)` where each row is `(label, dense x, sparse active set)`.
fn stream() -> impl Strategy<Value = (usize, usize, Vec<(usize, Vec<f64>)>, bool)> {
    (2usize..=20, 1usize..=400, any::<bool>()).prop_flat_map(|(k, d, binary)| {
        let row = (
            0..k,
            proptest::collection::vec(
                prop_oneof![3 => Just(0.0), 1 => Just(1.0), 1 => -2.0..2.0f64],
                d,
            ),
        )
            .prop_map(move |(y, x)| {
                if binary {
                    (y, x.into_iter().map(|v| f64::from(v != 0.0)).collect())
                } else {
                    (y, x)
                }
            });
        (
            Just(k),
            Just(d),
            proptest::collection::vec(row, 1..40),
            Just(binary),
        )
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    /// The fast closed form (sums + norms, O(K × active)) equals the dense transcription of
    /// Algorithm 5: same probabilities before every update and same weights after, to 1e-9.
    #[test]
    fn fast_form_equals_dense_algorithm_5(
        (k, d, rows, binary) in stream(),
        lambda in prop_oneof![Just(0.0), Just(0.05), 0.001..0.3f64],
        alpha in 0.2..3.0f64,
    ) {
        let params = MdaglParams { lambda, alpha, intercept: false };
        let mut fast = Mdagl::new(k, d, params).unwrap();
        let mut reference = DenseReference::new(k, d, lambda, alpha);
        let mut probs = vec![0.0; k];
        let mut column = vec![0.0; k];
        for (y, x) in &rows {
            let active: Vec<u32> = (0..d as u32).filter(|&i| x[i as usize] != 0.0).collect();
            let features = if binary { Features::SparseBinary(&active) } else { Features::Dense(x) };
            fast.predict_into(features, &mut probs).unwrap();
            let expected = reference.probabilities(x);
            for (a, b) in probs.iter().zip(&expected) {
                prop_assert!((a - b).abs() <= 1e-9, "p {a} vs {b}");
            }
            let pre = fast.update(features, *y).unwrap();
            prop_assert!((pre.log_prob - expected[*y].ln()).abs() <= 1e-9);
            reference.update(x, *y);
            for i in 0..d {
                fast.weight_column(i, &mut column).unwrap();
                for kk in 0..k {
                    prop_assert!(
                        (column[kk] - reference.w[kk][i]).abs() <= 1e-9,
                        "W[{kk}][{i}] {} vs {}", column[kk], reference.w[kk][i]
                    );
                }
                // Selection agrees wherever rounding cannot flip the threshold test (at the
                // threshold itself the column is ~0 either way, as checked above).
                let largest = reference.w.iter().map(|row| row[i].abs()).fold(0.0, f64::max);
                if largest > 1e-9 {
                    prop_assert!(fast.is_selected(i));
                } else if largest == 0.0 && fast.average_gradient_norm(i) < lambda * (k as f64).sqrt() * (1.0 - 1e-9) {
                    prop_assert!(!fast.is_selected(i));
                }
            }
        }
    }

    /// A weights-only copy (the planner's hand-over), made again and again into the same
    /// buffer while the source learns — so its switched-off columns hold stale sums — predicts
    /// and reports weight columns exactly as its source, bit for bit.
    #[test]
    fn a_weights_only_copy_predicts_as_its_source(
        (k, d, rows, _) in stream(),
        lambda in prop_oneof![Just(0.0), Just(0.05), 0.01..0.5f64],
        intercept in any::<bool>(),
    ) {
        let params = MdaglParams { lambda, alpha: 0.5, intercept };
        let mut source = Mdagl::new(k, d, params).unwrap();
        let mut copy = Mdagl::new(k, d, params).unwrap();
        let (mut want, mut got) = (vec![0.0; k], vec![0.0; k]);
        for (y, x) in &rows {
            source.update(Features::Dense(x), *y).unwrap();
            copy.copy_weights_from(&source);
            for (_, probe) in &rows {
                source.predict_into(Features::Dense(probe), &mut want).unwrap();
                copy.predict_into(Features::Dense(probe), &mut got).unwrap();
                prop_assert_eq!(&want, &got);
            }
            let mut columns = Vec::new();
            source.for_each_weight_column(|c, scale, sums| columns.push((c, scale, sums.to_vec())));
            let mut copied = Vec::new();
            copy.for_each_weight_column(|c, scale, sums| copied.push((c, scale, sums.to_vec())));
            prop_assert_eq!(columns, copied);
            prop_assert_eq!(source.selected_features().collect::<Vec<_>>(), copy.selected_features().collect::<Vec<_>>());
        }
    }

    /// Probabilities always form a distribution, whatever the data.
    #[test]
    fn predictions_are_distributions((k, d, rows, _) in stream()) {
        let mut m = Mdagl::new(k, d, MdaglParams { lambda: 0.0, alpha: 0.3, intercept: true }).unwrap();
        for (y, x) in &rows {
            m.update(Features::Dense(x), *y).unwrap();
            let p = m.predict(Features::Dense(x)).unwrap();
            prop_assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            prop_assert!(p.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }
}

#[test]
fn fresh_model_predicts_uniform() {
    let mut m = Mdagl::new(4, 10, MdaglParams::default()).unwrap();
    let p = m.predict(Features::SparseBinary(&[1, 5])).unwrap();
    assert!(p.iter().all(|&v| (v - 0.25).abs() < 1e-15));
    assert_eq!(m.selected_features().count(), 0);
    let lp = m.log_prob(Features::SparseBinary(&[]), 2).unwrap();
    assert!((lp - 0.25f64.ln()).abs() < 1e-15);
}

#[test]
fn bad_input_is_refused_and_changes_nothing() {
    let mut m = Mdagl::new(3, 4, MdaglParams::default()).unwrap();
    m.update(Features::Dense(&[1.0, 0.0, 1.0, 0.5]), 1).unwrap();
    let before = m.clone();
    let cases: [(Features<'_>, usize, MdaglError); 7] = [
        (
            Features::Dense(&[1.0, f64::NAN, 0.0, 0.0]),
            0,
            MdaglError::NonFinite {
                index: 1,
                value: f64::NAN,
            },
        ),
        (
            Features::Dense(&[1.0, 0.0, f64::INFINITY, 0.0]),
            0,
            MdaglError::NonFinite {
                index: 2,
                value: f64::INFINITY,
            },
        ),
        (
            Features::Dense(&[1.0, 0.0, 0.0]),
            0,
            MdaglError::WrongFeatureCount {
                expected: 4,
                got: 3,
            },
        ),
        (
            Features::Dense(&[0.0; 4]),
            3,
            MdaglError::LabelOutOfRange {
                label: 3,
                classes: 3,
            },
        ),
        (
            Features::SparseBinary(&[0, 4]),
            0,
            MdaglError::IndexOutOfRange {
                index: 4,
                features: 4,
            },
        ),
        (
            Features::SparseBinary(&[2, 1]),
            0,
            MdaglError::UnsortedIndices {
                previous: 2,
                index: 1,
            },
        ),
        (
            Features::SparseBinary(&[1, 1]),
            0,
            MdaglError::UnsortedIndices {
                previous: 1,
                index: 1,
            },
        ),
    ];
    for (x, y, expected) in cases {
        let err = m.update(x, y).unwrap_err();
        // NaN != NaN, so compare the rendered errors.
        assert_eq!(err.to_string(), expected.to_string());
        assert_eq!(m, before, "model changed after {expected}");
        if y < 3 {
            assert!(m.predict(x).is_err());
            assert!(m.log_prob(x, y).is_err());
        }
    }
    assert!(matches!(
        m.predict_into(Features::Dense(&[0.0; 4]), &mut [0.0; 2]),
        Err(MdaglError::WrongOutputLen {
            expected: 3,
            got: 2
        })
    ));
}

#[test]
fn overflowing_scores_are_refused_and_change_nothing() {
    let mut m = Mdagl::new(2, 1, MdaglParams::default()).unwrap();
    for _ in 0..50 {
        m.update(Features::Dense(&[1.0]), 0).unwrap();
    }
    let before = m.clone();
    assert_eq!(
        m.update(Features::Dense(&[1e308]), 1),
        Err(MdaglError::Overflow)
    );
    assert_eq!(m, before);
}

#[test]
fn invalid_hyper_parameters_are_refused() {
    let ok = MdaglParams::default();
    assert_eq!(
        Mdagl::new(1, 3, ok).unwrap_err(),
        MdaglConfigError::TooFewClasses(1)
    );
    assert_eq!(
        Mdagl::new(2, 0, ok).unwrap_err(),
        MdaglConfigError::NoInputs
    );
    // A size that would abort on allocation is an error instead (e.g. `tes fit --classes`
    // set to a time stamp).
    assert_eq!(
        Mdagl::new(1 << 40, 312, ok).unwrap_err(),
        MdaglConfigError::TooLarge {
            classes: 1 << 40,
            columns: 312
        }
    );
    assert!(matches!(
        Mdagl::new(usize::MAX, 2, ok),
        Err(MdaglConfigError::TooLarge { .. })
    ));
    assert!(Mdagl::new(20, 5000, ok).is_ok());
    assert!(
        Mdagl::new(
            2,
            0,
            MdaglParams {
                intercept: true,
                ..ok
            }
        )
        .is_ok()
    );
    for lambda in [-0.1, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            Mdagl::new(2, 3, MdaglParams { lambda, ..ok }),
            Err(MdaglConfigError::InvalidLambda(_))
        ));
    }
    for alpha in [0.0, -1.0, f64::NAN] {
        assert!(matches!(
            Mdagl::new(2, 3, MdaglParams { alpha, ..ok }),
            Err(MdaglConfigError::InvalidAlpha(_))
        ));
    }
}

#[test]
fn intercept_learns_the_class_prior_without_features() {
    let params = MdaglParams {
        intercept: true,
        ..MdaglParams::default()
    };
    let mut m = Mdagl::new(2, 3, params).unwrap();
    for t in 0..4000 {
        m.update(Features::SparseBinary(&[]), usize::from(t % 4 == 0))
            .unwrap();
    }
    let p = m.predict(Features::SparseBinary(&[])).unwrap();
    assert!((p[1] - 0.25).abs() < 0.03, "{p:?}");
    assert_eq!(m.selected_features().count(), 0);
}

/// The paper's point: among hundreds of irrelevant binary features, mDAGL keeps exactly the
/// columns the true model uses and drops the rest.
///
/// λ is the knob that says how strong a feature's effect must be to be kept (a column survives
/// while its average gradient exceeds λ√K); 0.01 keeps every feature of this ground truth,
/// whose weights peak at ±3. The always-on bias column (feature 0) is the model's intercept.
#[test]
fn recovers_the_relevant_columns_among_200_irrelevant_features() {
    for seed in 1..=6 {
        let spec = SyntheticSpec {
            classes: 5,
            features: 205,
            relevant: 5,
            density: 0.5,
            bias: true,
            weight_scale: 3.0,
        };
        let mut data = SparseMultinomialStream::new(spec, seed).unwrap();
        let params = MdaglParams {
            lambda: 0.01,
            ..MdaglParams::default()
        };
        let mut m = Mdagl::new(5, 205, params).unwrap();
        let mut late_log_loss = 0.0;
        let n = 20_000;
        for t in 0..n {
            let (y, x) = data.next_row();
            let pre = m.update(Features::SparseBinary(x), y).unwrap();
            if t >= n - 2000 {
                late_log_loss -= pre.log_prob;
            }
        }
        let selected: Vec<u32> = m
            .selected_features()
            .map(|i| i as u32)
            .filter(|&i| i != 0)
            .collect();
        assert_eq!(selected, data.relevant(), "seed {seed}");
        assert_eq!(data.relevant().len(), 5);
        // And it predicts well: far better than the uniform ln 5 ≈ 1.61 nats.
        assert!(late_log_loss / 2000.0 < 1.0, "seed {seed}: {late_log_loss}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Binary rows take their own path (two columns at a time); it learns exactly what the
    /// same rows given densely learn, to the bit, with or without an intercept and with an
    /// odd or even number of active columns.
    #[test]
    fn binary_rows_learn_as_their_dense_twins_to_the_bit(
        (k, d, rows, _) in stream(),
        intercept in any::<bool>(),
        lambda in prop_oneof![Just(0.0), 0.001..0.1f64],
    ) {
        let params = MdaglParams { lambda, alpha: 0.5, intercept };
        let mut binary = Mdagl::new(k, d, params).unwrap();
        let mut dense_twin = binary.clone();
        for (y, x) in &rows {
            let x: Vec<f64> = x.iter().map(|&v| f64::from(v != 0.0)).collect();
            let active: Vec<u32> = (0..d as u32).filter(|&i| x[i as usize] != 0.0).collect();
            let a = binary.update(Features::SparseBinary(&active), *y).unwrap();
            let b = dense_twin.update(Features::Dense(&x), *y).unwrap();
            prop_assert_eq!(a, b);
        }
        prop_assert_eq!(&binary, &dense_twin);
    }
}

#[test]
fn dense_and_sparse_inputs_agree() {
    let spec = SyntheticSpec {
        features: 50,
        ..SyntheticSpec::default()
    };
    let mut data = SparseMultinomialStream::new(spec, 9).unwrap();
    let mut a = Mdagl::new(5, 50, MdaglParams::default()).unwrap();
    let mut b = a.clone();
    for _ in 0..500 {
        let (y, x) = data.next_row();
        let xd = dense(x, 50);
        let pa = a.update(Features::SparseBinary(x), y).unwrap();
        let pb = b.update(Features::Dense(&xd), y).unwrap();
        assert_eq!(pa, pb);
    }
    assert_eq!(a, b);
}

#[test]
fn reset_forgets() {
    let mut m = Mdagl::new(3, 2, MdaglParams::default()).unwrap();
    let fresh = m.clone();
    for _ in 0..100 {
        m.update(Features::SparseBinary(&[0]), 2).unwrap();
    }
    assert!(m.is_selected(0));
    assert!(m.average_gradient_norm(0) > 0.05 * 3f64.sqrt());
    m.reset();
    assert_eq!(m, fresh);
}

#[test]
fn learning_state_round_trips_exactly_and_bad_states_are_refused() {
    let params = MdaglParams {
        intercept: true,
        ..MdaglParams::default()
    };
    let mut model = Mdagl::new(4, 30, params).unwrap();
    for t in 0..500u32 {
        let x = [t % 30, (t * 7 + 3) % 30];
        let x = if x[0] < x[1] { x } else { [x[1], x[0]] };
        if x[0] == x[1] {
            continue;
        }
        model
            .update(Features::SparseBinary(&x), (t % 4) as usize)
            .unwrap();
    }
    let restored = Mdagl::from_state(
        4,
        30,
        params,
        model.n_updates(),
        model.gradient_sums().to_vec(),
    )
    .unwrap();
    assert_eq!(restored, model);
    let mut a = model.clone();
    let mut b = restored;
    let x = Features::SparseBinary(&[2, 5]);
    assert_eq!(a.predict(x).unwrap(), b.predict(x).unwrap());

    let sums = model.gradient_sums().to_vec();
    assert!(matches!(
        Mdagl::from_state(4, 29, params, 1, sums.clone()),
        Err(MdaglStateError::WrongLength { .. })
    ));
    let mut nan = sums.clone();
    nan[7] = f64::NAN;
    assert!(matches!(
        Mdagl::from_state(4, 30, params, 1, nan),
        Err(MdaglStateError::BadSum { index: 7, .. })
    ));
    assert!(matches!(
        Mdagl::from_state(4, 30, params, 0, sums),
        Err(MdaglStateError::Inconsistent { .. })
    ));
    assert!(matches!(
        Mdagl::from_state(1, 30, params, 0, vec![0.0; 31]),
        Err(MdaglStateError::Config(_))
    ));
}
