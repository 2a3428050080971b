//! Simulated worlds for TES: what the agent acts in, and what its camera sees.
//!
//! * [`grid`] — the paper's §5.1 grid tasks: surfaces, walls, hundreds of irrelevant binary
//!   features, logistic true dynamics, and the 15-task suite the transfer experiments use.
//! * [`arena`] — the paper's §5.2 robot arenas (Env 1–3): a differential-drive robot with
//!   surface-dependent wheel slip, 8 orientations, 20 effects and the 312 camera features.
//! * `process` — the perception-sim process: an arena and its camera over iceoryx2 (the
//!   default `process` feature; without it the crate is the worlds alone, with no IPC).
//! * `structure` — each world's CMDP structure as an agent is told it, and the contexts of its
//!   true dynamics (the `structure` feature, over `tes-learning`): the one builder the
//!   experiments and the Python package share.
//!
//! Every world is seeded and reproducible; per-step methods allocate nothing.
//!
//! ```
//! use rand::SeedableRng;
//! use tes_perception_sim::grid::GridTask;
//!
//! // A hand-drawn 3×3 task: sand, one water cell, fire in a corner, the exit opposite.
//! let task = GridTask::from_map("..F\n.~.\nE..", 0, 0, 1)?;
//! let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
//! let start = task.random_start(&mut rng);
//! let outcome = task.step(start, 2, &mut rng); // try to move south
//! assert!(outcome.next_state < task.n_states());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod arena;
pub mod grid;
#[cfg(feature = "process")]
pub mod process;
#[cfg(feature = "structure")]
pub mod structure;
