//! TES's benchmarks: the criterion benches under `benches/` (the view learner, the learning
//! path, the NXT codec) and the harnesses behind `tes bench`:
//!
//! * [`relay`] — the floor: a bare iceoryx2 two-hop relay of the group's payloads, measured in
//!   the same run as the group (`tes bench latency`);
//! * [`scaling`] — the acting step's cost against the number of features and views
//!   (`tes bench scaling`);
//! * [`fixtures`] — the learned arena libraries both of them, and the benches, run on.

pub mod fixtures;
pub mod relay;
pub mod scaling;
