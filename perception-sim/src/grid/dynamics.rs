//! A grid task's true dynamics: the paper's logistic sets ([`DYNAMICS_SETS`]), logistic sets
//! drawn at random, and interaction tables that no logistic model over the features fits.
//!
//! The last two give the lifelong benchmark more worlds than a bounded view library holds,
//! and worlds where mDAGL's model class is wrong: an [`InteractionTable`] draws the effect
//! distribution of every (surface, walls around the mover) pair on its own, so the walls'
//! effect depends on the surface and on each other — an interaction an additive logistic
//! model over the one-hot surface and the wall bits cannot represent.

use rand::{Rng, RngExt};

use super::{
    DYNAMICS_SETS, DynamicsSet, N_ACTIONS, N_EFFECTS, N_RELEVANT_FEATURES, STAY, Surface,
    SurfaceDynamics,
};

/// A task's true `P(effect | cell, action)` before blocked moves are masked.
#[derive(Debug, Clone, PartialEq)]
pub enum Dynamics {
    /// `softmax(W_a · φ)` over the relevant features (bias, surface, walls).
    Logistic(DynamicsSet),
    /// A distribution per surface and pattern of walls around the mover.
    Table(Box<InteractionTable>),
}

/// Per surface ([`Surface::ALL`] order) and per pattern of walls around the mover, relative
/// to its move (bit 0 a wall ahead, bit 1 on its right, bit 2 behind, bit 3 on its left), the
/// distribution over the relative effects (intended, to the right, backwards, to the left,
/// stay).
#[derive(Debug, Clone, PartialEq)]
pub struct InteractionTable {
    /// `probs[surface][pattern][relative effect]`, each row summing to 1.
    pub probs: [[[f64; N_EFFECTS]; 16]; 5],
}

/// Where relative effect `k` (intended, right, back, left) of a move `action` leads, as an
/// absolute effect (N, E, S, W); `STAY` stays.
fn absolute(action: usize, k: usize) -> usize {
    if k == STAY {
        STAY
    } else {
        (action + k) % N_ACTIONS
    }
}

impl Dynamics {
    /// The paper's set `set` (< 3).
    pub fn paper(set: usize) -> Option<Self> {
        DYNAMICS_SETS.get(set).copied().map(Self::Logistic)
    }

    /// A logistic set drawn at random, in the ranges the paper's three span: the intended
    /// move the likeliest effect on every open cell of every surface but, at most, one.
    pub fn random_logistic(rng: &mut impl Rng) -> Self {
        let mut draw = |lo: f64, hi: f64| lo + (hi - lo) * rng.random::<f64>();
        let mut surfaces = [SurfaceDynamics {
            intended: 0.0,
            sideways: 0.0,
            backwards: 0.0,
            stay: 0.0,
        }; 5];
        for s in surfaces.iter_mut().take(4) {
            *s = SurfaceDynamics {
                intended: draw(1.0, 3.0),
                sideways: draw(-0.3, 1.4),
                backwards: draw(-1.0, 1.2),
                stay: draw(-0.5, 1.5),
            };
        }
        Self::Logistic(DynamicsSet {
            surfaces,
            wall_beside_stay: draw(0.0, 0.8),
            wall_ahead_sideways: draw(0.0, 0.8),
        })
    }

    /// An interaction table drawn at random: each (surface, wall pattern) row on its own, the
    /// intended move favoured on average but not everywhere.
    pub fn random_table(rng: &mut impl Rng) -> Self {
        let mut probs = [[[0.0; N_EFFECTS]; 16]; 5];
        for (surface, rows) in probs.iter_mut().enumerate() {
            for row in rows.iter_mut() {
                if surface == Surface::Fire.index() {
                    *row = [1.0 / N_EFFECTS as f64; N_EFFECTS];
                    continue;
                }
                let sharpness = 0.5 + 2.5 * rng.random::<f64>();
                let mut logits = [0.0; N_EFFECTS];
                for (k, l) in logits.iter_mut().enumerate() {
                    let favour = if k == 0 { 1.0 } else { 0.0 };
                    *l = sharpness * (favour + standard_normal(rng));
                }
                *row = softmax(logits);
            }
        }
        Self::Table(Box::new(InteractionTable { probs }))
    }

    /// Whether the dynamics are logistic in the task's features (mDAGL's model class).
    pub fn is_logistic(&self) -> bool {
        matches!(self, Self::Logistic(_))
    }

    /// `P(effect | cell, action)` before masking, in absolute effect order, for a cell with
    /// `features` (sorted, relevant ones first), `surface` and `walls` bits.
    pub(super) fn unmasked(
        &self,
        features: &[u32],
        surface: Surface,
        walls: u8,
        action: usize,
    ) -> [f64; N_EFFECTS] {
        match self {
            Self::Logistic(set) => {
                let w = set.weights(action);
                let mut scores = [0.0; N_EFFECTS];
                for &j in features
                    .iter()
                    .take_while(|&&j| (j as usize) < N_RELEVANT_FEATURES)
                {
                    for (score, row) in scores.iter_mut().zip(&w) {
                        *score += row[j as usize];
                    }
                }
                softmax(scores)
            }
            Self::Table(table) => {
                let pattern = (0..N_ACTIONS)
                    .filter(|k| walls & (1 << ((action + k) % N_ACTIONS)) != 0)
                    .fold(0usize, |p, k| p | 1 << k);
                let row = &table.probs[surface.index()][pattern];
                let mut p = [0.0; N_EFFECTS];
                for (k, &q) in row.iter().enumerate() {
                    p[absolute(action, k)] += q;
                }
                p
            }
        }
    }
}

fn softmax(scores: [f64; N_EFFECTS]) -> [f64; N_EFFECTS] {
    let max = scores.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let p = scores.map(|v| (v - max).exp());
    let total: f64 = p.iter().sum();
    p.map(|v| v / total)
}

/// A standard normal draw (Box–Muller).
fn standard_normal(rng: &mut impl Rng) -> f64 {
    let u: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}
