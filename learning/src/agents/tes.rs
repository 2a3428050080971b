//! TES: transferring expectations with a library of views (the paper's §3.2, Algorithm 2), and
//! the transfer baselines that share its machinery — LWT and fixed random view combinations.
//!
//! At a task's start the *working library* is every library view of every action (as a working
//! copy that keeps learning, plus its frozen original) and one fresh view per action. Each
//! action first uses its view with the best track record `Φ`. After every step `(s, a, e)`:
//!
//! 1. every view of `a` — working copies, the fresh view and the frozen originals — adds
//!    `log τ(s, a, e)` to its score, *before* learning from the step (prequential);
//! 2. the working views of `a` learn the step (mDAGL);
//! 3. `a`'s selected view becomes its highest-scoring working view, and the model the planner
//!    plans on is refreshed from it.
//!
//! This path allocates nothing. At the task's end [`Tes::finish_task`] hands the outcome to
//! [`ViewLibrary::end_task`], which grows and prunes the library (Algorithm 3).
//!
//! Two baselines reuse the agent with a different [`ViewPolicy`]:
//!
//! * **LWT** (Atkeson et al., *Locally weighted learning for control*, AI Review 1997, as the
//!   paper adapts it to a discrete setting: "adopting a fixed single view") — per action the
//!   library view with the best track record, used as it is: never updated, never switched.
//!   An action the library has no view for gets a fresh view that learns.
//! * **Random views** (the paper's Fig. 4b "Rands") — per action a library view drawn at
//!   random; it learns online but is never switched, which isolates what view *selection*
//!   is worth.

use std::sync::Arc;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{Agent, AgentError, check_step};
use crate::cmdp::CmdpStructure;
use crate::library::{ActionOutcome, LibraryError, TaskReport, ViewLibrary, Winner};
use crate::mdagl::{Features, Mdagl};
use crate::plan::{PlannedModel, PlannerParams, ValueIteration};

/// How a transfer agent picks and adapts its views.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewPolicy {
    /// TES: score every view, learn with every working view, follow the best score.
    Tes,
    /// LWT: the best-track-record library view per action, frozen.
    Lwt,
    /// A random library view per action, learning, never switched (Fig. 4b's "Rands").
    RandomFixed,
}

/// Settings of a transfer agent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TesParams {
    /// Value-iteration settings (paper: γ = 0.95).
    pub planner: PlannerParams,
    /// Probability of a uniformly random action (paper §5.1: ε = 0.05).
    pub epsilon: f64,
    /// How views are picked and adapted.
    pub policy: ViewPolicy,
}

impl Default for TesParams {
    /// TES with the paper's §5.1 settings: ε = 0.05, γ = 0.95.
    fn default() -> Self {
        Self {
            planner: PlannerParams::default(),
            epsilon: 0.05,
            policy: ViewPolicy::Tes,
        }
    }
}

/// Where a working view came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// The task's fresh view.
    Fresh,
    /// A working copy of the library view with this id.
    Library(u64),
}

/// One view in the working library.
#[derive(Debug, Clone)]
pub struct WorkingView {
    origin: Origin,
    model: Mdagl,
    score: f64,
    /// For a library view: its frozen original and that original's score.
    original: Option<(Mdagl, f64)>,
    /// `Φ` at the task's start (the initial selection's criterion).
    track_record: f64,
}

impl WorkingView {
    /// Where it came from.
    pub fn origin(&self) -> Origin {
        self.origin
    }

    /// Its current model.
    pub fn model(&self) -> &Mdagl {
        &self.model
    }

    /// Its log-score over the task so far.
    pub fn score(&self) -> f64 {
        self.score
    }

    /// The frozen original's log-score over the task so far (library views only).
    pub fn original_score(&self) -> Option<f64> {
        self.original.as_ref().map(|(_, s)| *s)
    }
}

/// The working views of one action.
#[derive(Debug, Clone)]
struct ActionViews {
    views: Vec<WorkingView>,
    selected: usize,
    observations: u64,
}

/// The TES agent (and, by [`ViewPolicy`], LWT and fixed random views).
#[derive(Debug, Clone)]
pub struct Tes {
    name: &'static str,
    policy: ViewPolicy,
    library: ViewLibrary,
    actions: Vec<ActionViews>,
    model: PlannedModel,
    epsilon: f64,
    rng: ChaCha8Rng,
}

impl Tes {
    /// Starts a task on `structure` with `library` (its views must fit the structure's actions,
    /// effects and features); `seed` drives exploration and, for random views, the draw.
    pub fn new(
        structure: Arc<CmdpStructure>,
        library: ViewLibrary,
        params: TesParams,
        seed: u64,
    ) -> Result<Self, AgentError> {
        if !(0.0..=1.0).contains(&params.epsilon) {
            return Err(AgentError::BadEpsilon(params.epsilon));
        }
        if library.n_actions() != structure.n_actions()
            || library.n_effects() != structure.n_effects()
            || library.n_features() != structure.n_features()
        {
            return Err(AgentError::LibraryShape {
                actions: library.n_actions(),
                effects: library.n_effects(),
                features: library.n_features(),
            });
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut actions = Vec::with_capacity(structure.n_actions());
        for a in 0..structure.n_actions() {
            let mut views: Vec<WorkingView> = library
                .views_for(a)
                .map(|v| WorkingView {
                    origin: Origin::Library(v.id()),
                    model: v.model().clone(),
                    score: 0.0,
                    original: Some((v.model().clone(), 0.0)),
                    track_record: library.track_record(v),
                })
                .collect();
            let n_library = views.len();
            views.push(WorkingView {
                origin: Origin::Fresh,
                model: library.fresh_model(),
                score: 0.0,
                original: None,
                track_record: 0.0,
            });
            let selected = match params.policy {
                ViewPolicy::RandomFixed if n_library > 0 => rng.random_range(0..n_library),
                // Best track record; the first (oldest) on ties; the fresh view (last, Φ = 0)
                // only when the library has nothing for this action.
                _ => (0..views.len()).fold(0, |best, i| {
                    if views[i].track_record > views[best].track_record {
                        i
                    } else {
                        best
                    }
                }),
            };
            actions.push(ActionViews {
                views,
                selected,
                observations: 0,
            });
        }
        let mut model = PlannedModel::new(structure, params.planner)?;
        for (a, av) in actions.iter().enumerate() {
            model.refresh(a, &av.views[av.selected].model)?;
        }
        Ok(Self {
            name: match params.policy {
                ViewPolicy::Tes => "TES",
                ViewPolicy::Lwt => "LWT",
                ViewPolicy::RandomFixed => "Rands",
            },
            policy: params.policy,
            library,
            actions,
            model,
            epsilon: params.epsilon,
            rng,
        })
    }

    /// The library the task started with (unchanged until [`finish_task`](Self::finish_task)).
    pub fn library(&self) -> &ViewLibrary {
        &self.library
    }

    /// The working views of `action`, library copies first (in library order), the fresh view
    /// last.
    pub fn working_views(&self, action: usize) -> &[WorkingView] {
        self.actions.get(action).map_or(&[], |a| &a.views)
    }

    /// The view `action` currently plans with.
    pub fn selected(&self, action: usize) -> Option<&WorkingView> {
        self.actions.get(action).map(|a| &a.views[a.selected])
    }

    /// The planner, with the values and policy of the last plan.
    pub fn planner(&self) -> &ValueIteration {
        self.model.planner()
    }

    /// The learned model and its plan (for an acting loop that plans on another thread:
    /// the controller's planner thread).
    pub fn model_mut(&mut self) -> &mut PlannedModel {
        &mut self.model
    }

    /// Ends the task: grows and prunes the library from this task's winners (Algorithm 3) and
    /// returns it with what changed. Only TES learns a library; the baselines return it
    /// unchanged (with an empty report).
    pub fn finish_task(self) -> Result<(ViewLibrary, TaskReport), LibraryError> {
        let mut library = self.library;
        if self.policy != ViewPolicy::Tes {
            return Ok((library, TaskReport::default()));
        }
        let outcomes = self
            .actions
            .into_iter()
            .enumerate()
            .map(|(action, av)| {
                let best = best_score(&av.views, av.selected);
                let library_scores = av
                    .views
                    .iter()
                    .filter_map(|v| match v.origin {
                        Origin::Library(id) => Some((id, v.score)),
                        Origin::Fresh => None,
                    })
                    .collect();
                let observations = av.observations;
                let mut views = av.views;
                let winner = views.swap_remove(best);
                ActionOutcome {
                    action,
                    observations,
                    winner: match (winner.origin, winner.original) {
                        (Origin::Library(id), Some((_, original_score))) => {
                            Winner::Adjusted { id, original_score }
                        }
                        _ => Winner::Fresh,
                    },
                    score: winner.score,
                    model: winner.model,
                    library_scores,
                }
            })
            .collect();
        let report = library.end_task(outcomes)?;
        Ok((library, report))
    }
}

/// The highest-scoring view; `current` wins ties (no switching on equal evidence).
fn best_score(views: &[WorkingView], current: usize) -> usize {
    let mut best = current;
    for (i, v) in views.iter().enumerate() {
        if v.score > views[best].score {
            best = i;
        }
    }
    best
}

impl Agent for Tes {
    fn name(&self) -> &str {
        self.name
    }

    fn act(&mut self, state: usize) -> Result<usize, AgentError> {
        check_step(self.model.structure(), state, 0, None)?;
        if self.epsilon > 0.0 && self.rng.random::<f64>() < self.epsilon {
            return Ok(self.rng.random_range(0..self.actions.len()));
        }
        self.model.replan();
        Ok(self.model.action(state))
    }

    fn observe(&mut self, state: usize, action: usize, effect: usize) -> Result<(), AgentError> {
        check_step(self.model.structure(), state, action, Some(effect))?;
        let x = Features::SparseBinary(self.model.structure().features(state));
        let av = &mut self.actions[action];
        match self.policy {
            ViewPolicy::Tes => {
                for v in &mut av.views {
                    // Prequential: `update` reports the probability from before it learned.
                    v.score += v.model.update(x, effect)?.log_prob;
                    if let Some((original, score)) = &mut v.original {
                        *score += original.log_prob(x, effect)?;
                    }
                }
                av.selected = best_score(&av.views, av.selected);
            }
            ViewPolicy::Lwt | ViewPolicy::RandomFixed => {
                let v = &mut av.views[av.selected];
                let learns = self.policy == ViewPolicy::RandomFixed || v.origin == Origin::Fresh;
                if !learns {
                    // A frozen view: the model does not change, nothing to re-plan.
                    v.score += v.model.log_prob(x, effect)?;
                    av.observations += 1;
                    return Ok(());
                }
                v.score += v.model.update(x, effect)?.log_prob;
            }
        }
        av.observations += 1;
        self.model.refresh(action, &av.views[av.selected].model)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests;
