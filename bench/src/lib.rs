//! TES's benchmarks: the criterion benches under `benches/` (the view learner, the learning
//! path, the NXT codec) and the harnesses behind `tes bench`, usable without the command line:
//!
//! * [`latency`] — the controller's per-action latency, the real process group measured
//!   against its floor in the same run (`tes bench latency`): the measured group, its
//!   [`floor`] (by [`relay`] over shared memory, or over the Zenoh link), and with `record`
//!   the [`recorder_cost`]; at the fastest pace the floor is measured again with every CPU
//!   kept out of its idle state ([`keep_awake`]);
//! * [`scaling`] — the acting step's cost against the number of features and views
//!   (`tes bench scaling`);
//! * [`fixtures`] — the learned arena libraries the harnesses and the benches run on.
//!
//! Every process a harness starts is a program its caller names ([`latency::Programs`]): the
//! `tes` command line passes its own executable in each role.

pub mod error;
pub mod fixtures;
pub mod floor;
mod group;
pub mod harness;
pub mod keep_awake;
pub mod latency;
pub mod recorder_cost;
pub mod relay;
pub mod rerun_client;
pub mod scaling;
pub mod table;
pub mod viewer_client;

pub use error::{BenchError, GroupFailure};
pub use latency::{
    CheckedLatency, Harness, LatencyResult, LatencySettings, Note, Pace, Programs, Via,
};
