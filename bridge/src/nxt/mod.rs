//! The LEGO Mindstorms NXT Bluetooth protocol subset this robot needs, byte for byte.
//!
//! A *telegram* is at most [`MAX_TELEGRAM_LEN`] bytes: a type byte, an opcode and the
//! arguments, all multi-byte integers little-endian. Over Bluetooth (and the serial devices
//! that carry it, `/dev/rfcomm0`) each telegram travels in a *frame*: a 2-byte little-endian
//! length, then the telegram ([`frame`]).
//!
//! | type byte | meaning |
//! |---|---|
//! | `0x00` | direct command, reply required |
//! | `0x80` | direct command, no reply |
//! | `0x01` | system command, reply required |
//! | `0x81` | system command, no reply |
//! | `0x02` | reply: `02 <opcode> <status> <body…>` |
//!
//! [`Request`] encodes and decodes the commands (direct: SETOUTPUTSTATE, GETOUTPUTSTATE,
//! RESETMOTORPOSITION, GETBATTERYLEVEL, KEEPALIVE, PLAYTONE; system: GETFIRMWAREVERSION,
//! GETDEVICEINFO), [`Reply`] their replies. Encoding writes into a fixed [`Telegram`] buffer and
//! decoding reads a `&[u8]` into `Copy` values: neither allocates, and every malformed input is
//! a [`DecodeError`], never a panic. Decoding is *canonical*: any telegram that decodes
//! re-encodes to exactly the same bytes.
//!
//! ```
//! use tes_bridge::nxt::{Mode, Port, PortSelector, RegulationMode, Request, RunState, SetOutputState};
//!
//! let cmd = Request::SetOutputState(SetOutputState {
//!     port: PortSelector::One(Port::B),
//!     power: 75,
//!     mode: Mode::MOTOR_ON | Mode::BRAKE | Mode::REGULATED,
//!     regulation: RegulationMode::Speed,
//!     turn_ratio: 0,
//!     run_state: RunState::Running,
//!     tacho_limit: 246,
//! });
//! let telegram = cmd.encode(false);
//! assert_eq!(telegram.as_bytes(), &[0x80, 0x04, 0x01, 75, 0x07, 0x01, 0x00, 0x20, 246, 0, 0, 0]);
//! assert_eq!(Request::decode(telegram.as_bytes())?, (cmd, false));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod frame;
mod reply;
mod request;
mod wire;

use core::fmt;

pub use frame::{Accept, Frame, FrameDecoder, FrameError, MAX_FRAME_LEN, PARTIAL_FRAME_TIMEOUT};
pub use reply::{DeviceInfo, OutputState, Reply, Version};
pub use request::{Request, SetOutputState};

/// Largest telegram the NXT accepts over Bluetooth (type byte and opcode included).
pub const MAX_TELEGRAM_LEN: usize = 64;

/// Telegram type bytes (the first byte of every telegram).
pub mod telegram_type {
    /// Direct command, reply required.
    pub const DIRECT: u8 = 0x00;
    /// System command, reply required.
    pub const SYSTEM: u8 = 0x01;
    /// A reply telegram.
    pub const REPLY: u8 = 0x02;
    /// OR-ed into [`DIRECT`] or [`SYSTEM`]: the sender wants no reply.
    pub const NO_REPLY: u8 = 0x80;
}

/// The opcodes this codec implements.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Opcode {
    /// Direct `PLAYTONE` (0x03).
    PlayTone = 0x03,
    /// Direct `SETOUTPUTSTATE` (0x04).
    SetOutputState = 0x04,
    /// Direct `GETOUTPUTSTATE` (0x06).
    GetOutputState = 0x06,
    /// Direct `RESETMOTORPOSITION` (0x0A).
    ResetMotorPosition = 0x0A,
    /// Direct `GETBATTERYLEVEL` (0x0B).
    GetBatteryLevel = 0x0B,
    /// Direct `KEEPALIVE` (0x0D).
    KeepAlive = 0x0D,
    /// System `GETFIRMWAREVERSION` (0x88).
    GetFirmwareVersion = 0x88,
    /// System `GETDEVICEINFO` (0x9B).
    GetDeviceInfo = 0x9B,
}

impl Opcode {
    /// Every implemented opcode.
    pub const ALL: [Opcode; 8] = [
        Opcode::PlayTone,
        Opcode::SetOutputState,
        Opcode::GetOutputState,
        Opcode::ResetMotorPosition,
        Opcode::GetBatteryLevel,
        Opcode::KeepAlive,
        Opcode::GetFirmwareVersion,
        Opcode::GetDeviceInfo,
    ];

    /// The opcode with this byte, if implemented.
    pub fn from_u8(b: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|op| *op as u8 == b)
    }

    /// Whether this is a system command (type byte 0x01/0x81) rather than a direct one.
    pub fn is_system(self) -> bool {
        (self as u8) & 0x80 != 0
    }

    /// Total length of the request telegram, type byte and opcode included.
    pub fn request_len(self) -> usize {
        match self {
            Opcode::PlayTone => 6,
            Opcode::SetOutputState => 12,
            Opcode::GetOutputState => 3,
            Opcode::ResetMotorPosition => 4,
            Opcode::GetBatteryLevel
            | Opcode::KeepAlive
            | Opcode::GetFirmwareVersion
            | Opcode::GetDeviceInfo => 2,
        }
    }

    /// Total length of a full reply telegram (`02 <opcode> <status>` and the body).
    pub fn reply_len(self) -> usize {
        3 + match self {
            Opcode::PlayTone | Opcode::SetOutputState | Opcode::ResetMotorPosition => 0,
            Opcode::GetOutputState => 22,
            Opcode::GetBatteryLevel => 2,
            Opcode::KeepAlive => 4,
            Opcode::GetFirmwareVersion => 4,
            Opcode::GetDeviceInfo => 30,
        }
    }

    /// The name LEGO's documentation uses.
    pub fn name(self) -> &'static str {
        match self {
            Opcode::PlayTone => "PLAYTONE",
            Opcode::SetOutputState => "SETOUTPUTSTATE",
            Opcode::GetOutputState => "GETOUTPUTSTATE",
            Opcode::ResetMotorPosition => "RESETMOTORPOSITION",
            Opcode::GetBatteryLevel => "GETBATTERYLEVEL",
            Opcode::KeepAlive => "KEEPALIVE",
            Opcode::GetFirmwareVersion => "GETFIRMWAREVERSION",
            Opcode::GetDeviceInfo => "GETDEVICEINFO",
        }
    }
}

impl fmt::Display for Opcode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (0x{:02X})", self.name(), *self as u8)
    }
}

/// An output (motor) port.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Deserialize, serde::Serialize,
)]
#[repr(u8)]
pub enum Port {
    /// Output port A (byte 0).
    #[default]
    A = 0,
    /// Output port B (byte 1).
    B = 1,
    /// Output port C (byte 2).
    C = 2,
}

impl Port {
    /// The three ports in order.
    pub const ALL: [Port; 3] = [Port::A, Port::B, Port::C];

    /// The port with this byte, if any.
    pub fn from_u8(b: u8) -> Option<Self> {
        match b {
            0 => Some(Port::A),
            1 => Some(Port::B),
            2 => Some(Port::C),
            _ => None,
        }
    }

    /// 0, 1 or 2.
    pub fn index(self) -> usize {
        self as usize
    }
}

/// The port field of SETOUTPUTSTATE: one port, or 0xFF for all three.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PortSelector {
    /// A single port.
    One(Port),
    /// All three ports (byte 0xFF).
    All,
}

impl PortSelector {
    /// The wire byte.
    pub fn to_u8(self) -> u8 {
        match self {
            PortSelector::One(p) => p as u8,
            PortSelector::All => 0xFF,
        }
    }

    /// Parses the wire byte.
    pub fn from_u8(b: u8) -> Option<Self> {
        if b == 0xFF {
            Some(PortSelector::All)
        } else {
            Port::from_u8(b).map(PortSelector::One)
        }
    }

    /// Whether `port` is selected.
    pub fn contains(self, port: Port) -> bool {
        match self {
            PortSelector::One(p) => p == port,
            PortSelector::All => true,
        }
    }
}

/// The motor mode bit field of SETOUTPUTSTATE / GETOUTPUTSTATE.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Mode(u8);

impl Mode {
    /// No bit set: the output is unpowered.
    pub const IDLE: Mode = Mode(0x00);
    /// `MOTORON` (0x01): power the output.
    pub const MOTOR_ON: Mode = Mode(0x01);
    /// `BRAKE` (0x02): short the windings when not driving instead of floating.
    pub const BRAKE: Mode = Mode(0x02);
    /// `REGULATED` (0x04): apply the regulation mode.
    pub const REGULATED: Mode = Mode(0x04);

    /// The mode with these bits; `None` if a bit outside 0x07 is set.
    pub fn from_bits(bits: u8) -> Option<Self> {
        (bits & !0x07 == 0).then_some(Mode(bits))
    }

    /// The raw bits.
    pub fn bits(self) -> u8 {
        self.0
    }

    /// Whether all bits of `other` are set here.
    pub fn contains(self, other: Mode) -> bool {
        self.0 & other.0 == other.0
    }
}

impl core::ops::BitOr for Mode {
    type Output = Mode;
    fn bitor(self, rhs: Mode) -> Mode {
        Mode(self.0 | rhs.0)
    }
}

impl fmt::Debug for Mode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0 == 0 {
            return f.write_str("Mode(IDLE)");
        }
        f.write_str("Mode(")?;
        let mut first = true;
        for (bit, name) in [(0x01, "MOTOR_ON"), (0x02, "BRAKE"), (0x04, "REGULATED")] {
            if self.0 & bit != 0 {
                if !first {
                    f.write_str("|")?;
                }
                f.write_str(name)?;
                first = false;
            }
        }
        f.write_str(")")
    }
}

/// Regulation mode of an output.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Deserialize, serde::Serialize,
)]
#[serde(rename_all = "lowercase")]
#[repr(u8)]
pub enum RegulationMode {
    /// No regulation (0x00).
    #[default]
    Idle = 0x00,
    /// Speed regulation (0x01).
    Speed = 0x01,
    /// Two-motor synchronisation (0x02).
    Sync = 0x02,
}

impl RegulationMode {
    /// Parses the wire byte.
    pub fn from_u8(b: u8) -> Option<Self> {
        match b {
            0x00 => Some(RegulationMode::Idle),
            0x01 => Some(RegulationMode::Speed),
            0x02 => Some(RegulationMode::Sync),
            _ => None,
        }
    }
}

/// Run state of an output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[repr(u8)]
pub enum RunState {
    /// Not running (0x00).
    #[default]
    Idle = 0x00,
    /// Ramping up (0x10).
    RampUp = 0x10,
    /// Running (0x20).
    Running = 0x20,
    /// Ramping down (0x40).
    RampDown = 0x40,
}

impl RunState {
    /// Parses the wire byte.
    pub fn from_u8(b: u8) -> Option<Self> {
        match b {
            0x00 => Some(RunState::Idle),
            0x10 => Some(RunState::RampUp),
            0x20 => Some(RunState::Running),
            0x40 => Some(RunState::RampDown),
            _ => None,
        }
    }
}

macro_rules! statuses {
    ($($(#[$doc:meta])* $name:ident = $val:literal, $text:literal;)*) => {
        /// A reply's status byte, with the codes LEGO's documentation defines.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum Status {
            $($(#[$doc])* $name = $val,)*
        }

        impl Status {
            /// Every defined status.
            pub const ALL: &'static [Status] = &[$(Status::$name,)*];

            /// The status with this byte, if defined.
            pub fn from_u8(b: u8) -> Option<Self> {
                match b {
                    $($val => Some(Status::$name),)*
                    _ => None,
                }
            }

            /// What the status means, in LEGO's words.
            pub fn description(self) -> &'static str {
                match self {
                    $(Status::$name => $text,)*
                }
            }
        }
    };
}

statuses! {
    /// 0x00: success.
    Success = 0x00, "success";
    /// 0x20: pending communication transaction in progress.
    PendingCommunication = 0x20, "pending communication transaction in progress";
    /// 0x40: specified mailbox queue is empty.
    MailboxEmpty = 0x40, "specified mailbox queue is empty";
    /// 0x81: no more handles.
    NoMoreHandles = 0x81, "no more handles";
    /// 0x82: no space.
    NoSpace = 0x82, "no space";
    /// 0x83: no more files.
    NoMoreFiles = 0x83, "no more files";
    /// 0x84: end of file expected.
    EndOfFileExpected = 0x84, "end of file expected";
    /// 0x85: end of file.
    EndOfFile = 0x85, "end of file";
    /// 0x86: not a linear file.
    NotALinearFile = 0x86, "not a linear file";
    /// 0x87: file not found.
    FileNotFound = 0x87, "file not found";
    /// 0x88: handle already closed.
    HandleAlreadyClosed = 0x88, "handle already closed";
    /// 0x89: no linear space.
    NoLinearSpace = 0x89, "no linear space";
    /// 0x8A: undefined error.
    UndefinedError = 0x8A, "undefined error";
    /// 0x8B: file is busy.
    FileIsBusy = 0x8B, "file is busy";
    /// 0x8C: no write buffers.
    NoWriteBuffers = 0x8C, "no write buffers";
    /// 0x8D: append not possible.
    AppendNotPossible = 0x8D, "append not possible";
    /// 0x8E: file is full.
    FileIsFull = 0x8E, "file is full";
    /// 0x8F: file exists.
    FileExists = 0x8F, "file exists";
    /// 0x90: module not found.
    ModuleNotFound = 0x90, "module not found";
    /// 0x91: out of bounds.
    OutOfBounds = 0x91, "out of bounds";
    /// 0x92: illegal file name.
    IllegalFileName = 0x92, "illegal file name";
    /// 0x93: illegal handle.
    IllegalHandle = 0x93, "illegal handle";
    /// 0xBD: request failed (i.e. specified file not found).
    RequestFailed = 0xBD, "request failed";
    /// 0xBE: unknown command opcode.
    UnknownCommand = 0xBE, "unknown command opcode";
    /// 0xBF: insane packet.
    InsanePacket = 0xBF, "insane packet";
    /// 0xC0: data contains out-of-range values.
    OutOfRange = 0xC0, "data contains out-of-range values";
    /// 0xDD: communication bus error.
    BusError = 0xDD, "communication bus error";
    /// 0xDE: no free memory in communication buffer.
    NoFreeBufferMemory = 0xDE, "no free memory in communication buffer";
    /// 0xDF: specified channel/connection is not valid.
    InvalidChannel = 0xDF, "specified channel/connection is not valid";
    /// 0xE0: specified channel/connection not configured or busy.
    ChannelBusy = 0xE0, "specified channel/connection not configured or busy";
    /// 0xEC: no active program.
    NoActiveProgram = 0xEC, "no active program";
    /// 0xED: illegal size specified.
    IllegalSize = 0xED, "illegal size specified";
    /// 0xEE: illegal mailbox queue ID specified.
    IllegalMailbox = 0xEE, "illegal mailbox queue ID specified";
    /// 0xEF: attempted to access invalid field of a structure.
    InvalidField = 0xEF, "attempted to access invalid field of a structure";
    /// 0xF0: bad input or output specified.
    BadInputOutput = 0xF0, "bad input or output specified";
    /// 0xFB: insufficient memory available.
    InsufficientMemory = 0xFB, "insufficient memory available";
    /// 0xFF: bad arguments.
    BadArguments = 0xFF, "bad arguments";
}

impl Status {
    /// Whether this is [`Status::Success`].
    pub fn is_success(self) -> bool {
        self == Status::Success
    }
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:02X} {}", *self as u8, self.description())
    }
}

/// Why a telegram could not be decoded. Every variant is a malformed or unsupported input;
/// none is a bug.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Fewer than the 2 bytes (3 for a reply) every telegram starts with.
    #[error("telegram too short: {len} bytes")]
    TooShort {
        /// The length received.
        len: usize,
    },
    /// Longer than [`MAX_TELEGRAM_LEN`].
    #[error("telegram too long: {len} bytes (at most {MAX_TELEGRAM_LEN})")]
    TooLong {
        /// The length received.
        len: usize,
    },
    /// The type byte is not one of 0x00, 0x01, 0x80, 0x81 (requests) or 0x02 (replies).
    #[error("bad telegram type byte 0x{0:02X}")]
    BadType(u8),
    /// The opcode is not one this codec implements (or not of the telegram's kind).
    #[error("unknown opcode 0x{opcode:02X} for telegram type 0x{telegram_type:02X}")]
    UnknownOpcode {
        /// The telegram's type byte.
        telegram_type: u8,
        /// The opcode byte.
        opcode: u8,
    },
    /// The telegram is shorter than its opcode requires.
    #[error("{opcode} telegram truncated: {len} bytes, expected {expected}")]
    Truncated {
        /// The opcode.
        opcode: Opcode,
        /// The length received.
        len: usize,
        /// The length the opcode requires.
        expected: usize,
    },
    /// The telegram is longer than its opcode allows.
    #[error("{opcode} telegram has trailing bytes: {len} bytes, expected {expected}")]
    TrailingBytes {
        /// The opcode.
        opcode: Opcode,
        /// The length received.
        len: usize,
        /// The length the opcode requires.
        expected: usize,
    },
    /// A port byte outside 0..=2 (or 0xFF where "all ports" is allowed).
    #[error("bad output port 0x{0:02X}")]
    BadPort(u8),
    /// A mode byte with bits outside MOTORON|BRAKE|REGULATED.
    #[error("bad motor mode 0x{0:02X}")]
    BadMode(u8),
    /// A regulation mode byte outside 0..=2.
    #[error("bad regulation mode 0x{0:02X}")]
    BadRegulation(u8),
    /// A run state byte outside {0x00, 0x10, 0x20, 0x40}.
    #[error("bad run state 0x{0:02X}")]
    BadRunState(u8),
    /// A boolean byte other than 0 or 1.
    #[error("bad boolean 0x{0:02X}")]
    BadBool(u8),
    /// A reply status byte the protocol does not define.
    #[error("unknown status 0x{0:02X}")]
    UnknownStatus(u8),
}

impl DecodeError {
    /// The status a firmware-like brick answers a request that failed to decode with this
    /// error: unknown opcode → [`Status::UnknownCommand`], a value out of range →
    /// [`Status::OutOfRange`], anything else → [`Status::InsanePacket`].
    pub fn reply_status(self) -> Status {
        match self {
            DecodeError::UnknownOpcode { .. } => Status::UnknownCommand,
            DecodeError::BadPort(_)
            | DecodeError::BadMode(_)
            | DecodeError::BadRegulation(_)
            | DecodeError::BadRunState(_)
            | DecodeError::BadBool(_) => Status::OutOfRange,
            DecodeError::TooShort { .. }
            | DecodeError::TooLong { .. }
            | DecodeError::BadType(_)
            | DecodeError::Truncated { .. }
            | DecodeError::TrailingBytes { .. }
            | DecodeError::UnknownStatus(_) => Status::InsanePacket,
        }
    }
}

/// One telegram in a fixed buffer: what the encoders produce and the transports carry.
#[derive(Clone, Copy)]
pub struct Telegram {
    len: u8,
    bytes: [u8; MAX_TELEGRAM_LEN],
}

impl Telegram {
    /// An empty telegram (length 0), to be filled by an encoder.
    pub const EMPTY: Telegram = Telegram {
        len: 0,
        bytes: [0; MAX_TELEGRAM_LEN],
    };

    /// Copies `bytes` into a telegram; fails if empty or longer than [`MAX_TELEGRAM_LEN`].
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, DecodeError> {
        if bytes.is_empty() {
            return Err(DecodeError::TooShort { len: 0 });
        }
        let mut t = Telegram::EMPTY;
        let dst = t
            .bytes
            .get_mut(..bytes.len())
            .ok_or(DecodeError::TooLong { len: bytes.len() })?;
        dst.copy_from_slice(bytes);
        t.len = bytes.len() as u8;
        Ok(t)
    }

    /// The telegram's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len).min(MAX_TELEGRAM_LEN)]
    }

    /// Length in bytes.
    pub fn len(&self) -> usize {
        self.as_bytes().len()
    }

    /// Whether the telegram holds no bytes.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The type byte (0 for an empty telegram).
    pub fn telegram_type(&self) -> u8 {
        self.as_bytes().first().copied().unwrap_or(0)
    }

    /// The opcode byte (0 if absent).
    pub fn opcode(&self) -> u8 {
        self.as_bytes().get(1).copied().unwrap_or(0)
    }

    /// Whether this is a request whose sender expects a reply (type 0x00 or 0x01).
    pub fn reply_required(&self) -> bool {
        matches!(
            self.telegram_type(),
            telegram_type::DIRECT | telegram_type::SYSTEM
        )
    }

    /// The frame carrying this telegram over Bluetooth: 2-byte LE length, then the bytes.
    pub fn to_frame(&self) -> Frame {
        Frame::new(self)
    }

    /// Appends one byte; silently ignored past [`MAX_TELEGRAM_LEN`] (encoders never get there).
    pub(crate) fn push(&mut self, b: u8) {
        if let Some(slot) = self.bytes.get_mut(usize::from(self.len)) {
            *slot = b;
            self.len += 1;
        }
        debug_assert!(usize::from(self.len) <= MAX_TELEGRAM_LEN);
    }

    pub(crate) fn push_slice(&mut self, bs: &[u8]) {
        for &b in bs {
            self.push(b);
        }
    }
}

impl PartialEq for Telegram {
    fn eq(&self, other: &Self) -> bool {
        self.as_bytes() == other.as_bytes()
    }
}

impl Eq for Telegram {}

impl fmt::Debug for Telegram {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Telegram[")?;
        for (i, b) in self.as_bytes().iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{b:02X}")?;
        }
        f.write_str("]")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opcode_lengths_match_the_spec() {
        assert_eq!(Opcode::SetOutputState.request_len(), 12);
        assert_eq!(Opcode::GetOutputState.reply_len(), 25);
        assert_eq!(Opcode::GetDeviceInfo.reply_len(), 33);
        assert_eq!(Opcode::GetFirmwareVersion.reply_len(), 7);
        for op in Opcode::ALL {
            assert_eq!(Opcode::from_u8(op as u8), Some(op));
            assert!(op.request_len() <= MAX_TELEGRAM_LEN && op.reply_len() <= MAX_TELEGRAM_LEN);
        }
        assert!(Opcode::GetDeviceInfo.is_system() && !Opcode::KeepAlive.is_system());
    }

    #[test]
    fn status_codes_round_trip() {
        for s in Status::ALL {
            assert_eq!(Status::from_u8(*s as u8), Some(*s));
        }
        assert_eq!(Status::from_u8(0x01), None);
        assert_eq!(Status::OutOfRange as u8, 0xC0);
        assert_eq!(Status::UnknownCommand as u8, 0xBE);
    }

    #[test]
    fn telegram_bounds() {
        assert!(Telegram::from_bytes(&[]).is_err());
        assert!(Telegram::from_bytes(&[0; 65]).is_err());
        let t = Telegram::from_bytes(&[0; 64]).expect("64 bytes fit");
        assert_eq!(t.len(), 64);
        let mut t = t;
        t.push(1);
        assert_eq!(t.len(), 64);
    }

    #[test]
    fn mode_bits() {
        assert_eq!(Mode::from_bits(0x08), None);
        let m = Mode::MOTOR_ON | Mode::REGULATED;
        assert!(m.contains(Mode::MOTOR_ON) && !m.contains(Mode::BRAKE));
        assert_eq!(format!("{m:?}"), "Mode(MOTOR_ON|REGULATED)");
    }
}

#[cfg(test)]
pub(crate) mod proptests;
