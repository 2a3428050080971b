//! What the TES processes share at run time, apart from their messages (those are in
//! `tes-topics`):
//!
//! * [`channel`] — one-way channels over iceoryx2 publish–subscribe plus an event to wake the
//!   receiver ([`channel::Outbox`], [`channel::Inbox`]); [`board`] — latest-value channels over
//!   a blackboard, which allocate nothing per message ([`board::LatestOutbox`],
//!   [`board::LatestInbox`]);
//! * [`wait`] — how a receiver waits: block, spin, spin then block, or anticipate the next
//!   message ([`anticipate`]);
//! * [`cpu`] — a process's or thread's CPU time per action and share of a core;
//! * [`ipc`] — the node, the service settings every opener must share, stale-resource clean-up;
//! * [`affinity`] — CPU placement of threads; [`memory`] — keeping a process's pages resident;
//!   [`background`] — background threads at the lowest priority, raised back when a run needs them;
//! * [`latency`] — latency histograms against a budget;
//! * [`settings`] — the one error type for a bad settings key, and the TOML parsing every
//!   process shares;
//! * [`clock`], [`signals`], [`logging`] — the monotonic stamp, SIGINT/SIGTERM as a stop flag,
//!   `tracing` set-up;
//! * [`alloc_count`] — a counting global allocator, to prove a loop allocates nothing;
//! * [`cause`] — an operating-system error said as its cause (disk full, read-only, out of
//!   descriptors, missing device);
//! * [`progress`] — each process's progress report, and who holds a stalled group up;
//! * [`lock`] — one owner at a time for a data directory or a library (a `flock` naming its pid);
//! * `test_support` (feature `test-support`) — what tests of several crates share.

pub mod affinity;
pub mod alloc_count;
pub mod anticipate;
pub mod background;
pub mod board;
pub mod cause;
pub mod channel;
pub mod clock;
pub mod cpu;
pub mod ipc;
pub mod latency;
pub mod lock;
pub mod logging;
pub mod memory;
pub mod progress;
mod receive;
pub mod ring;
pub mod settings;
pub mod signals;
#[cfg(feature = "test-support")]
pub mod test_support;
pub mod wait;
