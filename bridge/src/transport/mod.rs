//! Transports carry telegrams to a brick and bring its replies back.
//!
//! - [`SimTransport`]: the [`SimBrick`](crate::brick::SimBrick) in-process, stepped to a
//!   [`Clock`](crate::clock::Clock) at each telegram.
//! - [`SerialTransport`]: a serial device (`/dev/rfcomm0` for a Bluetooth-paired NXT, or the
//!   pseudo-terminal `tes-bridge brick --pty` serves), with read timeouts and reconnection.
//! - [`DelayedTransport`]: wraps either and delays each reply like a Bluetooth link
//!   (≈ 30 ms with jitter), for realistic timing off the robot.
//!
//! The bridge sees only the [`Transport`] trait, so the transport is one config setting.
//!
//! ```
//! use tes_bridge::brick::{SimBrick, SimBrickConfig};
//! use tes_bridge::clock::ManualClock;
//! use tes_bridge::nxt::{Reply, Request};
//! use tes_bridge::transport::{SimTransport, Transport};
//!
//! let brick = SimBrick::new(SimBrickConfig::default(), 7)?;
//! let mut link = SimTransport::new(brick, ManualClock::new());
//! match link.request(&Request::GetBatteryLevel)? {
//!     Reply::BatteryLevel { millivolts, .. } => assert!(millivolts > 7000),
//!     other => panic!("unexpected {other:?}"),
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod delay;
mod serial;
mod sim;

use std::time::Duration;

pub use delay::{DelayedTransport, LinkDelay, Sleep, ThreadSleep};
pub use serial::{SerialConfig, SerialStats, SerialTransport};
pub use sim::SimTransport;

use crate::nxt::{DecodeError, FrameError, Opcode, Reply, Request, Status, Telegram};

/// Why a transaction failed.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The device could not be opened (the bridge retries after a back-off).
    #[error("cannot open {path}: {reason}")]
    Open {
        /// Device path.
        path: String,
        /// The operating system's reason.
        reason: String,
    },
    /// The device is closed after a failure and the back-off has not elapsed.
    #[error("link to {path} is down; reconnecting in {wait:?}")]
    Backoff {
        /// Device path.
        path: String,
        /// Time until the next attempt.
        wait: Duration,
    },
    /// Reading or writing the device failed.
    #[error("I/O error on {path}: {error}")]
    Io {
        /// Device path.
        path: String,
        /// The error (part of the message, so not also chained as a source).
        error: std::io::Error,
    },
    /// No (complete) reply within the read timeout.
    #[error("no reply from the brick within {0:?}")]
    Timeout(Duration),
    /// The byte stream from the brick is not valid framing.
    #[error("bad frame from the brick: {0}")]
    Frame(#[from] FrameError),
    /// A reply telegram did not decode.
    #[error("undecodable reply from the brick: {0}")]
    Decode(#[from] DecodeError),
    /// The reply answers another opcode.
    #[error("reply to opcode 0x{got:02X} where 0x{expected:02X} was expected")]
    OpcodeMismatch {
        /// The opcode asked.
        expected: u8,
        /// The opcode answered.
        got: u8,
    },
    /// A reply was required but none came back.
    #[error("the brick sent no reply to {0}")]
    NoReply(Opcode),
    /// The brick answered with an error status.
    #[error("{opcode} failed: status {status}")]
    Status {
        /// The opcode.
        opcode: Opcode,
        /// The status.
        status: Status,
    },
}

impl TransportError {
    /// Whether the error means the link itself is unusable (as opposed to a refused request).
    pub fn is_link_failure(&self) -> bool {
        matches!(
            self,
            TransportError::Open { .. }
                | TransportError::Backoff { .. }
                | TransportError::Io { .. }
                | TransportError::Timeout(_)
                | TransportError::Frame(_)
        )
    }
}

/// Something that carries telegrams to a brick.
pub trait Transport {
    /// Sends one telegram; returns the brick's reply if the telegram requires one
    /// (type 0x00 or 0x01), `None` otherwise.
    fn transact(&mut self, telegram: &Telegram) -> Result<Option<Telegram>, TransportError>;

    /// A short description for logs (`sim`, `serial:/dev/rfcomm0`).
    fn describe(&self) -> String;

    /// Sends `req` requiring a reply, checks that the reply answers it and succeeded.
    fn request(&mut self, req: &Request) -> Result<Reply, TransportError> {
        let op = req.opcode();
        let reply = self
            .transact(&req.encode(true))?
            .ok_or(TransportError::NoReply(op))?;
        let reply = Reply::decode(reply.as_bytes())?;
        if reply.opcode() != op as u8 {
            return Err(TransportError::OpcodeMismatch {
                expected: op as u8,
                got: reply.opcode(),
            });
        }
        if !reply.status().is_success() {
            return Err(TransportError::Status {
                opcode: op,
                status: reply.status(),
            });
        }
        Ok(reply)
    }

    /// Sends `req` without asking for a reply.
    fn send(&mut self, req: &Request) -> Result<(), TransportError> {
        self.transact(&req.encode(false)).map(|_| ())
    }
}

impl<T: Transport + ?Sized> Transport for Box<T> {
    fn transact(&mut self, telegram: &Telegram) -> Result<Option<Telegram>, TransportError> {
        (**self).transact(telegram)
    }

    fn describe(&self) -> String {
        (**self).describe()
    }
}
