//! Saving the view library: atomically, off the acting thread, and once more at shutdown.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tes_learning::agents::Tes;
use tes_learning::library::LibraryError;
use tes_learning::library::store::{self, StoreError, StoredLibrary};
use thiserror::Error;

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

/// The library as it would be if the task ended now, saved atomically.
pub fn save_library(agent: Tes, path: &Path, world: u32) -> Result<(), SaveError> {
    let (library, _) = agent.finish_task()?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|error| SaveError::DataDir {
            path: dir.to_owned(),
            error,
        })?;
    }
    store::save(
        path,
        &StoredLibrary {
            library,
            world: format!("arena {world}"),
            action_names: Vec::new(),
            feature_names: Vec::new(),
        },
    )?;
    Ok(())
}

/// Saves libraries on a thread of its own, so that encoding and `fsync` never delay the
/// acting loop (the next episode's first observation arrives right after the last one's).
pub struct Saver {
    jobs: Option<crossbeam::channel::Sender<Box<Tes>>>,
    failures: Arc<std::sync::atomic::AtomicU64>,
    handle: Option<std::thread::JoinHandle<()>>,
}

impl Saver {
    /// Starts the saver thread for the library file `path` of world (arena) `world`.
    pub fn spawn(path: PathBuf, world: u32) -> Result<Self, SaveError> {
        let (jobs, queue) = crossbeam::channel::bounded::<Box<Tes>>(1);
        let failures = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let failed = failures.clone();
        let handle = std::thread::Builder::new()
            .name("library-saver".into())
            .spawn(move || {
                crate::realtime::lower_this_threads_priority();
                while let Ok(agent) = queue.recv() {
                    if let Err(e) = save_library(*agent, &path, world) {
                        failed.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        tracing::error!(error = %e, "the library was not saved; the previous file is intact");
                    }
                }
            })
            .map_err(SaveError::SaverThread)?;
        Ok(Self {
            jobs: Some(jobs),
            failures,
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

    /// Waits for the queued saves; returns how many failed.
    pub fn finish(mut self) -> u64 {
        self.jobs = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
        self.failures.load(std::sync::atomic::Ordering::Relaxed)
    }
}
