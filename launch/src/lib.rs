//! The TES process group as a library: perception-sim, controller and bridge started as one
//! group, watched, restarted or stopped, by a [`Supervisor`] that tells what happens as typed
//! [`Event`]s.
//!
//! The three are separate OS processes sharing fixed-size buffers through iceoryx2. What a
//! launch does:
//!
//! * [`mod@file`]: reads an optional TOML launch file (`[launch]`, `[perception]`,
//!   `[controller]`, `[bridge]`) once, into each process's typed settings; sets the
//!   launch-wide values on them where a table does not set its own; checks every child's
//!   settings *before* starting anything (a bad key is reported with the file, its line, the
//!   table and key, and the reason); and writes each child's settings, serialised from those
//!   typed values, into the run folder ([`file::prepare`]);
//! * [`Supervisor`]: removes iceoryx2 resources left by crashed runs, starts the children
//!   (the program and its arguments are the caller's [`ChildCommand`]) with a parent-death
//!   signal, relays their lines, watches the group's progress (a stalled group names the
//!   process holding it up), respawns a failed child or stops the group, and at the end says
//!   what became of the run, the recording and the view library, and its [`Verdict`];
//! * with roles (`[launch] roles`), starts only those children and reaches the others, in
//!   launches on other hosts, through the Zenoh link ([`tes_link`]).
//!
//! Everything a launch has to say is an [`Event`]: the command line prints them, its live
//! view draws them, a test collects them.
//!
//! ```no_run
//! use std::sync::Arc;
//! use std::sync::atomic::AtomicBool;
//! use tes_launch::{ChildCommand, Event, LaunchFile, Options, Supervisor};
//!
//! let file = LaunchFile::default();
//! let stop = Arc::new(AtomicBool::new(false));
//! let options = Options::new(ChildCommand::new("tes").arg("child"), stop);
//! let mut episodes = 0;
//! let verdict = tes_launch::run(&file, options, &mut |event: &Event| {
//!     if let Event::EpisodeEnded { text, .. } = event {
//!         episodes += 1;
//!         println!("{text}");
//!     }
//! })?;
//! println!("{} episodes, failures: {:?}", verdict.episodes, verdict.failures);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod children;
pub mod event;
pub mod file;
pub mod library;
pub mod logs;
pub mod recording;
pub mod reference;
pub mod role;
pub mod ros2;
pub mod run_folder;
pub mod run_record;
pub mod status;
pub mod supervisor;
pub mod world;

pub use children::{ChildCommand, ChildSpec};
pub use event::{Event, ExitConsequence, Observer, Verdict};
pub use file::{LaunchFile, LaunchFileError, LaunchSection, Restart, prepare, read_launch_file};
pub use role::{RoleError, run_role};
pub use status::{GroupStatus, Status, StatusError};
pub use supervisor::{LaunchError, Options, Step, Supervisor, run};

/// A file or directory operation of a launch that failed, said with what it was doing.
#[derive(Debug, thiserror::Error)]
#[error("{what}")]
pub struct IoError {
    /// What the launch was doing ("cannot create …/episodes.csv").
    pub what: String,
    /// Why.
    #[source]
    pub source: std::io::Error,
}

impl IoError {
    /// A `map_err` adapter: the I/O error, said as `what`.
    pub fn with(what: String) -> impl FnOnce(std::io::Error) -> Self {
        move |source| Self { what, source }
    }

    /// Any other error, said as `what` (its text becomes the source's).
    pub fn other(what: String, error: impl std::fmt::Display) -> Self {
        Self {
            what,
            source: std::io::Error::other(error.to_string()),
        }
    }
}
