//! Where the children's output goes: files in the run directory, followed by the launcher.
//!
//! Each child writes its standard output to `ROLE.out` and its log (standard error) to
//! `ROLE.log` in the run directory, opened for appending, so a respawned child continues its
//! predecessor's files. Nothing a child writes depends on the launcher being alive: a child
//! whose launcher was killed (or whose launcher's own output was closed, as by `| head`) still
//! writes its last lines and saves its library on the way out, instead of dying of a broken
//! pipe. The launcher follows the files ([`follow`]) and relays their lines.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use anyhow::{Context, Result};

/// Which of a child's two outputs a line came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stream {
    /// Standard output: the controller's episode lines and summary.
    Out,
    /// Standard error: the `tracing` log.
    Log,
}

/// One line a child wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct ChildLine {
    /// The child's role.
    pub(crate) role: &'static str,
    /// Which output.
    pub(crate) stream: Stream,
    /// The line, without its end.
    pub(crate) text: String,
}

/// The two files of `role` in `dir`.
pub(crate) fn paths(dir: &Path, role: &str) -> [(Stream, PathBuf); 2] {
    [
        (Stream::Out, dir.join(format!("{role}.out"))),
        (Stream::Log, dir.join(format!("{role}.log"))),
    ]
}

/// Empties `role`'s files in `dir` (a new launch starts them afresh).
pub(crate) fn reset(dir: &Path, role: &str) -> Result<()> {
    for (_, path) in paths(dir, role) {
        File::create(&path).with_context(|| format!("cannot create {}", path.display()))?;
    }
    Ok(())
}

/// `role`'s standard output and standard error, appending to its files in `dir`.
pub(crate) fn open(dir: &Path, role: &str) -> Result<(File, File)> {
    let [(_, out), (_, log)] = paths(dir, role);
    let append = |path: &Path| {
        OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("cannot open {}", path.display()))
    };
    Ok((append(&out)?, append(&log)?))
}

/// Follows `path` from its current end on a thread of its own, sending each complete line to
/// `lines`, until `done` is raised and the file has no more complete lines. The file may be
/// appended to by several processes in turn (a child and its respawned successor).
pub(crate) fn follow(
    path: PathBuf,
    role: &'static str,
    stream: Stream,
    lines: mpsc::Sender<ChildLine>,
    done: Arc<AtomicBool>,
) -> Result<()> {
    let mut file = File::open(&path).with_context(|| format!("cannot read {}", path.display()))?;
    file.seek(SeekFrom::End(0))
        .with_context(|| format!("cannot read {}", path.display()))?;
    std::thread::Builder::new()
        .name(format!("follow-{role}"))
        .spawn(move || {
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
        .context("cannot start a thread to follow a child's output")?;
    Ok(())
}

/// The launcher's own output, which must never end the launch: a closed terminal or pipe
/// (`tes launch | head -2`) only silences it, and the group runs to its end.
#[derive(Debug, Default)]
pub(crate) struct Say {
    out_closed: AtomicBool,
    /// While a live view owns the terminal: the lines said, newest last, instead of printed.
    held: std::sync::Mutex<Option<std::collections::VecDeque<String>>>,
}

/// How many lines [`Say::hold`] keeps.
const HELD_LINES: usize = 500;

impl Say {
    /// Keeps what is said from now on (the last [`HELD_LINES`]) instead of printing it: the
    /// terminal belongs to the live view.
    pub(crate) fn hold(&self) {
        if let Ok(mut held) = self.held.lock() {
            held.get_or_insert_with(Default::default);
        }
    }

    /// Prints what is said again (the held lines are dropped: the run folder has them).
    pub(crate) fn release(&self) {
        if let Ok(mut held) = self.held.lock() {
            *held = None;
        }
    }

    /// The last `n` held lines, oldest first.
    pub(crate) fn held_lines(&self, n: usize) -> Vec<String> {
        match self.held.lock() {
            Ok(held) => held.as_ref().map_or_else(Vec::new, |h| {
                h.iter().skip(h.len().saturating_sub(n)).cloned().collect()
            }),
            Err(_) => Vec::new(),
        }
    }

    /// Whether `line` was held (and so must not be printed).
    fn held(&self, line: &str) -> bool {
        let Ok(mut held) = self.held.lock() else {
            return false;
        };
        let Some(held) = held.as_mut() else {
            return false;
        };
        if held.len() == HELD_LINES {
            held.pop_front();
        }
        held.push_back(line.to_owned());
        true
    }

    /// Prints `line` on standard output (nothing once that is closed).
    pub(crate) fn out(&self, line: &str) {
        if self.held(line) {
            return;
        }
        if !self.out_closed.load(Ordering::Relaxed) {
            let mut out = std::io::stdout().lock();
            if writeln!(out, "{line}").and_then(|()| out.flush()).is_err() {
                self.out_closed.store(true, Ordering::Relaxed);
            }
        }
    }

    /// Prints `line` on standard error (errors ignored: there is nowhere else to say them).
    pub(crate) fn err(&self, line: &str) {
        if self.held(line) {
            return;
        }
        let _ = writeln!(std::io::stderr().lock(), "{line}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        follow(out.clone(), "controller", Stream::Out, tx, done.clone()).unwrap();
        let (mut first, _) = open(dir.path(), "controller").unwrap();
        write!(first, "episode 1\nepisode").unwrap();
        first.flush().unwrap();
        let got = rx.recv_timeout(Duration::from_secs(5)).unwrap();
        assert_eq!(got.text, "episode 1");
        assert_eq!((got.role, got.stream), ("controller", Stream::Out));
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
