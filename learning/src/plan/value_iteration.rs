//! Value iteration with its values and greedy policy kept between plans (the warm start).

use std::ops::Range;

use super::{PlanError, PlanStats, PlannerParams};
use crate::cmdp::{CmdpStructure, EffectTable, LANES, Step, TableParts};

/// What a sweep in progress has found: the largest value change so far and the range of
/// `R(s) + γV(s)` over the states visited.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SweepTally {
    pub(super) residual: f64,
    pub(super) lo: f64,
    pub(super) hi: f64,
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
///
/// Two planners are equal when their settings, values, policies and last spans are (not
/// their scratch or their bookkeeping of which states changed).
#[derive(Debug, Clone)]
pub struct ValueIteration {
    pub(super) params: PlannerParams,
    pub(super) values: Vec<f64>,
    pub(super) policy: Vec<u32>,
    /// Scratch: `R(s'_e) + γ V(s'_e)` for each effect of the state being backed up.
    pub(super) backup: Vec<f64>,
    /// The spread of `R(s) + γV(s)` over all states after the last sweep made here.
    pub(super) backup_span: f64,
    /// Per state, for [`sweep_tracked`](Self::sweep_tracked): a successor's value changed
    /// since the state was last backed up.
    pub(super) stale: Vec<bool>,
    /// Whether `stale` is up to date (else the next tracked sweep backs up every state).
    pub(super) tracking: bool,
}

impl PartialEq for ValueIteration {
    fn eq(&self, other: &Self) -> bool {
        self.params == other.params
            && self.values == other.values
            && self.policy == other.policy
            && self.backup_span == other.backup_span
    }
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
            stale: vec![true; structure.n_states()],
            tracking: false,
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
        self.tracking = false;
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
                p * (structure.step_reward(s, a, e) + future)
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
        // Values change here without the table's flags being read: a tracked sweep must
        // start over.
        self.tracking = false;
        let (probs, lanes) = table.layouts();
        let table = TableParts {
            probs,
            lanes,
            fresh: &mut [],
        };
        self.dispatch::<false>(structure, table, optimism, states, tally);
    }

    /// [`sweep_states`](Self::sweep_states) without optimism that skips every state whose
    /// backup would give the bits it gave last time: neither a successor's value nor any of
    /// its rows in `table` changed since this planner last backed it up. Such a state's value
    /// and action are already what the backup would write, and its change (0) cannot raise
    /// the residual, so the sweep's outcome is the same bit for bit.
    ///
    /// The caller must sweep the same `table` every time (a [`PlannedModel`] does, its own);
    /// anything else that changes the values ([`adopt`](Self::adopt),
    /// [`reset`](Self::reset), an untracked sweep) makes the next tracked sweep back up
    /// every state once.
    ///
    /// [`PlannedModel`]: super::PlannedModel
    pub(crate) fn sweep_tracked(
        &mut self,
        structure: &CmdpStructure,
        table: &mut EffectTable,
        states: Range<usize>,
        tally: &mut SweepTally,
    ) {
        if !self.tracking {
            self.stale.fill(true);
            self.tracking = true;
        }
        self.dispatch::<true>(structure, table.parts(), None, states, tally);
    }

    /// Picks the sweep specialised for the effect count and, on x86-64, the AVX2 build of
    /// it when the CPU has AVX2.
    fn dispatch<const TRACK: bool>(
        &mut self,
        structure: &CmdpStructure,
        table: TableParts<'_>,
        optimism: Option<Optimism<'_>>,
        states: Range<usize>,
        tally: &mut SweepTally,
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: `sweep_avx2` needs AVX2 and nothing else, and the CPU has it.
            unsafe { self.sweep_avx2::<TRACK>(structure, table, optimism, states, tally) };
            return;
        }
        self.sweep_portable::<TRACK>(structure, table, optimism, states, tally);
    }

    /// The sweep built for the default target (on x86-64, SSE2).
    pub(super) fn sweep_portable<const TRACK: bool>(
        &mut self,
        structure: &CmdpStructure,
        table: TableParts<'_>,
        optimism: Option<Optimism<'_>>,
        states: Range<usize>,
        tally: &mut SweepTally,
    ) {
        // The grid tasks have 5 effects, the robot arenas 20.
        match structure.n_effects() {
            5 => self.sweep::<5, TRACK>(structure, table, optimism, states, tally),
            20 => self.sweep::<20, TRACK>(structure, table, optimism, states, tally),
            _ => self.sweep::<0, TRACK>(structure, table, optimism, states, tally),
        }
    }

    /// The same sweep compiled with AVX2: the per-action sums of a state, one lane per
    /// action, in 256-bit registers. Each lane adds the same products in the same order
    /// (no fused multiply-add: Rust never contracts), so the bits are the portable sweep's.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) fn sweep_avx2<const TRACK: bool>(
        &mut self,
        structure: &CmdpStructure,
        table: TableParts<'_>,
        optimism: Option<Optimism<'_>>,
        states: Range<usize>,
        tally: &mut SweepTally,
    ) {
        match structure.n_effects() {
            5 => self.sweep::<5, TRACK>(structure, table, optimism, states, tally),
            20 => self.sweep::<20, TRACK>(structure, table, optimism, states, tally),
            _ => self.sweep::<0, TRACK>(structure, table, optimism, states, tally),
        }
    }

    /// The sweep for `E` effects, skipping unchanged states when `TRACK`.
    ///
    /// `E` is the number of effects when it is one the planner is specialised for, 0 for any
    /// other: with the count a constant the compiler unrolls the per-effect loops and drops
    /// their bounds checks (the sweep is most of an agent's time per step). Every
    /// specialisation runs the same arithmetic in the same order, so all give the same bits.
    /// Inlined into each caller, so that the AVX2 caller's copy is compiled with AVX2.
    #[inline(always)]
    fn sweep<const E: usize, const TRACK: bool>(
        &mut self,
        structure: &CmdpStructure,
        table: TableParts<'_>,
        optimism: Option<Optimism<'_>>,
        states: Range<usize>,
        tally: &mut SweepTally,
    ) {
        let n_effects = if E == 0 { structure.n_effects() } else { E };
        let n_states = structure.n_states();
        let n_actions = structure.n_actions();
        let gamma = self.params.gamma;
        // What `Iterator::sum` starts from (the scalar sum of products this reproduces).
        let zero: f64 = std::iter::empty::<f64>().sum();
        // Rewards that depend on the action are added per action, which the lanes (one shared
        // `R + γV` per effect) do not do.
        let by_lanes =
            optimism.is_none() && !table.lanes.is_empty() && !structure.has_step_rewards();
        let Self {
            values,
            policy,
            backup,
            stale,
            ..
        } = self;
        let backup = &mut backup[..n_effects];
        let TableParts {
            probs,
            lanes,
            fresh,
        } = table;
        let steps = structure.steps();
        // The successor reads below skip their bounds checks on the strength of this (and of
        // `CmdpStructure::new`, which checks every successor and predecessor is below
        // `n_states`); the slices of length `n_states` let the compiler drop the checks of
        // the reads by `s < states.end <= n_states`.
        assert_eq!(values.len(), n_states, "a planner for another structure");
        assert!(states.end <= n_states, "states beyond the structure's");
        let values = &mut values[..n_states];
        let policy = &mut policy[..n_states];
        let stale = &mut stale[..n_states];
        let fresh: &mut [bool] = if TRACK { &mut fresh[..n_states] } else { fresh };
        let rewards = &structure.rewards()[..n_states];
        let terminals = &structure.terminals()[..n_states];
        for s in states {
            let terminal = terminals[s];
            if !terminal && (!TRACK || stale[s] || fresh[s]) {
                // Every action's Q-value in `s` reads the same successors (effects, not
                // actions, decide where the agent lands), so each successor's `R + γV` is
                // computed once and shared by all actions: `E` lookups per state, not `A × E`.
                let steps = &steps[s * n_effects..][..n_effects];
                let backup_of = |step: &Step| {
                    let future = if step.live {
                        let next = step.next as usize;
                        debug_assert!(next < values.len());
                        // SAFETY: `next < n_states` (`CmdpStructure::new` checks every
                        // successor) and `values.len() == n_states` (asserted above).
                        gamma * unsafe { *values.get_unchecked(next) }
                    } else {
                        0.0
                    };
                    step.reward + future
                };
                // The best action (lowest id on ties) and its value.
                let (a, v) = if by_lanes {
                    let (rows, _) =
                        lanes[s * n_effects * LANES..][..n_effects * LANES].as_chunks::<LANES>();
                    best_by_lanes(rows, steps, backup_of, n_actions, zero)
                } else {
                    for (b, step) in backup.iter_mut().zip(steps) {
                        *b = backup_of(step);
                    }
                    let rows = ActionRows {
                        probs,
                        optimism,
                        step_rewards: structure.step_rewards_of(s),
                        n_states,
                        n_effects,
                    };
                    rows.best(backup, s, n_actions)
                };
                tally.residual = tally.residual.max((v - values[s]).abs());
                if TRACK {
                    stale[s] = false;
                    fresh[s] = false;
                    if v.to_bits() != values[s].to_bits() {
                        mark_predecessors_stale(structure, s, stale);
                    }
                }
                values[s] = v;
                policy[s] = a as u32;
            }
            // `V(s)` is final for this sweep once its state has been visited.
            let b = rewards[s] + if terminal { 0.0 } else { gamma * values[s] };
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

    /// [`plan_inner`](Self::plan_inner) without optimism by tracked sweeps (see
    /// [`sweep_tracked`](Self::sweep_tracked)): the same plan, bit for bit.
    pub(super) fn plan_tracked(
        &mut self,
        structure: &CmdpStructure,
        table: &mut EffectTable,
        good_enough: f64,
    ) -> PlanStats {
        let mut stats = PlanStats::NONE;
        let n = structure.n_states();
        loop {
            let mut tally = SweepTally::new();
            self.sweep_tracked(structure, table, 0..n, &mut tally);
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
        self.tracking = false;
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
        self.tracking = false;
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

/// The best action of a state (lowest id on ties) and its value, all actions at once: lane
/// `a` sums `P(e | s, a) · backup[e]` over `e` in order, as the scalar sum does. `rows` are
/// the state's per-effect lanes, `steps` its successors. Inlined into the sweep, so that the
/// AVX2 sweep's copy is compiled with AVX2.
#[inline(always)]
fn best_by_lanes(
    rows: &[[f64; LANES]],
    steps: &[Step],
    backup_of: impl Fn(&Step) -> f64,
    n_actions: usize,
    zero: f64,
) -> (usize, f64) {
    let mut best = (0, f64::NEG_INFINITY);
    let mut q = [zero; LANES];
    for (p, step) in rows.iter().zip(steps) {
        let b = backup_of(step);
        for l in 0..LANES {
            q[l] += p[l] * b;
        }
    }
    for (a, &q) in q[..n_actions].iter().enumerate() {
        if q > best.1 {
            best = (a, q);
        }
    }
    best
}

/// The effect table's rows, one action at a time, with R-max's optimism when planning with
/// it: the other way [`ValueIteration::sweep`] finds a state's best action.
#[derive(Clone, Copy)]
struct ActionRows<'a> {
    /// `probs[(a * S + s) * E + e]`.
    probs: &'a [f64],
    optimism: Option<Optimism<'a>>,
    /// The state's step rewards, `[a * E + e]`, when the structure has them (the backups
    /// then hold `γV` alone and each action adds its own rewards).
    step_rewards: Option<&'a [f64]>,
    n_states: usize,
    n_effects: usize,
}

impl ActionRows<'_> {
    /// The best action of state `s` (lowest id on ties) and its value, from `backup`, its
    /// successors' `R + γV` per effect: each action's Q-value is the scalar sum of
    /// `P(e | s, a) · backup[e]` over `e` in order (or the optimistic value of an unknown
    /// pair). Inlined into the sweep, as [`best_by_lanes`] is.
    #[inline(always)]
    fn best(self, backup: &[f64], s: usize, n_actions: usize) -> (usize, f64) {
        let Self {
            probs,
            optimism,
            step_rewards,
            n_states,
            n_effects,
        } = self;
        let mut best = (0, f64::NEG_INFINITY);
        for a in 0..n_actions {
            let q = match optimism {
                Some(o) if o.unknown[a * n_states + s] => o.value,
                _ => {
                    let row = (a * n_states + s) * n_effects;
                    let probs = probs[row..row + n_effects].iter();
                    match step_rewards {
                        None => probs.zip(backup.iter()).map(|(&p, &b)| p * b).sum(),
                        Some(rewards) => probs
                            .zip(backup.iter())
                            .zip(&rewards[a * n_effects..][..n_effects])
                            .map(|((&p, &b), &r)| p * (r + b))
                            .sum(),
                    }
                }
            };
            if q > best.1 {
                best = (a, q);
            }
        }
        best
    }
}

/// `V(s)` changed: every state whose backup reads it must be backed up again (if before
/// `s`, in the next sweep; `s` itself, when it can stay). `stale` has one flag per state.
#[inline(always)]
fn mark_predecessors_stale(structure: &CmdpStructure, s: usize, stale: &mut [bool]) {
    // The sweep slices `stale` so already: inlined there, this check folds away.
    let stale = &mut stale[..structure.n_states()];
    for &p in structure.predecessors(s) {
        let p = p as usize;
        debug_assert!(p < stale.len());
        // SAFETY: `p < n_states` (a predecessor is a state that some effect leads from,
        // checked by `CmdpStructure::new`) and `stale.len() == n_states` (sliced above).
        unsafe { *stale.get_unchecked_mut(p) = true };
    }
}
