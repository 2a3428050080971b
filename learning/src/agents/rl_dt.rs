//! RL-DT: model-based RL with decision-tree models of relative effects — a baseline of the
//! paper's §5.1 (Fig. 3a, Table 1).
//!
//! Hester & Stone, "Generalized model learning for reinforcement learning in factored
//! domains", AAMAS 2009. RL-DT learns, per action, a C4.5-style decision tree that predicts the
//! *relative effect* of the action from the state's features, so what is learned in one state
//! generalises to every state in the same leaf. In a CMDP the relative effect is exactly the
//! effect class `e`, so here one [`DecisionTree`] per action predicts `P(e | x(s), a)` over the
//! state's binary features, and the shared value-iteration planner plans on the CMDP those
//! trees define. As the paper (§5.1) says of its RL-DT, exploration is ε-greedy (default
//! ε = 0.1; Nguyen et al. do not give RL-DT's ε, so this follows the default and the
//! paper's fEpsG).
//!
//! **Keeping all data and re-inducing.** Like Hester & Stone's implementation, the agent stores
//! *every* observed example and, by default, re-induces the taken action's tree from all of
//! them after every step ([`RlDtParams::rebuild_every`] = 1). How the examples are kept is
//! [`RlDtParams::examples`]:
//!
//! * [`ExampleStore::List`] (the default) keeps the list of examples as observed, one entry
//!   per step, and induces from it — the published algorithm and its cost: each induction
//!   scans every example the action ever produced (Nguyen et al. §6 name this, and storing all
//!   data, as why RL-DT is slow).
//! * [`ExampleStore::PerStateCounts`] keeps, per state, how often each effect followed. A
//!   state's features are fixed in a CMDP, so the counts are the list with equal examples
//!   merged into weights: the induced trees are identical (integer class weights per node do
//!   not depend on order or grouping; tested), at a cost bounded by the number of states
//!   rather than the number of steps. This is our shortcut, not the paper's.
//!
//! With a larger `rebuild_every` a tree is re-induced only when
//!
//! * the new example *contradicts* its leaf — the leaf is empty or its most frequent effect is
//!   not the observed one (Hester & Stone rebuild when a new instance is mis-predicted), or
//! * `rebuild_every` examples of the action have arrived since the last rebuild (a periodic
//!   refit, since agreeing examples can still change the best split);
//!
//! otherwise the example is only added to its leaf's counts, which keeps every leaf's
//! distribution equal to the frequencies of the examples in it. An action with no data
//! predicts every effect equally.
//!
//! Reconstructed rather than taken from the paper: Hester & Stone predict each state variable's
//! change with its own tree; with one categorical effect per step a single tree per action is
//! the direct analogue. The split criterion is information gain on binary features (C4.5's
//! gain ratio and pruning are not used).

use std::sync::Arc;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::decision_tree::{DecisionTree, Example, TreeParams};
use super::{Agent, AgentError, check_step};
use crate::cmdp::{CmdpStructure, EffectTable};
use crate::plan::{PlannedModel, PlannerParams, ValueIteration};

/// RL-DT's settings, checked by [`RlDt::new`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RlDtParams {
    /// Value-iteration settings (paper: γ = 0.95).
    pub planner: PlannerParams,
    /// Probability of a uniformly random action, in [0, 1].
    pub epsilon: f64,
    /// Tree-induction settings.
    pub tree: TreeParams,
    /// Re-induce an action's tree after this many of its examples even if none contradicted
    /// the tree (≥ 1; 1 rebuilds on every step).
    pub rebuild_every: u32,
    /// How the examples are kept for re-induction (same trees either way, different cost).
    pub examples: ExampleStore,
}

/// How [`RlDt`] keeps the examples it re-induces its trees from. Both give the same trees
/// and so the same behaviour; they differ in memory and induction time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExampleStore {
    /// Every example as observed, one entry per step (Hester & Stone's RL-DT): induction
    /// scans all of an action's examples, so its cost grows with the number of steps.
    #[default]
    List,
    /// Per state, how often each effect followed (equal examples merged into weights):
    /// induction scans at most one entry per visited state and effect.
    PerStateCounts,
}

impl Default for RlDtParams {
    /// γ = 0.95, ε = 0.1, default tree settings, the tree re-induced after every example from
    /// the list of all examples.
    fn default() -> Self {
        Self {
            planner: PlannerParams::default(),
            epsilon: 0.1,
            tree: TreeParams::default(),
            rebuild_every: 1,
            examples: ExampleStore::List,
        }
    }
}

/// The RL-DT agent (Hester & Stone, AAMAS 2009): one [`DecisionTree`] per action predicts the
/// effect from the state's features, re-induced from all stored examples when a new example
/// contradicts its leaf or every [`RlDtParams::rebuild_every`] examples; ε-greedy on value
/// iteration.
#[derive(Debug, Clone)]
pub struct RlDt {
    structure: Arc<CmdpStructure>,
    params: RlDtParams,
    trees: Vec<DecisionTree>,
    /// `counts[(a * S + s) * E + e]`: every example ever seen, losslessly.
    counts: Vec<u32>,
    /// Per action, the states it was tried in, in first-visit order
    /// ([`ExampleStore::PerStateCounts`]).
    visited: Vec<Vec<u32>>,
    /// Per action, every `(state, effect)` in the order observed ([`ExampleStore::List`]).
    list: Vec<Vec<(u32, u32)>>,
    /// Per action, examples since its tree was last re-induced.
    since_rebuild: Vec<u32>,
    rebuilds: u64,
    model: PlannedModel,
    rng: ChaCha8Rng,
    scratch: Vec<f64>,
}

impl RlDt {
    /// A fresh agent on `structure`; `seed` drives its exploration.
    pub fn new(
        structure: Arc<CmdpStructure>,
        params: RlDtParams,
        seed: u64,
    ) -> Result<Self, AgentError> {
        if !(0.0..=1.0).contains(&params.epsilon) {
            return Err(AgentError::BadEpsilon(params.epsilon));
        }
        if params.rebuild_every == 0 {
            return Err(AgentError::Invalid {
                param: "rebuild_every",
                requirement: "at least 1",
            });
        }
        if params.tree.min_leaf == 0
            || !(params.tree.min_gain.is_finite() && params.tree.min_gain >= 0.0)
        {
            return Err(AgentError::Invalid {
                param: "tree",
                requirement: "min_leaf >= 1 and a finite min_gain >= 0",
            });
        }
        let model = PlannedModel::new(structure.clone(), params.planner)?;
        let (s, a, e, f) = (
            structure.n_states(),
            structure.n_actions(),
            structure.n_effects(),
            structure.n_features(),
        );
        Ok(Self {
            trees: vec![DecisionTree::empty(f, e); a],
            counts: vec![0; a * s * e],
            visited: vec![Vec::new(); a],
            list: vec![Vec::new(); a],
            since_rebuild: vec![0; a],
            rebuilds: 0,
            model,
            rng: ChaCha8Rng::seed_from_u64(seed),
            scratch: vec![0.0; e],
            structure,
            params,
        })
    }

    /// The settings.
    pub fn params(&self) -> RlDtParams {
        self.params
    }

    /// The effect tree of `action`.
    pub fn tree(&self, action: usize) -> Option<&DecisionTree> {
        self.trees.get(action)
    }

    /// How many times any tree was re-induced from all data.
    pub fn n_rebuilds(&self) -> u64 {
        self.rebuilds
    }

    /// The planner, with the values and policy of the last plan.
    pub fn planner(&self) -> &ValueIteration {
        self.model.planner()
    }

    /// The learned `P(e | x(s), a)` for every state and action.
    pub fn effect_table(&self) -> &EffectTable {
        self.model.table()
    }

    /// Re-plans if the trees moved the model enough since the last plan (see
    /// [`PlannedModel`]).
    pub fn replan(&mut self) {
        self.model.replan();
    }

    /// Re-induces `action`'s tree from all its stored examples.
    fn rebuild(&mut self, action: usize) {
        let (n_s, n_e) = (self.structure.n_states(), self.structure.n_effects());
        let structure = &self.structure;
        let examples: Vec<Example<'_>> = match self.params.examples {
            ExampleStore::List => self.list[action]
                .iter()
                .map(|&(s, class)| Example {
                    features: structure.features(s as usize),
                    class: class as usize,
                    weight: 1,
                })
                .collect(),
            ExampleStore::PerStateCounts => {
                let mut examples = Vec::new();
                for &s in &self.visited[action] {
                    let s = s as usize;
                    let row = &self.counts[(action * n_s + s) * n_e..(action * n_s + s + 1) * n_e];
                    for (class, &weight) in row.iter().enumerate() {
                        if weight > 0 {
                            examples.push(Example {
                                features: structure.features(s),
                                class,
                                weight,
                            });
                        }
                    }
                }
                examples
            }
        };
        self.trees[action] =
            DecisionTree::fit_unchecked(structure.n_features(), n_e, &examples, self.params.tree);
        self.since_rebuild[action] = 0;
        self.rebuilds += 1;
    }

    /// How many examples are stored, over all actions (every observed step).
    pub fn n_examples(&self) -> u64 {
        self.counts.iter().map(|&n| u64::from(n)).sum()
    }
}

impl Agent for RlDt {
    fn name(&self) -> &str {
        "RL-DT"
    }

    fn act(&mut self, state: usize) -> Result<usize, AgentError> {
        check_step(&self.structure, state, 0, None)?;
        let epsilon = self.params.epsilon;
        if epsilon > 0.0 && self.rng.random::<f64>() < epsilon {
            return Ok(self.rng.random_range(0..self.structure.n_actions()));
        }
        self.replan();
        Ok(self.model.action(state))
    }

    fn observe(&mut self, state: usize, action: usize, effect: usize) -> Result<(), AgentError> {
        check_step(&self.structure, state, action, Some(effect))?;
        let (n_s, n_e) = (self.structure.n_states(), self.structure.n_effects());
        let cell = (action * n_s + state) * n_e;
        match self.params.examples {
            ExampleStore::List => self.list[action].push((state as u32, effect as u32)),
            ExampleStore::PerStateCounts => {
                if self.counts[cell..cell + n_e].iter().all(|&n| n == 0) {
                    self.visited[action].push(state as u32);
                }
            }
        }
        self.counts[cell + effect] = self.counts[cell + effect].saturating_add(1);
        self.since_rebuild[action] += 1;
        let x = self.structure.features(state);
        let leaf = self.trees[action].leaf(x);
        let contradicts = self.trees[action].majority(leaf) != Some(effect);
        if contradicts || self.since_rebuild[action] >= self.params.rebuild_every {
            self.rebuild(action);
        } else {
            self.trees[action].add_to_leaf(leaf, effect);
        }
        let tree = &self.trees[action];
        for s in 0..n_s {
            tree.predict_into(self.structure.features(s), &mut self.scratch);
            self.model.set(action, s, &self.scratch);
        }
        Ok(())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::agents::tests::assert_refuses_bad_steps;
    use crate::cmdp::examples::{corridor, corridor_with};

    /// A corridor of `n` cells with four binary features: 0 is a bias, 1 ("even cell") and
    /// 2 ("cell ≡ 1 mod 4") are noise unrelated to the dynamics, 3 marks the `ice` cells, where
    /// moves are reversed (see [`icy_effect`]). Left end −1, right end +1.
    pub(crate) fn icy_corridor(n: usize, ice: &[usize]) -> CmdpStructure {
        let feats: Vec<Vec<u32>> = (0..n)
            .map(|s| {
                let mut x = vec![0];
                if s % 2 == 0 {
                    x.push(1);
                }
                if s % 4 == 1 {
                    x.push(2);
                }
                if ice.contains(&s) {
                    x.push(3);
                }
                x
            })
            .collect();
        corridor_with(feats, 4)
    }

    /// On ice (feature 3) the move is reversed w.p. 0.8; elsewhere it succeeds w.p. 0.9, else
    /// the agent stays.
    pub(crate) fn icy_effect(
        structure: &CmdpStructure,
        s: usize,
        a: usize,
        rng: &mut ChaCha8Rng,
    ) -> usize {
        let u: f64 = rng.random();
        let (intended, opposite) = if a == 0 { (0, 1) } else { (1, 0) };
        if structure.features(s).contains(&3) {
            if u < 0.8 { opposite } else { intended }
        } else if u < 0.9 {
            intended
        } else {
            2
        }
    }

    /// Runs `episodes` episodes from `start`; returns every episode's return.
    pub(crate) fn run(
        agent: &mut dyn Agent,
        structure: &CmdpStructure,
        start: usize,
        episodes: usize,
        world_seed: u64,
    ) -> Vec<f64> {
        let mut world = ChaCha8Rng::seed_from_u64(world_seed);
        (0..episodes)
            .map(|_| {
                let mut s = start;
                agent.begin_episode(s);
                let mut ret = 0.0;
                for _ in 0..100 {
                    let a = agent.act(s).unwrap();
                    let e = icy_effect(structure, s, a, &mut world);
                    agent.observe(s, a, e).unwrap();
                    s = structure.next_state(s, e);
                    ret += structure.reward(s);
                    if structure.is_terminal(s) {
                        break;
                    }
                }
                ret
            })
            .collect()
    }

    #[test]
    fn learns_the_task_and_splits_on_the_relevant_feature() {
        // Starting at 5, "right" reaches the ice at 6 and is mostly thrown back; "left" on
        // the ice carries the agent on towards the exit. Cell 3 is ice the agent seldom sees:
        // the tree must generalise to it from cell 6.
        let c = Arc::new(icy_corridor(10, &[3, 6]));
        let mut agent = RlDt::new(c.clone(), RlDtParams::default(), 7).unwrap();
        let returns = run(&mut agent, &c, 5, 120, 11);
        let late = returns[90..].iter().sum::<f64>() / 30.0;
        for a in 0..2 {
            let tree = agent.tree(a).unwrap();
            assert_eq!(tree.root_split(), Some(3), "action {a} splits on ice first");
        }
        // "right" on ice is predicted to go left most of the time, elsewhere rarely.
        let t = agent.effect_table();
        assert!(t.probs(1, 3)[0] > 0.6 && t.probs(1, 4)[0] < 0.1);
        // Moving left on ice (cell 6) carries the agent right.
        agent.replan();
        assert_eq!(agent.planner().action(7), 1);
        assert_eq!(agent.planner().action(6), 0, "exploit the ice");
        assert!(late > 0.7, "late mean return {late}");
        assert!(agent.n_rebuilds() > 0);
    }

    #[test]
    fn rebuilds_on_contradiction_and_periodically() {
        let c = Arc::new(corridor(5, &[]));
        let params = RlDtParams {
            rebuild_every: 2,
            ..RlDtParams::default()
        };
        let mut agent = RlDt::new(c, params, 0).unwrap();
        agent.observe(2, 1, 1).unwrap(); // empty leaf: contradiction
        assert_eq!(agent.n_rebuilds(), 1);
        agent.observe(2, 1, 1).unwrap(); // agrees: leaf update only
        assert_eq!(agent.n_rebuilds(), 1);
        assert_eq!(
            agent
                .tree(1)
                .unwrap()
                .leaf_counts(agent.tree(1).unwrap().leaf(&[0])),
            &[0, 2, 0]
        );
        agent.observe(3, 1, 1).unwrap(); // second since the rebuild: periodic refit
        assert_eq!(agent.n_rebuilds(), 2);
        agent.observe(3, 1, 2).unwrap(); // contradiction
        assert_eq!(agent.n_rebuilds(), 3);
        let p = agent.effect_table().probs(1, 1);
        assert_eq!(p, &[0.0, 0.75, 0.25]);
        // Action 0 has no data and predicts uniformly.
        assert!((agent.effect_table().probs(0, 1)[0] - 1.0 / 3.0).abs() < 1e-15);
    }

    #[test]
    fn the_example_list_and_per_state_counts_induce_the_same_trees() {
        // Same seeds, two stores: every tree, every effect-table row and every return must be
        // identical, while the list holds one entry per step.
        let c = Arc::new(icy_corridor(12, &[3, 6, 9]));
        let agents: Vec<(RlDt, Vec<f64>)> = [ExampleStore::List, ExampleStore::PerStateCounts]
            .into_iter()
            .map(|examples| {
                let params = RlDtParams {
                    examples,
                    ..RlDtParams::default()
                };
                let mut agent = RlDt::new(c.clone(), params, 5).unwrap();
                let returns = run(&mut agent, &c, 5, 40, 9);
                (agent, returns)
            })
            .collect();
        let (list, counts) = (&agents[0], &agents[1]);
        assert_eq!(list.1, counts.1);
        for a in 0..c.n_actions() {
            assert_eq!(list.0.tree(a), counts.0.tree(a));
            assert!(list.0.tree(a).unwrap().n_leaves() > 1, "action {a} split");
        }
        assert_eq!(list.0.effect_table(), counts.0.effect_table());
        assert_eq!(list.0.n_rebuilds(), counts.0.n_rebuilds());
        let steps: usize = list.0.list.iter().map(Vec::len).sum();
        assert_eq!(steps as u64, list.0.n_examples());
        assert!(counts.0.list.iter().all(Vec::is_empty));
        let merged: usize = counts.0.visited.iter().map(Vec::len).sum();
        assert!(merged < steps / 4, "{merged} states for {steps} steps");
    }

    #[test]
    fn bad_steps_and_settings_are_refused() {
        let c = Arc::new(corridor(5, &[]));
        let mut agent = RlDt::new(c.clone(), RlDtParams::default(), 1).unwrap();
        assert_refuses_bad_steps(&mut agent);
        assert_eq!(agent.n_rebuilds(), 0);
        assert_eq!(agent.n_examples(), 0);
        assert!(agent.list.iter().all(Vec::is_empty));
        let ok = RlDtParams::default();
        for bad in [
            RlDtParams {
                epsilon: -0.1,
                ..ok
            },
            RlDtParams {
                rebuild_every: 0,
                ..ok
            },
            RlDtParams {
                tree: TreeParams {
                    min_leaf: 0,
                    ..TreeParams::default()
                },
                ..ok
            },
        ] {
            assert!(RlDt::new(c.clone(), bad, 0).is_err());
        }
        assert_eq!(agent.name(), "RL-DT");
    }

    #[test]
    fn same_seed_same_behaviour() {
        let c = Arc::new(icy_corridor(8, &[4]));
        let runs: Vec<Vec<f64>> = (0..2)
            .map(|_| {
                let mut agent = RlDt::new(c.clone(), RlDtParams::default(), 3).unwrap();
                run(&mut agent, &c, 4, 15, 5)
            })
            .collect();
        assert_eq!(runs[0], runs[1]);
    }
}
