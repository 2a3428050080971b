//! Count-based model learners: R-max, factored R-max and factored ε-greedy — the paper's
//! classical baselines.
//!
//! All three estimate `P(e | ·, a)` by counting observed effects in a *context*:
//!
//! * **Rmax** — Brafman & Tennenholtz, "R-max – a general polynomial time algorithm for
//!   near-optimal reinforcement learning", JMLR 3 (2002). The context is the state itself
//!   (tabular). A pair `(s, a)` seen fewer than `m` times is *unknown* and valued optimistically
//!   at `R_max / (1 − γ)`, which drives the agent to try it; once known its effect frequencies
//!   are frozen.
//! * **fRmax** — factored R-max (Guestrin, Patrascu & Schuurmans, ICML 2002; Strehl, Diuk &
//!   Littman, AAAI 2007) with the true DBN structure given by an oracle: the context is the
//!   configuration of the features the true dynamics depend on (in the grid tasks, surface ×
//!   walls), so experience generalises across states that share it. Same optimism, with `m`
//!   counted per context.
//! * **fEpsG** — the paper's factored ε-greedy: the same oracle contexts and counts, with the
//!   optimism replaced by ε-greedy exploration; unseen contexts predict all effects equally.

use std::sync::Arc;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{Agent, AgentError, check_step};
use crate::cmdp::CmdpStructure;
use crate::plan::{Optimism, PlannedModel, PlannerParams, ValueIteration};

/// How a counting agent explores.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Exploration {
    /// R-max optimism: a context–action pair is unknown until seen `m` times.
    Rmax {
        /// Visits before a pair is known (paper: 5 for Rmax, 10 for fRmax).
        m: u32,
    },
    /// ε-greedy on the maximum-likelihood model.
    EpsilonGreedy {
        /// Probability of a random action (paper: 0.1 for fEpsG).
        epsilon: f64,
    },
}

/// Which states share counts.
#[derive(Debug, Clone, PartialEq)]
pub struct Contexts {
    /// `of_state[s]`: the context of state `s`.
    of_state: Vec<u32>,
    n_contexts: usize,
    /// States per context, CSR.
    offsets: Vec<usize>,
    members: Vec<u32>,
}

impl Contexts {
    /// Every state its own context (tabular learning).
    pub fn tabular(n_states: usize) -> Self {
        Self::new((0..n_states as u32).collect(), n_states).expect("identity contexts are valid")
    }

    /// Contexts from an oracle: `of_state[s] < n_contexts`.
    pub fn new(of_state: Vec<u32>, n_contexts: usize) -> Option<Self> {
        if of_state.iter().any(|&c| c as usize >= n_contexts) {
            return None;
        }
        let mut counts = vec![0usize; n_contexts + 1];
        for &c in &of_state {
            counts[c as usize + 1] += 1;
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let offsets = counts.clone();
        let mut fill = counts;
        let mut members = vec![0u32; of_state.len()];
        for (s, &c) in of_state.iter().enumerate() {
            members[fill[c as usize]] = s as u32;
            fill[c as usize] += 1;
        }
        Some(Self {
            of_state,
            n_contexts,
            offsets,
            members,
        })
    }

    /// Number of contexts.
    pub fn n_contexts(&self) -> usize {
        self.n_contexts
    }

    fn members(&self, c: usize) -> &[u32] {
        &self.members[self.offsets[c]..self.offsets[c + 1]]
    }
}

/// A count-based model learner with R-max or ε-greedy exploration.
#[derive(Debug, Clone)]
pub struct CountingAgent {
    name: &'static str,
    structure: Arc<CmdpStructure>,
    contexts: Contexts,
    exploration: Exploration,
    /// `counts[(a * C + c) * E + e]`.
    counts: Vec<u32>,
    /// `totals[a * C + c]`.
    totals: Vec<u32>,
    /// R-max only: `unknown[a * S + s]`.
    unknown: Vec<bool>,
    optimistic_value: f64,
    model: PlannedModel,
    rng: ChaCha8Rng,
    scratch: Vec<f64>,
}

impl CountingAgent {
    /// Tabular R-max (paper: m = 5).
    pub fn rmax(
        structure: Arc<CmdpStructure>,
        m: u32,
        planner: PlannerParams,
        seed: u64,
    ) -> Result<Self, AgentError> {
        let contexts = Contexts::tabular(structure.n_states());
        Self::new(
            "Rmax",
            structure,
            contexts,
            Exploration::Rmax { m },
            planner,
            seed,
        )
    }

    /// Factored R-max with oracle contexts (paper: m = 10).
    pub fn factored_rmax(
        structure: Arc<CmdpStructure>,
        contexts: Contexts,
        m: u32,
        planner: PlannerParams,
        seed: u64,
    ) -> Result<Self, AgentError> {
        Self::new(
            "fRmax",
            structure,
            contexts,
            Exploration::Rmax { m },
            planner,
            seed,
        )
    }

    /// Factored ε-greedy with oracle contexts (paper: ε = 0.1).
    pub fn factored_epsilon_greedy(
        structure: Arc<CmdpStructure>,
        contexts: Contexts,
        epsilon: f64,
        planner: PlannerParams,
        seed: u64,
    ) -> Result<Self, AgentError> {
        Self::new(
            "fEpsG",
            structure,
            contexts,
            Exploration::EpsilonGreedy { epsilon },
            planner,
            seed,
        )
    }

    /// A counting agent with any grouping and exploration.
    pub fn new(
        name: &'static str,
        structure: Arc<CmdpStructure>,
        contexts: Contexts,
        exploration: Exploration,
        planner: PlannerParams,
        seed: u64,
    ) -> Result<Self, AgentError> {
        if let Exploration::EpsilonGreedy { epsilon } = exploration
            && !(0.0..=1.0).contains(&epsilon)
        {
            return Err(AgentError::BadEpsilon(epsilon));
        }
        let (s, a, e, c) = (
            structure.n_states(),
            structure.n_actions(),
            structure.n_effects(),
            contexts.n_contexts(),
        );
        let model = PlannedModel::new(structure.clone(), planner)?;
        let r_max = (0..s).map(|i| structure.reward(i)).fold(0.0, f64::max);
        Ok(Self {
            name,
            unknown: vec![matches!(exploration, Exploration::Rmax { .. }); a * s],
            optimistic_value: r_max / (1.0 - planner.gamma),
            model,
            structure,
            contexts,
            exploration,
            counts: vec![0; a * c * e],
            totals: vec![0; a * c],
            rng: ChaCha8Rng::seed_from_u64(seed),
            scratch: vec![0.0; e],
        })
    }

    /// The planner, with the values and policy of the last plan.
    pub fn planner(&self) -> &ValueIteration {
        self.model.planner()
    }

    /// Re-plans if the model moved enough since the last plan (see [`PlannedModel`]).
    pub fn replan(&mut self) {
        match self.exploration {
            Exploration::Rmax { .. } => {
                let optimism = Optimism {
                    unknown: &self.unknown,
                    value: self.optimistic_value,
                };
                self.model.replan_optimistic(optimism)
            }
            Exploration::EpsilonGreedy { .. } => self.model.replan(),
        };
    }
}

impl Agent for CountingAgent {
    fn name(&self) -> &str {
        self.name
    }

    fn act(&mut self, state: usize) -> Result<usize, AgentError> {
        check_step(&self.structure, state, 0, None)?;
        if let Exploration::EpsilonGreedy { epsilon } = self.exploration
            && epsilon > 0.0
            && self.rng.random::<f64>() < epsilon
        {
            return Ok(self.rng.random_range(0..self.structure.n_actions()));
        }
        self.replan();
        Ok(self.model.action(state))
    }

    fn observe(&mut self, state: usize, action: usize, effect: usize) -> Result<(), AgentError> {
        check_step(&self.structure, state, action, Some(effect))?;
        let (n_s, n_e, n_c) = (
            self.structure.n_states(),
            self.structure.n_effects(),
            self.contexts.n_contexts(),
        );
        let c = self.contexts.of_state[state] as usize;
        let pair = action * n_c + c;
        if let Exploration::Rmax { m } = self.exploration
            && self.totals[pair] >= m
        {
            // Known pairs keep the model they had when they became known.
            return Ok(());
        }
        self.counts[pair * n_e + effect] += 1;
        self.totals[pair] += 1;
        let total = self.totals[pair];
        let becomes_known = match self.exploration {
            Exploration::Rmax { m } => total >= m,
            Exploration::EpsilonGreedy { .. } => true,
        };
        if !becomes_known {
            return Ok(());
        }
        for (p, &n) in self
            .scratch
            .iter_mut()
            .zip(&self.counts[pair * n_e..(pair + 1) * n_e])
        {
            *p = f64::from(n) / f64::from(total);
        }
        for &s in self.contexts.members(c) {
            self.model.set(action, s as usize, &self.scratch);
            self.unknown[action * n_s + s as usize] = false;
        }
        if let Exploration::Rmax { .. } = self.exploration {
            // The pair just became known: its optimism is gone, which drift cannot see.
            self.model.invalidate();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cmdp::examples::corridor;

    fn run(agent: &mut CountingAgent, c: &CmdpStructure, episodes: usize) -> f64 {
        let mut world = ChaCha8Rng::seed_from_u64(3);
        let mut late = 0.0;
        for ep in 0..episodes {
            let mut s = 4;
            for _ in 0..100 {
                let a = agent.act(s).unwrap();
                // Intended move w.p. 0.8, else stay.
                let e = if world.random::<f64>() < 0.8 { a } else { 2 };
                agent.observe(s, a, e).unwrap();
                s = c.next_state(s, e);
                if ep + 10 >= episodes {
                    late += c.reward(s);
                }
                if c.is_terminal(s) {
                    break;
                }
            }
        }
        late / 10.0
    }

    #[test]
    fn rmax_learns_a_small_task() {
        let c = Arc::new(corridor(9, &[]));
        let mut agent = CountingAgent::rmax(c.clone(), 5, PlannerParams::default(), 1).unwrap();
        let late = run(&mut agent, &c, 60);
        assert!(late > 0.9, "late return {late}");
        agent.replan();
        assert!((1..8).all(|s| agent.planner().action(s) == 1));
    }

    #[test]
    fn factored_agents_share_counts_across_a_context() {
        let c = Arc::new(corridor(9, &[]));
        // One context for every state: experience anywhere informs everywhere.
        let contexts = Contexts::new(vec![0; 9], 1).unwrap();
        let mut frmax = CountingAgent::factored_rmax(
            c.clone(),
            contexts.clone(),
            10,
            PlannerParams::default(),
            1,
        )
        .unwrap();
        assert!(run(&mut frmax, &c, 40) > 0.9);
        let mut eps = CountingAgent::factored_epsilon_greedy(
            c.clone(),
            contexts,
            0.1,
            PlannerParams::default(),
            1,
        )
        .unwrap();
        assert!(run(&mut eps, &c, 40) > 0.8);
        // After 10 "right" visits anywhere the whole row is known.
        assert!(frmax.unknown[9..].iter().all(|u| !u));
    }

    #[test]
    fn contexts_are_validated_and_bad_steps_refused() {
        assert!(Contexts::new(vec![0, 2], 2).is_none());
        let ctx = Contexts::new(vec![1, 0, 1], 2).unwrap();
        assert_eq!(ctx.members(1), &[0, 2]);
        let c = Arc::new(corridor(5, &[]));
        let mut agent = CountingAgent::rmax(c, 5, PlannerParams::default(), 0).unwrap();
        assert!(agent.observe(1, 7, 0).is_err());
        assert!(agent.totals.iter().all(|&t| t == 0));
    }
}
