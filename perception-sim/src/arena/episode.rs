//! An episode on an arena: rewards, terminal states, and getting stuck.

use super::*;

/// How an episode stands after an action.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EpisodeStatus {
    /// The episode goes on.
    Continuing,
    /// A terminal state was entered (the ball, a death spot or the out state).
    Terminal,
    /// The state did not change for [`STUCK_ACTIONS`] consecutive actions.
    Stuck,
}

/// What one action meant for the episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeStep {
    /// The reward for entering the new state.
    pub reward: f64,
    /// Whether the episode goes on.
    pub status: EpisodeStatus,
}

/// Tracks one episode's states: rewards, terminal states and the stuck rule (the episode also
/// ends after [`STUCK_ACTIONS`] consecutive actions that did not change the state).
///
/// ```
/// use tes_perception_sim::arena::{Arena, ArenaId, Episode, EpisodeStatus, StateAttributes};
///
/// let arena = Arena::new(ArenaId::Env2);
/// let start = arena
///     .state_index(StateAttributes::at(0, 3, 0))
///     .ok_or("no such state")?;
/// let mut episode = Episode::new(&arena, start)?;
/// for _ in 0..3 {
///     assert_eq!(episode.observe(&arena, start)?.status, EpisodeStatus::Continuing);
/// }
/// assert_eq!(episode.observe(&arena, start)?.status, EpisodeStatus::Stuck);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct Episode {
    state: usize,
    unchanged: usize,
    actions: usize,
    total_reward: f64,
    status: EpisodeStatus,
}

impl Episode {
    /// Starts an episode in `start` (an episode started in a terminal state is over at once).
    pub fn new(arena: &Arena, start: usize) -> Result<Self, ArenaError> {
        if start >= arena.n_states() {
            return Err(ArenaError::BadState {
                state: start,
                states: arena.n_states(),
            });
        }
        Ok(Self {
            state: start,
            unchanged: 0,
            actions: 0,
            total_reward: 0.0,
            status: if arena.is_terminal(start) {
                EpisodeStatus::Terminal
            } else {
                EpisodeStatus::Continuing
            },
        })
    }

    /// Records that the last action led to `next`: its reward and whether the episode ends
    /// (a terminal state wins over being stuck).
    pub fn observe(&mut self, arena: &Arena, next: usize) -> Result<EpisodeStep, ArenaError> {
        if next >= arena.n_states() {
            return Err(ArenaError::BadState {
                state: next,
                states: arena.n_states(),
            });
        }
        if self.status != EpisodeStatus::Continuing {
            return Err(ArenaError::EpisodeOver);
        }
        let reward = arena.reward(next);
        self.unchanged = if next == self.state {
            self.unchanged + 1
        } else {
            0
        };
        self.state = next;
        self.actions += 1;
        self.total_reward += reward;
        self.status = if arena.is_terminal(next) {
            EpisodeStatus::Terminal
        } else if self.unchanged >= STUCK_ACTIONS {
            EpisodeStatus::Stuck
        } else {
            EpisodeStatus::Continuing
        };
        Ok(EpisodeStep {
            reward,
            status: self.status,
        })
    }

    /// The current state.
    pub fn state(&self) -> usize {
        self.state
    }

    /// Actions observed so far.
    pub fn actions(&self) -> usize {
        self.actions
    }

    /// Sum of the rewards so far.
    pub fn total_reward(&self) -> f64 {
        self.total_reward
    }

    /// Consecutive actions, up to now, that left the state unchanged.
    pub fn unchanged_streak(&self) -> usize {
        self.unchanged
    }

    /// How the episode stands.
    pub fn status(&self) -> EpisodeStatus {
        self.status
    }

    /// Whether the episode has ended (terminal or stuck).
    pub fn is_over(&self) -> bool {
        self.status != EpisodeStatus::Continuing
    }
}
