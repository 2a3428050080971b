//! A serial-device transport: Bluetooth SPP (`/dev/rfcomm0`) or a pseudo-terminal.

use std::io::{ErrorKind, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use serialport::{ClearBuffer, SerialPort};

use crate::nxt::frame::parse_header;
use crate::nxt::{Telegram, telegram_type};

use super::{Transport, TransportError};

/// Settings of a [`SerialTransport`] (the `[serial]` table of the bridge config, plus the path
/// from `transport = "serial:PATH"`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialConfig {
    /// The device, e.g. `/dev/rfcomm0`.
    pub path: PathBuf,
    /// Line speed; ignored by rfcomm and pseudo-terminals, kept for USB-serial adapters.
    pub baud_rate: u32,
    /// How long to wait for each part (header, body) of a reply.
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
    /// Replies dropped because they answered an earlier, timed-out request.
    pub stale_replies: u64,
}

/// Talks to a brick over a serial device, one frame per write.
///
/// Opens the device lazily and reopens it after an I/O error (or `max_timeouts` timeouts in a
/// row), waiting `reconnect_backoff` between attempts; a transaction attempted while the link
/// is down fails fast with [`TransportError::Backoff`].
pub struct SerialTransport {
    cfg: SerialConfig,
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
                        reason: e.to_string(),
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

    fn read_frame(
        port: &mut dyn SerialPort,
    ) -> Result<Result<Telegram, TransportError>, std::io::Error> {
        let mut header = [0u8; 2];
        port.read_exact(&mut header)?;
        let n = match parse_header(header) {
            Ok(n) => n,
            Err(e) => return Ok(Err(e.into())),
        };
        let mut body = [0u8; crate::nxt::MAX_TELEGRAM_LEN];
        port.read_exact(&mut body[..n])?;
        Ok(Telegram::from_bytes(&body[..n]).map_err(TransportError::from))
    }
}

impl Transport for SerialTransport {
    fn transact(&mut self, telegram: &Telegram) -> Result<Option<Telegram>, TransportError> {
        let frame = telegram.to_frame();
        let port = self.ensure_open()?;
        // Anything unread belongs to an earlier, abandoned transaction.
        let _ = port.clear(ClearBuffer::Input);
        if let Err(e) = port.write_all(frame.as_bytes()).and_then(|()| port.flush()) {
            return Err(self.io_error(e));
        }
        if !telegram.reply_required() {
            return Ok(None);
        }
        // A late reply to a timed-out request may precede ours: skip a few mismatches.
        for _ in 0..4 {
            let Some(port) = self.port.as_mut() else {
                break;
            };
            match Self::read_frame(port.as_mut()) {
                Err(e) => return Err(self.io_error(e)),
                Ok(Err(e)) => {
                    // Lost framing: start afresh on a clean line.
                    let _ = port.clear(ClearBuffer::Input);
                    return Err(e);
                }
                Ok(Ok(reply)) => {
                    self.consecutive_timeouts = 0;
                    if reply.telegram_type() == telegram_type::REPLY
                        && reply.opcode() == telegram.opcode()
                    {
                        return Ok(Some(reply));
                    }
                    self.stats.stale_replies += 1;
                }
            }
        }
        Err(TransportError::OpcodeMismatch {
            expected: telegram.opcode(),
            got: 0,
        })
    }

    fn describe(&self) -> String {
        format!("serial:{}", self.cfg.path.display())
    }
}
