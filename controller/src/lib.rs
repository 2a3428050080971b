//! The TES learning core.
//!
//! * [`mdagl`] — the view learner: online sparse multinomial logistic regression with group
//!   lasso by dual averaging (the paper's Algorithms 4–5), which picks the few features that
//!   predict an action's effect out of hundreds.
//! * [`labelled_csv`] — the labelled-row format `tes fit` reads.
//!
//! The model, planner, agents and the controller process are built on top of these.

pub mod labelled_csv;
pub mod mdagl;
