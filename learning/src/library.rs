//! The view library: TES's lifelong memory (the paper's §3.2, Algorithms 2–3).
//!
//! A *view* is one action's effect predictor — an mDAGL model, i.e. a feature selection plus
//! its parameters — with a track record: the tasks in which it was the best-scoring predictor
//! for its action (`H_τ`) and its score in every task it took part in. The library holds at
//! most `M` views and changes only at a task's end ([`ViewLibrary::end_task`]):
//!
//! * **growing** (Algorithm 3, §3.2.2) — per action, the task's best working view `τ*` is
//!   recruited. A fresh view that wins is added. A winner that is the adjusted working copy of
//!   a library view `τ̄` is added as a new member when it beat its frozen original by more
//!   than `c` in log-score (`S(τ*) − S(τ̄) > c`, the prequential likelihood ratio; default
//!   `c = ln 300`); otherwise `τ̄` takes `τ*`'s parameters. The winner's task index joins its
//!   history `H`.
//! * **pruning** (§3.2.3) — while the library holds more than `M` views (default 20), the
//!   view with the lowest recency-weighted track record `Φ(τ, j) = Σ_{t ∈ H_τ} e^{−μ(j−t)}`
//!   is removed (ties: the view whose last win is oldest, then the oldest view). `μ = 0` (the
//!   default, as in the paper's §5.1) makes `Φ` the number of tasks won.
//!
//! What happens *during* a task — scoring every view online and switching between them — is
//! the agent's business: [`crate::agents::Tes`]. Saving and loading: [`store`].

use thiserror::Error;

use crate::mdagl::{Mdagl, MdaglConfigError, MdaglParams};

pub mod store;

/// Library settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LibraryParams {
    /// The most views the library keeps (`M`, paper: 20).
    pub max_views: usize,
    /// Log-likelihood-ratio margin `c` by which an adjusted copy must beat its original to be
    /// added as a new view (paper: ln 300).
    pub growth_threshold: f64,
    /// Recency decay `μ ≥ 0` of the track record `Φ` (paper §5.1: 0, no decay).
    pub recency: f64,
    /// Settings of the fresh views a task starts with (paper: λ = 0.05, α = 1.5).
    pub mdagl: MdaglParams,
    /// How a task's end brings the library back towards `M` views.
    pub pruning: Pruning,
}

/// How the end of a task prunes a library that holds more than `M` views.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pruning {
    /// Remove the least valuable view until `M` are left: the library never holds more than
    /// `M` (ours, and the default: a task may add a view per action, which one removal
    /// does not balance).
    #[default]
    ToLimit,
    /// Remove the one least valuable view, as Algorithm 2 writes it (`if |T| > M then T ← T −
    /// {argmin Φ}`): a task that adds several views leaves the library above `M`.
    OnePerTask,
}

impl Default for LibraryParams {
    /// The paper's §5.1: `M = 20`, `c = ln 300`, `μ = 0`, λ = 0.05, α = 1.5.
    fn default() -> Self {
        Self {
            max_views: 20,
            growth_threshold: 300f64.ln(),
            recency: 0.0,
            mdagl: MdaglParams::default(),
            pruning: Pruning::ToLimit,
        }
    }
}

/// Why a library cannot be built or updated.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum LibraryError {
    /// A setting is out of range.
    #[error("library setting {param} must be {requirement}")]
    Invalid {
        /// The setting.
        param: &'static str,
        /// What it must be.
        requirement: &'static str,
    },
    /// The fresh-view settings are invalid.
    #[error("fresh-view settings: {0}")]
    View(#[from] MdaglConfigError),
    /// A view or outcome does not fit the library's shape.
    #[error(
        "a view for action {action} predicts {classes} effects from {features} features; \
         the library holds views of {expected_actions} actions, {expected_classes} effects, \
         {expected_features} features"
    )]
    WrongShape {
        /// The view's action.
        action: usize,
        /// Its classes.
        classes: usize,
        /// Its features.
        features: usize,
        /// The library's actions.
        expected_actions: usize,
        /// The library's effects.
        expected_classes: usize,
        /// The library's features.
        expected_features: usize,
    },
    /// An outcome names a view the library does not hold.
    #[error("no view with id {0} in the library")]
    UnknownView(u64),
    /// Two outcomes for the same action.
    #[error("two task outcomes for action {0}")]
    DuplicateAction(usize),
}

/// One task's score of a view: what [`ViewLibrary::end_task`] records in its history.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaskScore {
    /// The task's index in the agent's life (`j`).
    pub task: u32,
    /// The view's log-score `S(τ, D^a)` over the task (its working copy's, for a library view).
    pub score: f64,
    /// How many observations of its action the score sums over.
    pub observations: u64,
    /// Whether the view was the task's best for its action.
    pub won: bool,
}

/// A view: an mDAGL effect predictor for one action and its track record.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    pub(crate) id: u64,
    pub(crate) action: usize,
    pub(crate) model: Mdagl,
    pub(crate) wins: Vec<u32>,
    pub(crate) history: Vec<TaskScore>,
}

impl View {
    /// The view's id: unique in its library and never reused.
    pub fn id(&self) -> u64 {
        self.id
    }

    /// The action whose effects it predicts.
    pub fn action(&self) -> usize {
        self.action
    }

    /// The effect predictor.
    pub fn model(&self) -> &Mdagl {
        &self.model
    }

    /// `H_τ`: the tasks in which it was the best predictor for its action, oldest first.
    pub fn wins(&self) -> &[u32] {
        &self.wins
    }

    /// Its score in every task it took part in, oldest first.
    pub fn history(&self) -> &[TaskScore] {
        &self.history
    }

    /// The recency-weighted track record `Φ(τ, j) = Σ_{t ∈ H_τ} e^{−μ(j−t)}`.
    pub fn track_record(&self, task: u32, recency: f64) -> f64 {
        self.wins
            .iter()
            .map(|&t| (-recency * f64::from(task.saturating_sub(t))).exp())
            .sum()
    }
}

/// Where a task's winning view for an action came from.
#[derive(Debug, Clone, PartialEq)]
pub enum Winner {
    /// The fresh view the task started with.
    Fresh,
    /// The working copy of library view `id`; `original_score` is the frozen original's
    /// score `S(τ̄)` over the same observations.
    Adjusted {
        /// The library view it was copied from.
        id: u64,
        /// `S(τ̄, D^a)`.
        original_score: f64,
    },
}

/// What a task taught about one action: the input of Algorithm 3.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionOutcome {
    /// The action.
    pub action: usize,
    /// Observations of the action in the task (no growth without any).
    pub observations: u64,
    /// Where the best working view came from.
    pub winner: Winner,
    /// The best working view `τ*` after the task.
    pub model: Mdagl,
    /// Its score `S(τ*, D^a)`.
    pub score: f64,
    /// The final scores of the working copies of library views (id, score), for their
    /// histories.
    pub library_scores: Vec<(u64, f64)>,
}

/// What [`ViewLibrary::end_task`] did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TaskReport {
    /// The task index the outcomes were recorded under.
    pub task: u32,
    /// Views added (ids).
    pub added: Vec<u64>,
    /// Library views that took their adjusted copy's parameters (ids).
    pub updated: Vec<u64>,
    /// Views pruned (ids).
    pub removed: Vec<u64>,
}

/// The view library.
///
/// ```
/// use tes_learning::library::{ActionOutcome, LibraryParams, ViewLibrary, Winner};
/// use tes_learning::mdagl::{Features, Mdagl};
///
/// let params = LibraryParams::default();
/// let mut library = ViewLibrary::new(2, 3, 10, params)?;
/// // A task in which action 0's fresh view learned something and won.
/// let mut view = Mdagl::new(3, 10, params.mdagl)?;
/// let mut score = 0.0;
/// for _ in 0..50 {
///     score += view.update(Features::SparseBinary(&[0, 4]), 1)?.log_prob;
/// }
/// let report = library.end_task(vec![ActionOutcome {
///     action: 0,
///     observations: 50,
///     winner: Winner::Fresh,
///     model: view,
///     score,
///     library_scores: vec![],
/// }])?;
/// assert_eq!(report.added.len(), 1);
/// assert_eq!(library.views()[0].wins(), &[0]);
/// assert_eq!(library.tasks_seen(), 1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct ViewLibrary {
    pub(crate) n_actions: usize,
    pub(crate) n_effects: usize,
    pub(crate) n_features: usize,
    pub(crate) params: LibraryParams,
    pub(crate) tasks_seen: u32,
    pub(crate) next_id: u64,
    pub(crate) views: Vec<View>,
}

impl ViewLibrary {
    /// An empty library for views of `n_actions` actions predicting `n_effects` effects from
    /// `n_features` features.
    pub fn new(
        n_actions: usize,
        n_effects: usize,
        n_features: usize,
        params: LibraryParams,
    ) -> Result<Self, LibraryError> {
        if n_actions == 0 {
            return Err(LibraryError::Invalid {
                param: "actions",
                requirement: "at least 1",
            });
        }
        check_params(&params)?;
        // Fails now, not at the first task, if fresh views cannot be built.
        Mdagl::new(n_effects, n_features, params.mdagl)?;
        Ok(Self {
            n_actions,
            n_effects,
            n_features,
            params,
            tasks_seen: 0,
            next_id: 0,
            views: Vec::new(),
        })
    }

    /// Actions the views are for.
    pub fn n_actions(&self) -> usize {
        self.n_actions
    }

    /// Effects each view predicts.
    pub fn n_effects(&self) -> usize {
        self.n_effects
    }

    /// Features each view reads.
    pub fn n_features(&self) -> usize {
        self.n_features
    }

    /// The settings.
    pub fn params(&self) -> LibraryParams {
        self.params
    }

    /// Tasks finished so far: the index `j` the next task will have.
    pub fn tasks_seen(&self) -> u32 {
        self.tasks_seen
    }

    /// All views, oldest first.
    pub fn views(&self) -> &[View] {
        &self.views
    }

    /// The views of `action`.
    pub fn views_for(&self, action: usize) -> impl Iterator<Item = &View> + '_ {
        self.views.iter().filter(move |v| v.action == action)
    }

    /// Number of views.
    pub fn len(&self) -> usize {
        self.views.len()
    }

    /// Whether the library holds no view.
    pub fn is_empty(&self) -> bool {
        self.views.is_empty()
    }

    /// `Φ(τ, j)` of `view` for the next task.
    pub fn track_record(&self, view: &View) -> f64 {
        view.track_record(self.tasks_seen, self.params.recency)
    }

    /// A fresh, uninformed view model with the library's settings.
    pub fn fresh_model(&self) -> Mdagl {
        Mdagl::new(self.n_effects, self.n_features, self.params.mdagl)
            .expect("the settings were checked when the library was built")
    }

    /// Checks that `model` could be a view of this library for `action`.
    pub fn check_shape(&self, action: usize, model: &Mdagl) -> Result<(), LibraryError> {
        if action >= self.n_actions
            || model.n_classes() != self.n_effects
            || model.n_features() != self.n_features
        {
            return Err(LibraryError::WrongShape {
                action,
                classes: model.n_classes(),
                features: model.n_features(),
                expected_actions: self.n_actions,
                expected_classes: self.n_effects,
                expected_features: self.n_features,
            });
        }
        Ok(())
    }

    /// Ends task `j = tasks_seen()`: grows the library from the task's winners (Algorithm 3),
    /// records every participating view's score, prunes it ([`Pruning`]) and moves on to task
    /// `j + 1`. Actions without outcome or without observations leave the library as it was.
    /// On error nothing changes.
    pub fn end_task(&mut self, outcomes: Vec<ActionOutcome>) -> Result<TaskReport, LibraryError> {
        for (i, o) in outcomes.iter().enumerate() {
            self.check_shape(o.action, &o.model)?;
            if outcomes[..i].iter().any(|p| p.action == o.action) {
                return Err(LibraryError::DuplicateAction(o.action));
            }
            let ids = o.library_scores.iter().map(|&(id, _)| id);
            let winner = match o.winner {
                Winner::Adjusted { id, .. } => Some(id),
                Winner::Fresh => None,
            };
            for id in ids.chain(winner) {
                if !self
                    .views
                    .iter()
                    .any(|v| v.id == id && v.action == o.action)
                {
                    return Err(LibraryError::UnknownView(id));
                }
            }
        }
        let task = self.tasks_seen;
        let mut report = TaskReport {
            task,
            ..TaskReport::default()
        };
        for o in outcomes {
            if o.observations == 0 {
                continue;
            }
            let winner_id = match o.winner {
                Winner::Adjusted { id, .. } => Some(id),
                Winner::Fresh => None,
            };
            for &(id, score) in &o.library_scores {
                if let Some(v) = self.views.iter_mut().find(|v| v.id == id) {
                    v.history.push(TaskScore {
                        task,
                        score,
                        observations: o.observations,
                        won: false,
                    });
                }
            }
            let recruit = match o.winner {
                Winner::Fresh => true,
                Winner::Adjusted { original_score, .. } => {
                    o.score - original_score > self.params.growth_threshold
                }
            };
            let record = TaskScore {
                task,
                score: o.score,
                observations: o.observations,
                won: true,
            };
            if recruit {
                let id = self.next_id;
                self.next_id += 1;
                self.views.push(View {
                    id,
                    action: o.action,
                    model: o.model,
                    wins: vec![task],
                    history: vec![record],
                });
                report.added.push(id);
            } else if let Some(id) = winner_id
                && let Some(v) = self.views.iter_mut().find(|v| v.id == id)
            {
                v.model = o.model;
                v.wins.push(task);
                // Its working copy's score is this task's record; mark it as the winner.
                if let Some(last) = v.history.last_mut().filter(|h| h.task == task) {
                    last.won = true;
                } else {
                    v.history.push(record);
                }
                report.updated.push(id);
            }
        }
        self.tasks_seen = task.saturating_add(1);
        while self.views.len() > self.params.max_views {
            let worst = self.least_valuable(task);
            report.removed.push(self.views.remove(worst).id);
            if self.params.pruning == Pruning::OnePerTask {
                break;
            }
        }
        Ok(report)
    }

    /// Index of the view to prune: lowest `Φ(τ, task)`, then oldest last win, then oldest.
    fn least_valuable(&self, task: u32) -> usize {
        let key = |v: &View| {
            (
                v.track_record(task, self.params.recency),
                v.wins.last().copied(),
                v.id,
            )
        };
        let mut worst = 0;
        for i in 1..self.views.len() {
            let (a, b) = (key(&self.views[i]), key(&self.views[worst]));
            if a.0 < b.0 || (a.0 == b.0 && (a.1, a.2) < (b.1, b.2)) {
                worst = i;
            }
        }
        worst
    }
}

fn check_params(params: &LibraryParams) -> Result<(), LibraryError> {
    if params.max_views == 0 {
        return Err(LibraryError::Invalid {
            param: "max_views",
            requirement: "at least 1",
        });
    }
    if !params.growth_threshold.is_finite() {
        return Err(LibraryError::Invalid {
            param: "growth_threshold",
            requirement: "a finite number",
        });
    }
    if !(params.recency.is_finite() && params.recency >= 0.0) {
        return Err(LibraryError::Invalid {
            param: "recency",
            requirement: "a finite number >= 0",
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests;
