//! Planning on the learned CMDP: warm-started value iteration.
//!
//! `V(s) = max_a Σ_e P(e | x(s), a) · [R(s'_e) + γ · V(s'_e)]` with `s'_e` the state effect
//! `e` leads to, `V = 0` beyond a terminal state, γ = 0.95 by default (the paper's §5).
//!
//! Sweeps are Gauss–Seidel (values updated in place, which converges in fewer sweeps) and
//! start from the previous solution, so after one view learned from one step a re-plan costs a
//! few sweeps, not a solve from scratch. A plan stops when the largest change of any value in a
//! sweep is at most [`PlannerParams::tolerance`] or after [`PlannerParams::max_sweeps`] sweeps;
//! with γ < 1 the values are then within `tolerance·γ/(1−γ)` of the fixed point.
//!
//! **Anytime.** The default sweep cap is small (10): an agent re-plans before every greedy
//! action, so a plan that has not converged simply continues, warm-started, at the next step
//! ([`PlannedModel`] re-plans until it converges even if the model stops changing, and can stop
//! a re-plan early while the model keeps moving: see its "How far it re-plans"). Planning
//! work per action is therefore bounded — as the real-time controller needs, and as it was in
//! the paper's Table 1, where every ε-greedy agent pays about the same planning cost per step.
//! For a one-off solve to convergence raise `max_sweeps`.

use thiserror::Error;

mod model;
mod pieces;
mod value_iteration;

pub use model::PlannedModel;
pub use pieces::{ChangeError, ModelChanges, Pieces};
use value_iteration::SweepTally;
pub use value_iteration::{Optimism, ValueIteration};

/// Planner settings, validated by [`ValueIteration::new`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlannerParams {
    /// Discount factor γ in [0, 1).
    pub gamma: f64,
    /// Stop when no value changes by more than this in a sweep (> 0).
    pub tolerance: f64,
    /// Stop after this many sweeps even if not converged (≥ 1); the next plan continues from
    /// where this one stopped.
    pub max_sweeps: usize,
    /// Let a [`PlannedModel`] stop a re-plan early while its model keeps moving (see its
    /// "How far it re-plans"). Off by default: the controller's planner thread has the time
    /// between actions to plan to the tolerance. The grid experiment turns it on for every
    /// agent, since there planning time per step is what Table 1 compares.
    pub stop_at_drift: bool,
}

impl Default for PlannerParams {
    /// γ = 0.95, tolerance 1e-4 (values within 2·10⁻³ of the fixed point, far below the
    /// −0.01 step reward that separates plans), at most 10 sweeps per plan (anytime: see the
    /// module docs).
    fn default() -> Self {
        Self {
            gamma: 0.95,
            tolerance: 1e-4,
            max_sweeps: 10,
            stop_at_drift: false,
        }
    }
}

/// Invalid planner settings.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum PlanError {
    /// γ outside [0, 1).
    #[error("gamma must be in [0, 1), got {0}")]
    BadGamma(f64),
    /// Tolerance not finite and positive.
    #[error("tolerance must be a finite number > 0, got {0}")]
    BadTolerance(f64),
    /// Zero sweeps allowed.
    #[error("max_sweeps must be at least 1")]
    NoSweeps,
    /// A solution for another state space.
    #[error("a solution with {values} values and {policy} actions for {expected} states")]
    WrongSize {
        /// States of this planner.
        expected: usize,
        /// Values given.
        values: usize,
        /// Policy entries given.
        policy: usize,
    },
}

/// How a plan went.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanStats {
    /// Sweeps run.
    pub sweeps: usize,
    /// Largest value change in the last sweep.
    pub residual: f64,
    /// Whether the residual fell to the tolerance.
    pub converged: bool,
}

impl PlanStats {
    /// No sweep made yet.
    const NONE: Self = Self {
        sweeps: 0,
        residual: f64::INFINITY,
        converged: false,
    };
}

#[cfg(test)]
mod tests;
