//! Saving the view library: atomically, off the acting thread, and once more at shutdown.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tes_learning::agents::Tes;
use tes_learning::library::LibraryError;
use tes_learning::library::store::{self, StoreError, StoredLibrary};
use tes_topics::WorldMap;
use thiserror::Error;

use crate::summary::LibraryCounts;
use tes_runtime::background::Background;

/// Why the library could not be saved.
#[derive(Debug, Error)]
pub enum SaveError {
    /// The library cannot be finished for saving.
    #[error("view library: {0}")]
    Library(#[from] LibraryError),
    /// The file store refused it.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The library's directory cannot be created.
    #[error("cannot create the data directory {}: {error}", path.display())]
    DataDir {
        /// The directory.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// The library saver thread could not start.
    #[error("cannot start the library saver thread: {0}")]
    SaverThread(std::io::Error),
}

/// What a saved library says about the world it was learned in: the world, and one name per
/// action and per feature (empty where the world does not say what they mean), so that
/// `tes library show` can say what each view's action and selected features are.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct WorldNames {
    /// Which world, e.g. "arena 3".
    pub world: String,
    /// One name per action, or none.
    pub action_names: Vec<String>,
    /// One name per feature, or none.
    pub feature_names: Vec<String>,
}

impl WorldNames {
    /// The names of the world `map` describes ([`tes_topics::names::map_names`]).
    pub fn of_map(map: &WorldMap) -> Self {
        let (action_names, feature_names) = tes_topics::names::map_names(map);
        Self {
            world: format!("arena {}", map.world),
            action_names,
            feature_names,
        }
    }
}

/// The library as it would be if the task ended now, saved atomically with the world's
/// names; returns what the saved library holds.
pub fn save_library(
    agent: Tes,
    path: &Path,
    names: &WorldNames,
) -> Result<LibraryCounts, SaveError> {
    let (library, _) = agent.finish_task()?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|error| SaveError::DataDir {
            path: dir.to_owned(),
            error,
        })?;
    }
    let counts = LibraryCounts::of(&library);
    store::save(
        path,
        &StoredLibrary {
            library,
            world: names.world.clone(),
            action_names: names.action_names.clone(),
            feature_names: names.feature_names.clone(),
        },
    )?;
    Ok(counts)
}

/// Saves libraries on a thread of its own, so that encoding and `fsync` never delay the
/// acting loop (the next episode's first observation arrives right after the last one's).
pub struct Saver {
    jobs: Option<crossbeam::channel::Sender<Box<Tes>>>,
    failures: Arc<std::sync::atomic::AtomicU64>,
    /// The saver thread's priority, raised back to normal when the run ends.
    priority: Arc<Background>,
    handle: Option<std::thread::JoinHandle<()>>,
}

impl Saver {
    /// Starts the saver thread for the library file `path` of the world `names` names.
    pub fn spawn(path: PathBuf, names: WorldNames) -> Result<Self, SaveError> {
        let (jobs, queue) = crossbeam::channel::bounded::<Box<Tes>>(1);
        let failures = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let failed = failures.clone();
        let priority = Arc::new(Background::new());
        let lowered = priority.clone();
        let handle = std::thread::Builder::new()
            .name("library-saver".into())
            .spawn(move || {
                // Lowered only where the shutdown can raise it back: the final save waits for
                // a save in progress, which SCHED_IDLE could starve on a busy machine.
                lowered.lower_if_restorable();
                while let Ok(agent) = queue.recv() {
                    if let Err(e) = save_library(*agent, &path, &names) {
                        failed.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        tracing::error!(error = %e, "the library was not saved; the previous file is intact");
                    }
                }
            })
            .map_err(SaveError::SaverThread)?;
        Ok(Self {
            jobs: Some(jobs),
            failures,
            priority,
            handle: Some(handle),
        })
    }

    /// Queues a save of `agent`'s library as it would be if the task ended now, unless one
    /// is already waiting (the next episode's save will carry this one's learning).
    pub fn offer(&self, agent: &Tes) {
        if let Some(jobs) = self.jobs.as_ref().filter(|j| j.is_empty()) {
            let _ = jobs.try_send(Box::new(agent.clone()));
        }
    }

    /// Waits for the queued saves, the saver thread back at normal priority so that a busy
    /// machine cannot starve a save in progress; returns how many failed.
    pub fn finish(mut self) -> u64 {
        if !self.priority.restore() {
            tracing::warn!(
                "the library saver stays at SCHED_IDLE; a save in progress may be slow to finish"
            );
        }
        self.jobs = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
        self.failures.load(std::sync::atomic::Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_learning::agents::TesParams;
    use tes_learning::library::{LibraryParams, ViewLibrary};
    use tes_topics::ARENA_FEATURES;

    /// One cell with 8 orientations (states 0..8, the out state 8), 3 actions, 2 effects
    /// (stay, leave), `features` features: the orientation indicator when there are 312.
    fn map(features: u32) -> WorldMap {
        let mut m = WorldMap::EMPTY;
        (m.world, m.width, m.height, m.orientations) = (3, 1, 1, 8);
        (m.n_states, m.n_actions, m.n_effects, m.n_features) = (9, 3, 2, features);
        m.action_wheels[..3].copy_from_slice(&[[246, 246], [90, -90], [90, 0]]);
        for s in 0..8 {
            m.next_state[s][..2].copy_from_slice(&[s as u16, 8]);
            m.reward[s] = -0.05;
            if features as usize == ARENA_FEATURES {
                m.features[s].set(300 + s);
            }
        }
        m.next_state[8][..2].copy_from_slice(&[8, 8]);
        (m.terminal[8], m.reward[8]) = (1, -1.0);
        m
    }

    fn agent(map: &WorldMap) -> Tes {
        let structure = crate::acting::structure_from_map(map).unwrap();
        let library =
            ViewLibrary::new(3, 2, map.n_features as usize, LibraryParams::default()).unwrap();
        Tes::new(
            std::sync::Arc::new(structure),
            library,
            TesParams::default(),
            0,
        )
        .unwrap()
    }

    /// A robot library is saved with the arena's feature names and its actions' names; the
    /// counts returned are those of the library on disk.
    #[test]
    fn a_robot_library_names_its_features_and_actions() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("data/library.tesl");
        let m = map(ARENA_FEATURES as u32);
        let names = WorldNames::of_map(&m);
        let counts = save_library(agent(&m), &path, &names).unwrap();
        let stored = store::load(&path).unwrap();
        assert_eq!(stored.world, "arena 3");
        assert_eq!(
            stored.action_names,
            [
                "forward (both wheels 246°)",
                "spin right (left 90°, right -90°)",
                "pivot right (left 90°, right 0°)"
            ]
        );
        assert_eq!(stored.feature_names.len(), ARENA_FEATURES);
        assert_eq!(stored.feature_names[0], "green ring 0");
        assert_eq!(stored.feature_names[301], "facing NE");
        assert_eq!(stored.feature_names[311], "no blue mark in cell");
        assert_eq!(counts, LibraryCounts::of(&stored.library));
        assert_eq!(
            counts.tasks, 1,
            "the run's task is finished in the saved library"
        );
    }

    /// A map that is not of the arena layout: only the actions are named.
    #[test]
    fn a_library_of_another_layout_names_only_its_actions() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("library.tesl");
        let m = map(4);
        save_library(agent(&m), &path, &WorldNames::of_map(&m)).unwrap();
        let stored = store::load(&path).unwrap();
        assert_eq!(stored.action_names.len(), 3);
        assert!(stored.feature_names.is_empty());
    }
}
