//! Ownership of a directory or file by one process at a time: an advisory `flock` on a lock
//! file that names its holder's pid.
//!
//! The kernel releases a `flock` when its holder dies, however it dies, so a lock left by a
//! killed process is taken over by the next one without any clean-up; the pid written into the
//! file only serves to name the holder when the lock is refused.
//!
//! ```
//! use tes_runtime::lock::{Lock, LockError};
//!
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("tes.lock");
//! let held = Lock::acquire(&path, "data directory")?;
//! // A second owner is refused, naming the holder.
//! let Err(LockError::Held { pid, .. }) = Lock::acquire(&path, "data directory") else {
//!     return Err("a second owner must be refused".into());
//! };
//! assert_eq!(pid, Some(std::process::id()));
//! drop(held);
//! let _again = Lock::acquire(&path, "data directory")?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::fcntl::{Flock, FlockArg};
use thiserror::Error;

/// Why a lock was not taken.
#[derive(Debug, Error)]
pub enum LockError {
    /// Another live process holds it.
    #[error("{what} {} is in use by another process{}", path.display(), holder(*pid))]
    Held {
        /// What the lock guards, for the message ("data directory", "view library").
        what: &'static str,
        /// The lock file.
        path: PathBuf,
        /// The holder's pid, as it wrote it (none if it has not written it yet).
        pid: Option<u32>,
    },
    /// The lock file cannot be created or locked.
    #[error("cannot lock {what} {}: {error}", path.display())]
    Io {
        /// What the lock guards.
        what: &'static str,
        /// The lock file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

fn holder(pid: Option<u32>) -> String {
    pid.map_or_else(String::new, |p| format!(" (pid {p})"))
}

/// A held lock; released when dropped (or when the process dies).
#[derive(Debug)]
pub struct Lock {
    _file: Flock<File>,
    path: PathBuf,
}

impl Lock {
    /// Takes the lock file `path` (created if missing) for this process, or says who holds it.
    /// `what` names what it guards in the error.
    pub fn acquire(path: &Path, what: &'static str) -> Result<Self, LockError> {
        let io = |error: std::io::Error| LockError::Io {
            what,
            path: path.to_owned(),
            error,
        };
        let mut file = loop {
            let file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(path)
                .map_err(io)?;
            let locked = match Flock::lock(file, FlockArg::LockExclusiveNonblock) {
                Ok(locked) => locked,
                Err((mut file, Errno::EWOULDBLOCK)) => {
                    let mut text = String::new();
                    let pid = file
                        .read_to_string(&mut text)
                        .ok()
                        .and_then(|_| text.trim().parse().ok());
                    return Err(LockError::Held {
                        what,
                        path: path.to_owned(),
                        pid,
                    });
                }
                Err((_, e)) => return Err(io(e.into())),
            };
            // A holder removes the file as it lets go (see `Drop`): a lock taken on a file
            // removed meanwhile guards nothing, so it is taken again on the file now there.
            if still_at(&locked, path).map_err(io)? {
                break locked;
            }
        };
        // Name the holder: this process (a dead holder's pid is overwritten).
        let named = (|| {
            file.set_len(0)?;
            file.seek(SeekFrom::Start(0))?;
            writeln!(file, "{}", std::process::id())?;
            file.sync_data()
        })();
        named.map_err(io)?;
        Ok(Self {
            _file: file,
            path: path.to_owned(),
        })
    }

    /// [`acquire`](Self::acquire), retried for up to `patience` while another process holds
    /// it (say, a predecessor still saving on its way out).
    pub fn acquire_within(
        path: &Path,
        what: &'static str,
        patience: Duration,
    ) -> Result<Self, LockError> {
        let deadline = Instant::now() + patience;
        loop {
            match Self::acquire(path, what) {
                Err(LockError::Held { .. }) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(20));
                }
                done => return done,
            }
        }
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Removes the lock file while the lock is still held, so a clean exit leaves nothing behind;
/// a process that opened the file meanwhile finds it gone once it gets the lock, and tries
/// again (see [`Lock::acquire`]). A killed holder's file stays, and is taken over.
impl Drop for Lock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Whether `path` is still the file `file` has open (not removed or replaced).
fn still_at(file: &File, path: &Path) -> std::io::Result<bool> {
    use std::os::unix::fs::MetadataExt;
    let open = file.metadata()?;
    match std::fs::metadata(path) {
        Ok(there) => Ok((there.dev(), there.ino()) == (open.dev(), open.ino())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) => Err(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lock_is_refused_while_held_and_taken_over_once_released() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.lock");
        let first = Lock::acquire(&path, "data directory").unwrap();
        let err = Lock::acquire(&path, "data directory").unwrap_err();
        let shown = err.to_string();
        assert!(
            shown.contains("in use by another process")
                && shown.contains(&format!("(pid {})", std::process::id())),
            "{shown}"
        );
        assert!(Lock::acquire_within(&path, "data directory", Duration::from_millis(60)).is_err());
        drop(first);
        assert!(!path.exists(), "a lock let go of leaves no file behind");
        let second = Lock::acquire(&path, "data directory").unwrap();
        assert_eq!(second.path(), path);
    }

    /// A process that opened the lock file just before its holder let go (and removed it)
    /// does not hold a lock on the removed file: it takes the lock on the file now there.
    #[test]
    fn a_lock_on_a_removed_file_is_taken_again_on_the_new_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.lock");
        let old = File::create(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        std::fs::write(&path, "").unwrap();
        assert!(!still_at(&old, &path).unwrap());
        let lock = Lock::acquire(&path, "data directory").unwrap();
        assert!(still_at(&lock._file, &path).unwrap());
    }

    /// A lock file left by a process that died (here: one whose pid no process has) names
    /// nobody alive and is taken over: the kernel dropped its lock with its holder.
    #[test]
    fn a_dead_holders_lock_file_is_taken_over() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.lock");
        std::fs::write(&path, "4000000\n").unwrap();
        let lock = Lock::acquire(&path, "data directory").unwrap();
        let text = std::fs::read_to_string(lock.path()).unwrap();
        assert_eq!(text.trim(), std::process::id().to_string());
    }

    #[test]
    fn an_unwritable_place_is_an_io_error_naming_it() {
        let err = Lock::acquire(Path::new("/proc/no-such-dir/x.lock"), "view library").unwrap_err();
        assert!(matches!(err, LockError::Io { .. }), "{err:?}");
        assert!(err.to_string().contains("/proc/no-such-dir/x.lock"));
    }
}
