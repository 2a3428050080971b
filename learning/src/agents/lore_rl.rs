//! loreRL: model-based RL with regularised logistic regression (the paper's §4.2, Algorithm 6).
//!
//! One mDAGL view per action predicts the action's effect from the state's features; value
//! iteration plans on the CMDP those views define; the agent acts ε-greedily on the plan and
//! feeds every observed effect to the taken action's view. With λ = 0 (no regulariser) this is
//! the paper's *bloreRL* baseline.

use std::sync::Arc;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{Agent, AgentError, check_step};
use crate::cmdp::CmdpStructure;
use crate::mdagl::{Features, Mdagl, MdaglParams};
use crate::plan::{PlannedModel, PlannerParams, ValueIteration};

/// loreRL's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoreRlParams {
    /// The views' mDAGL settings (paper: λ = 0.05, α = 1.5).
    pub mdagl: MdaglParams,
    /// Value-iteration settings (paper: γ = 0.95).
    pub planner: PlannerParams,
    /// Probability of a uniformly random action (paper: ε = 0.05).
    pub epsilon: f64,
}

impl Default for LoreRlParams {
    /// The paper's §5.1 settings: λ = 0.05, α = 1.5, γ = 0.95, ε = 0.05.
    fn default() -> Self {
        Self {
            mdagl: MdaglParams::default(),
            planner: PlannerParams::default(),
            epsilon: 0.05,
        }
    }
}

impl LoreRlParams {
    /// The paper's bloreRL baseline: loreRL without the group-lasso regulariser (λ = 0).
    pub fn blore_rl() -> Self {
        let mut p = Self::default();
        p.mdagl.lambda = 0.0;
        p
    }
}

/// The loreRL agent.
#[derive(Debug, Clone)]
pub struct LoreRl {
    name: &'static str,
    views: Vec<Mdagl>,
    model: PlannedModel,
    epsilon: f64,
    rng: ChaCha8Rng,
}

impl LoreRl {
    /// A fresh agent (uninformed views) on `structure`; `seed` drives its exploration.
    pub fn new(
        structure: Arc<CmdpStructure>,
        params: LoreRlParams,
        seed: u64,
    ) -> Result<Self, AgentError> {
        if !(0.0..=1.0).contains(&params.epsilon) {
            return Err(AgentError::BadEpsilon(params.epsilon));
        }
        let views = (0..structure.n_actions())
            .map(|_| Mdagl::new(structure.n_effects(), structure.n_features(), params.mdagl))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            name: if params.mdagl.lambda == 0.0 {
                "bloreRL"
            } else {
                "loreRL"
            },
            model: PlannedModel::new(structure, params.planner)?,
            views,
            epsilon: params.epsilon,
            rng: ChaCha8Rng::seed_from_u64(seed),
        })
    }

    /// An agent on `structure` that starts from `views` (one per action, shaped for the
    /// structure's effects and features) and goes on learning them: a model carried from task
    /// to task (the lifelong benchmark's continual baseline). [`into_views`](Self::into_views)
    /// hands them back at the task's end.
    pub fn with_views(
        structure: Arc<CmdpStructure>,
        params: LoreRlParams,
        views: Vec<Mdagl>,
        seed: u64,
    ) -> Result<Self, AgentError> {
        let fits = views.len() == structure.n_actions()
            && views.iter().all(|v| {
                v.n_classes() == structure.n_effects() && v.n_features() == structure.n_features()
            });
        if !fits {
            return Err(AgentError::ViewsShape {
                views: views.len(),
                actions: structure.n_actions(),
                effects: structure.n_effects(),
                features: structure.n_features(),
            });
        }
        let mut agent = Self::new(structure, params, seed)?;
        for (a, view) in views.into_iter().enumerate() {
            agent.model.refresh(a, &view)?;
            agent.views[a] = view;
        }
        Ok(agent)
    }

    /// The views as learned so far, one per action: what a continual learner carries on.
    pub fn into_views(self) -> Vec<Mdagl> {
        self.views
    }

    /// The view (effect predictor) of `action`.
    pub fn view(&self, action: usize) -> Option<&Mdagl> {
        self.views.get(action)
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

    /// Re-plans if the views moved the model enough since the last plan (see
    /// [`PlannedModel`]).
    pub fn replan(&mut self) {
        self.model.replan();
    }
}

impl Agent for LoreRl {
    fn name(&self) -> &str {
        self.name
    }

    fn act(&mut self, state: usize) -> Result<usize, AgentError> {
        check_step(self.model.structure(), state, 0, None)?;
        if self.epsilon > 0.0 && self.rng.random::<f64>() < self.epsilon {
            return Ok(self.rng.random_range(0..self.views.len()));
        }
        self.model.replan();
        Ok(self.model.action(state))
    }

    fn observe(&mut self, state: usize, action: usize, effect: usize) -> Result<(), AgentError> {
        check_step(self.model.structure(), state, action, Some(effect))?;
        let x = Features::SparseBinary(self.model.structure().features(state));
        self.views[action].update(x, effect)?;
        // Only the updated action's rows of the model change.
        self.model.refresh(action, &self.views[action])?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::agents::tests::assert_refuses_bad_steps;
    use crate::cmdp::examples::corridor;

    /// True corridor dynamics: intended move w.p. 0.9 (else stay) on normal cells; on slippery
    /// cells (feature 1) the move goes the *other* way w.p. 0.7.
    fn true_effect(structure: &CmdpStructure, s: usize, a: usize, rng: &mut ChaCha8Rng) -> usize {
        let slippery = structure.features(s).contains(&1);
        let u: f64 = rng.random();
        let (intended, opposite) = if a == 0 { (0, 1) } else { (1, 0) };
        if slippery {
            if u < 0.7 { opposite } else { intended }
        } else if u < 0.9 {
            intended
        } else {
            2
        }
    }

    fn run_episode(
        agent: &mut LoreRl,
        structure: &CmdpStructure,
        start: usize,
        rng: &mut ChaCha8Rng,
    ) -> f64 {
        let mut s = start;
        let mut ret = 0.0;
        for _ in 0..100 {
            let a = agent.act(s).unwrap();
            let e = true_effect(structure, s, a, rng);
            agent.observe(s, a, e).unwrap();
            s = structure.next_state(s, e);
            ret += structure.reward(s);
            if structure.is_terminal(s) {
                break;
            }
        }
        ret
    }

    #[test]
    fn learns_to_reach_the_exit_and_the_slippery_feature() {
        let c = Arc::new(corridor(10, &[3, 6]));
        let mut agent = LoreRl::new(c.clone(), LoreRlParams::default(), 7).unwrap();
        let mut world = ChaCha8Rng::seed_from_u64(11);
        let mut late = 0.0;
        for episode in 0..150 {
            let r = run_episode(&mut agent, &c, 5, &mut world);
            if episode >= 100 {
                late += r;
            }
        }
        // The slippery cells reverse moves: the model must know it to plan well.
        let right = agent.view(1).unwrap();
        assert!(right.is_selected(1), "the slippery feature matters");
        // "right" on a slippery cell is predicted to go left far more often than elsewhere.
        let mut right = right.clone();
        let slip = right.predict(Features::SparseBinary(&[0, 1])).unwrap()[0];
        let normal = right.predict(Features::SparseBinary(&[0])).unwrap()[0];
        assert!(
            slip > 0.4 && slip > 2.0 * normal,
            "slip {slip}, normal {normal}"
        );
        agent.replan();
        assert_eq!(agent.planner().action(7), 1, "head for the exit");
        assert!(late / 50.0 > 0.5, "mean late return {}", late / 50.0);
    }

    #[test]
    fn bad_steps_are_refused_and_change_nothing() {
        let c = Arc::new(corridor(5, &[]));
        let mut agent = LoreRl::new(c, LoreRlParams::default(), 1).unwrap();
        assert_refuses_bad_steps(&mut agent);
        assert_eq!(agent.view(0).unwrap().n_updates(), 0);
    }

    #[test]
    fn settings_are_checked_and_blore_is_named() {
        let c = Arc::new(corridor(5, &[]));
        let bad = LoreRlParams {
            epsilon: 1.5,
            ..LoreRlParams::default()
        };
        assert!(matches!(
            LoreRl::new(c.clone(), bad, 0),
            Err(AgentError::BadEpsilon(_))
        ));
        let blore = LoreRl::new(c, LoreRlParams::blore_rl(), 0).unwrap();
        assert_eq!(blore.name(), "bloreRL");
    }

    /// Views carried into a new task (a longer corridor of the same features) go on from what
    /// they learned: the continued agent plans with them at once and keeps updating them.
    #[test]
    fn carried_views_start_the_next_task_where_the_last_ended() {
        let first = Arc::new(corridor(10, &[3, 6]));
        let mut agent = LoreRl::new(first.clone(), LoreRlParams::default(), 7).unwrap();
        let mut world = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..100 {
            run_episode(&mut agent, &first, 5, &mut world);
        }
        let views = agent.into_views();
        let learned: Vec<u64> = views.iter().map(Mdagl::n_updates).collect();
        assert!(learned.iter().all(|&n| n > 0), "{learned:?}");
        let next = Arc::new(corridor(12, &[2, 8]));
        let mut carried = LoreRl::with_views(next.clone(), LoreRlParams::default(), views, 9)
            .expect("same features and effects");
        // The slip learned in the first corridor is known on arrival in the second.
        assert!(carried.view(1).unwrap().is_selected(1));
        run_episode(&mut carried, &next, 6, &mut world);
        let after: Vec<u64> = (0..2)
            .map(|a| carried.view(a).unwrap().n_updates())
            .collect();
        assert!(
            after.iter().zip(&learned).any(|(a, b)| a > b),
            "still learning"
        );
        assert!(after.iter().zip(&learned).all(|(a, b)| a >= b));
    }

    #[test]
    fn views_that_do_not_fit_the_task_are_refused() {
        let c = Arc::new(corridor(5, &[]));
        let one = LoreRl::new(c.clone(), LoreRlParams::default(), 0)
            .unwrap()
            .into_views()
            .into_iter()
            .take(1)
            .collect();
        let e = LoreRl::with_views(c, LoreRlParams::default(), one, 0).unwrap_err();
        assert!(matches!(e, AgentError::ViewsShape { views: 1, .. }), "{e}");
    }

    #[test]
    fn same_seed_same_behaviour() {
        let c = Arc::new(corridor(8, &[4]));
        let mut returns = Vec::new();
        for _ in 0..2 {
            let mut agent = LoreRl::new(c.clone(), LoreRlParams::default(), 3).unwrap();
            let mut world = ChaCha8Rng::seed_from_u64(5);
            returns.push(
                (0..20)
                    .map(|_| run_episode(&mut agent, &c, 4, &mut world))
                    .collect::<Vec<_>>(),
            );
        }
        assert_eq!(returns[0], returns[1]);
    }
}
