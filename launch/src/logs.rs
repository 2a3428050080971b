//! Where the children's output goes: files in the run directory, followed by the launcher.
//!
//! Each child writes its standard output to `ROLE.out` and its log (standard error) to
//! `ROLE.log` in the run directory, opened for appending, so a respawned child continues its
//! predecessor's files. Nothing a child writes depends on the launcher being alive: a child
//! whose launcher was killed (or whose launcher's own output was closed, as by `| head`) still
//! writes its last lines and saves its library on the way out, instead of dying of a broken
//! pipe. The launcher follows the files ([`follow`]) and relays their lines.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use tes_topics::Role;

use crate::IoError;

type Result<T, E = IoError> = std::result::Result<T, E>;

/// Which of a child's two outputs a line came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    /// Standard output: the controller's episode lines and summary.
    Out,
    /// Standard error: the `tracing` log.
    Log,
}

/// One line a child wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChildLine {
    /// The child's role.
    pub role: Role,
    /// Which output.
    pub stream: Stream,
    /// The line, without its end.
    pub text: String,
}

/// The two files of `role` in `dir`.
pub fn paths(dir: &Path, role: &str) -> [(Stream, PathBuf); 2] {
    [
        (Stream::Out, dir.join(format!("{role}.out"))),
        (Stream::Log, dir.join(format!("{role}.log"))),
    ]
}

/// Empties `role`'s files in `dir` (a new launch starts them afresh).
pub fn reset(dir: &Path, role: &str) -> Result<()> {
    for (_, path) in paths(dir, role) {
        File::create(&path).map_err(IoError::with(format!("cannot create {}", path.display())))?;
    }
    Ok(())
}

/// `role`'s standard output and standard error, appending to its files in `dir`.
pub fn open(dir: &Path, role: &str) -> Result<(File, File)> {
    let [(_, out), (_, log)] = paths(dir, role);
    let append = |path: &Path| {
        OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(IoError::with(format!("cannot open {}", path.display())))
    };
    Ok((append(&out)?, append(&log)?))
}

/// Follows `path` from its current end on a thread of its own, sending each complete line to
/// `lines`, until `done` is raised and the file has no more complete lines. The file may be
/// appended to by several processes in turn (a child and its respawned successor).
pub fn follow(
    path: PathBuf,
    role: Role,
    stream: Stream,
    lines: mpsc::Sender<ChildLine>,
    done: Arc<AtomicBool>,
) -> Result<()> {
    let unreadable = || IoError::with(format!("cannot read {}", path.display()));
    let mut file = File::open(&path).map_err(unreadable())?;
    file.seek(SeekFrom::End(0)).map_err(unreadable())?;
    std::thread::Builder::new()
        .name(format!("follow-{role}"))
        .spawn(move || {
            // It wakes every 10 ms: never where the controller's acting thread polls alone
            // (best effort: unpinned, it follows all the same).
            let _ = tes_runtime::affinity::pin_off_the_acting_cpu();
            let mut reader = BufReader::new(file);
            let mut partial = String::new();
            loop {
                // Read everything there is; a line without its end waits for the rest.
                let finished = done.load(Ordering::Acquire);
                loop {
                    match reader.read_line(&mut partial) {
                        Ok(0) | Err(_) => break,
                        Ok(_) if partial.ends_with('\n') => {
                            let text = partial.trim_end_matches(['\n', '\r']).to_owned();
                            partial.clear();
                            if lines.send(ChildLine { role, stream, text }).is_err() {
                                return;
                            }
                        }
                        Ok(_) => {}
                    }
                }
                if finished {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        })
        .map_err(IoError::with(
            "cannot start a thread to follow a child's output".into(),
        ))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    /// Lines appended by two writers in turn (a child and its successor) arrive once each, in
    /// order; a line is sent only once its end is written; what was there before the
    /// follower started is not sent.
    #[test]
    fn a_followed_file_gives_each_appended_line_once() {
        let dir = tempfile::tempdir().unwrap();
        reset(dir.path(), "controller").unwrap();
        let [(_, out), _] = paths(dir.path(), "controller");
        std::fs::write(&out, "before\n").unwrap();
        let (tx, rx) = mpsc::channel();
        let done = Arc::new(AtomicBool::new(false));
        follow(out.clone(), Role::Controller, Stream::Out, tx, done.clone()).unwrap();
        let (mut first, _) = open(dir.path(), "controller").unwrap();
        write!(first, "episode 1\nepisode").unwrap();
        first.flush().unwrap();
        let got = rx.recv_timeout(Duration::from_secs(5)).unwrap();
        assert_eq!(got.text, "episode 1");
        assert_eq!((got.role, got.stream), (Role::Controller, Stream::Out));
        assert!(rx.recv_timeout(Duration::from_millis(100)).is_err());
        writeln!(first, " 2").unwrap();
        drop(first);
        let (mut second, _) = open(dir.path(), "controller").unwrap();
        writeln!(second, "episode 3").unwrap();
        done.store(true, Ordering::Release);
        let rest: Vec<String> = rx.iter().map(|l| l.text).collect();
        assert_eq!(rest, ["episode 2", "episode 3"]);
    }
}
