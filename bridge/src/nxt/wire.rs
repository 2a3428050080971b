//! Little-endian field readers over a telegram whose length was already checked.

use super::{DecodeError, Mode, Opcode, Port, RegulationMode, RunState, Telegram};

/// Reads fields from the body of a telegram whose total length the caller has verified.
///
/// Every getter is total: past the end it yields zeros (and a `debug_assert` fires), so a
/// length bug can corrupt a value but never panic in release builds.
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(bytes: &'a [u8], pos: usize) -> Self {
        Self { bytes, pos }
    }

    pub(crate) fn u8(&mut self) -> u8 {
        let b = self.bytes.get(self.pos).copied();
        debug_assert!(b.is_some(), "read past the checked length");
        self.pos += 1;
        b.unwrap_or(0)
    }

    pub(crate) fn i8(&mut self) -> i8 {
        self.u8() as i8
    }

    pub(crate) fn array<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        for b in &mut out {
            *b = self.u8();
        }
        out
    }

    pub(crate) fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.array())
    }

    pub(crate) fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.array())
    }

    pub(crate) fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.array())
    }

    pub(crate) fn port(&mut self) -> Result<Port, DecodeError> {
        let b = self.u8();
        Port::from_u8(b).ok_or(DecodeError::BadPort(b))
    }

    pub(crate) fn mode(&mut self) -> Result<Mode, DecodeError> {
        let b = self.u8();
        Mode::from_bits(b).ok_or(DecodeError::BadMode(b))
    }

    pub(crate) fn regulation(&mut self) -> Result<RegulationMode, DecodeError> {
        let b = self.u8();
        RegulationMode::from_u8(b).ok_or(DecodeError::BadRegulation(b))
    }

    pub(crate) fn run_state(&mut self) -> Result<RunState, DecodeError> {
        let b = self.u8();
        RunState::from_u8(b).ok_or(DecodeError::BadRunState(b))
    }

    pub(crate) fn bool(&mut self) -> Result<bool, DecodeError> {
        match self.u8() {
            0 => Ok(false),
            1 => Ok(true),
            b => Err(DecodeError::BadBool(b)),
        }
    }
}

/// Checks that `bytes` is exactly `expected` long for `opcode`.
pub(crate) fn check_len(bytes: &[u8], opcode: Opcode, expected: usize) -> Result<(), DecodeError> {
    let len = bytes.len();
    if len < expected {
        Err(DecodeError::Truncated {
            opcode,
            len,
            expected,
        })
    } else if len > expected {
        Err(DecodeError::TrailingBytes {
            opcode,
            len,
            expected,
        })
    } else {
        Ok(())
    }
}

/// Little-endian writers onto a [`Telegram`].
pub(crate) trait Writer {
    fn u16(&mut self, v: u16);
    fn u32(&mut self, v: u32);
    fn i32(&mut self, v: i32);
}

impl Writer for Telegram {
    fn u16(&mut self, v: u16) {
        self.push_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.push_slice(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.push_slice(&v.to_le_bytes());
    }
}
