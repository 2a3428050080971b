//! mDAGL without hand-tuning: a grid of (λ, α) settings learning side by side on the same
//! rows, raced on their prequential log-loss.
//!
//! The paper's λ = 0.05 suits its grid tasks; on a stream whose relevant features are on in a
//! few percent of rows no column's average gradient ever reaches λ√K, nothing is selected and
//! the model predicts the uniform distribution. Rather than ask the user for λ and α,
//! [`MdaglRace`] runs every setting of a grid ([`auto_grid`]) in one pass. Every entrant
//! learns every row; the *leader* — the entrant with the lowest prequential log-loss so far —
//! is the model reported and used. The race's own prediction of a row, made before any
//! entrant learns it, mixes the entrants' predictions weighted by `exp(−loss so far)` (Bayes
//! over the grid): its total log-loss exceeds the best entrant's by at most `ln m` for `m`
//! entrants (the mixture's classic bound) while they all race, where following the leader
//! alone pays for every switch of leader.
//!
//! Racing keeps the cost near one model's: after [`RaceSchedule::first_cut`] rows the worse
//! half of the field — by their loss since the previous cut, never the leader — retires, and
//! again each time the row count doubles, until [`RaceSchedule::finalists`] remain: by default
//! one, after 32 000 rows, which from then on predicts alone and costs what one model costs.
//! Over `n` rows a field of `m` costs about `first_cut · (2m + log₂ m) + n` updates instead of
//! `m · n`.
//!
//! ```
//! use tes_learning::mdagl::Features;
//! use tes_learning::tuning::{MdaglRace, RaceSchedule, auto_grid};
//!
//! // Feature 0 decides the class; it is on in 1 row of 20.
//! let grid = auto_grid(None, None, true);
//! let mut race = MdaglRace::new(2, 3, &grid, RaceSchedule::default())?;
//! for i in 0..20_000u32 {
//!     let on = i % 20 == 0;
//!     let x: &[u32] = if on { &[0, 2] } else { &[1] };
//!     race.update(Features::SparseBinary(x), usize::from(on))?;
//! }
//! let winner = race.leader();
//! assert!(winner.params.lambda < 0.05, "the paper's λ keeps nothing here");
//! assert!(race.model().is_selected(0));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::mdagl::{Features, Mdagl, MdaglConfigError, MdaglError, MdaglParams, Prequential};

/// The λ values `auto` races: the paper's 0.05 and four smaller ones, each about a third of
/// the one before.
pub const AUTO_LAMBDAS: [f64; 5] = [0.05, 0.015, 0.005, 0.0015, 0.0005];

/// The α values `auto` races: the paper's 1.5, and faster steps.
pub const AUTO_ALPHAS: [f64; 3] = [1.5, 0.3, 0.05];

/// The grid `auto` races: every λ of [`AUTO_LAMBDAS`] (or just `lambda` when given) with
/// every α of [`AUTO_ALPHAS`] (or just `alpha`), all with `intercept`.
///
/// ```
/// use tes_learning::tuning::auto_grid;
///
/// assert_eq!(auto_grid(None, None, false).len(), 15);
/// assert_eq!(auto_grid(Some(0.01), None, false).len(), 3);
/// assert_eq!(auto_grid(Some(0.01), Some(0.1), true).len(), 1);
/// ```
pub fn auto_grid(lambda: Option<f64>, alpha: Option<f64>, intercept: bool) -> Vec<MdaglParams> {
    let lambdas = lambda.map_or(AUTO_LAMBDAS.to_vec(), |l| vec![l]);
    let alphas = alpha.map_or(AUTO_ALPHAS.to_vec(), |a| vec![a]);
    lambdas
        .iter()
        .flat_map(|&lambda| {
            alphas.iter().map(move |&alpha| MdaglParams {
                lambda,
                alpha,
                intercept,
            })
        })
        .collect()
}

/// Losses within this share of the lowest count as a tie for the leader, which then goes to
/// the sparsest setting (see [`MdaglRace::leader`]).
pub const TIE: f64 = 0.005;

/// When entrants retire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RaceSchedule {
    /// Rows before the first cut; the next cuts come each time the row count doubles.
    pub first_cut: u64,
    /// Entrants left racing to the end (at least 1).
    pub finalists: usize,
}

impl Default for RaceSchedule {
    /// The first cut after 4000 rows (a small λ keeps more columns and is noisier at first:
    /// cut earlier, at 1000 or 2000 rows, it was retired before it could lead, and the
    /// relevant set was missed); one finalist (three cost a third more time on a
    /// 100 000-row robot-shaped stream for the same log-loss to four decimals).
    fn default() -> Self {
        Self {
            first_cut: 4000,
            finalists: 1,
        }
    }
}

/// A row of a block the race refused or could not learn (see [`MdaglRace::update_block`]).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("row {row} of the block: {source}")]
pub struct BlockError {
    /// The row's index in the block.
    pub row: usize,
    /// Why.
    #[source]
    pub source: MdaglError,
}

/// One entrant learns `run` in order, keeping each row's prequential record. The rows were
/// checked for every entrant ([`MdaglRace::update_block`]).
fn learn_entrant(
    entrant: &mut Entrant,
    run: &[(Features<'_>, usize)],
    records: &mut [Prequential],
) -> Result<(), (usize, MdaglError)> {
    for (row, (&(x, label), record)) in run.iter().zip(records).enumerate() {
        *record = entrant
            .model
            .update_checked(x, label)
            .map_err(|e| (row, e))?;
    }
    Ok(())
}

/// One setting's record in a race.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Standing {
    /// The setting.
    pub params: MdaglParams,
    /// Its mean prequential log-loss over the rows it learned, in nats.
    pub mean_log_loss: f64,
    /// Rows it learned (all of them, unless it retired).
    pub rows: u64,
    /// Whether it is still racing.
    pub racing: bool,
}

/// An entrant: a setting, its model, its summed log-loss.
///
/// Aligned to its own cache lines: a model writes its own fields on every update, and
/// neighbours in the field may learn on different threads.
#[derive(Debug, Clone)]
#[repr(align(128))]
struct Entrant {
    model: Mdagl,
    loss: f64,
    /// Loss since the last cut: what the next cut ranks by.
    recent: f64,
}

/// A grid of mDAGL settings raced on one stream (see the [module docs](self)). Cloning
/// copies the whole race: the copy learns on exactly as the original would.
#[derive(Debug, Clone)]
pub struct MdaglRace {
    entrants: Vec<Entrant>,
    /// Each entrant's log-probability of the current row's label (reused: no allocation
    /// per row).
    log_probs: Vec<f64>,
    retired: Vec<Standing>,
    schedule: RaceSchedule,
    rows: u64,
    next_cut: u64,
    leader: usize,
    /// Threads a block's entrants learn on ([`MdaglRace::set_threads`]).
    threads: usize,
    /// Each entrant's prequential records for the block being learned, entrant-major
    /// (reused between blocks).
    block: Vec<Prequential>,
}

impl MdaglRace {
    /// A race of `grid`'s settings for `classes` classes and `features` features. Fails as
    /// [`Mdagl::new`] does for any setting, or with an empty grid.
    pub fn new(
        classes: usize,
        features: usize,
        grid: &[MdaglParams],
        schedule: RaceSchedule,
    ) -> Result<Self, MdaglConfigError> {
        if grid.is_empty() {
            return Err(MdaglConfigError::EmptyGrid);
        }
        let entrants = grid
            .iter()
            .map(|&params| {
                Mdagl::new(classes, features, params).map(|model| Entrant {
                    model,
                    loss: 0.0,
                    recent: 0.0,
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            log_probs: Vec::with_capacity(entrants.len()),
            entrants,
            retired: Vec::new(),
            schedule: RaceSchedule {
                first_cut: schedule.first_cut.max(1),
                finalists: schedule.finalists.max(1),
            },
            rows: 0,
            next_cut: schedule.first_cut.max(1),
            leader: 0,
            threads: 1,
            block: Vec::new(),
        })
    }

    /// Lets [`update_block`](Self::update_block) spread the entrants over up to `threads`
    /// threads (at least 1; 1 by default). The entrants never read each other, so the result
    /// is the same to the bit on any number of threads.
    pub fn set_threads(&mut self, threads: usize) {
        self.threads = threads.max(1);
    }

    /// Learns `rows` in order, exactly as that many calls of [`update`](Self::update) would,
    /// writing the race's prediction of each row into `out` (cleared first).
    ///
    /// Each entrant learns a run of rows on its own before the race weighs them row by row:
    /// one model stays in cache for the whole run, and with [`set_threads`](Self::set_threads)
    /// the entrants learn on several threads. A run ends at each cut, so no entrant learns a
    /// row after it retires. A row refused for its shape or label is checked before any
    /// learning: the rows before it are learned, it and those after are not, and its index
    /// comes with the error.
    pub fn update_block(
        &mut self,
        rows: &[(Features<'_>, usize)],
        out: &mut Vec<Prequential>,
    ) -> Result<(), BlockError> {
        out.clear();
        let (valid, refused) = self.checked_prefix(rows);
        let mut done = 0;
        while done < valid {
            let until_cut = usize::try_from(self.next_cut - self.rows).unwrap_or(usize::MAX);
            let run = &rows[done..valid.min(done.saturating_add(until_cut))];
            self.learn_run(run).map_err(|(row, source)| BlockError {
                row: done + row,
                source,
            })?;
            self.weigh_run(run.len(), out);
            done += run.len();
        }
        refused.map_or(Ok(()), Err)
    }

    /// How many leading rows every entrant accepts, and the first refused row's error.
    fn checked_prefix(&self, rows: &[(Features<'_>, usize)]) -> (usize, Option<BlockError>) {
        for (row, &(x, label)) in rows.iter().enumerate() {
            if let Err(source) = self.check_row(x, label) {
                return (row, Some(BlockError { row, source }));
            }
        }
        (rows.len(), None)
    }

    /// Whether every entrant would accept the row: its shape and its label (the entrants
    /// share both).
    fn check_row(&self, x: Features<'_>, label: usize) -> Result<(), MdaglError> {
        let first = &self.entrants[0].model;
        x.validate(first.n_features())?;
        if label >= first.n_classes() {
            return Err(MdaglError::LabelOutOfRange {
                label,
                classes: first.n_classes(),
            });
        }
        Ok(())
    }

    /// Every entrant learns `run`, keeping its prequential records in `self.block`.
    fn learn_run(&mut self, run: &[(Features<'_>, usize)]) -> Result<(), (usize, MdaglError)> {
        let n = run.len();
        let empty = Prequential {
            log_prob: 0.0,
            predicted: 0,
        };
        self.block.clear();
        self.block.resize(self.entrants.len() * n, empty);
        let learn = |entrants: &mut [Entrant], records: &mut [Prequential]| {
            entrants
                .iter_mut()
                .zip(records.chunks_mut(n))
                .try_for_each(|(e, records)| learn_entrant(e, run, records))
        };
        let threads = self.threads.min(self.entrants.len());
        if threads <= 1 {
            return learn(&mut self.entrants, &mut self.block);
        }
        // In contiguous shares: a model's buffers were allocated beside its neighbours', and
        // neighbours learning on different threads would write to shared cache lines.
        let share = self.entrants.len().div_ceil(threads);
        let shares = self
            .entrants
            .chunks_mut(share)
            .zip(self.block.chunks_mut(share * n));
        std::thread::scope(|scope| {
            let workers: Vec<_> = shares
                .map(|(entrants, records)| scope.spawn(move || learn(entrants, records)))
                .collect();
            workers.into_iter().try_for_each(|worker| {
                worker
                    .join()
                    .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
            })
        })
    }

    /// The race's bookkeeping for the `n` rows just learned, row by row as
    /// [`update`](Self::update) does it, from the records in `self.block`.
    fn weigh_run(&mut self, n: usize, out: &mut Vec<Prequential>) {
        if let [lone] = self.entrants.as_mut_slice() {
            // A lone entrant is its own mixture (weight 1: the mixture's log-probability is
            // its own, to the bit) and the leader: its records are the race's.
            for record in &self.block[..n] {
                lone.loss -= record.log_prob;
                lone.recent -= record.log_prob;
            }
            out.extend_from_slice(&self.block[..n]);
            self.rows += n as u64;
            // A run ends at a cut, so a cut can only be due after its last row.
            if self.rows >= self.next_cut {
                self.cut();
            }
            return;
        }
        for row in 0..n {
            self.log_probs.clear();
            self.log_probs
                .extend((0..self.entrants.len()).map(|e| self.block[e * n + row].log_prob));
            let predicted = self.block[self.leader * n + row].predicted;
            out.push(self.settle_row(predicted));
        }
    }

    /// Scores the row whose entrants' log-probabilities are in `log_probs`: the mixture's
    /// prediction, then the losses, the leader, and a cut when one is due.
    fn settle_row(&mut self, predicted: usize) -> Prequential {
        let log_prob = self.mixture_log_prob();
        for (entrant, lp) in self.entrants.iter_mut().zip(&self.log_probs) {
            entrant.loss -= lp;
            entrant.recent -= lp;
        }
        self.rows += 1;
        self.leader = self.best_entrant();
        if self.rows >= self.next_cut {
            self.cut();
        }
        Prequential {
            log_prob,
            predicted,
        }
    }

    /// Has every entrant learn `(x, label)` and returns the race's prediction of it, made
    /// before learning: the log-probability the loss-weighted mixture of the entrants gave the
    /// label, and the leader's most likely class. A row refused for its shape or label changes
    /// nothing.
    pub fn update(&mut self, x: Features<'_>, label: usize) -> Result<Prequential, MdaglError> {
        // Checked once up front, so no entrant learns a row another refuses.
        self.check_row(x, label)?;
        let mut predicted = None;
        self.log_probs.clear();
        for (i, entrant) in self.entrants.iter_mut().enumerate() {
            let pre = entrant.model.update(x, label)?;
            self.log_probs.push(pre.log_prob);
            if i == self.leader {
                predicted = Some(pre.predicted);
            }
        }
        let predicted = predicted.ok_or(MdaglError::Overflow)?;
        Ok(self.settle_row(predicted))
    }

    /// `ln Σ_j w_j p_j(label)` with `w_j ∝ exp(−loss_j)` (the losses before this row), in
    /// log space throughout: a lone entrant's is its own log-probability exactly.
    fn mixture_log_prob(&self) -> f64 {
        let top = self
            .entrants
            .iter()
            .map(|e| -e.loss)
            .fold(f64::NEG_INFINITY, f64::max);
        let norm: f64 = self.entrants.iter().map(|e| (-e.loss - top).exp()).sum();
        let weighted = || {
            self.entrants
                .iter()
                .zip(&self.log_probs)
                .map(|(e, lp)| lp + (-e.loss - top) - norm.ln())
        };
        let peak = weighted().fold(f64::NEG_INFINITY, f64::max);
        peak + weighted().map(|v| (v - peak).exp()).sum::<f64>().ln()
    }

    /// The leading setting's standing: the lowest prequential log-loss so far, ties within
    /// [`TIE`] going to the sparsest setting (the largest λ).
    pub fn leader(&self) -> Standing {
        self.standing(self.leader)
    }

    /// The leading model: the one reported and used.
    pub fn model(&self) -> &Mdagl {
        &self.entrants[self.leader].model
    }

    /// Takes the leading model out of the race.
    pub fn into_model(mut self) -> Mdagl {
        self.entrants.swap_remove(self.leader).model
    }

    /// Every setting's standing, best first: those still racing by their loss, then the
    /// retired in the order they retired (the last to retire first).
    pub fn standings(&self) -> Vec<Standing> {
        let mut racing: Vec<Standing> =
            (0..self.entrants.len()).map(|i| self.standing(i)).collect();
        racing.sort_by(|a, b| a.mean_log_loss.total_cmp(&b.mean_log_loss));
        racing.extend(self.retired.iter().rev());
        racing
    }

    /// Entrants still racing.
    pub fn racing(&self) -> usize {
        self.entrants.len()
    }

    /// Rows learned.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    fn standing(&self, i: usize) -> Standing {
        let e = &self.entrants[i];
        Standing {
            params: e.model.params(),
            mean_log_loss: if self.rows == 0 {
                0.0
            } else {
                e.loss / self.rows as f64
            },
            rows: self.rows,
            racing: true,
        }
    }

    /// The leader: the entrant with the lowest summed loss — where others come within
    /// [`TIE`] of it, the sparsest of them (the largest λ, then the lowest loss). Settings that
    /// predict equally well differ mostly in how many columns they keep, and the fewest that
    /// predict as well are the relevant ones.
    fn best_entrant(&self) -> usize {
        let lowest = self
            .entrants
            .iter()
            .map(|e| e.loss)
            .fold(f64::INFINITY, f64::min);
        let close = |e: &Entrant| e.loss <= lowest * (1.0 + TIE);
        let mut best = 0;
        for (i, e) in self.entrants.iter().enumerate() {
            let b = &self.entrants[best];
            let (lambda, best_lambda) = (e.model.params().lambda, b.model.params().lambda);
            let better = match (close(e), close(b)) {
                (true, false) => true,
                (true, true) => lambda > best_lambda || (lambda == best_lambda && e.loss < b.loss),
                _ => false,
            };
            if better {
                best = i;
            }
        }
        best
    }

    /// Retires the worse half of the field (never below the finalists), ranked by their loss
    /// since the last cut — the latest half of the rows: a setting that starts slowly but
    /// learns better (a smaller λ keeps more columns, so it is noisier at first) is judged on
    /// how it does now, not on its start. The leader always stays: it is the model reported
    /// and used, and the sparsest of a tie may trail the denser settings it tied with by a
    /// hair over the recent rows. The next cut comes when the row count has doubled.
    fn cut(&mut self) {
        self.next_cut = self.rows.saturating_mul(2);
        let keep = self.entrants.len().div_ceil(2).max(self.schedule.finalists);
        self.entrants.swap(0, self.leader);
        self.entrants[1..].sort_by(|a, b| a.recent.total_cmp(&b.recent));
        for e in &mut self.entrants {
            e.recent = 0.0;
        }
        if keep >= self.entrants.len() {
            self.leader = self.best_entrant();
            return;
        }
        let gone = self.entrants.split_off(keep);
        let rows = self.rows as f64;
        // Worst first, so `standings` (which lists the retired last-in first) ends on it.
        for e in gone.into_iter().rev() {
            self.retired.push(Standing {
                params: e.model.params(),
                mean_log_loss: e.loss / rows,
                rows: self.rows,
                racing: false,
            });
        }
        self.leader = self.best_entrant();
    }
}

#[cfg(test)]
mod tests;

/// One racing entrant's saved state (see [`RaceState`]).
#[derive(Debug, Clone, PartialEq)]
pub struct EntrantState {
    /// Its model, with its whole learning state.
    pub model: Mdagl,
    /// Its summed prequential log-loss.
    pub loss: f64,
    /// Its loss since the last cut.
    pub recent: f64,
}

/// A race's whole state: with it, [`MdaglRace::from_state`] rebuilds a race that predicts and
/// learns on exactly as the saved one would (how a race is saved and restored).
#[derive(Debug, Clone, PartialEq)]
pub struct RaceState {
    /// The entrants still racing, in the race's order.
    pub entrants: Vec<EntrantState>,
    /// The retired settings' standings, in the order they retired.
    pub retired: Vec<Standing>,
    /// When entrants retire.
    pub schedule: RaceSchedule,
    /// Rows learned.
    pub rows: u64,
    /// The row count at which the next cut comes.
    pub next_cut: u64,
    /// The leading entrant's index in `entrants`.
    pub leader: usize,
}

/// Why a saved race cannot be restored.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RaceStateError {
    /// No entrant is left racing.
    #[error("a race needs at least one entrant")]
    NoEntrants,
    /// The leader is not one of the entrants.
    #[error("leader {leader} is not one of the {entrants} entrants")]
    BadLeader {
        /// The saved leader.
        leader: usize,
        /// Entrants saved.
        entrants: usize,
    },
    /// The entrants disagree on the shape, or a loss is not finite.
    #[error("the entrants differ in shape, or a loss is not finite")]
    Inconsistent,
}

impl MdaglRace {
    /// The race's whole state (see [`RaceState`]).
    pub fn state(&self) -> RaceState {
        RaceState {
            entrants: self
                .entrants
                .iter()
                .map(|e| EntrantState {
                    model: e.model.clone(),
                    loss: e.loss,
                    recent: e.recent,
                })
                .collect(),
            retired: self.retired.clone(),
            schedule: self.schedule,
            rows: self.rows,
            next_cut: self.next_cut,
            leader: self.leader,
        }
    }

    /// Rebuilds a race from [`state`](Self::state)'s record, checked: at least one entrant,
    /// all of one shape with finite losses, and a leader among them. It learns on one thread
    /// ([`set_threads`](Self::set_threads) changes that, never the result).
    pub fn from_state(state: RaceState) -> Result<Self, RaceStateError> {
        let Some(first) = state.entrants.first() else {
            return Err(RaceStateError::NoEntrants);
        };
        if state.leader >= state.entrants.len() {
            return Err(RaceStateError::BadLeader {
                leader: state.leader,
                entrants: state.entrants.len(),
            });
        }
        let shape = (first.model.n_classes(), first.model.n_features());
        let consistent = state.entrants.iter().all(|e| {
            (e.model.n_classes(), e.model.n_features()) == shape
                && e.loss.is_finite()
                && e.recent.is_finite()
        });
        if !consistent {
            return Err(RaceStateError::Inconsistent);
        }
        let entrants: Vec<Entrant> = state
            .entrants
            .into_iter()
            .map(|e| Entrant {
                model: e.model,
                loss: e.loss,
                recent: e.recent,
            })
            .collect();
        Ok(Self {
            log_probs: Vec::with_capacity(entrants.len()),
            entrants,
            retired: state.retired,
            schedule: RaceSchedule {
                first_cut: state.schedule.first_cut.max(1),
                finalists: state.schedule.finalists.max(1),
            },
            rows: state.rows,
            next_cut: state.next_cut.max(1),
            leader: state.leader,
            threads: 1,
            block: Vec::new(),
        })
    }
}
