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

use std::ops::Range;
use std::sync::Arc;

use thiserror::Error;

use crate::cmdp::{CmdpError, CmdpStructure, EffectTable};
use crate::mdagl::{Mdagl, MdaglError};

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
    params: PlannerParams,
    values: Vec<f64>,
    policy: Vec<u32>,
    /// Scratch: `R(s'_e) + γ V(s'_e)` for each effect of the state being backed up.
    backup: Vec<f64>,
    /// The spread of `R(s) + γV(s)` over all states after the last sweep made here.
    backup_span: f64,
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
    fn sweep<const E: usize>(
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
    fn end_sweep(&mut self, stats: &mut PlanStats, tally: SweepTally, good_enough: f64) -> bool {
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
    fn plan_inner(
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
        if values.len() != self.values.len() || policy.len() != self.policy.len() {
            return Err(PlanError::WrongSize {
                expected: self.values.len(),
                values: values.len(),
                policy: policy.len(),
            });
        }
        self.values.copy_from_slice(values);
        self.policy.copy_from_slice(policy);
        Ok(())
    }
}

/// An agent's learned model and the plan on it: the CMDP structure, the effect table its
/// predictors fill, and a warm-started planner that re-plans only when the model has moved
/// enough to matter.
///
/// **When it re-plans.** A change of state `s`'s effect distribution by L1 distance `δ` moves
/// that state's backup `Σ_e P(e) (R + γV)` by at most `δ/2 · span`, where `span` is the spread
/// of `R + γV` over all states under the current values. The model accumulates that bound over
/// every change since the last plan and re-plans when it exceeds the planner's tolerance; so
/// the policy acted on always comes from values whose Bellman residual on the *current* model
/// is at most twice the tolerance. Online learners move their model a little after every
/// step — an mDAGL view's intercept shifts every state's row — and most of those moves are far
/// below what could change a decision. [`PlannedModel::invalidate`] forces the next re-plan.
///
/// **How far it re-plans** (with [`PlannerParams::stop_at_drift`]; otherwise every plan
/// sweeps to the tolerance or the cap). A re-plan triggered by a drift bound `d` above the
/// tolerance stops
/// as soon as a sweep changes no value by more than `d` — no more than the change itself could
/// have moved a backup — instead of sweeping on to the tolerance. While the model keeps moving
/// by `d` per step, converging further is wasted: the next step moves the fixed point by as much
/// again. Such a plan counts as not converged, so planning continues, warm, at the next chance,
/// and reaches the tolerance once the model holds still. A learner that keeps moving (loreRL's
/// views: every update rescales their columns) thus pays about one sweep per step; forced plans
/// (the first, or after [`invalidate`](Self::invalidate)) always sweep to the tolerance or the
/// cap.
///
/// ```
/// use std::sync::Arc;
/// use tes_learning::cmdp::CmdpStructure;
/// use tes_learning::plan::{PlannedModel, PlannerParams};
///
/// // Two states; effect 0 moves to the rewarding terminal state 1, effect 1 stays.
/// let features: [&[u32]; 2] = [&[0], &[0]];
/// let structure = CmdpStructure::new(
///     2, 2, 2, 1,
///     |s, e| if e == 0 { 1 } else { s },
///     vec![0.0, 1.0],
///     vec![false, true],
///     |s| features[s],
/// )?;
/// let mut model = PlannedModel::new(Arc::new(structure), PlannerParams::default())?;
/// model.set(0, 0, &[0.1, 0.9]); // action 0 rarely works
/// model.set(1, 0, &[0.8, 0.2]); // action 1 mostly does
/// model.replan();
/// assert_eq!(model.action(0), 1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone)]
pub struct PlannedModel {
    structure: Arc<CmdpStructure>,
    table: EffectTable,
    planner: ValueIteration,
    /// Upper bound on how far the model changes since the last plan moved any backup.
    drift: f64,
    /// `max − min` of `R(s') + γ V(s')` over all states, under the last plan's values.
    backup_span: f64,
    /// Re-plan at the next chance whatever the drift (set at start and by `invalidate`).
    forced: bool,
    /// Whether the last plan reached the tolerance (if not, the next re-plan continues it).
    converged: bool,
    /// Whether [`PlannedModel::replan`] plans on the calling thread (else a planner thread
    /// does, through [`PlannedModel::snapshot_into`] and [`PlannedModel::adopt`]).
    inline: bool,
    /// Statistics of the last plan made or adopted.
    last: PlanStats,
    /// With planning elsewhere: the table has changes (from [`PlannedModel::set`]) the planner
    /// has not seen.
    table_unsent: bool,
    /// With planning elsewhere: each action's latest view, not yet handed to the planner.
    pending_views: Vec<Option<Mdagl>>,
    /// Which of `pending_views` are newer than what the planner has.
    pending: Vec<bool>,
}

/// What an acting loop hands a planner elsewhere: the whole effect table when it changed
/// directly, and the latest view of each action whose view changed. The planner recomputes
/// those actions' rows itself ([`PlannedModel::begin_pieces`]), so the acting loop neither refreshes
/// the table nor copies it per step — it copies one view (a few kB to tens of kB).
///
/// Built once at full size; passing it back and forth allocates nothing once every action's
/// view has been sent.
#[derive(Debug, Clone)]
pub struct ModelChanges {
    table: EffectTable,
    whole_table: bool,
    force: bool,
    views: Vec<Option<Mdagl>>,
    changed: Vec<bool>,
}

impl ModelChanges {
    /// Empty changes for a model of `structure`'s shape.
    pub fn new(structure: &CmdpStructure) -> Self {
        Self {
            table: EffectTable::uniform(structure),
            whole_table: false,
            force: false,
            views: vec![placeholder_view(structure); structure.n_actions()],
            changed: vec![false; structure.n_actions()],
        }
    }

    /// Whether these changes carry anything (or ask for a plan regardless).
    pub fn is_empty(&self) -> bool {
        !self.whole_table && !self.force && !self.changed.iter().any(|&c| c)
    }
}

/// How far a piecewise apply-and-replan has come ([`PlannedModel::begin_pieces`],
/// [`PlannedModel::advance`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pieces {
    stage: Stage,
}

impl Pieces {
    /// Nothing to do (as if done).
    pub const DONE: Self = Self { stage: Stage::Done };

    /// Whether all the work is done.
    pub fn done(&self) -> bool {
        self.stage == Stage::Done
    }
}

/// The stages of [`Pieces`], in order; each keeps where it stopped.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Stage {
    /// Copying the table sent whole, from row `next`.
    CopyTable { next: usize },
    /// Looking for the next action, from `a`, whose view changed.
    Refresh { a: usize },
    /// Building action `a`'s new rows, from state `next`.
    Rows { a: usize, next: usize },
    /// Writing them, from state `next`; `moved` so far.
    Write { a: usize, next: usize, moved: f64 },
    /// Deciding whether the changes need a plan.
    Plan,
    /// Sweeping, from state `next`, with the sweep's tally and the plan's statistics so far.
    Sweep {
        next: usize,
        tally: SweepTally,
        stats: PlanStats,
        good_enough: f64,
    },
    /// Finished.
    Done,
}

/// Why a planner could not apply [`ModelChanges`].
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ChangeError {
    /// The table has another shape.
    #[error(transparent)]
    Shape(#[from] CmdpError),
    /// A view does not fit the model.
    #[error(transparent)]
    View(#[from] MdaglError),
}

/// A view of `structure`'s shape to copy real views into, so that the first copy of each
/// action's view does not allocate in the acting loop (`None` if the shape has no view).
fn placeholder_view(structure: &CmdpStructure) -> Option<Mdagl> {
    Mdagl::new(
        structure.n_effects(),
        structure.n_features(),
        crate::mdagl::MdaglParams::default(),
    )
    .ok()
}

/// Makes `to` a read-only copy of `from` for the planner: the same weights, bit for bit,
/// reusing `to`'s buffers when it already holds a model and copying only the columns `from`
/// uses ([`Mdagl::copy_weights_from`]): the hand-over is on the acting path.
fn copy_view(to: &mut Option<Mdagl>, from: &Mdagl) {
    match to {
        Some(m) => m.copy_weights_from(from),
        None => *to = Some(from.clone()),
    }
}

impl PlannedModel {
    /// A model with every effect equally likely everywhere and no plan yet.
    pub fn new(structure: Arc<CmdpStructure>, params: PlannerParams) -> Result<Self, PlanError> {
        let planner = ValueIteration::new(&structure, params)?;
        Ok(Self {
            table: EffectTable::uniform(&structure),
            structure,
            planner,
            drift: 0.0,
            backup_span: 0.0,
            forced: true,
            converged: false,
            inline: true,
            last: PlanStats::NONE,
            table_unsent: false,
            pending_views: Vec::new(),
            pending: Vec::new(),
        })
    }

    /// The CMDP structure.
    pub fn structure(&self) -> &Arc<CmdpStructure> {
        &self.structure
    }

    /// The learned `P(e | x(s), a)` for every state and action.
    pub fn table(&self) -> &EffectTable {
        &self.table
    }

    /// The planner, with the values and policy of the last plan.
    pub fn planner(&self) -> &ValueIteration {
        &self.planner
    }

    /// Recomputes action `a`'s rows from `view` (see [`EffectTable::refresh`]).
    ///
    /// With planning elsewhere ([`set_inline_planning(false)`](Self::set_inline_planning))
    /// this only keeps a copy of `view` for the planner, which recomputes the rows on its own
    /// thread: [`table`](Self::table) then no longer follows the views.
    pub fn refresh(&mut self, a: usize, view: &Mdagl) -> Result<(), MdaglError> {
        if self.inline {
            let moved = self.table.refresh(a, view, &self.structure)?;
            self.note_change(moved);
            return Ok(());
        }
        if view.n_classes() != self.structure.n_effects() {
            return Err(MdaglError::WrongOutputLen {
                expected: view.n_classes(),
                got: self.structure.n_effects(),
            });
        }
        if view.n_features() != self.structure.n_features() {
            return Err(MdaglError::WrongFeatureCount {
                expected: view.n_features(),
                got: self.structure.n_features(),
            });
        }
        if let (Some(slot), Some(flag)) = (self.pending_views.get_mut(a), self.pending.get_mut(a)) {
            copy_view(slot, view);
            *flag = true;
        }
        Ok(())
    }

    /// Overwrites `P(· | s, a)` (for predictors that are not mDAGL views).
    pub fn set(&mut self, a: usize, s: usize, probs: &[f64]) {
        let moved = self.table.set(a, s, probs);
        self.note_change(moved);
        self.table_unsent = !self.inline;
    }

    /// Makes the next [`replan`](Self::replan) plan whatever the model's drift (for changes
    /// the drift cannot see, such as R-max's unknown pairs becoming known).
    pub fn invalidate(&mut self) {
        self.forced = true;
    }

    fn note_change(&mut self, l1: f64) {
        self.drift += 0.5 * l1 * self.backup_span;
    }

    /// Whether the model moved enough since the last plan to need another (or the last plan
    /// stopped before converging).
    pub fn needs_plan(&self) -> bool {
        self.forced
            || !self.converged
            || self.drift > self.planner.params().tolerance
            || self.table_unsent
            || self.pending.iter().any(|&p| p)
    }

    /// Chooses who plans: `true` (the default) plans inside [`replan`](Self::replan) on the
    /// calling thread; `false` makes `replan` a no-op, for an acting loop that hands its
    /// changes to a planner thread (the controller's planner thread) and adopts its plans.
    /// From then on [`refresh`](Self::refresh) defers the table's rows to that planner.
    pub fn set_inline_planning(&mut self, inline: bool) {
        if self.inline && !inline {
            // The planner starts from the table as it is now.
            self.table_unsent = true;
            let n = self.structure.n_actions();
            self.pending_views
                .resize(n, placeholder_view(&self.structure));
            self.pending.resize(n, false);
        }
        self.inline = inline;
    }

    /// Hands the changes since the last snapshot to `changes`, for a planner elsewhere, and
    /// counts the model as planned from here on. Allocation-free once each action's view has
    /// been handed over once.
    pub fn snapshot_into(&mut self, changes: &mut ModelChanges) -> Result<(), CmdpError> {
        changes.whole_table = self.table_unsent;
        if self.table_unsent {
            changes.table.copy_from(&self.table)?;
            self.table_unsent = false;
        }
        changes.force = self.forced;
        changes.changed.fill(false);
        for (a, pending) in self.pending.iter_mut().enumerate() {
            if let (true, Some(view), Some(slot)) = (
                *pending,
                self.pending_views.get_mut(a),
                changes.views.get_mut(a),
            ) {
                // Both hold a view of this shape: swapping hands it over without a copy, and
                // the next `refresh` overwrites the buffer that came back.
                std::mem::swap(slot, view);
                changes.changed[a] = true;
            }
            *pending = false;
        }
        self.drift = 0.0;
        self.forced = false;
        // Until the plan comes back, a further change must be measured against this one.
        self.converged = true;
        Ok(())
    }

    /// Starts applying changes made elsewhere (the planner side of
    /// [`snapshot_into`](Self::snapshot_into)) and re-planning, in pieces
    /// ([`advance`](Self::advance)): copies the table if it was sent whole, recomputes the
    /// rows of every action whose view changed, then re-plans as [`replan`](Self::replan)
    /// would (the drift gate decides whether there is work). In one piece for a planner
    /// thread; in many for a caller that must stay able to stop every few microseconds (an
    /// acting loop planning between polls, the controller's sliced planner). `changes`
    /// must not change until done.
    pub fn begin_pieces(&mut self, changes: &ModelChanges) -> Pieces {
        if changes.force {
            self.forced = true;
        }
        Pieces {
            stage: if changes.whole_table {
                Stage::CopyTable { next: 0 }
            } else {
                Stage::Refresh { a: 0 }
            },
        }
    }

    /// Does about `budget` states' worth of the work `pieces` stands at (a copied table row,
    /// a refreshed state's row, a state backed up in a sweep count one each; starting an
    /// action's refresh, a pass over its used columns, ends the call), and returns whether it
    /// is all done, the last plan then in [`last_plan`](Self::last_plan) and the planner.
    /// Allocation-free.
    ///
    /// However the work is cut, it is done in the same order, so the result is the same bit
    /// for bit, and the same as refreshing the views inline and calling
    /// [`replan`](Self::replan). After an error the changes are partly applied and nothing is
    /// planned.
    pub fn advance(
        &mut self,
        changes: &ModelChanges,
        pieces: &mut Pieces,
        budget: usize,
    ) -> Result<bool, ChangeError> {
        let result = self.advance_pieces(changes, pieces, budget);
        if result.is_err() {
            pieces.stage = Stage::Done;
        }
        result
    }

    /// [`advance`](Self::advance), but leaves `pieces` where an error stopped it.
    fn advance_pieces(
        &mut self,
        changes: &ModelChanges,
        pieces: &mut Pieces,
        budget: usize,
    ) -> Result<bool, ChangeError> {
        let n = self.structure.n_states();
        let mut left = budget.max(1);
        while left > 0 {
            let step = |next: usize, end: usize| next.saturating_add(left).min(end);
            pieces.stage = match pieces.stage {
                Stage::Done => return Ok(true),
                Stage::CopyTable { next } => {
                    let end = step(next, self.table.n_rows());
                    self.table.copy_rows_from(&changes.table, next..end)?;
                    left -= end - next;
                    if end == self.table.n_rows() {
                        self.forced = true;
                        Stage::Refresh { a: 0 }
                    } else {
                        Stage::CopyTable { next: end }
                    }
                }
                Stage::Refresh { a } => {
                    let changed = changes
                        .views
                        .iter()
                        .enumerate()
                        .skip(a)
                        .find_map(|(b, view)| {
                            Some((b, view.as_ref().filter(|_| changes.changed[b])?))
                        });
                    match changed {
                        None => Stage::Plan,
                        Some((a, view)) => {
                            self.table.begin_refresh(view, &self.structure)?;
                            left = 0;
                            Stage::Rows { a, next: 0 }
                        }
                    }
                }
                Stage::Rows { a, next } => {
                    let end = step(next, n);
                    self.table.refresh_rows(next..end)?;
                    left -= end - next;
                    if end == n {
                        Stage::Write {
                            a,
                            next: 0,
                            moved: 0.0,
                        }
                    } else {
                        Stage::Rows { a, next: end }
                    }
                }
                Stage::Write { a, next, moved } => {
                    let end = step(next, n);
                    let moved = moved.max(self.table.refresh_write(a, next..end));
                    left -= end - next;
                    if end == n {
                        self.note_change(moved);
                        Stage::Refresh { a: a + 1 }
                    } else {
                        Stage::Write {
                            a,
                            next: end,
                            moved,
                        }
                    }
                }
                Stage::Plan => {
                    if self.needs_plan() {
                        Stage::Sweep {
                            next: 0,
                            tally: SweepTally::new(),
                            stats: PlanStats::NONE,
                            good_enough: self.good_enough(),
                        }
                    } else {
                        Stage::Done
                    }
                }
                Stage::Sweep {
                    next,
                    mut tally,
                    mut stats,
                    good_enough,
                } => {
                    let end = step(next, n);
                    self.planner.sweep_states(
                        &self.structure,
                        &self.table,
                        None,
                        next..end,
                        &mut tally,
                    );
                    left -= end - next;
                    if end < n {
                        Stage::Sweep {
                            next: end,
                            tally,
                            stats,
                            good_enough,
                        }
                    } else if self.planner.end_sweep(&mut stats, tally, good_enough) {
                        self.planned(stats, self.planner.backup_span);
                        Stage::Done
                    } else {
                        Stage::Sweep {
                            next: 0,
                            tally: SweepTally::new(),
                            stats,
                            good_enough,
                        }
                    }
                }
            };
        }
        Ok(pieces.stage == Stage::Done)
    }

    /// Statistics of the last plan made here or adopted.
    pub fn last_plan(&self) -> PlanStats {
        self.last
    }

    /// Adopts a plan made elsewhere on a snapshot of this model: its values and policy, its
    /// statistics, and the spread of `R + γV` under its values (the planning model's
    /// [`plan_span`](Self::plan_span), which its last sweep measured, so that adopting costs
    /// no pass over the states).
    pub fn adopt(
        &mut self,
        values: &[f64],
        policy: &[u32],
        stats: PlanStats,
        backup_span: f64,
    ) -> Result<(), PlanError> {
        self.planner.adopt(values, policy)?;
        let drift = self.drift;
        self.planned(stats, backup_span);
        // Changes since the snapshot still count.
        self.drift = drift;
        Ok(())
    }

    /// Re-plans if the model moved enough since the last plan; returns the plan's statistics
    /// if it did. Allocation-free.
    pub fn replan(&mut self) -> Option<PlanStats> {
        if !self.inline || !self.needs_plan() {
            return None;
        }
        let stats = self
            .planner
            .plan_inner(&self.structure, &self.table, None, self.good_enough());
        self.planned(stats, self.planner.backup_span);
        Some(stats)
    }

    /// [`replan`](Self::replan) with R-max optimism (see [`ValueIteration::plan_optimistic`]).
    pub fn replan_optimistic(&mut self, optimism: Optimism<'_>) -> Option<PlanStats> {
        if !self.inline || !self.needs_plan() {
            return None;
        }
        let stats = self.planner.plan_inner(
            &self.structure,
            &self.table,
            Some(optimism),
            self.good_enough(),
        );
        self.planned(stats, self.planner.backup_span);
        Some(stats)
    }

    /// How small a residual a re-plan needs beyond the tolerance: with
    /// [`PlannerParams::stop_at_drift`], the drift bound of the changes that triggered it (see
    /// the type's docs); 0 (the tolerance decides) for a forced plan or without it.
    fn good_enough(&self) -> f64 {
        if self.forced || !self.planner.params().stop_at_drift {
            0.0
        } else {
            self.drift
        }
    }

    /// Records a finished plan whose values spread `R + γV` over `backup_span`.
    fn planned(&mut self, stats: PlanStats, backup_span: f64) {
        self.last = stats;
        self.converged = stats.converged;
        self.backup_span = backup_span;
        self.drift = 0.0;
        self.forced = false;
    }

    /// The spread of `R(s) + γV(s)` over all states under the last plan's values (measured by
    /// its last sweep), which bounds how far a model change moves a backup; what a planner
    /// elsewhere hands over with its plan ([`adopt`](Self::adopt)).
    pub fn plan_span(&self) -> f64 {
        self.backup_span
    }

    /// The greedy action in `s` under the last plan.
    #[inline]
    pub fn action(&self, s: usize) -> usize {
        self.planner.action(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cmdp::examples::corridor;

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
}
