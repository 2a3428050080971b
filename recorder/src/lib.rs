//! Recording a TES run to MCAP and replaying it.
//!
//! * [`live::Recorder`] — a subscriber of the group on a thread of its own (the launcher's,
//!   never the controller's acting thread), writing one MCAP file per run: a channel per
//!   service (the world map, every observation, command, keep-alive and motor state), each
//!   message as JSON with a JSON Schema and its publish time, the run's settings, seed and
//!   version as metadata and its starting view library as an attachment ([`writer`]); beside
//!   them, the run drawn in Foxglove's Protobuf schemas for Foxglove and Rerun, and the same
//!   drawings served live when asked ([`live::Outputs`]);
//! * [`reader::Recording`] — the file read back (a truncated one up to its last complete
//!   record), with a clear error for anything that is not a TES recording this build reads;
//! * [`replay::replay`] — the recorded observations fed to the acting loop with the recorded
//!   settings, seed and library, every decision compared with the recorded command;
//! * [`summary`] — the run's episodes and latencies from the file alone, and CSV export.
//!
//! ```
//! use tes_recorder::reader::Recording;
//! use tes_recorder::writer::{RunInfo, RunWriter, RecordCounts};
//! use tes_topics::Observation;
//!
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("run.mcap");
//! let info = RunInfo { tes_version: "0.1.0".into(), ..RunInfo::default() };
//! let mut file = RunWriter::create(&path, &info)?;
//! file.observation(&Observation { seq: 1, stamp_ns: 5, ..Observation::default() })?;
//! file.finish(RecordCounts::default())?;
//! let read = Recording::open(&path)?;
//! assert_eq!(read.observations.len(), 1);
//! assert!(read.truncated.is_none());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod framing;
pub mod live;
mod merge;
pub mod reader;
pub mod replay;
pub mod schema;
pub mod summary;
pub mod writer;
