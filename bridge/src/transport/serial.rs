//! A serial-device transport: Bluetooth SPP (`/dev/rfcomm0`) or a pseudo-terminal.

use std::io::{ErrorKind, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use serialport::{ClearBuffer, SerialPort};

use crate::nxt::{FrameDecoder, Telegram, telegram_type};

use super::{Transport, TransportError};

/// Settings of a [`SerialTransport`] (the `[serial]` table of the bridge config, plus the path
/// from `transport = "serial:PATH"`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialConfig {
    /// The device, e.g. `/dev/rfcomm0`.
    pub path: PathBuf,
    /// Line speed; ignored by rfcomm and pseudo-terminals, kept for USB-serial adapters.
    pub baud_rate: u32,
    /// How long to wait for the reply to a request (from the request's write to the reply's
    /// last byte); also the age after which a partial reply is dropped.
    pub read_timeout: Duration,
    /// Wait between reconnection attempts after the device failed.
    pub reconnect_backoff: Duration,
    /// Consecutive timeouts after which the device is closed and reopened.
    pub max_timeouts: u32,
    /// Open the device exclusively (TIOCEXCL), so no second process talks to the brick.
    pub exclusive: bool,
}

impl SerialConfig {
    /// Defaults for `path`: 115200 baud, 500 ms read timeout, 1 s back-off, reopen after 3
    /// timeouts in a row, exclusive.
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            baud_rate: 115_200,
            read_timeout: Duration::from_millis(500),
            reconnect_backoff: Duration::from_secs(1),
            max_timeouts: 3,
            exclusive: true,
        }
    }
}

/// Counters of a [`SerialTransport`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SerialStats {
    /// Successful opens of the device (the first one included).
    pub connects: u64,
    /// Read timeouts.
    pub timeouts: u64,
    /// Replies dropped because they answered another opcode (an earlier, timed-out request).
    pub stale_replies: u64,
    /// Bad frame starts and dropped partial replies skipped while reading replies (junk, a bad
    /// length, a byte that is no reply type after a length).
    pub bad_frames: u64,
}

/// Talks to a brick over a serial device, one frame per write.
///
/// Opens the device lazily and reopens it after an I/O error (or `max_timeouts` timeouts in a
/// row), waiting `reconnect_backoff` between attempts; a transaction attempted while the link
/// is down fails fast with [`TransportError::Backoff`].
///
/// Replies are read with a resynchronising [`FrameDecoder`] (see [`FrameDecoder::replies`]):
/// junk and bad lengths are skipped a byte at a time, a reply to another opcode (a late reply to
/// an earlier, timed-out request) is counted and skipped, never taken as the answer, and
/// whatever is left of a partial reply when a transaction ends is dropped (the next transaction
/// starts on an emptied input queue with a fresh decoder). A transaction that gets no matching
/// reply within `read_timeout` fails with [`TransportError::Timeout`].
pub struct SerialTransport {
    cfg: SerialConfig,
    decoder: FrameDecoder,
    port: Option<Box<dyn SerialPort>>,
    retry_at: Option<Instant>,
    consecutive_timeouts: u32,
    stats: SerialStats,
}

impl std::fmt::Debug for SerialTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SerialTransport")
            .field("cfg", &self.cfg)
            .field("connected", &self.port.is_some())
            .field("stats", &self.stats)
            .finish()
    }
}

impl SerialTransport {
    /// A transport that opens the device at its first transaction.
    pub fn new(cfg: SerialConfig) -> Self {
        Self {
            decoder: FrameDecoder::replies().with_timeout(cfg.read_timeout),
            cfg,
            port: None,
            retry_at: None,
            consecutive_timeouts: 0,
            stats: SerialStats::default(),
        }
    }

    /// Opens the device now.
    pub fn connect(cfg: SerialConfig) -> Result<Self, TransportError> {
        let mut t = Self::new(cfg);
        t.ensure_open()?;
        Ok(t)
    }

    /// Whether the device is open.
    pub fn is_connected(&self) -> bool {
        self.port.is_some()
    }

    /// Counters.
    pub fn stats(&self) -> SerialStats {
        self.stats
    }

    fn path(&self) -> String {
        self.cfg.path.display().to_string()
    }

    fn ensure_open(&mut self) -> Result<&mut Box<dyn SerialPort>, TransportError> {
        if self.port.is_none() {
            if let Some(at) = self.retry_at {
                let now = Instant::now();
                if now < at {
                    return Err(TransportError::Backoff {
                        path: self.path(),
                        wait: at - now,
                    });
                }
            }
            let path = self.cfg.path.to_string_lossy().into_owned();
            match serialport::new(path, self.cfg.baud_rate)
                .timeout(self.cfg.read_timeout)
                .exclusive(self.cfg.exclusive)
                .open()
            {
                Ok(port) => {
                    self.port = Some(port);
                    self.retry_at = None;
                    self.consecutive_timeouts = 0;
                    self.stats.connects += 1;
                    tracing::info!(path = %self.cfg.path.display(), "serial link open");
                }
                Err(e) => {
                    self.retry_at = Some(Instant::now() + self.cfg.reconnect_backoff);
                    return Err(TransportError::Open {
                        path: self.path(),
                        reason: open_failure(&e),
                    });
                }
            }
        }
        self.port.as_mut().ok_or_else(|| TransportError::Backoff {
            path: String::new(),
            wait: Duration::ZERO,
        })
    }

    /// Closes the device; the next transaction reopens it after the back-off.
    pub fn disconnect(&mut self) {
        if self.port.take().is_some() {
            tracing::warn!(path = %self.cfg.path.display(), "serial link closed; will reconnect");
        }
        self.retry_at = Some(Instant::now() + self.cfg.reconnect_backoff);
    }

    fn io_error(&mut self, e: std::io::Error) -> TransportError {
        if e.kind() == ErrorKind::TimedOut {
            self.stats.timeouts += 1;
            self.consecutive_timeouts += 1;
            if self.consecutive_timeouts >= self.cfg.max_timeouts {
                self.disconnect();
            } else if let Some(p) = self.port.as_mut() {
                // A partial reply may still trickle in: drop it before the next request.
                let _ = p.clear(ClearBuffer::Input);
            }
            return TransportError::Timeout(self.cfg.read_timeout);
        }
        self.disconnect();
        TransportError::Io {
            path: self.path(),
            error: e,
        }
    }

    /// Reads until the reply to `request` (same opcode, a reply telegram of at least
    /// `02 <opcode> <status>`), skipping everything else, or until `deadline`.
    fn read_reply(
        &mut self,
        request: &Telegram,
        deadline: Instant,
    ) -> Result<Telegram, TransportError> {
        let mut buf = [0u8; 128];
        loop {
            let now = Instant::now();
            let Some(port) = self.port.as_mut() else {
                return Err(TransportError::Backoff {
                    path: self.path(),
                    wait: self.cfg.reconnect_backoff,
                });
            };
            if now >= deadline {
                return Err(self.io_error(ErrorKind::TimedOut.into()));
            }
            if let Err(e) = port.set_timeout(deadline - now) {
                return Err(self.io_error(e.into()));
            }
            let n = match port.read(&mut buf) {
                Ok(n) => n,
                Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::Interrupted) => 0,
                Err(e) => return Err(self.io_error(e)),
            };
            let now = Instant::now();
            for &b in &buf[..n] {
                match self.decoder.push_at(b, now) {
                    None => {}
                    Some(Err(e)) => {
                        self.stats.bad_frames += 1;
                        tracing::debug!(error = %e, "skipping junk from the brick");
                    }
                    Some(Ok(reply)) => {
                        if reply.len() >= 3
                            && reply.telegram_type() == telegram_type::REPLY
                            && reply.opcode() == request.opcode()
                        {
                            self.consecutive_timeouts = 0;
                            return Ok(reply);
                        }
                        self.stats.stale_replies += 1;
                    }
                }
            }
        }
    }
}

impl Transport for SerialTransport {
    fn transact(&mut self, telegram: &Telegram) -> Result<Option<Telegram>, TransportError> {
        let frame = telegram.to_frame();
        let read_timeout = self.cfg.read_timeout;
        let port = self.ensure_open()?;
        // Anything unread belongs to an earlier, abandoned transaction.
        let _ = port.clear(ClearBuffer::Input);
        let _ = port.set_timeout(read_timeout);
        if let Err(e) = port.write_all(frame.as_bytes()).and_then(|()| port.flush()) {
            return Err(self.io_error(e));
        }
        if !telegram.reply_required() {
            return Ok(None);
        }
        self.decoder.reset();
        let reply = self.read_reply(telegram, Instant::now() + read_timeout);
        // A partial reply left now is abandoned: the next transaction starts clean.
        self.decoder.reset();
        reply.map(Some)
    }

    fn describe(&self) -> String {
        format!("serial:{}", self.cfg.path.display())
    }
}

/// Why a serial device did not open, said as its cause.
fn open_failure(e: &serialport::Error) -> String {
    let hint = match e.kind() {
        serialport::ErrorKind::NoDevice => {
            Some("no such device (is the brick paired and the rfcomm device bound?)")
        }
        serialport::ErrorKind::Io(std::io::ErrorKind::NotFound) => {
            Some("no such device (is the brick paired and the rfcomm device bound?)")
        }
        serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => {
            Some("permission denied (is the user in the dialout group?)")
        }
        _ => None,
    };
    match hint {
        Some(h) => format!("{e}: {h}"),
        None => e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    //! The transport against a scripted brick on the master side of a pseudo-terminal.

    use std::os::fd::{AsFd, OwnedFd};
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::thread;

    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

    use super::*;
    use crate::nxt::{Reply, Request, Status};
    use crate::transport::TransportError;

    /// What the scripted brick does after receiving a request.
    enum Step {
        Write(Vec<u8>),
        Sleep(Duration),
    }

    /// A pty whose master side answers the n-th request with the n-th script; stopped on drop.
    struct ScriptedBrick {
        path: PathBuf,
        quit: Arc<AtomicBool>,
        thread: Option<thread::JoinHandle<()>>,
        _slave: OwnedFd,
    }

    impl ScriptedBrick {
        fn start(scripts: Vec<Vec<Step>>) -> Self {
            let pty = nix::pty::openpty(None, None).expect("openpty");
            let mut t = tcgetattr(&pty.slave).expect("tcgetattr");
            cfmakeraw(&mut t);
            tcsetattr(&pty.slave, SetArg::TCSANOW, &t).expect("tcsetattr");
            let path = nix::unistd::ttyname(&pty.slave).expect("ttyname");
            let quit = Arc::new(AtomicBool::new(false));
            let flag = Arc::clone(&quit);
            let master = pty.master;
            let thread = thread::spawn(move || {
                let mut decoder = FrameDecoder::requests();
                let mut scripts = scripts.into_iter();
                let mut buf = [0u8; 256];
                while !flag.load(Ordering::SeqCst) {
                    let mut fds = [PollFd::new(master.as_fd(), PollFlags::POLLIN)];
                    if !matches!(poll(&mut fds, PollTimeout::from(20u16)), Ok(n) if n > 0) {
                        continue;
                    }
                    let Ok(n) = nix::unistd::read(&master, &mut buf) else {
                        continue;
                    };
                    for &b in &buf[..n] {
                        if let Some(Ok(_)) = decoder.push(b) {
                            for step in scripts.next().unwrap_or_default() {
                                match step {
                                    Step::Write(bytes) => {
                                        nix::unistd::write(&master, &bytes).expect("write");
                                    }
                                    Step::Sleep(d) => thread::sleep(d),
                                }
                            }
                        }
                    }
                }
            });
            Self {
                path,
                quit,
                thread: Some(thread),
                _slave: pty.slave,
            }
        }

        fn transport(&self) -> SerialTransport {
            let mut cfg = SerialConfig::new(&self.path);
            cfg.read_timeout = Duration::from_millis(300);
            cfg.exclusive = false;
            SerialTransport::connect(cfg).expect("open the pty")
        }
    }

    impl Drop for ScriptedBrick {
        fn drop(&mut self) {
            self.quit.store(true, Ordering::SeqCst);
            if let Some(t) = self.thread.take() {
                let _ = t.join();
            }
        }
    }

    fn frame(reply: Reply) -> Vec<u8> {
        reply.encode().to_frame().as_bytes().to_vec()
    }

    fn battery(millivolts: u16) -> Reply {
        Reply::BatteryLevel {
            status: Status::Success,
            millivolts,
        }
    }

    fn keep_alive() -> Reply {
        Reply::KeepAlive {
            status: Status::Success,
            sleep_timeout_ms: 600_000,
        }
    }

    #[test]
    fn junk_and_bad_lengths_before_a_reply_are_skipped() {
        let mut junk = vec![0x42, 0x00, 0x00, 0x41, 0x00, 0xFF, 0xFF, 0x05];
        junk.extend(frame(battery(8100)));
        let brick = ScriptedBrick::start(vec![vec![Step::Write(junk)]]);
        let mut link = brick.transport();
        assert_eq!(
            link.request(&Request::GetBatteryLevel).ok(),
            Some(battery(8100))
        );
        assert!(link.stats().bad_frames >= 4, "{:?}", link.stats());
    }

    #[test]
    fn a_half_reply_older_than_the_timeout_is_dropped() {
        let half = frame(battery(8000))[..4].to_vec();
        let brick = ScriptedBrick::start(vec![
            // The first request gets half a reply, and the rest only after the timeout.
            vec![
                Step::Write(half),
                Step::Sleep(Duration::from_millis(400)),
                Step::Write(frame(battery(8000))[4..].to_vec()),
            ],
            vec![Step::Write(frame(battery(8200)))],
        ]);
        let mut link = brick.transport();
        let err = link.request(&Request::GetBatteryLevel).err();
        assert!(matches!(err, Some(TransportError::Timeout(_))), "{err:?}");
        // The next request's answer is its own, not the old half completed by new bytes.
        assert_eq!(
            link.request(&Request::GetBatteryLevel).ok(),
            Some(battery(8200))
        );
        assert_eq!(link.stats().timeouts, 1);
    }

    #[test]
    fn a_reply_to_another_opcode_is_not_taken_as_the_answer() {
        let mut two = frame(keep_alive());
        two.extend(frame(battery(7900)));
        let brick = ScriptedBrick::start(vec![
            vec![Step::Write(two)],
            // Only a reply to another opcode: a timeout, not an answer.
            vec![Step::Write(frame(keep_alive()))],
        ]);
        let mut link = brick.transport();
        assert_eq!(
            link.request(&Request::GetBatteryLevel).ok(),
            Some(battery(7900))
        );
        assert_eq!(link.stats().stale_replies, 1);
        let err = link.request(&Request::GetBatteryLevel).err();
        assert!(matches!(err, Some(TransportError::Timeout(_))), "{err:?}");
        assert_eq!(link.stats().stale_replies, 2);
    }
}
