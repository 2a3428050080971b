//! The hand-over to a planner elsewhere: the model's changes, and applying them and
//! re-planning in pieces small enough to do between an acting loop's polls.

use super::{PlanStats, PlannedModel, SweepTally};
use crate::cmdp::{CmdpError, CmdpStructure, EffectTable};
use crate::mdagl::{Mdagl, MdaglError};
use thiserror::Error;

/// What an acting loop hands a planner elsewhere: the whole effect table when it changed
/// directly, and the latest view of each action whose view changed. The planner recomputes
/// those actions' rows itself ([`PlannedModel::begin_pieces`]), so the acting loop neither refreshes
/// the table nor copies it per step — it copies one view (a few kB to tens of kB).
///
/// Built once at full size; passing it back and forth allocates nothing once every action's
/// view has been sent.
#[derive(Debug, Clone)]
pub struct ModelChanges {
    pub(super) table: EffectTable,
    pub(super) whole_table: bool,
    pub(super) force: bool,
    pub(super) views: Vec<Option<Mdagl>>,
    pub(super) changed: Vec<bool>,
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
    pub(super) stage: Stage,
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
pub(super) enum Stage {
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
pub(super) fn placeholder_view(structure: &CmdpStructure) -> Option<Mdagl> {
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
pub(super) fn copy_view(to: &mut Option<Mdagl>, from: &Mdagl) {
    match to {
        Some(m) => m.copy_weights_from(from),
        None => *to = Some(from.clone()),
    }
}

impl PlannedModel {
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
    pub(super) fn advance_pieces(
        &mut self,
        changes: &ModelChanges,
        pieces: &mut Pieces,
        budget: usize,
    ) -> Result<bool, ChangeError> {
        let mut left = budget.max(1);
        while left > 0 {
            pieces.stage = match pieces.stage {
                Stage::Done => return Ok(true),
                Stage::CopyTable { next } => self.copy_table_piece(changes, next, &mut left)?,
                Stage::Refresh { a } => self.begin_next_refresh(changes, a, &mut left)?,
                Stage::Rows { a, next } => self.rows_piece(a, next, &mut left)?,
                Stage::Write { a, next, moved } => self.write_piece(a, next, moved, &mut left),
                Stage::Plan => self.plan_stage(),
                Stage::Sweep {
                    next,
                    tally,
                    stats,
                    good_enough,
                } => self.sweep_piece(next, tally, stats, good_enough, &mut left),
            };
        }
        Ok(pieces.stage == Stage::Done)
    }

    /// Copies the table sent whole from row `next`, as far as `left` goes; after its last
    /// row, the refresh of changed views starts (and a plan is forced: the table moved).
    fn copy_table_piece(
        &mut self,
        changes: &ModelChanges,
        next: usize,
        left: &mut usize,
    ) -> Result<Stage, ChangeError> {
        let end = piece_end(next, *left, self.table.n_rows());
        self.table.copy_rows_from(&changes.table, next..end)?;
        *left -= end - next;
        Ok(if end == self.table.n_rows() {
            self.forced = true;
            Stage::Refresh { a: 0 }
        } else {
            Stage::CopyTable { next: end }
        })
    }

    /// Finds the next action, from `a`, whose view changed and starts its refresh (which
    /// ends the call: a pass over the view's used columns); with none left, the plan.
    fn begin_next_refresh(
        &mut self,
        changes: &ModelChanges,
        a: usize,
        left: &mut usize,
    ) -> Result<Stage, ChangeError> {
        let changed = changes
            .views
            .iter()
            .enumerate()
            .skip(a)
            .find_map(|(b, view)| Some((b, view.as_ref().filter(|_| changes.changed[b])?)));
        Ok(match changed {
            None => Stage::Plan,
            Some((a, view)) => {
                self.table.begin_refresh(view, &self.structure)?;
                *left = 0;
                Stage::Rows { a, next: 0 }
            }
        })
    }

    /// Builds action `a`'s new rows from state `next`, as far as `left` goes; after the
    /// last state, their writing starts.
    fn rows_piece(
        &mut self,
        a: usize,
        next: usize,
        left: &mut usize,
    ) -> Result<Stage, ChangeError> {
        let n = self.structure.n_states();
        let end = piece_end(next, *left, n);
        self.table.refresh_rows(next..end)?;
        *left -= end - next;
        Ok(if end == n {
            Stage::Write {
                a,
                next: 0,
                moved: 0.0,
            }
        } else {
            Stage::Rows { a, next: end }
        })
    }

    /// Writes action `a`'s new rows from state `next`, as far as `left` goes, keeping the
    /// largest move; after the last state, the move is noted and the next action's refresh
    /// is looked for.
    fn write_piece(&mut self, a: usize, next: usize, moved: f64, left: &mut usize) -> Stage {
        let n = self.structure.n_states();
        let end = piece_end(next, *left, n);
        let moved = moved.max(self.table.refresh_write(a, next..end));
        *left -= end - next;
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

    /// Whether the changes need a plan: its first sweep, or nothing more to do.
    fn plan_stage(&self) -> Stage {
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

    /// Backs up states from `next` in the current sweep, as far as `left` goes; a finished
    /// sweep either ends the plan (which is then recorded) or starts the next sweep.
    fn sweep_piece(
        &mut self,
        next: usize,
        mut tally: SweepTally,
        mut stats: PlanStats,
        good_enough: f64,
        left: &mut usize,
    ) -> Stage {
        let n = self.structure.n_states();
        let end = piece_end(next, *left, n);
        self.planner
            .sweep_tracked(&self.structure, &mut self.table, next..end, &mut tally);
        *left -= end - next;
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
}

/// Where a piece that starts at `next` with `left` of the budget stops, at most at `end`.
#[inline]
fn piece_end(next: usize, left: usize, end: usize) -> usize {
    next.saturating_add(left).min(end)
}
