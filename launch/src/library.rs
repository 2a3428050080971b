//! What a launch says of the view library: where it is at the start, and at the end the
//! controller's report of what it loaded and saved — or, when the controller could not
//! report, what the file is now against what it was.

use std::path::{Path, PathBuf};

use tes_controller::config::ControllerConfig;
use tes_controller::summary::ControllerSummary;
use tes_runtime::settings::Origin;

use crate::IoError;
use crate::children::ChildSpec;

/// The controller's report in the run directory, when the launch file sets none.
pub const CONTROLLER_REPORT: &str = "controller-report.json";

/// Where the controller of `spec` writes its summary (as JSON) at exit: the `report` its
/// settings set, else [`CONTROLLER_REPORT`] in `run_dir`, which is then added to its
/// settings file.
pub fn controller_report(spec: &ChildSpec, run_dir: &Path) -> Result<PathBuf, IoError> {
    let shown = spec.config.display();
    let text = std::fs::read_to_string(&spec.config)
        .map_err(IoError::with(format!("cannot read {shown}")))?;
    let mut config = ControllerConfig::from_toml_in(&text, Origin::File(spec.config.clone()))
        .map_err(|e| IoError::other(format!("cannot read {shown}"), e))?;
    if let Some(path) = &config.report {
        return Ok(path.clone());
    }
    let path = run_dir.join(CONTROLLER_REPORT);
    config.report = Some(path.clone());
    let text = toml::to_string(&config)
        .map_err(|e| IoError::other("cannot write the controller's settings".into(), e))?;
    std::fs::write(&spec.config, text).map_err(IoError::with(format!("cannot write {shown}")))?;
    Ok(path)
}

/// The controller's summary in its report at `report`, if there is one that reads.
pub fn read_report(report: Option<&Path>) -> Option<ControllerSummary> {
    let text = std::fs::read_to_string(report?).ok()?;
    serde_json::from_str(&text).ok()
}

/// Removes a previous run's report at `path` (it would say what that run did); `whose` names
/// it in the error (`controller`, `bridge`).
pub fn remove_stale_report(path: &Path, whose: &str) -> Result<(), IoError> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(IoError {
            what: format!(
                "cannot remove the previous {whose} report {}",
                path.display()
            ),
            source: e,
        }),
        _ => Ok(()),
    }
}

/// Which file is at a path: its inode, length and modification time (an atomic save
/// replaces the inode).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fingerprint {
    inode: u64,
    len: u64,
    modified: Option<std::time::SystemTime>,
}

impl Fingerprint {
    /// The file at `path`, or `None` if there is none (or it cannot be looked at).
    pub fn of(path: &Path) -> Option<Self> {
        use std::os::unix::fs::MetadataExt;
        let meta = std::fs::metadata(path).ok()?;
        Some(Self {
            inode: meta.ino(),
            len: meta.len(),
            modified: meta.modified().ok(),
        })
    }
}

/// What the end of a launch says about the view library.
#[derive(Debug, Clone, PartialEq)]
pub enum LibraryOutcome {
    /// The controller reported what it loaded and what became of the file.
    Reported(tes_controller::summary::LibraryFacts),
    /// The controller ended before it loaded the library (before the world map came).
    NotLoaded,
    /// The controller did not report (it failed or was killed): what the file is now against
    /// what it was at the start.
    Unreported {
        /// The file's fingerprint at the start.
        at_start: Option<Fingerprint>,
        /// Its fingerprint now.
        now: Option<Fingerprint>,
        /// What it holds now, if it changed and loads (else why not).
        holds: Option<std::result::Result<tes_controller::summary::LibraryCounts, String>>,
    },
}

impl LibraryOutcome {
    /// Reads the controller's report at `report` (if the launcher knows one), falling back on
    /// comparing the library file at `library` with its fingerprint at the start.
    pub fn read(report: Option<&Path>, library: &Path, at_start: Option<Fingerprint>) -> Self {
        Self::of(read_report(report).as_ref(), library, at_start)
    }

    /// What the controller's `summary` says of the library, else what the file at `library`
    /// is now against its fingerprint at the start.
    pub fn of(
        summary: Option<&ControllerSummary>,
        library: &Path,
        at_start: Option<Fingerprint>,
    ) -> Self {
        match summary {
            Some(s) => s.library.clone().map_or(Self::NotLoaded, Self::Reported),
            None => {
                let now = Fingerprint::of(library);
                let holds = (now.is_some() && now != at_start).then(|| {
                    tes_learning::library::store::load(library)
                        .map(|s| tes_controller::summary::LibraryCounts::of(&s.library))
                        .map_err(|e| e.to_string())
                });
                Self::Unreported {
                    at_start,
                    now,
                    holds,
                }
            }
        }
    }

    /// The launcher's lines: the library's facts, then how to see its views (when there is a
    /// file to see; `tes library show` alone when it is the `default` library).
    pub fn lines(&self, library: &Path, default: &Path) -> Vec<String> {
        let shown = library.display();
        let not_saved = "not saved (the controller did not finish)";
        let mut lines = vec![match self {
            Self::Reported(facts) => format!("launch: {facts}"),
            Self::NotLoaded => format!(
                "launch: library {shown}: not loaded (the controller stopped before the world \
                 map came); left as it was"
            ),
            Self::Unreported {
                at_start,
                now,
                holds,
            } => match (at_start, now, holds) {
                (None, None, _) => {
                    format!("launch: library {shown}: {not_saved}; there is still no library file")
                }
                (_, None, _) => format!("launch: library {shown}: {not_saved}; the file is gone"),
                (a, b, _) if a == b => {
                    format!("launch: library {shown}: {not_saved}; left as it was")
                }
                (_, _, Some(Ok(counts))) => format!(
                    "launch: library {shown}: {not_saved}; saved after an episode of the run, \
                     it holds {counts}"
                ),
                (_, _, Some(Err(e))) => {
                    format!(
                        "launch: library {shown}: {not_saved}; it changed and does not load: {e}"
                    )
                }
                (_, _, None) => format!("launch: library {shown}: {not_saved}"),
            },
        }];
        if std::fs::metadata(library).is_ok_and(|m| m.is_file()) {
            lines.push(if library == default {
                "launch: see its views with `tes library show`".to_owned()
            } else {
                format!("launch: see its views with `tes library show {shown}`")
            });
        }
        lines
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_controller::summary::{LibraryCounts, LibraryEnd, LibraryFacts};
    use tes_learning::library::store::{self, StoredLibrary};
    use tes_learning::library::{LibraryParams, ViewLibrary};

    fn save_empty_library(path: &Path) {
        let stored = StoredLibrary {
            library: ViewLibrary::new(3, 20, 312, LibraryParams::default()).expect("library"),
            world: "arena 3".into(),
            action_names: Vec::new(),
            feature_names: Vec::new(),
        };
        store::save(path, &stored).expect("saved");
    }

    /// With the controller's report, the end says its facts and how to see the views (the
    /// short command for the default library).
    #[test]
    fn the_end_states_the_controllers_facts_and_what_to_look_at_next() {
        let dir = tempfile::tempdir().expect("temp dir");
        let library = dir.path().join("library.tesl");
        save_empty_library(&library);
        let report = dir.path().join(CONTROLLER_REPORT);
        let facts = LibraryFacts {
            path: library.display().to_string(),
            started_empty: false,
            before: LibraryCounts { views: 9, tasks: 3 },
            after: LibraryCounts {
                views: 11,
                tasks: 4,
            },
            end: LibraryEnd::Saved,
        };
        let summary = ControllerSummary {
            library: Some(facts.clone()),
            ..ControllerSummary::default()
        };
        std::fs::write(&report, serde_json::to_string(&summary).expect("json")).expect("report");
        let end = LibraryOutcome::read(Some(&report), &library, None);
        assert_eq!(end, LibraryOutcome::Reported(facts));
        let shown = library.display();
        assert_eq!(
            end.lines(&library, &library),
            [
                format!("launch: library {shown}: 9 views, 3 tasks -> 11 views, 4 tasks (saved)"),
                "launch: see its views with `tes library show`".to_owned()
            ]
        );
        let elsewhere = dir.path().join("default.tesl");
        assert_eq!(
            end.lines(&library, &elsewhere)[1],
            format!("launch: see its views with `tes library show {shown}`")
        );

        // A report of a controller that stopped before the map came.
        std::fs::write(
            &report,
            serde_json::to_string(&ControllerSummary::default()).expect("json"),
        )
        .expect("report");
        let end = LibraryOutcome::read(Some(&report), &library, None);
        assert_eq!(end, LibraryOutcome::NotLoaded);
        assert!(end.lines(&library, &library)[0].ends_with("left as it was"));
    }

    /// Without a report (the controller failed or was killed), the end still says only what
    /// is true: no file, the file as it was, or the file saved during the run, with its counts.
    #[test]
    fn without_a_report_the_end_compares_the_file_with_the_start() {
        let dir = tempfile::tempdir().expect("temp dir");
        let library = dir.path().join("library.tesl");
        let missing = dir.path().join(CONTROLLER_REPORT);
        let not_saved = "not saved (the controller did not finish)";

        let end = LibraryOutcome::read(Some(&missing), &library, None);
        let lines = end.lines(&library, &library);
        assert_eq!(lines.len(), 1, "no file, nothing to show: {lines:?}");
        assert!(
            lines[0].contains(not_saved) && lines[0].ends_with("there is still no library file"),
            "{lines:?}"
        );

        save_empty_library(&library);
        let at_start = Fingerprint::of(&library);
        let end = LibraryOutcome::read(None, &library, at_start);
        let lines = end.lines(&library, &library);
        assert!(
            lines[0].contains(not_saved) && lines[0].ends_with("left as it was"),
            "{lines:?}"
        );
        assert_eq!(lines.len(), 2, "{lines:?}");

        // Saved again (a new file replaces the old one): the run changed it.
        save_empty_library(&library);
        let end = LibraryOutcome::read(Some(&missing), &library, at_start);
        let lines = end.lines(&library, &library);
        assert!(
            lines[0].ends_with("saved after an episode of the run, it holds 0 views, 0 tasks"),
            "{lines:?}"
        );
        // Something that is not a file there: nothing to show.
        let directory = dir.path().join("directory.tesl");
        std::fs::create_dir(&directory).expect("dir");
        let at_start = Fingerprint::of(&directory);
        let lines = LibraryOutcome::read(None, &directory, at_start).lines(&directory, &directory);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].ends_with("left as it was"), "{lines:?}");
        // A report that is not one is no report.
        std::fs::write(&missing, "not json").expect("write");
        assert!(matches!(
            LibraryOutcome::read(Some(&missing), &library, None),
            LibraryOutcome::Unreported { .. }
        ));
    }

    /// The launcher adds the report to the controller's settings when they set none, and
    /// keeps one they set.
    #[test]
    fn the_controller_reports_into_the_run_directory_unless_told_elsewhere() {
        let dir = tempfile::tempdir().expect("temp dir");
        let config = dir.path().join("controller.toml");
        let write = |c: &ControllerConfig| {
            std::fs::write(&config, toml::to_string(c).expect("toml")).expect("settings");
        };
        let spec = ChildSpec {
            role: tes_topics::Role::Controller,
            config: config.clone(),
        };
        let base = ControllerConfig {
            service_prefix: "x/".into(),
            ..ControllerConfig::default()
        };
        write(&base);
        let path = controller_report(&spec, dir.path()).expect("report path");
        assert_eq!(path, dir.path().join(CONTROLLER_REPORT));
        let text = std::fs::read_to_string(&config).expect("settings");
        let read = ControllerConfig::from_toml_in(&text, Origin::File(config.clone()))
            .expect("valid settings");
        assert_eq!(
            read,
            ControllerConfig {
                report: Some(path),
                ..base.clone()
            }
        );

        let own = dir.path().join("mine.json");
        write(&ControllerConfig {
            report: Some(own.clone()),
            ..base
        });
        assert_eq!(
            controller_report(&spec, dir.path()).expect("report path"),
            own
        );
    }
}
