//! Serves the simulated brick on a pseudo-terminal, so any NXT client can drive it.
//!
//! [`PtyServer::open`] creates a pseudo-terminal in raw mode and links its slave side at the
//! path you give; clients open that path as they would `/dev/rfcomm0`. [`PtyServer::serve`]
//! reads frames from the master side, hands each telegram to the [`SimBrick`] (stepped to the
//! clock first) and writes each reply frame in one `write`, because clients such as
//! nxt-python's devfile backend read the 2-byte header and then the body in one read each.
//! The server keeps its own descriptor of the slave open, so clients may come and go (and the
//! raw mode stays set between them).
//!
//! Robust against what clients do wrong:
//!
//! - **Junk and bad frames** — a stray byte, a length of 0 or over 64, a type byte that is no
//!   request's: the [`FrameDecoder`] skips them one byte at a time until a plausible request
//!   frame, so the next valid request is answered. A bad length gets **no reply**: the opcode
//!   a reply must echo (`02 <opcode> <status>`) is unknowable, and the firmware itself has no
//!   reply for a frame it cannot delimit. A well-framed telegram with an unknown opcode or a body
//!   too short for its opcode does reach the brick, which answers it like the firmware
//!   (`0xBE` unknown command, `0xBF` insane packet; see [`SimBrick::handle`]).
//! - **An abandoned half frame** is dropped when it is older than [`PARTIAL_FRAME_TIMEOUT`](crate::nxt::PARTIAL_FRAME_TIMEOUT), and
//!   at once when a client opens or closes the device (seen with inotify on the slave device;
//!   without inotify the timeout alone does it). When the last client closes the device, the
//!   replies still queued for it are discarded, so the next client reads only its own.
//! - **A client that does not read its replies** cannot block the server: the master is
//!   non-blocking, a reply that finds no room is dropped and counted
//!   ([`ServeStats::replies_dropped`], one warning per run of drops), and the stop flag is
//!   checked at least every [`STOP_CHECK`].

use std::io;
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::inotify::{AddWatchFlags, InitFlags, Inotify};
use nix::sys::termios::{FlushArg, SetArg, cfmakeraw, tcflush, tcgetattr, tcsetattr};

use crate::brick::SimBrick;
use crate::clock::Clock;
use crate::nxt::{FrameDecoder, FrameError};
use crate::transport::LinkDelay;

/// The least time between two warnings about bad frames from a client (a babbling client
/// must not flood the log).
const WARN_EVERY: Duration = Duration::from_secs(1);

/// The longest [`PtyServer::serve`] goes without checking its stop flag (one poll, one slice
/// of a link-delay sleep, or the wait to finish a reply already half written).
pub const STOP_CHECK: Duration = Duration::from_millis(50);

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
    /// Bad frame starts skipped (a length of 0 or over 64, or a type byte no request has).
    pub bad_frames: u64,
    /// Partial frames dropped: older than [`PARTIAL_FRAME_TIMEOUT`](crate::nxt::PARTIAL_FRAME_TIMEOUT), or left by a client that
    /// went away.
    pub stale_frames: u64,
    /// Bytes skipped while looking for frames (junk, bad headers, dropped partial frames).
    pub skipped_bytes: u64,
    /// Replies dropped, or cut short, because the client does not read its replies.
    pub replies_dropped: u64,
    /// Opens of the device by clients (0 if inotify is unavailable).
    pub clients: u64,
}

impl std::fmt::Display for ServeStats {
    /// In words, for the log: "120 telegrams, 118 replies, 2 bad frames, …".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} telegrams, {} replies, {} bad frames, {} stale frames, {} bytes skipped, \
             {} replies dropped, {} clients",
            self.telegrams,
            self.replies,
            self.bad_frames,
            self.stale_frames,
            self.skipped_bytes,
            self.replies_dropped,
            self.clients
        )
    }
}

/// The simulated brick's pseudo-terminal. Dropping it removes the link.
#[derive(Debug)]
pub struct PtyServer {
    master: OwnedFd,
    slave: OwnedFd,
    slave_path: PathBuf,
    link: PathBuf,
    watch: Option<ClientWatch>,
}

impl PtyServer {
    /// Opens a raw pseudo-terminal and symlinks `link` to its slave device. An existing
    /// symbolic link at `link` (say, left by a killed server) is replaced.
    pub fn open(link: &Path) -> Result<Self, PtyError> {
        let pty = nix::pty::openpty(None, None).map_err(sys("openpty"))?;
        let mut t = tcgetattr(&pty.slave).map_err(sys("tcgetattr on the pty slave"))?;
        cfmakeraw(&mut t);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &t).map_err(sys("tcsetattr on the pty slave"))?;
        // Replies are written non-blocking: a client that does not read cannot stall the server.
        let flags =
            fcntl(&pty.master, FcntlArg::F_GETFL).map_err(sys("F_GETFL on the pty master"))?;
        fcntl(
            &pty.master,
            FcntlArg::F_SETFL(OFlag::from_bits_retain(flags) | OFlag::O_NONBLOCK),
        )
        .map_err(sys("F_SETFL O_NONBLOCK on the pty master"))?;
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
        // Watch for clients before any can find the device through the link.
        let watch = ClientWatch::new(&slave_path);
        std::os::unix::fs::symlink(&slave_path, link).map_err(|error| PtyError::Sys {
            context: format!("symlink {} -> {}", link.display(), slave_path.display()),
            error,
        })?;
        Ok(Self {
            master: pty.master,
            slave: pty.slave,
            slave_path,
            link: link.to_owned(),
            watch,
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

    /// Serves `brick` until `stop` becomes true (checked at least every [`STOP_CHECK`]). With
    /// `delay`, each reply is held back by a link-delay draw, like a Bluetooth link.
    pub fn serve<C: Clock>(
        &self,
        brick: &mut SimBrick,
        clock: &C,
        mut delay: Option<LinkDelay>,
        stop: &AtomicBool,
    ) -> Result<ServeStats, PtyError> {
        let mut st = ServeState {
            stats: ServeStats::default(),
            decoder: FrameDecoder::requests(),
            last_warning: None,
            unwarned: 0,
            dropping: false,
            open_clients: 0,
        };
        let watch = self.watch.as_ref();
        let mut buf = [0u8; 256];
        while !stop.load(Ordering::SeqCst) {
            st.stats.skipped_bytes = st.decoder.skipped_bytes();
            match self.poll_input(watch) {
                Ok(0) | Err(Errno::EINTR) => {
                    if let Some(e) = st.decoder.expire(Instant::now()) {
                        st.frame_error(e);
                    }
                    continue;
                }
                Ok(_) => {}
                Err(e) => return Err(sys("poll the pty master")(e)),
            }
            let n = match nix::unistd::read(&self.master, &mut buf) {
                Ok(n) => n,
                Err(Errno::EINTR | Errno::EAGAIN) => 0,
                Err(Errno::EIO) => {
                    // No slave open (cannot happen while we hold one, but be robust): whatever
                    // was partial belongs to a client that is gone.
                    st.drop_partial("the device was hung up");
                    std::thread::sleep(Duration::from_millis(20));
                    continue;
                }
                Err(e) => return Err(sys("read the pty master")(e)),
            };
            let now = Instant::now();
            for &b in &buf[..n] {
                match st.decoder.push_at(b, now) {
                    None => {}
                    Some(Err(e)) => st.frame_error(e),
                    Some(Ok(telegram)) => {
                        st.stats.telegrams += 1;
                        brick.advance_to(clock.now());
                        let Some(reply) = brick.handle(telegram.as_bytes()) else {
                            continue;
                        };
                        if let Some(d) = delay.as_mut()
                            && !sleep_unless_stopped(d.sample(), stop)
                        {
                            break;
                        }
                        let written = self.write_frame(reply.to_frame().as_bytes(), stop)?;
                        st.reply_written(written);
                    }
                }
            }
            // Client changes are applied after the bytes read with them: a client writes
            // before it closes, so a partial frame left now is the departed client's (or, if
            // the server read nothing in between, mixed with the next client's first frame,
            // which that client's retry after the timeout recovers).
            if let Some(w) = watch {
                self.client_events(w, &mut st);
            }
        }
        st.stats.skipped_bytes = st.decoder.skipped_bytes();
        Ok(st.stats)
    }

    /// Waits up to [`STOP_CHECK`] for bytes from a client, or for client opens and closes
    /// (with a watch): how many of the two are ready.
    fn poll_input(&self, watch: Option<&ClientWatch>) -> nix::Result<i32> {
        let mut fds = [
            PollFd::new(self.master.as_fd(), PollFlags::POLLIN),
            PollFd::new(
                watch.map_or(self.master.as_fd(), |w| w.inotify.as_fd()),
                PollFlags::POLLIN,
            ),
        ];
        let n = if watch.is_some() { 2 } else { 1 };
        poll(&mut fds[..n], poll_timeout(STOP_CHECK))
    }

    /// Applies client opens and closes: each drops a partial frame; when the last client has
    /// gone, the replies still queued for it are discarded, so the next client reads only its
    /// own. (The slave has one input queue for all its openers, so it is flushed only when no
    /// client has it open.)
    fn client_events(&self, watch: &ClientWatch, st: &mut ServeState) {
        let (opened, closed) = watch.drain();
        if opened + closed == 0 {
            return;
        }
        st.stats.clients += opened;
        st.open_clients = (st.open_clients + opened).saturating_sub(closed);
        st.drop_partial(if closed > 0 {
            "a client closed the device"
        } else {
            "a client opened the device"
        });
        if st.open_clients == 0 {
            if let Err(e) = tcflush(&self.slave, FlushArg::TCIFLUSH) {
                tracing::warn!(error = %e, "cannot discard the replies of a departed client");
            }
            st.dropping = false;
        }
    }

    /// Writes one frame without blocking. Nothing written when the client's queue is full:
    /// dropped. Part written: the rest gets up to [`STOP_CHECK`] (the client is reading), then
    /// it is cut short (the client's decoder drops the partial frame after its timeout).
    fn write_frame(&self, bytes: &[u8], stop: &AtomicBool) -> Result<Written, PtyError> {
        let deadline = Instant::now() + STOP_CHECK;
        let mut rest = bytes;
        while !rest.is_empty() {
            match nix::unistd::write(&self.master, rest) {
                Ok(n) => rest = rest.get(n..).unwrap_or_default(),
                Err(Errno::EINTR) => {}
                Err(Errno::EAGAIN | Errno::EIO) if rest.len() == bytes.len() => {
                    return Ok(Written::Dropped);
                }
                Err(Errno::EAGAIN) => {
                    let now = Instant::now();
                    if now >= deadline || stop.load(Ordering::SeqCst) {
                        return Ok(Written::CutShort);
                    }
                    let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLOUT)];
                    match poll(&mut fds, poll_timeout(deadline - now)) {
                        Ok(_) | Err(Errno::EINTR) => {}
                        Err(e) => return Err(sys("poll the pty master for writing")(e)),
                    }
                }
                Err(Errno::EIO) => return Ok(Written::CutShort),
                Err(e) => return Err(sys("write the pty master")(e)),
            }
        }
        Ok(Written::All)
    }
}

/// What became of a reply frame.
enum Written {
    All,
    Dropped,
    CutShort,
}

/// The mutable state of one `serve` run.
struct ServeState {
    stats: ServeStats,
    decoder: FrameDecoder,
    /// When the last warning about a bad or stale frame was logged.
    last_warning: Option<Instant>,
    /// Bad or stale frames since that warning.
    unwarned: u64,
    /// Whether replies are being dropped (one warning per run of drops).
    dropping: bool,
    /// Clients that have the device open (opens minus closes seen).
    open_clients: u64,
}

impl ServeState {
    /// Counts a bad or stale frame; warns at most once per [`WARN_EVERY`], with the count.
    fn frame_error(&mut self, e: FrameError) {
        match e {
            FrameError::Stale { .. } => self.stats.stale_frames += 1,
            _ => self.stats.bad_frames += 1,
        }
        self.unwarned += 1;
        let now = Instant::now();
        if self
            .last_warning
            .is_none_or(|t| now.saturating_duration_since(t) >= WARN_EVERY)
        {
            tracing::warn!(
                error = %e,
                frames = self.unwarned,
                "bad or abandoned frames from the client; resynchronising"
            );
            self.last_warning = Some(now);
            self.unwarned = 0;
        }
    }

    /// Counts what became of a reply; says once when the client stops reading its replies,
    /// and once when it reads them again.
    fn reply_written(&mut self, written: Written) {
        match written {
            Written::All => {
                self.stats.replies += 1;
                if self.dropping {
                    self.dropping = false;
                    tracing::info!(
                        replies_dropped = self.stats.replies_dropped,
                        "the client reads its replies again"
                    );
                }
            }
            Written::Dropped | Written::CutShort => {
                self.stats.replies_dropped += 1;
                if !self.dropping {
                    self.dropping = true;
                    tracing::warn!(
                        replies_dropped = self.stats.replies_dropped,
                        "the client does not read its replies; dropping them"
                    );
                }
            }
        }
    }

    fn drop_partial(&mut self, why: &str) {
        let bytes = self.decoder.reset();
        if bytes > 0 {
            self.stats.stale_frames += 1;
            tracing::warn!(bytes, "{why}: dropped a partial frame");
        }
    }
}

/// Watches the slave device for opens and closes by clients.
#[derive(Debug)]
struct ClientWatch {
    inotify: Inotify,
}

impl ClientWatch {
    /// `None` (with a warning) if inotify is unavailable; the partial-frame timeout remains.
    fn new(device: &Path) -> Option<Self> {
        let watch = Inotify::init(InitFlags::IN_NONBLOCK | InitFlags::IN_CLOEXEC).and_then(|i| {
            i.add_watch(device, AddWatchFlags::IN_OPEN | AddWatchFlags::IN_CLOSE)
                .map(|_| i)
        });
        match watch {
            Ok(inotify) => Some(Self { inotify }),
            Err(e) => {
                tracing::warn!(
                    error = %e,
                    device = %device.display(),
                    "cannot watch the device for clients; partial frames are dropped by timeout only"
                );
                None
            }
        }
    }

    /// Opens and closes since the last call.
    fn drain(&self) -> (u64, u64) {
        let (mut opened, mut closed) = (0, 0);
        while let Ok(events) = self.inotify.read_events() {
            if events.is_empty() {
                break;
            }
            for e in events {
                if e.mask.contains(AddWatchFlags::IN_OPEN) {
                    opened += 1;
                }
                if e.mask.intersects(AddWatchFlags::IN_CLOSE) {
                    closed += 1;
                }
            }
        }
        (opened, closed)
    }
}

fn poll_timeout(d: Duration) -> PollTimeout {
    let ms = u16::try_from(d.as_millis()).unwrap_or(u16::MAX);
    PollTimeout::from(ms.max(1))
}

/// Sleeps `d` in slices of at most [`STOP_CHECK`]; `false` if `stop` was set meanwhile.
fn sleep_unless_stopped(d: Duration, stop: &AtomicBool) -> bool {
    let end = Instant::now() + d;
    loop {
        if stop.load(Ordering::SeqCst) {
            return false;
        }
        let now = Instant::now();
        if now >= end {
            return true;
        }
        std::thread::sleep((end - now).min(STOP_CHECK));
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

#[cfg(test)]
mod tests;
