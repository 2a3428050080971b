//! Transports carry telegrams to a brick and bring its replies back.
//!
//! - [`SimTransport`]: the [`SimBrick`](crate::brick::SimBrick) in-process, stepped to a
//!   [`Clock`](crate::clock::Clock) at each telegram.
//! - [`LinkTransport`]: a real link, with read timeouts, junk skipping and reconnection
//!   ([`link`]): [`SerialTransport`] (a serial device: `/dev/rfcomm0`, or the pseudo-terminal
//!   `tes-bridge brick --pty` serves), [`BluetoothTransport`] (a kernel RFCOMM socket to a
//!   paired brick) and [`UsbTransport`] (the NXT's USB bulk endpoints).
//! - [`DelayedTransport`]: wraps one and delays each reply like a Bluetooth link (≈ 30 ms
//!   with jitter), for realistic timing off the robot.
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

mod bluetooth;
mod delay;
pub mod link;
mod serial;
mod sim;
mod timed;
mod usb;

use std::time::Duration;

pub(crate) use bluetooth::kernel_support;
pub use bluetooth::{
    BluetoothTarget, BluetoothTransport, NXT_RFCOMM_CHANNEL, RfcommDevice, StreamConnection,
};
pub use delay::{DelayedTransport, LinkDelay, Sleep, ThreadSleep};
pub use link::{LinkStats, LinkTiming, LinkTransport};
pub use serial::{SerialConfig, SerialDevice, SerialTransport};
pub use sim::SimTransport;
pub use timed::{LinkReport, TimedTransport, in_words};
pub(crate) use usb::usb_bus;
pub use usb::{
    LEGO_VENDOR_ID, NXT_PRODUCT_ID, UsbBrick, UsbConnection, UsbDevice, UsbTransport, find_bricks,
};

use crate::nxt::{DecodeError, FrameError, Opcode, Reply, Request, Status, Telegram};

/// Why a transaction failed.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The link could not be opened (the bridge retries after a back-off).
    #[error("cannot open {link}: {reason}")]
    Open {
        /// The link, as the config names it.
        link: String,
        /// The cause, and what to do about it.
        reason: String,
        /// The link cannot exist on this machine (no Bluetooth, no USB bus): no retry helps.
        impossible: bool,
    },
    /// The link is closed after a failure and the back-off has not elapsed.
    #[error("link {link} is down; reconnecting in {wait:?}")]
    Backoff {
        /// The link, as the config names it.
        link: String,
        /// Time until the next attempt.
        wait: Duration,
    },
    /// Reading or writing the link failed (the peer closing it included).
    #[error("I/O error on {link}: {error}")]
    Io {
        /// The link, as the config names it.
        link: String,
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
    /// Whether no retry can bring the link up on this machine.
    pub fn is_impossible(&self) -> bool {
        matches!(
            self,
            TransportError::Open {
                impossible: true,
                ..
            }
        )
    }

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
