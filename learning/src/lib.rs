//! The TES learning core: what the agent learns and how it decides, with no IPC or process
//! code inside and no decision that reads a clock (only [`prequential`] times its own work, for
//! the throughput it reports); the controller process, the experiments and `tes fit` all
//! build on it.
//!
//! * [`mdagl`] — the view learner: online sparse multinomial logistic regression with group
//!   lasso by dual averaging (the paper's Algorithms 4–5), which picks the few features that
//!   predict an action's effect out of hundreds.
//! * [`cmdp`] — the situation-calculus MDP (§3.1): known effect semantics, rewards and
//!   features, and the learned effect probabilities.
//! * [`plan`] — warm-started value iteration on that model, inline or handed to a planner
//!   elsewhere.
//! * [`agents`] — agents that learn and act: loreRL (Algorithm 6), TES and LWT (Algorithms
//!   2–3), bloreRL, the count-based baselines Rmax, factored Rmax and factored ε-greedy, and
//!   the structure learners RL-DT (decision trees) and LSE-Rmax.
//! * [`library`] — TES's view library: growing, pruning, and its versioned file store.
//! * [`labelled_csv`] and [`labelled_sparse`] — the labelled-row formats `tes fit` reads:
//!   CSV (`label,x1,…`, with or without a header) and libsvm / Vowpal Wabbit rows
//!   (`label column:value …`).
//! * [`prequential`] — `tes fit` without the command line: mDAGL over a labelled stream.
//! * [`tuning`] — mDAGL without hand-tuning: a grid of (λ, α) raced on one stream.
//!
//! Each module's documentation opens with a runnable example ([`mdagl`]: a view finding the
//! relevant features of a synthetic stream; [`plan`]: planning on a learned model).

pub mod agents;
pub mod cmdp;
pub mod labelled_csv;
pub mod labelled_sparse;
pub mod library;
pub mod mdagl;
pub mod plan;
pub mod prequential;
pub mod tuning;
