//! Labelled streams drawn from a known sparse multinomial logistic model.
//!
//! Used to check that mDAGL finds the few relevant features among many irrelevant ones, to
//! benchmark it on realistic inputs, and to make the demo data `tes fit` ships with. Every
//! stream is fully determined by its [`SyntheticSpec`] and seed.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

/// The shape of a synthetic stream.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticSpec {
    /// Number of classes `K` (≥ 2).
    pub classes: usize,
    /// Number of binary features `d`.
    pub features: usize,
    /// How many of them the true model uses (≤ `features`).
    pub relevant: usize,
    /// Probability that any one feature is on in a row, in (0, 1).
    pub density: f64,
    /// Make feature 0 an always-on bias column (not part of the true model, never relevant).
    /// It lets a model without intercept express the class prior; without one it has to
    /// borrow irrelevant features for that.
    pub bias: bool,
    /// Largest absolute true weight of each relevant feature (weights are centred per feature).
    pub weight_scale: f64,
}

impl Default for SyntheticSpec {
    /// 5 classes, 205 features: an always-on bias, and 5 relevant ones among the other 204; features
    /// on half the time, weights in ±3.
    fn default() -> Self {
        Self {
            classes: 5,
            features: 205,
            relevant: 5,
            density: 0.5,
            bias: true,
            weight_scale: 3.0,
        }
    }
}

/// Why a [`SyntheticSpec`] is unusable.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum SyntheticError {
    /// Fewer than two classes.
    #[error("a synthetic stream needs at least 2 classes, got {0}")]
    TooFewClasses(usize),
    /// More relevant features than features (besides the bias), or none at all.
    #[error(
        "relevant features ({relevant}) must be between 1 and the non-bias feature count ({features})"
    )]
    BadRelevantCount {
        /// Requested relevant count.
        relevant: usize,
        /// Feature count.
        features: usize,
    },
    /// Density outside (0, 1).
    #[error("density must be in (0, 1), got {0}")]
    BadDensity(f64),
    /// Weight scale not finite and positive.
    #[error("weight scale must be finite and > 0, got {0}")]
    BadWeightScale(f64),
}

/// An endless stream of `(label, active features)` rows from a sparse ground-truth model.
#[derive(Debug, Clone)]
pub struct SparseMultinomialStream {
    spec: SyntheticSpec,
    relevant: Vec<u32>,
    /// `K × relevant` true weights, row-major.
    weights: Vec<f64>,
    rng: ChaCha8Rng,
    active: Vec<u32>,
    scores: Vec<f64>,
}

impl SparseMultinomialStream {
    /// A stream for `spec`; the seed fixes the relevant features, the weights and every row.
    pub fn new(spec: SyntheticSpec, seed: u64) -> Result<Self, SyntheticError> {
        if spec.classes < 2 {
            return Err(SyntheticError::TooFewClasses(spec.classes));
        }
        let first = usize::from(spec.bias);
        if spec.relevant == 0 || spec.relevant + first > spec.features {
            return Err(SyntheticError::BadRelevantCount {
                relevant: spec.relevant,
                features: spec.features,
            });
        }
        if !(spec.density > 0.0 && spec.density < 1.0) {
            return Err(SyntheticError::BadDensity(spec.density));
        }
        if !(spec.weight_scale.is_finite() && spec.weight_scale > 0.0) {
            return Err(SyntheticError::BadWeightScale(spec.weight_scale));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // Partial Fisher–Yates: the first `relevant` entries are a uniform random subset.
        let mut all: Vec<u32> = (first as u32..spec.features as u32).collect();
        for i in 0..spec.relevant {
            let j = rng.random_range(i..all.len());
            all.swap(i, j);
        }
        let mut relevant = all[..spec.relevant].to_vec();
        relevant.sort_unstable();
        let (k, r) = (spec.classes, relevant.len());
        let mut weights: Vec<f64> = (0..k * r).map(|_| rng.random_range(-1.0..=1.0)).collect();
        // Centre each feature's weights across classes (a common shift changes no probability)
        // and stretch them so the largest is `weight_scale`: every relevant feature matters.
        for j in 0..r {
            let mean = (0..k).map(|c| weights[c * r + j]).sum::<f64>() / k as f64;
            let peak = (0..k)
                .map(|c| (weights[c * r + j] - mean).abs())
                .fold(0.0, f64::max)
                .max(f64::MIN_POSITIVE);
            for c in 0..k {
                weights[c * r + j] = (weights[c * r + j] - mean) / peak * spec.weight_scale;
            }
        }
        Ok(Self {
            spec,
            relevant,
            weights,
            rng,
            active: Vec::with_capacity(spec.features),
            scores: vec![0.0; spec.classes],
        })
    }

    /// The stream's shape.
    pub fn spec(&self) -> SyntheticSpec {
        self.spec
    }

    /// The features the true model uses, in increasing order.
    pub fn relevant(&self) -> &[u32] {
        &self.relevant
    }

    /// The true class probabilities for a row with these active features (sorted).
    pub fn true_probabilities(&self, active: &[u32], out: &mut [f64]) {
        let r = self.relevant.len();
        for (k, o) in out.iter_mut().enumerate().take(self.spec.classes) {
            *o = self
                .relevant
                .iter()
                .enumerate()
                .filter(|(_, f)| active.binary_search(f).is_ok())
                .map(|(j, _)| self.weights[k * r + j])
                .sum();
        }
        let max = out.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut sum = 0.0;
        for o in out.iter_mut() {
            *o = (*o - max).exp();
            sum += *o;
        }
        out.iter_mut().for_each(|o| *o /= sum);
    }

    /// Draws the next row: its label and its active features (sorted, valid until the next call).
    pub fn next_row(&mut self) -> (usize, &[u32]) {
        self.active.clear();
        for i in 0..self.spec.features as u32 {
            if (self.spec.bias && i == 0) || self.rng.random::<f64>() < self.spec.density {
                self.active.push(i);
            }
        }
        let mut scores = std::mem::take(&mut self.scores);
        self.true_probabilities(&self.active, &mut scores);
        let u: f64 = self.rng.random();
        let mut acc = 0.0;
        let mut label = self.spec.classes - 1;
        for (k, &p) in scores.iter().enumerate() {
            acc += p;
            if u < acc {
                label = k;
                break;
            }
        }
        self.scores = scores;
        (label, &self.active)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream_and_labels_follow_the_model() {
        let spec = SyntheticSpec::default();
        let mut a = SparseMultinomialStream::new(spec, 3).unwrap();
        let mut b = SparseMultinomialStream::new(spec, 3).unwrap();
        assert_eq!(a.relevant(), b.relevant());
        assert_eq!(a.relevant().len(), 5);
        assert_ne!(a.relevant()[0], 0);
        for _ in 0..100 {
            let (la, xa) = a.next_row();
            let xa = xa.to_vec();
            let (lb, xb) = b.next_row();
            assert_eq!((la, xa.as_slice()), (lb, xb));
            assert!(la < spec.classes);
            assert!(xa.windows(2).all(|w| w[0] < w[1]));
        }
        let c = SparseMultinomialStream::new(spec, 4).unwrap();
        assert_ne!(a.weights, c.weights);
    }

    #[test]
    fn rejects_bad_specs() {
        let ok = SyntheticSpec::default();
        let bad = [
            SyntheticSpec { classes: 1, ..ok },
            SyntheticSpec { relevant: 0, ..ok },
            SyntheticSpec {
                relevant: 205,
                ..ok
            },
            SyntheticSpec { density: 1.0, ..ok },
            SyntheticSpec {
                weight_scale: f64::NAN,
                ..ok
            },
        ];
        for spec in bad {
            assert!(SparseMultinomialStream::new(spec, 0).is_err(), "{spec:?}");
        }
    }
}
