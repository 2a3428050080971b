//! The learned model and the plan on it, planned here or handed to a planner elsewhere.

use std::sync::Arc;

use super::pieces::{ModelChanges, copy_view, placeholder_view};
use super::{Optimism, PlanError, PlanStats, PlannerParams, ValueIteration};
use crate::cmdp::{CmdpError, CmdpStructure, EffectTable};
use crate::mdagl::{Mdagl, MdaglError};

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
    pub(super) structure: Arc<CmdpStructure>,
    pub(super) table: EffectTable,
    pub(super) planner: ValueIteration,
    /// Upper bound on how far the model changes since the last plan moved any backup.
    pub(super) drift: f64,
    /// `max − min` of `R(s') + γ V(s')` over all states, under the last plan's values.
    pub(super) backup_span: f64,
    /// Re-plan at the next chance whatever the drift (set at start and by `invalidate`).
    pub(super) forced: bool,
    /// Whether the last plan reached the tolerance (if not, the next re-plan continues it).
    pub(super) converged: bool,
    /// Statistics of the last plan made or adopted.
    pub(super) last: PlanStats,
    /// Who plans: [`PlannedModel::replan`] on the calling thread, or a planner elsewhere fed
    /// through [`PlannedModel::snapshot_into`] and [`PlannedModel::adopt`].
    pub(super) site: PlanSite,
}

/// Where a [`PlannedModel`]'s plans are made.
#[derive(Debug, Clone)]
pub(super) enum PlanSite {
    /// Here: views refresh the table at once and [`PlannedModel::replan`] plans.
    Here,
    /// Elsewhere: the model keeps what the planner has not seen yet.
    Elsewhere(HandOver),
}

/// What an acting-side [`PlannedModel`] keeps for a planner elsewhere until the next
/// [`PlannedModel::snapshot_into`].
#[derive(Debug, Clone)]
pub(super) struct HandOver {
    /// The table has changes (from [`PlannedModel::set`]) the planner has not seen.
    pub(super) table_unsent: bool,
    /// Each action's latest view, not yet handed to the planner.
    pub(super) views: Vec<Option<Mdagl>>,
    /// Which of `views` are newer than what the planner has.
    pub(super) pending: Vec<bool>,
}

impl HandOver {
    /// Nothing handed over yet: the planner starts from the whole table.
    pub(super) fn new(structure: &CmdpStructure) -> Self {
        let n = structure.n_actions();
        Self {
            table_unsent: true,
            views: vec![placeholder_view(structure); n],
            pending: vec![false; n],
        }
    }

    /// Keeps `view` as action `a`'s latest, for the planner.
    pub(super) fn keep(&mut self, a: usize, view: &Mdagl) {
        if let (Some(slot), Some(flag)) = (self.views.get_mut(a), self.pending.get_mut(a)) {
            copy_view(slot, view);
            *flag = true;
        }
    }

    /// Whether anything waits to be handed over.
    pub(super) fn has_changes(&self) -> bool {
        self.table_unsent || self.pending.iter().any(|&p| p)
    }

    /// Moves what waits into `changes` (the table is copied from `table` if it changed).
    pub(super) fn hand_into(
        &mut self,
        table: &EffectTable,
        changes: &mut ModelChanges,
    ) -> Result<(), CmdpError> {
        changes.whole_table = self.table_unsent;
        if self.table_unsent {
            changes.table.copy_from(table)?;
            self.table_unsent = false;
        }
        changes.changed.fill(false);
        for (a, pending) in self.pending.iter_mut().enumerate() {
            if let (true, Some(view), Some(slot)) =
                (*pending, self.views.get_mut(a), changes.views.get_mut(a))
            {
                // Both hold a view of this shape: swapping hands it over without a copy, and
                // the next `keep` overwrites the buffer that came back.
                std::mem::swap(slot, view);
                changes.changed[a] = true;
            }
            *pending = false;
        }
        Ok(())
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
            last: PlanStats::NONE,
            site: PlanSite::Here,
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
    /// With planning elsewhere ([`plan_elsewhere`](Self::plan_elsewhere)) this only keeps a
    /// copy of `view` for the planner, which recomputes the rows on its own side:
    /// [`table`](Self::table) then no longer follows the views.
    pub fn refresh(&mut self, a: usize, view: &Mdagl) -> Result<(), MdaglError> {
        let hand_over = match &mut self.site {
            PlanSite::Here => {
                let moved = self.table.refresh(a, view, &self.structure)?;
                self.note_change(moved);
                return Ok(());
            }
            PlanSite::Elsewhere(hand_over) => hand_over,
        };
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
        hand_over.keep(a, view);
        Ok(())
    }

    /// Overwrites `P(· | s, a)` (for predictors that are not mDAGL views).
    pub fn set(&mut self, a: usize, s: usize, probs: &[f64]) {
        let moved = self.table.set(a, s, probs);
        self.note_change(moved);
        if let PlanSite::Elsewhere(hand_over) = &mut self.site {
            hand_over.table_unsent = true;
        }
    }

    /// Makes the next [`replan`](Self::replan) plan whatever the model's drift (for changes
    /// the drift cannot see, such as R-max's unknown pairs becoming known).
    pub fn invalidate(&mut self) {
        self.forced = true;
    }

    pub(super) fn note_change(&mut self, l1: f64) {
        self.drift += 0.5 * l1 * self.backup_span;
    }

    /// Whether the model moved enough since the last plan to need another (or the last plan
    /// stopped before converging).
    pub fn needs_plan(&self) -> bool {
        self.forced
            || !self.converged
            || self.drift > self.planner.params().tolerance
            || matches!(&self.site, PlanSite::Elsewhere(h) if h.has_changes())
    }

    /// Hands the planning to a planner elsewhere (an acting loop's planner thread, or its
    /// slices between polls): from now on [`replan`](Self::replan) does nothing,
    /// [`refresh`](Self::refresh) keeps the views for that planner instead of refreshing the
    /// table, and [`snapshot_into`](Self::snapshot_into) hands them over. The planner starts
    /// from the table as it is now. (A model plans here, inside `replan`, until this is called.)
    pub fn plan_elsewhere(&mut self) {
        if let PlanSite::Here = self.site {
            self.site = PlanSite::Elsewhere(HandOver::new(&self.structure));
        }
    }

    /// Hands the changes since the last snapshot to `changes`, for a planner elsewhere, and
    /// counts the model as planned from here on. Allocation-free once each action's view has
    /// been handed over once.
    pub fn snapshot_into(&mut self, changes: &mut ModelChanges) -> Result<(), CmdpError> {
        match &mut self.site {
            PlanSite::Elsewhere(hand_over) => hand_over.hand_into(&self.table, changes)?,
            PlanSite::Here => {
                changes.whole_table = false;
                changes.changed.fill(false);
            }
        }
        changes.force = self.forced;
        self.drift = 0.0;
        self.forced = false;
        // Until the plan comes back, a further change must be measured against this one.
        self.converged = true;
        Ok(())
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
        self.adopted(stats, backup_span);
        Ok(())
    }

    /// [`adopt`](Self::adopt) without a copy (see [`ValueIteration::adopt_swapping`]):
    /// `values` and `policy` come back holding the previous plan's.
    pub fn adopt_swapping(
        &mut self,
        values: &mut Vec<f64>,
        policy: &mut Vec<u32>,
        stats: PlanStats,
        backup_span: f64,
    ) -> Result<(), PlanError> {
        self.planner.adopt_swapping(values, policy)?;
        self.adopted(stats, backup_span);
        Ok(())
    }

    /// Records a plan made elsewhere as the last plan.
    fn adopted(&mut self, stats: PlanStats, backup_span: f64) {
        let drift = self.drift;
        self.planned(stats, backup_span);
        // Changes since the snapshot still count.
        self.drift = drift;
    }

    /// Re-plans if the model moved enough since the last plan; returns the plan's statistics
    /// if it did. Allocation-free.
    pub fn replan(&mut self) -> Option<PlanStats> {
        if !self.plans_here() || !self.needs_plan() {
            return None;
        }
        let good_enough = self.good_enough();
        let stats = self
            .planner
            .plan_tracked(&self.structure, &mut self.table, good_enough);
        self.planned(stats, self.planner.backup_span);
        Some(stats)
    }

    /// [`replan`](Self::replan) with R-max optimism (see [`ValueIteration::plan_optimistic`]).
    pub fn replan_optimistic(&mut self, optimism: Optimism<'_>) -> Option<PlanStats> {
        if !self.plans_here() || !self.needs_plan() {
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

    /// Whether [`replan`](Self::replan) plans (else a planner elsewhere does).
    pub fn plans_here(&self) -> bool {
        matches!(self.site, PlanSite::Here)
    }

    /// How small a residual a re-plan needs beyond the tolerance: with
    /// [`PlannerParams::stop_at_drift`], the drift bound of the changes that triggered it (see
    /// the type's docs); 0 (the tolerance decides) for a forced plan or without it.
    pub(super) fn good_enough(&self) -> f64 {
        if self.forced || !self.planner.params().stop_at_drift {
            0.0
        } else {
            self.drift
        }
    }

    /// Records a finished plan whose values spread `R + γV` over `backup_span`.
    pub(super) fn planned(&mut self, stats: PlanStats, backup_span: f64) {
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
