//! The controller process: the central processor of the paper's Fig. 7.
//!
//! The learning itself (mDAGL, the CMDP model, the planner, TES) is `tes-learning`; this crate
//! is what runs it in real time between perception and the bridge:
//!
//! * [`realtime`] — the planner hand-over: planning on its own thread, or in slices between
//!   the acting loop's polls, so acting never waits for a plan;
//! * [`acting`] — the acting loop: observation → effect → score and update → action →
//!   command, as a plain struct with the clock passed in;
//! * [`config`] — its settings, checked once;
//! * [`saver`] — the library saved atomically off the acting thread;
//! * [`summary`] — the per-episode lines and the run's summary;
//! * [`process`] — the controller process's loop over iceoryx2.

pub mod acting;
pub mod config;
pub mod process;
pub mod realtime;
pub mod saver;
pub mod summary;
