//! The controller process: the central processor of the paper's Fig. 7.
//!
//! The learning itself (mDAGL, the CMDP model, the planner, TES) is `tes-learning`; this crate
//! is what runs it in real time between perception and the bridge:
//!
//! * [`realtime`] — the planner hand-over: planning on its own thread, or in slices between
//!   the acting loop's polls, so acting never waits for a plan;
//! * [`config`] — its settings, checked once;
//! * [`process`] — the controller process's loop over iceoryx2.

pub mod config;
pub mod process;
pub mod realtime;
