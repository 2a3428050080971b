//! What every real link to a brick shares: opening it lazily, the read timeout, skipping junk
//! and stale replies, reconnecting after a failure with a back-off, and the link's counters.
//!
//! A real link is a [`Device`] (how to reach the brick: a serial device, a Bluetooth address, a
//! USB brick) that opens a [`Connection`] (the byte stream or packet pipe to it), and a
//! [`Framing`] (a 2-byte length before each telegram on serial and Bluetooth; one telegram per
//! USB packet). [`LinkTransport`] turns any of them into a [`Transport`], so the serial,
//! Bluetooth and USB links behave alike: the bridge's link tracking, retries, watchdog and
//! link-down handling see one kind of failure whichever link it is.

use std::io::ErrorKind;
use std::time::{Duration, Instant};

use crate::nxt::{FrameDecoder, Telegram, telegram_type};

use super::{Transport, TransportError};

/// How telegrams are cut on a link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Framing {
    /// A 2-byte little-endian length, then the telegram: the byte streams (serial devices,
    /// Bluetooth RFCOMM).
    LengthPrefixed,
    /// One telegram per packet, no length: USB bulk transfers.
    Packets,
}

/// Why a link could not be opened: the cause, and what the user can do about it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OpenFailure {
    /// What went wrong, in the operating system's or the library's words.
    pub cause: String,
    /// What to do about it, when we know.
    pub fix: Option<String>,
    /// The link cannot exist on this machine (no Bluetooth in its kernel, no USB bus): trying
    /// again is pointless.
    pub impossible: bool,
}

impl OpenFailure {
    /// A failure with its cause and a fix.
    pub fn new(cause: impl Into<String>, fix: impl Into<String>) -> Self {
        Self {
            cause: cause.into(),
            fix: Some(fix.into()),
            impossible: false,
        }
    }

    /// A failure whose fix we do not know.
    pub fn bare(cause: impl Into<String>) -> Self {
        Self {
            cause: cause.into(),
            fix: None,
            impossible: false,
        }
    }

    /// The same failure, marked as one no retry can cure on this machine.
    pub fn for_good(mut self) -> Self {
        self.impossible = true;
        self
    }
}

impl std::fmt::Display for OpenFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.cause)?;
        match &self.fix {
            Some(fix) => write!(f, "; {fix}"),
            None => Ok(()),
        }
    }
}

/// How to reach a brick: opens [`Connection`]s to it.
pub trait Device {
    /// An open link.
    type Connection: Connection;

    /// Opens a link to the brick.
    fn open(&mut self) -> Result<Self::Connection, OpenFailure>;

    /// The link as the config names it (`serial:/dev/rfcomm0`, `bluetooth:00:16:53:…`, `usb`).
    fn describe(&self) -> String;

    /// How telegrams are cut on this link.
    fn framing(&self) -> Framing;
}

/// An open link to a brick.
pub trait Connection {
    /// Sends one whole frame (with its length prefix under [`Framing::LengthPrefixed`]; one
    /// telegram, one packet, under [`Framing::Packets`]).
    fn send(&mut self, frame: &[u8]) -> std::io::Result<()>;

    /// Waits up to `timeout` for bytes (a byte stream) or one packet (a packet link) and
    /// copies them into `buf`. Fails with [`ErrorKind::TimedOut`] when nothing came,
    /// [`ErrorKind::Interrupted`] to be called again, and any other error (the peer closed
    /// the link: [`ErrorKind::UnexpectedEof`]) when the link is gone.
    fn receive(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize>;

    /// Drops whatever has arrived and not been read (replies to abandoned requests).
    fn discard_input(&mut self);
}

/// Settings of a [`LinkTransport`], shared by every real link (the `[serial]` table's timing
/// keys).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkTiming {
    /// How long to wait for the reply to a request (from the request's write to the reply's
    /// last byte); also the age after which a partial reply is dropped.
    pub read_timeout: Duration,
    /// Wait between reconnection attempts after the link failed.
    pub reconnect_backoff: Duration,
    /// Consecutive timeouts after which the link is closed and reopened.
    pub max_timeouts: u32,
}

impl Default for LinkTiming {
    /// 500 ms read timeout, 1 s back-off, reopen after 3 timeouts in a row.
    fn default() -> Self {
        Self {
            read_timeout: Duration::from_millis(500),
            reconnect_backoff: Duration::from_secs(1),
            max_timeouts: 3,
        }
    }
}

/// Counters of a [`LinkTransport`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Successful opens of the link (the first one included).
    pub connects: u64,
    /// Read timeouts.
    pub timeouts: u64,
    /// Replies dropped because they answered another opcode (an earlier, timed-out request).
    pub stale_replies: u64,
    /// Bad frame starts, dropped partial replies and packets that are no reply, skipped while
    /// reading replies.
    pub bad_frames: u64,
}

/// A real link to a brick as a [`Transport`], one frame per write.
///
/// Opens the link lazily and reopens it after an I/O error (the peer closing it included) or
/// `max_timeouts` timeouts in a row, waiting `reconnect_backoff` between attempts; a
/// transaction attempted while the link is down fails fast with [`TransportError::Backoff`].
///
/// Replies are read per the device's [`Framing`]. On a byte stream a resynchronising
/// [`FrameDecoder`] (see [`FrameDecoder::replies`]) skips junk and bad lengths a byte at a time,
/// and whatever is left of a partial reply when a transaction ends is dropped (the next
/// transaction starts on an emptied input queue with a fresh decoder). On a packet link each
/// packet is a telegram, and a packet that is no reply is skipped. Either way a reply to
/// another opcode (a late reply to an earlier, timed-out request) is counted and skipped, never
/// taken as the answer, and a transaction that gets no matching reply within `read_timeout`
/// fails with [`TransportError::Timeout`].
pub struct LinkTransport<D: Device> {
    device: D,
    timing: LinkTiming,
    decoder: FrameDecoder,
    connection: Option<D::Connection>,
    retry_at: Option<Instant>,
    consecutive_timeouts: u32,
    /// Whether the brick ever answered on this link: until it has, closing the link is part
    /// of bringing it up, and the bridge says the cause once when it gives up.
    answered: bool,
    stats: LinkStats,
}

impl<D: Device> std::fmt::Debug for LinkTransport<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LinkTransport")
            .field("link", &self.device.describe())
            .field("timing", &self.timing)
            .field("connected", &self.connection.is_some())
            .field("stats", &self.stats)
            .finish()
    }
}

impl<D: Device> LinkTransport<D> {
    /// A transport that opens `device` at its first transaction.
    pub fn new(device: D, timing: LinkTiming) -> Self {
        Self {
            device,
            decoder: FrameDecoder::replies().with_timeout(timing.read_timeout),
            timing,
            connection: None,
            retry_at: None,
            consecutive_timeouts: 0,
            answered: false,
            stats: LinkStats::default(),
        }
    }

    /// Opens `device` now.
    pub fn connect(device: D, timing: LinkTiming) -> Result<Self, TransportError> {
        let mut t = Self::new(device, timing);
        t.ensure_open()?;
        Ok(t)
    }

    /// Whether the link is open.
    pub fn is_connected(&self) -> bool {
        self.connection.is_some()
    }

    /// Counters.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Closes the link; the next transaction reopens it after the back-off.
    pub fn disconnect(&mut self) {
        if self.connection.take().is_some() {
            if self.answered {
                tracing::warn!(link = %self.device.describe(), "link closed; will reconnect");
            } else {
                tracing::debug!(link = %self.device.describe(), "link closed before the brick answered; will reconnect");
            }
        }
        self.retry_at = Some(Instant::now() + self.timing.reconnect_backoff);
    }

    /// Opens the link if it is closed and the back-off is over.
    fn ensure_open(&mut self) -> Result<(), TransportError> {
        if self.connection.is_none() {
            self.wait_out_backoff()?;
            match self.device.open() {
                Ok(connection) => {
                    self.connection = Some(connection);
                    self.retry_at = None;
                    self.consecutive_timeouts = 0;
                    self.stats.connects += 1;
                    tracing::info!(link = %self.device.describe(), "link open");
                }
                Err(failure) => {
                    self.retry_at = Some(Instant::now() + self.timing.reconnect_backoff);
                    return Err(TransportError::Open {
                        link: self.device.describe(),
                        reason: failure.to_string(),
                        impossible: failure.impossible,
                    });
                }
            }
        }
        Ok(())
    }

    /// Fails fast while the back-off after a failure lasts.
    fn wait_out_backoff(&self) -> Result<(), TransportError> {
        match self.retry_at {
            Some(at) if Instant::now() < at => Err(TransportError::Backoff {
                link: self.device.describe(),
                wait: at - Instant::now(),
            }),
            _ => Ok(()),
        }
    }

    fn down(&self) -> TransportError {
        TransportError::Backoff {
            link: self.device.describe(),
            wait: self.timing.reconnect_backoff,
        }
    }

    /// Turns an I/O failure into the transport's error, closing the link when it is gone (or
    /// timed out too often).
    fn io_error(&mut self, e: std::io::Error) -> TransportError {
        if e.kind() == ErrorKind::TimedOut {
            self.stats.timeouts += 1;
            self.consecutive_timeouts += 1;
            if self.consecutive_timeouts >= self.timing.max_timeouts {
                self.disconnect();
            } else if let Some(c) = self.connection.as_mut() {
                // A partial reply may still trickle in: drop it before the next request.
                c.discard_input();
            }
            return TransportError::Timeout(self.timing.read_timeout);
        }
        self.disconnect();
        TransportError::Io {
            link: self.device.describe(),
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
            if now >= deadline {
                return Err(self.io_error(ErrorKind::TimedOut.into()));
            }
            let Some(connection) = self.connection.as_mut() else {
                return Err(self.down());
            };
            let n = match connection.receive(&mut buf, deadline - now) {
                Ok(n) => n,
                Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::Interrupted) => 0,
                Err(e) => return Err(self.io_error(e)),
            };
            let found = match self.device.framing() {
                Framing::LengthPrefixed => self.decode_bytes(&buf[..n], request),
                Framing::Packets => (n > 0)
                    .then(|| self.take_packet(&buf[..n], request))
                    .flatten(),
            };
            if let Some(reply) = found {
                self.consecutive_timeouts = 0;
                self.answered = true;
                return Ok(reply);
            }
        }
    }

    /// Pushes stream bytes through the decoder; the reply to `request`, if they complete it.
    fn decode_bytes(&mut self, bytes: &[u8], request: &Telegram) -> Option<Telegram> {
        let now = Instant::now();
        for &b in bytes {
            match self.decoder.push_at(b, now) {
                None => {}
                Some(Err(e)) => {
                    self.stats.bad_frames += 1;
                    tracing::debug!(error = %e, "skipping junk from the brick");
                }
                Some(Ok(reply)) => {
                    if answers(&reply, request) {
                        return Some(reply);
                    }
                    self.stats.stale_replies += 1;
                }
            }
        }
        None
    }

    /// One packet: the reply to `request`, or counted as stale or bad and skipped.
    fn take_packet(&mut self, packet: &[u8], request: &Telegram) -> Option<Telegram> {
        match Telegram::from_bytes(packet) {
            Ok(reply) if answers(&reply, request) => Some(reply),
            Ok(reply) if is_reply(&reply) => {
                self.stats.stale_replies += 1;
                None
            }
            _ => {
                self.stats.bad_frames += 1;
                tracing::debug!(len = packet.len(), "skipping a packet that is no reply");
                None
            }
        }
    }
}

/// Whether `reply` is a reply telegram: `02 <opcode> <status>` at least.
fn is_reply(reply: &Telegram) -> bool {
    reply.len() >= 3 && reply.telegram_type() == telegram_type::REPLY
}

/// Whether `reply` answers `request`.
fn answers(reply: &Telegram, request: &Telegram) -> bool {
    is_reply(reply) && reply.opcode() == request.opcode()
}

impl<D: Device> Transport for LinkTransport<D> {
    fn transact(&mut self, telegram: &Telegram) -> Result<Option<Telegram>, TransportError> {
        let framing = self.device.framing();
        let read_timeout = self.timing.read_timeout;
        self.ensure_open()?;
        let Some(connection) = self.connection.as_mut() else {
            return Err(self.down());
        };
        // Anything unread belongs to an earlier, abandoned transaction.
        connection.discard_input();
        let sent = match framing {
            Framing::LengthPrefixed => connection.send(telegram.to_frame().as_bytes()),
            Framing::Packets => connection.send(telegram.as_bytes()),
        };
        if let Err(e) = sent {
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
        self.device.describe()
    }
}
