//! The launch's side of a recording (`[launch] record`, `tes launch --record`): the recorder
//! subscribes to the group's services before any child starts and is stopped after they all
//! have; what it wrote is one of the supervisor's events.

use std::path::{Path, PathBuf};

use tes_recorder::live::{Outputs, RecordError, Recorder};
use tes_recorder::writer::RecordCounts;
use tes_recorder::writer::RunInfo;
use tes_topics::Role;
use tes_viewer::scene::SceneSettings;

use crate::children::ChildSpec;
use crate::file::LaunchFile;

/// A recording that cannot be started, or did not end whole.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// A file the recording's metadata holds cannot be read.
    #[error("cannot read {what} {} to record it; nothing was started", path.display())]
    Read {
        /// What the file is.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// `[launch] foxglove` is not an address.
    #[error(transparent)]
    Setting(tes_runtime::settings::SettingError),
    /// The recorder cannot start.
    #[error("cannot start {target}; nothing was started")]
    Start {
        /// The recording's file, or the live server's address.
        target: String,
        /// Why.
        #[source]
        source: RecordError,
    },
    /// The recorder failed on the way.
    #[error("the recording {target} is incomplete")]
    Incomplete {
        /// The recording's file (or the live view).
        target: String,
        /// Why.
        #[source]
        source: RecordError,
    },
}

/// What a finished recording holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Recorded {
    /// The file.
    pub path: PathBuf,
    /// Its messages, per kind, and what the recorder missed.
    pub counts: RecordCounts,
}

impl std::fmt::Display for Recorded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.counts;
        let [_maps, observations, commands, keepalives, motor] = c.written;
        write!(
            f,
            "recorded {observations} observations, {commands} commands, {keepalives} \
             keep-alives and {motor} motor states to {}",
            self.path.display()
        )?;
        if c.missed_observations + c.missed_commands + c.missed_motor_states > 0 {
            write!(
                f,
                " (missed {} observations, {} commands, {} motor states)",
                c.missed_observations, c.missed_commands, c.missed_motor_states
            )?;
        }
        Ok(())
    }
}

/// Starts the recorder of a launch if its file asks for one: subscribed to the group's
/// services (prefix `prefix`) before any child starts; the run's settings, seed and starting
/// library go into the file's metadata.
pub fn start(
    file: &LaunchFile,
    specs: &[ChildSpec],
    prefix: &str,
    library: &Path,
) -> Result<Option<Recorder>, RecordingError> {
    let foxglove = file
        .launch
        .foxglove_addr()
        .map_err(RecordingError::Setting)?;
    if file.launch.record.is_none() && foxglove.is_none() {
        return Ok(None);
    }
    let controller_toml = match specs.iter().find(|s| s.role == Role::Controller) {
        Some(spec) => {
            std::fs::read_to_string(&spec.config).map_err(|source| RecordingError::Read {
                what: "the controller's settings",
                path: spec.config.clone(),
                source,
            })?
        }
        None => String::new(),
    };
    let library_bytes = match std::fs::read(library) {
        Ok(bytes) => Some(bytes),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(source) => {
            return Err(RecordingError::Read {
                what: "the view library",
                path: library.to_owned(),
                source,
            });
        }
    };
    let info = run_info(file, prefix, controller_toml, library, library_bytes);
    let scene = SceneSettings {
        wall_offset_ns: info.wall_offset_ns,
        wheel_ports: [file.perception.left_port, file.perception.right_port],
    };
    let outputs = Outputs {
        file: file.launch.record.clone().map(|path| (path, info)),
        foxglove,
        scene,
    };
    let target = match (&file.launch.record, foxglove) {
        (Some(path), Some(addr)) => format!(
            "recording to {} and the live Foxglove server on {addr}",
            path.display()
        ),
        (Some(path), None) => format!("recording to {}", path.display()),
        (None, Some(addr)) => format!("the live Foxglove server on {addr}"),
        (None, None) => String::new(),
    };
    Recorder::start_with(prefix, outputs)
        .map(Some)
        .map_err(|source| RecordingError::Start { target, source })
}

/// The recording's metadata: what a replay needs to run the controller again.
fn run_info(
    file: &LaunchFile,
    prefix: &str,
    controller_toml: String,
    library: &Path,
    library_bytes: Option<Vec<u8>>,
) -> RunInfo {
    let wall_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i128);
    RunInfo {
        tes_version: env!("CARGO_PKG_VERSION").to_owned(),
        seed: file.launch.seed,
        service_prefix: prefix.to_owned(),
        controller_toml,
        launch_toml: toml::to_string(&file.launch).unwrap_or_default(),
        library_path: library.display().to_string(),
        library: library_bytes,
        wall_offset_ns: wall_ns - i128::from(tes_runtime::clock::monotonic_ns()),
    }
}

/// Finishes a launch's recording (the group has stopped).
pub fn finish(recorder: Recorder) -> Result<Option<Recorded>, RecordingError> {
    let path = recorder.path().map(Path::to_owned);
    match (recorder.stop(), path) {
        (Ok(counts), Some(path)) => Ok(Some(Recorded { path, counts })),
        (Ok(_), None) => Ok(None),
        (Err(source), path) => Err(RecordingError::Incomplete {
            target: path.map_or_else(|| "the live view".into(), |p| p.display().to_string()),
            source,
        }),
    }
}
