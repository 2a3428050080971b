//! Agents that learn a CMDP's transition model online and act on it.
//!
//! Every agent speaks the same small protocol, so worlds, experiments and the controller
//! process can drive any of them: [`Agent::act`] in a state, then [`Agent::observe`] the
//! effect that action had.

use thiserror::Error;

use crate::mdagl::{MdaglConfigError, MdaglError};
use crate::plan::PlanError;

mod counting;
mod decision_tree;
mod lore_rl;
mod lse_rmax;
mod rl_dt;
mod tes;

pub use counting::{Contexts, CountingAgent, Exploration};
pub use decision_tree::{DecisionTree, Example, LeafId, TreeError, TreeParams};
pub use lore_rl::{LoreRl, LoreRlParams};
pub use lse_rmax::{LseRmax, LseRmaxParams};
pub use rl_dt::{ExampleStore, RlDt, RlDtParams};
pub use tes::{Origin, Tes, TesParams, ViewPolicy, WorkingView};

/// Why an agent could not be built or could not learn from a step. On a step error the agent
/// is unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum AgentError {
    /// A state id beyond the CMDP's states.
    #[error("state {state} is out of range ({states} states)")]
    UnknownState {
        /// The id.
        state: usize,
        /// Number of states.
        states: usize,
    },
    /// An action id beyond the CMDP's actions.
    #[error("action {action} is out of range ({actions} actions)")]
    UnknownAction {
        /// The id.
        action: usize,
        /// Number of actions.
        actions: usize,
    },
    /// An effect id beyond the CMDP's effects.
    #[error("effect {effect} is out of range ({effects} effects)")]
    UnknownEffect {
        /// The id.
        effect: usize,
        /// Number of effects.
        effects: usize,
    },
    /// ε outside [0, 1].
    #[error("epsilon must be in [0, 1], got {0}")]
    BadEpsilon(f64),
    /// Another setting is out of range.
    #[error("{param} must be {requirement}")]
    Invalid {
        /// The setting.
        param: &'static str,
        /// What it must be.
        requirement: &'static str,
    },
    /// The view settings are invalid.
    #[error("view settings: {0}")]
    View(#[from] MdaglConfigError),
    /// The planner settings are invalid.
    #[error("planner settings: {0}")]
    Planner(#[from] PlanError),
    /// The view library does not fit the task.
    #[error(
        "the view library holds views of {actions} actions, {effects} effects and {features} \
         features, which does not fit this task"
    )]
    LibraryShape {
        /// The library's actions.
        actions: usize,
        /// Its effects.
        effects: usize,
        /// Its features.
        features: usize,
    },
    /// Views given to start from do not fit the task.
    #[error(
        "{views} views do not fit a task of {actions} actions, {effects} effects and \
         {features} features: it needs one view per action, of its effects and features"
    )]
    ViewsShape {
        /// Views given.
        views: usize,
        /// The task's actions.
        actions: usize,
        /// Its effects.
        effects: usize,
        /// Its features.
        features: usize,
    },
    /// A view refused the step.
    #[error("view update: {0}")]
    Update(#[from] MdaglError),
}

/// An online model-based RL agent on a known CMDP structure.
pub trait Agent {
    /// Short name for reports ("loreRL", "fRmax", …).
    fn name(&self) -> &str;

    /// Called when an episode starts in `state`.
    fn begin_episode(&mut self, _state: usize) {}

    /// The action to take in `state`.
    fn act(&mut self, state: usize) -> Result<usize, AgentError>;

    /// Learns that `action` in `state` had `effect`.
    fn observe(&mut self, state: usize, action: usize, effect: usize) -> Result<(), AgentError>;
}

/// Checks a step's ids against a CMDP's sizes.
pub(crate) fn check_step(
    structure: &crate::cmdp::CmdpStructure,
    state: usize,
    action: usize,
    effect: Option<usize>,
) -> Result<(), AgentError> {
    if state >= structure.n_states() {
        return Err(AgentError::UnknownState {
            state,
            states: structure.n_states(),
        });
    }
    if action >= structure.n_actions() {
        return Err(AgentError::UnknownAction {
            action,
            actions: structure.n_actions(),
        });
    }
    if let Some(effect) = effect
        && effect >= structure.n_effects()
    {
        return Err(AgentError::UnknownEffect {
            effect,
            effects: structure.n_effects(),
        });
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Every agent refuses out-of-range ids on a 5-state, 2-action, 3-effect CMDP (the
    /// corridor of `cmdp::tests`). Callers then check that nothing changed.
    pub(crate) fn assert_refuses_bad_steps(agent: &mut dyn Agent) {
        assert!(matches!(
            agent.observe(9, 0, 0),
            Err(AgentError::UnknownState { .. })
        ));
        assert!(matches!(
            agent.observe(1, 2, 0),
            Err(AgentError::UnknownAction { .. })
        ));
        assert!(matches!(
            agent.observe(1, 0, 3),
            Err(AgentError::UnknownEffect { .. })
        ));
        assert!(agent.act(5).is_err());
    }
}
