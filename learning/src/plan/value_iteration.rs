//! Value iteration with its values and greedy policy kept between plans (the warm start).

use std::ops::Range;

use super::{PlanError, PlanStats, PlannerParams};
use crate::cmdp::{CmdpStructure, EffectTable};

/// What a sweep in progress has found: the largest value change so far and the range of
/// `R(s) + γV(s)` over the states visited.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SweepTally {
    residual: f64,
    lo: f64,
    hi: f64,
}

impl SweepTally {
    /// Nothing visited yet.
    pub(crate) fn new() -> Self {
        Self {
            residual: 0.0,
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
        }
    }
}

/// Which state–action pairs R-max treats as unknown, and what they are worth.
#[derive(Debug, Clone, Copy)]
pub struct Optimism<'a> {
    /// `unknown[a * n_states + s]`.
    pub unknown: &'a [bool],
    /// The optimistic value of an unknown pair.
    pub value: f64,
}

/// Value iteration with its values and greedy policy kept between plans (the warm start).
#[derive(Debug, Clone, PartialEq)]
pub struct ValueIteration {
    pub(super) params: PlannerParams,
    pub(super) values: Vec<f64>,
    pub(super) policy: Vec<u32>,
    /// Scratch: `R(s'_e) + γ V(s'_e)` for each effect of the state being backed up.
    pub(super) backup: Vec<f64>,
    /// The spread of `R(s) + γV(s)` over all states after the last sweep made here.
    pub(super) backup_span: f64,
}

impl ValueIteration {
    /// A planner for `structure`, starting from `V = 0`.
    pub fn new(structure: &CmdpStructure, params: PlannerParams) -> Result<Self, PlanError> {
        if !(0.0..1.0).contains(&params.gamma) {
            return Err(PlanError::BadGamma(params.gamma));
        }
        if !(params.tolerance.is_finite() && params.tolerance > 0.0) {
            return Err(PlanError::BadTolerance(params.tolerance));
        }
        if params.max_sweeps == 0 {
            return Err(PlanError::NoSweeps);
        }
        Ok(Self {
            params,
            values: vec![0.0; structure.n_states()],
            policy: vec![0; structure.n_states()],
            backup: vec![0.0; structure.n_effects()],
            backup_span: 0.0,
        })
    }

    /// The settings.
    pub fn params(&self) -> PlannerParams {
        self.params
    }

    /// Forgets the warm start: back to `V = 0`.
    pub fn reset(&mut self) {
        self.values.fill(0.0);
        self.policy.fill(0);
    }

    /// `Q(s, a)` under the current values.
    #[inline]
    pub fn q_value(
        &self,
        structure: &CmdpStructure,
        table: &EffectTable,
        s: usize,
        a: usize,
    ) -> f64 {
        let gamma = self.params.gamma;
        table
            .probs(a, s)
            .iter()
            .enumerate()
            .map(|(e, &p)| {
                if p == 0.0 {
                    return 0.0;
                }
                let next = structure.next_state(s, e);
                let future = if structure.is_terminal(next) {
                    0.0
                } else {
                    gamma * self.values[next]
                };
                p * (structure.reward(next) + future)
            })
            .sum()
    }

    /// Backs up `states` (in order) in the current Gauss–Seidel sweep, adding what it finds
    /// to `tally`: a whole sweep is one call over every state, or several over consecutive
    /// ranges (the same arithmetic in the same order, so the same bits).
    pub(crate) fn sweep_states(
        &mut self,
        structure: &CmdpStructure,
        table: &EffectTable,
        optimism: Option<Optimism<'_>>,
        states: Range<usize>,
        tally: &mut SweepTally,
    ) {
        // The grid tasks have 5 effects, the robot arenas 20.
        match structure.n_effects() {
            5 => self.sweep::<5>(structure, table, optimism, states, tally),
            20 => self.sweep::<20>(structure, table, optimism, states, tally),
            _ => self.sweep::<0>(structure, table, optimism, states, tally),
        }
    }

    /// [`sweep_states`](Self::sweep_states) for `E` effects.
    ///
    /// `E` is the number of effects when it is one the planner is specialised for, 0 for any
    /// other: with the count a constant the compiler unrolls the per-effect loops and drops
    /// their bounds checks (the sweep is most of an agent's time per step). Every
    /// specialisation runs the same code in the same order, so all give the same bits.
    pub(super) fn sweep<const E: usize>(
        &mut self,
        structure: &CmdpStructure,
        table: &EffectTable,
        optimism: Option<Optimism<'_>>,
        states: Range<usize>,
        tally: &mut SweepTally,
    ) {
        let n_effects = if E == 0 { structure.n_effects() } else { E };
        let gamma = self.params.gamma;
        let backup = &mut self.backup[..n_effects];
        for s in states {
            let terminal = structure.is_terminal(s);
            if !terminal {
                // Every action's Q-value in `s` reads the same successors (effects, not
                // actions, decide where the agent lands), so each successor's `R + γV` is
                // computed once and shared by all actions: `E` lookups per state, not `A × E`.
                let successors = &structure.successors(s)[..n_effects];
                for (b, &next) in backup.iter_mut().zip(successors) {
                    let next = next as usize;
                    let future = if structure.is_terminal(next) {
                        0.0
                    } else {
                        gamma * self.values[next]
                    };
                    *b = structure.reward(next) + future;
                }
                // The best action (lowest id on ties) and its value.
                let mut best = (0, f64::NEG_INFINITY);
                for a in 0..structure.n_actions() {
                    let q = match optimism {
                        Some(o) if o.unknown[a * structure.n_states() + s] => o.value,
                        _ => table.probs(a, s)[..n_effects]
                            .iter()
                            .zip(backup.iter())
                            .map(|(&p, &b)| p * b)
                            .sum(),
                    };
                    if q > best.1 {
                        best = (a, q);
                    }
                }
                let (a, v) = best;
                tally.residual = tally.residual.max((v - self.values[s]).abs());
                self.values[s] = v;
                self.policy[s] = a as u32;
            }
            // `V(s)` is final for this sweep once its state has been visited.
            let b = structure.reward(s)
                + if terminal {
                    0.0
                } else {
                    gamma * self.values[s]
                };
            tally.lo = tally.lo.min(b);
            tally.hi = tally.hi.max(b);
        }
    }

    /// Counts a finished sweep into `stats`; returns whether the plan stops here: converged
    /// (residual at most the tolerance), good enough (at most `good_enough`, not converged),
    /// or at the sweep cap.
    pub(super) fn end_sweep(
        &mut self,
        stats: &mut PlanStats,
        tally: SweepTally,
        good_enough: f64,
    ) -> bool {
        self.backup_span = tally.hi - tally.lo;
        stats.sweeps += 1;
        stats.residual = tally.residual;
        if tally.residual <= self.params.tolerance {
            stats.converged = true;
            return true;
        }
        tally.residual <= good_enough || stats.sweeps >= self.params.max_sweeps
    }

    /// Plans to convergence (or the sweep cap) from the current values. Allocation-free.
    pub fn plan(&mut self, structure: &CmdpStructure, table: &EffectTable) -> PlanStats {
        self.plan_inner(structure, table, None, 0.0)
    }

    /// Plans with R-max optimism: every `(s, a)` marked unknown is valued at `optimism.value`
    /// (typically `R_max / (1 − γ)`) instead of by the model, which drives exploration to it.
    ///
    /// `optimism.unknown` is indexed `a * n_states + s`.
    pub fn plan_optimistic(
        &mut self,
        structure: &CmdpStructure,
        table: &EffectTable,
        optimism: Optimism<'_>,
    ) -> PlanStats {
        self.plan_inner(structure, table, Some(optimism), 0.0)
    }

    /// Sweeps until the residual is at most the tolerance (converged) or at most `good_enough`
    /// (stopped early, not converged), or until the sweep cap.
    pub(super) fn plan_inner(
        &mut self,
        structure: &CmdpStructure,
        table: &EffectTable,
        optimism: Option<Optimism<'_>>,
        good_enough: f64,
    ) -> PlanStats {
        let mut stats = PlanStats::NONE;
        let n = structure.n_states();
        loop {
            let mut tally = SweepTally::new();
            self.sweep_states(structure, table, optimism, 0..n, &mut tally);
            if self.end_sweep(&mut stats, tally, good_enough) {
                return stats;
            }
        }
    }

    /// `V(s)` from the last plan.
    #[inline]
    pub fn value(&self, s: usize) -> f64 {
        self.values[s]
    }

    /// The greedy action in `s` from the last plan.
    #[inline]
    pub fn action(&self, s: usize) -> usize {
        self.policy[s] as usize
    }

    /// All values, by state.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The greedy action of every state, from the last plan.
    pub fn policy(&self) -> &[u32] {
        &self.policy
    }

    /// Adopts a solution computed elsewhere (a planner thread's): its values become the warm
    /// start, its policy the greedy policy. Both must have one entry per state.
    pub fn adopt(&mut self, values: &[f64], policy: &[u32]) -> Result<(), PlanError> {
        self.check_solution(values, policy)?;
        self.values.copy_from_slice(values);
        self.policy.copy_from_slice(policy);
        Ok(())
    }

    /// [`adopt`](Self::adopt) without a copy: swaps the buffers, so `values` and `policy`
    /// come back holding the previous solution. Adopting a plan made on another CPU this way
    /// reads none of it, so none of it crosses between the CPUs' caches until it is used.
    pub fn adopt_swapping(
        &mut self,
        values: &mut Vec<f64>,
        policy: &mut Vec<u32>,
    ) -> Result<(), PlanError> {
        self.check_solution(values, policy)?;
        std::mem::swap(&mut self.values, values);
        std::mem::swap(&mut self.policy, policy);
        Ok(())
    }

    /// A solution to adopt has one value and one action per state.
    fn check_solution(&self, values: &[f64], policy: &[u32]) -> Result<(), PlanError> {
        if values.len() != self.values.len() || policy.len() != self.policy.len() {
            return Err(PlanError::WrongSize {
                expected: self.values.len(),
                values: values.len(),
                policy: policy.len(),
            });
        }
        Ok(())
    }
}
