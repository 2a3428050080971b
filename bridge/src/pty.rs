//! Serves the simulated brick on a pseudo-terminal, so any NXT client can drive it.
//!
//! [`PtyServer::open`] creates a pseudo-terminal in raw mode and links its slave side at the
//! path you give; clients open that path as they would `/dev/rfcomm0`. [`PtyServer::serve`]
//! reads frames from the master side, hands each telegram to the [`SimBrick`] (stepped to the
//! clock first) and writes each reply frame in one `write`, because clients such as
//! nxt-python's devfile backend read the 2-byte header and then the body in one read each.
//! The server keeps its own descriptor of the slave open, so clients may come and go.

use std::io;
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use nix::errno::Errno;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

use crate::brick::SimBrick;
use crate::clock::Clock;
use crate::nxt::FrameDecoder;
use crate::transport::LinkDelay;

/// A pseudo-terminal failure.
#[derive(Debug, thiserror::Error)]
pub enum PtyError {
    /// A system call failed.
    #[error("{context}: {error}")]
    Sys {
        /// What was being done.
        context: String,
        /// The error (part of the message, so not also chained as a source).
        error: io::Error,
    },
    /// The link path exists and is not a symbolic link (it is not ours to replace).
    #[error("{0} exists and is not a symbolic link; refusing to replace it")]
    PathTaken(PathBuf),
}

fn sys(context: impl Into<String>) -> impl FnOnce(Errno) -> PtyError {
    let context = context.into();
    move |e| PtyError::Sys {
        context,
        error: io::Error::from(e),
    }
}

/// Counters of a [`PtyServer::serve`] run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServeStats {
    /// Telegrams received.
    pub telegrams: u64,
    /// Replies written.
    pub replies: u64,
    /// Bad frame headers (lost sync).
    pub bad_frames: u64,
}

/// The simulated brick's pseudo-terminal. Dropping it removes the link.
#[derive(Debug)]
pub struct PtyServer {
    master: OwnedFd,
    _slave: OwnedFd,
    slave_path: PathBuf,
    link: PathBuf,
}

impl PtyServer {
    /// Opens a raw pseudo-terminal and symlinks `link` to its slave device. An existing
    /// symbolic link at `link` (say, left by a killed server) is replaced.
    pub fn open(link: &Path) -> Result<Self, PtyError> {
        let pty = nix::pty::openpty(None, None).map_err(sys("openpty"))?;
        let mut t = tcgetattr(&pty.slave).map_err(sys("tcgetattr on the pty slave"))?;
        cfmakeraw(&mut t);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &t).map_err(sys("tcsetattr on the pty slave"))?;
        let slave_path =
            nix::unistd::ttyname(&pty.slave).map_err(sys("ttyname of the pty slave"))?;
        match std::fs::symlink_metadata(link) {
            Ok(m) if m.file_type().is_symlink() => {
                std::fs::remove_file(link).map_err(|error| PtyError::Sys {
                    context: format!("remove the stale link {}", link.display()),
                    error,
                })?;
            }
            Ok(_) => return Err(PtyError::PathTaken(link.to_owned())),
            Err(_) => {}
        }
        std::os::unix::fs::symlink(&slave_path, link).map_err(|error| PtyError::Sys {
            context: format!("symlink {} -> {}", link.display(), slave_path.display()),
            error,
        })?;
        Ok(Self {
            master: pty.master,
            _slave: pty.slave,
            slave_path,
            link: link.to_owned(),
        })
    }

    /// The slave device, e.g. `/dev/pts/3`.
    pub fn slave_path(&self) -> &Path {
        &self.slave_path
    }

    /// The link clients open.
    pub fn link(&self) -> &Path {
        &self.link
    }

    /// Serves `brick` until `stop` becomes true (checked every 100 ms). With `delay`, each
    /// reply is held back by a link-delay draw, like a Bluetooth link.
    pub fn serve<C: Clock>(
        &self,
        brick: &mut SimBrick,
        clock: &C,
        mut delay: Option<LinkDelay>,
        stop: &AtomicBool,
    ) -> Result<ServeStats, PtyError> {
        let mut stats = ServeStats::default();
        let mut decoder = FrameDecoder::new();
        let mut buf = [0u8; 256];
        while !stop.load(Ordering::SeqCst) {
            let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
            match poll(&mut fds, PollTimeout::from(100u16)) {
                Ok(0) | Err(Errno::EINTR) => continue,
                Ok(_) => {}
                Err(e) => return Err(sys("poll the pty master")(e)),
            }
            let n = match nix::unistd::read(&self.master, &mut buf) {
                Ok(n) => n,
                Err(Errno::EINTR | Errno::EAGAIN) => continue,
                Err(Errno::EIO) => {
                    // No slave open (cannot happen while we hold one, but be robust).
                    std::thread::sleep(std::time::Duration::from_millis(20));
                    continue;
                }
                Err(e) => return Err(sys("read the pty master")(e)),
            };
            for &b in &buf[..n] {
                match decoder.push(b) {
                    None => {}
                    Some(Err(e)) => {
                        stats.bad_frames += 1;
                        tracing::warn!(error = %e, "bad frame from the client; resynchronising");
                    }
                    Some(Ok(telegram)) => {
                        stats.telegrams += 1;
                        brick.advance_to(clock.now());
                        if let Some(reply) = brick.handle(telegram.as_bytes()) {
                            if let Some(d) = delay.as_mut() {
                                std::thread::sleep(d.sample());
                            }
                            self.write_frame(reply.to_frame().as_bytes())?;
                            stats.replies += 1;
                        }
                    }
                }
            }
        }
        Ok(stats)
    }

    fn write_frame(&self, mut bytes: &[u8]) -> Result<(), PtyError> {
        // One write normally takes the whole (≤ 66-byte) frame; loop only on a short write.
        while !bytes.is_empty() {
            match nix::unistd::write(&self.master, bytes) {
                Ok(n) => bytes = &bytes[n..],
                Err(Errno::EINTR | Errno::EAGAIN) => continue,
                Err(e) => return Err(sys("write the pty master")(e)),
            }
        }
        Ok(())
    }
}

impl Drop for PtyServer {
    fn drop(&mut self) {
        // Remove the link only if it still points at our slave.
        if std::fs::read_link(&self.link).is_ok_and(|t| t == self.slave_path) {
            let _ = std::fs::remove_file(&self.link);
        }
    }
}
