//! The TES learning core.
//!
//! * [`mdagl`] — the view learner: online sparse multinomial logistic regression with group
//!   lasso by dual averaging (the paper's Algorithms 4–5), which picks the few features that
//!   predict an action's effect out of hundreds.
//! * [`cmdp`] — the situation-calculus MDP (§3.1): known effect semantics, rewards and
//!   features, and the learned effect probabilities.
//! * [`plan`] — warm-started value iteration on that model.
//! * [`realtime`] — planning on its own thread, so acting never waits for a plan.
//! * [`agents`] — agents that learn and act: loreRL (Algorithm 6), bloreRL, the count-based
//!   baselines Rmax, factored Rmax and factored ε-greedy, and the structure learners RL-DT
//!   (decision trees) and LSE-Rmax.
//! * [`library`] — TES's view library: growing, pruning, and its file store.
//! * [`process`] — the controller process's loop over iceoryx2 (the one module with IPC).
//! * [`labelled_csv`] — the labelled-row format `tes fit` reads.
//!
//! Everything but [`process`] (and the library's file [`library::store`]) is a plain struct
//! with no IPC, clock or I/O inside; the controller process wraps it.

pub mod agents;
pub mod alloc_count;
pub mod cmdp;
pub mod labelled_csv;
pub mod library;
pub mod mdagl;
pub mod plan;
pub mod process;
pub mod realtime;
