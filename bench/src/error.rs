//! What can go wrong in `tes bench`'s harnesses: one error for the latency run, its floors and
//! the recorder's cost, each said as the command line has always said it.

use std::path::PathBuf;

use tes_launch::IoError;

/// A harness run that failed.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// Settings that cannot run, said with the flag that sets them.
    #[error("{0}")]
    Settings(String),
    /// A run that did not measure what it should have (too few commands, a lost round trip,
    /// a process that failed or did not stop).
    #[error("{0}")]
    Run(String),
    /// A file or process operation, said with what it was doing.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A launch of the group failed (`what`: "the process group failed").
    #[error("{what}")]
    Group {
        /// Which launch.
        what: &'static str,
        /// Why (boxed: a launch error is large, and every bench result carries this type).
        #[source]
        cause: Box<GroupFailure>,
    },
    /// The starting view library cannot be trained.
    #[error(transparent)]
    Fixture(Box<dyn std::error::Error + Send + Sync>),
    /// The starting view library cannot be saved.
    #[error(transparent)]
    Library(#[from] tes_learning::library::store::StoreError),
    /// The controller's summary cannot be read.
    #[error("the controller's report is malformed")]
    Malformed(#[source] serde_json::Error),
    /// The split run's second launch file cannot be written.
    #[error(transparent)]
    Render(#[from] tes_launch::reference::ReferenceError),
    /// One side of the Zenoh floor's link cannot open.
    #[error("the floor's {side} side")]
    Link {
        /// `robot` or `controller`.
        side: &'static str,
        /// Why.
        #[source]
        cause: tes_link::LinkError,
    },
    /// The arena's world map cannot be built.
    #[error(transparent)]
    Map(#[from] tes_perception_sim::process::PerceptionError),
    /// iceoryx2 refused something.
    #[error(transparent)]
    Ipc(#[from] tes_runtime::channel::IpcError),
    /// A thread cannot be pinned.
    #[error(transparent)]
    Affinity(#[from] tes_runtime::affinity::AffinityError),
    /// The relay's settings are refused.
    #[error(transparent)]
    Relay(#[from] tes_runtime::settings::SettingError),
    /// The relay's settings cannot be written.
    #[error(transparent)]
    Toml(#[from] toml::ser::Error),
    /// A relay process cannot be started.
    #[error(transparent)]
    Spawn(#[from] tes_launch::children::SpawnError),
    /// A block's recording cannot be read.
    #[error(transparent)]
    Recording(#[from] tes_recorder::reader::ReadError),
    /// A JSON output cannot be written.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A failure of the Zenoh floor's robot side, pointing at its other side's log.
    #[error("see also {}", log.display())]
    SeeAlso {
        /// The controller side's log.
        log: PathBuf,
        /// Why.
        #[source]
        cause: Box<BenchError>,
    },
}

/// Why a launch of the group failed.
#[derive(Debug, thiserror::Error)]
pub enum GroupFailure {
    /// The launcher stopped with an error.
    #[error(transparent)]
    Launch(#[from] tes_launch::LaunchError),
    /// The group ran, and these failed.
    #[error("a process failed: {}", .0.join("; "))]
    Failed(Vec<String>),
}

impl BenchError {
    /// An I/O error, said as `what`.
    pub(crate) fn io(what: String) -> impl FnOnce(std::io::Error) -> Self {
        move |source| Self::Io(IoError { what, source })
    }

    /// The starting library's training failed.
    pub(crate) fn fixture(e: anyhow::Error) -> Self {
        Self::Fixture(e.into())
    }
}

/// The harness's results.
pub type Result<T, E = BenchError> = std::result::Result<T, E>;
