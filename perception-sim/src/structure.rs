//! The worlds as an agent is told them: each world's CMDP structure (states, actions, effects,
//! the successor of each effect, rewards, terminal states, each state's features) and the
//! contexts of the true dynamics the factored baselines count by. Built here once, for the
//! experiments and for the Python package alike (the `structure` feature, over
//! `tes-learning`; off, the crate needs no learning code).
//!
//! ```
//! use tes_perception_sim::arena::{Arena, ArenaId, MAN_FEATURES};
//! use tes_perception_sim::grid::GridSuite;
//! use tes_perception_sim::structure::{self, ArenaFeatures};
//!
//! let arena = Arena::new(ArenaId::Env3);
//! let manual = structure::arena(&arena, ArenaFeatures::HandPicked)?;
//! assert_eq!(manual.n_features(), MAN_FEATURES.len());
//!
//! let task = GridSuite::paper(2017, 0).swap_remove(1);
//! let cmdp = structure::grid(&task)?;
//! let (of_state, n_contexts) = structure::grid_contexts(&task);
//! assert_eq!(of_state.len(), cmdp.n_states());
//! assert!(of_state.iter().all(|&c| (c as usize) < n_contexts));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use tes_learning::cmdp::{CmdpError, CmdpStructure};

use crate::arena::{Arena, MAN_FEATURES};
use crate::grid::GridTask;

/// The agent-known CMDP structure of a grid task (its every feature, relevant or not).
pub fn grid(task: &GridTask) -> Result<CmdpStructure, CmdpError> {
    let reward = (0..task.n_states()).map(|s| task.reward(s)).collect();
    let terminal = (0..task.n_states()).map(|s| task.is_terminal(s)).collect();
    CmdpStructure::new(
        task.n_states(),
        task.n_actions(),
        task.n_effects(),
        task.n_features(),
        |s, e| task.apply_effect(s, e),
        reward,
        terminal,
        |s| task.features(s),
    )
}

/// Each state's context of a grid task's true dynamics (surface × walls), and how many there
/// are: the factors fRmax and fEpsG are told.
pub fn grid_contexts(task: &GridTask) -> (Vec<u32>, usize) {
    let of_state = (0..task.n_states())
        .map(|s| task.oracle_context(s) as u32)
        .collect();
    (of_state, task.n_oracle_contexts())
}

/// Which features an arena's structure gives each state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArenaFeatures {
    /// All 312 (loreRL and the transfer agents).
    All,
    /// The 12 hand-picked ones of man-loreRL ([`MAN_FEATURES`]).
    HandPicked,
}

/// The agent-known CMDP structure of an arena, with `features`.
pub fn arena(arena: &Arena, features: ArenaFeatures) -> Result<CmdpStructure, CmdpError> {
    match features {
        ArenaFeatures::All => arena_with(arena, arena.n_features(), |s| arena.features(s)),
        ArenaFeatures::HandPicked => {
            arena_with(arena, MAN_FEATURES.len(), |s| arena.man_features(s))
        }
    }
}

/// An arena's structure with `n_features` features, `features(s)` those on in state `s`.
fn arena_with<'a>(
    arena: &Arena,
    n_features: usize,
    features: impl Fn(usize) -> &'a [u32],
) -> Result<CmdpStructure, CmdpError> {
    CmdpStructure::new(
        arena.n_states(),
        arena.n_actions(),
        arena.n_effects(),
        n_features,
        |s, e| arena.apply_effect(s, e),
        arena.rewards().to_vec(),
        arena.terminals().to_vec(),
        features,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arena::ArenaId;
    use crate::grid::GridSuite;

    #[test]
    fn a_grid_structure_says_what_its_task_does() {
        let task = GridSuite::paper(2017, 20).swap_remove(1);
        let cmdp = grid(&task).expect("a grid task forms a CMDP");
        assert_eq!(
            (cmdp.n_states(), cmdp.n_actions(), cmdp.n_effects()),
            (task.n_states(), task.n_actions(), task.n_effects())
        );
        assert_eq!(cmdp.n_features(), task.n_features());
        for s in 0..task.n_states() {
            assert_eq!(cmdp.features(s), task.features(s));
            assert_eq!(cmdp.is_terminal(s), task.is_terminal(s));
            for e in 0..task.n_effects() {
                assert_eq!(cmdp.next_state(s, e), task.apply_effect(s, e));
            }
        }
        let (of_state, n) = grid_contexts(&task);
        assert_eq!(n, task.n_oracle_contexts());
        assert!(of_state.iter().all(|&c| (c as usize) < n));
    }

    #[test]
    fn an_arena_structure_has_all_or_the_hand_picked_features() {
        let arena_3 = Arena::new(ArenaId::Env3);
        let all = arena(&arena_3, ArenaFeatures::All).expect("a CMDP");
        let manual = arena(&arena_3, ArenaFeatures::HandPicked).expect("a CMDP");
        assert_eq!(all.n_features(), arena_3.n_features());
        assert_eq!(manual.n_features(), MAN_FEATURES.len());
        for s in 0..arena_3.n_states() {
            assert_eq!(all.features(s), arena_3.features(s));
            assert_eq!(manual.features(s), arena_3.man_features(s));
            assert_eq!(all.reward(s), arena_3.rewards()[s]);
            assert_eq!(manual.next_state(s, 0), arena_3.apply_effect(s, 0));
        }
    }
}
