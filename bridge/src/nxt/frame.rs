//! Bluetooth framing: a 2-byte little-endian length, then the telegram.

use core::fmt;

use super::{MAX_TELEGRAM_LEN, Telegram};

/// Largest frame: the 2-byte header and a [`MAX_TELEGRAM_LEN`]-byte telegram.
pub const MAX_FRAME_LEN: usize = MAX_TELEGRAM_LEN + 2;

/// Why a frame was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// The length header is 0 or larger than [`MAX_TELEGRAM_LEN`].
    #[error("bad frame length {0} (must be 1..={MAX_TELEGRAM_LEN})")]
    BadLength(u16),
    /// Fewer bytes than the header announces (or than a header).
    #[error("frame truncated: {got} bytes, header announces {expected}")]
    Truncated {
        /// Bytes announced (header included).
        expected: usize,
        /// Bytes present.
        got: usize,
    },
    /// More bytes than the header announces.
    #[error("frame has {extra} trailing bytes")]
    Trailing {
        /// How many.
        extra: usize,
    },
}

/// One frame in a fixed buffer, ready to be written in a single `write`.
#[derive(Clone, Copy)]
pub struct Frame {
    len: u8,
    bytes: [u8; MAX_FRAME_LEN],
}

impl Frame {
    /// Frames `telegram`.
    pub fn new(telegram: &Telegram) -> Frame {
        let body = telegram.as_bytes();
        let mut bytes = [0u8; MAX_FRAME_LEN];
        let n = body.len().min(MAX_TELEGRAM_LEN);
        bytes[..2].copy_from_slice(&(n as u16).to_le_bytes());
        bytes[2..2 + n].copy_from_slice(&body[..n]);
        Frame {
            len: (n + 2) as u8,
            bytes,
        }
    }

    /// The frame's bytes (header and telegram).
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len).min(MAX_FRAME_LEN)]
    }
}

impl fmt::Debug for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Frame{:02X?}", self.as_bytes())
    }
}

/// Parses a length header; the telegram length it announces.
pub fn parse_header(header: [u8; 2]) -> Result<usize, FrameError> {
    let n = u16::from_le_bytes(header);
    if n == 0 || usize::from(n) > MAX_TELEGRAM_LEN {
        Err(FrameError::BadLength(n))
    } else {
        Ok(usize::from(n))
    }
}

/// Parses exactly one whole frame.
pub fn decode_frame(bytes: &[u8]) -> Result<Telegram, FrameError> {
    let header = match bytes {
        [a, b, ..] => [*a, *b],
        _ => {
            return Err(FrameError::Truncated {
                expected: 2,
                got: bytes.len(),
            });
        }
    };
    let n = parse_header(header)?;
    let body = &bytes[2..];
    if body.len() < n {
        return Err(FrameError::Truncated {
            expected: n + 2,
            got: bytes.len(),
        });
    }
    if body.len() > n {
        return Err(FrameError::Trailing {
            extra: body.len() - n,
        });
    }
    Telegram::from_bytes(body).map_err(|_| FrameError::BadLength(n as u16))
}

/// Reassembles frames from a byte stream that arrives in arbitrary pieces.
///
/// After a bad length header the decoder reports [`FrameError::BadLength`] once and starts
/// over with the next byte as a new header (the stream has lost sync; a server cannot do
/// better without a delimiter).
#[derive(Debug, Clone)]
pub struct FrameDecoder {
    header: [u8; 2],
    header_len: u8,
    want: u8,
    body: Telegram,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// A decoder waiting for a header.
    pub const fn new() -> Self {
        Self {
            header: [0; 2],
            header_len: 0,
            want: 0,
            body: Telegram::EMPTY,
        }
    }

    /// Whether the decoder is between frames.
    pub fn is_idle(&self) -> bool {
        self.header_len == 0
    }

    /// Discards any partial frame.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Feeds one byte; yields a telegram when a frame completes, or an error on a bad header.
    pub fn push(&mut self, byte: u8) -> Option<Result<Telegram, FrameError>> {
        if self.header_len < 2 {
            self.header[usize::from(self.header_len)] = byte;
            self.header_len += 1;
            if self.header_len == 2 {
                match parse_header(self.header) {
                    Ok(n) => {
                        self.want = n as u8;
                        self.body = Telegram::EMPTY;
                    }
                    Err(e) => {
                        self.reset();
                        return Some(Err(e));
                    }
                }
            }
            return None;
        }
        self.body.push(byte);
        if self.body.len() >= usize::from(self.want) {
            let t = self.body;
            self.reset();
            return Some(Ok(t));
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_layout_and_decoder() {
        let t = Telegram::from_bytes(&[0x00, 0x0B]).expect("fits");
        let f = t.to_frame();
        assert_eq!(f.as_bytes(), &[0x02, 0x00, 0x00, 0x0B]);
        assert_eq!(decode_frame(f.as_bytes()), Ok(t));
        let mut d = FrameDecoder::new();
        let mut out = vec![];
        for &b in f.as_bytes().iter().chain(f.as_bytes()) {
            if let Some(r) = d.push(b) {
                out.push(r);
            }
        }
        assert_eq!(out, vec![Ok(t), Ok(t)]);
        assert!(d.is_idle());
    }

    #[test]
    fn bad_frames() {
        assert_eq!(decode_frame(&[0x00, 0x00]), Err(FrameError::BadLength(0)));
        assert_eq!(decode_frame(&[0x41, 0x00]), Err(FrameError::BadLength(65)));
        assert_eq!(
            decode_frame(&[0x02]),
            Err(FrameError::Truncated {
                expected: 2,
                got: 1
            })
        );
        assert_eq!(
            decode_frame(&[0x02, 0x00, 1]),
            Err(FrameError::Truncated {
                expected: 4,
                got: 3
            })
        );
        assert_eq!(
            decode_frame(&[0x01, 0x00, 1, 2]),
            Err(FrameError::Trailing { extra: 1 })
        );
        let mut d = FrameDecoder::new();
        assert_eq!(d.push(0xFF), None);
        assert_eq!(d.push(0xFF), Some(Err(FrameError::BadLength(0xFFFF))));
        assert!(d.is_idle());
    }
}
