//! What a viewer may send: the WebSocket frames of its byte stream read as they pass, so a
//! message longer than the door allows is caught at the header that announces it, before its
//! bytes are buffered anywhere.
//!
//! A viewer sends small JSON requests (`subscribe`, `unsubscribe`, …), so a message of more
//! than [`CLIENT_MESSAGE_MAX`](super::CLIENT_MESSAGE_MAX) bytes, its fragments added up, is
//! not one: without this the crate's server would buffer up to 64 MiB per connection.

/// Why a viewer's stream was cut.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// A message (its fragments added up) longer than allowed.
    #[error("a message of at least {length} bytes (at most {limit} allowed)")]
    TooLong {
        /// Its length so far, with the frame that announced too many.
        length: u64,
        /// The limit.
        limit: u64,
    },
    /// A control frame (close, ping, pong) longer than RFC 6455 allows (125 bytes).
    #[error("a control frame of {0} bytes (at most 125)")]
    LongControl(u64),
}

/// The longest frame header: 2 bytes, an 8-byte length and a 4-byte mask.
const HEADER_MAX: usize = 14;

/// A viewer's frames, followed through its byte stream.
#[derive(Debug, Clone)]
pub struct ClientFrames {
    limit: u64,
    header: [u8; HEADER_MAX],
    header_len: usize,
    payload_left: u64,
    message_len: u64,
}

/// A frame's header, read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Header {
    fin: bool,
    opcode: u8,
    payload: u64,
}

impl ClientFrames {
    /// Follows a stream whose messages may be at most `limit` bytes long.
    pub fn new(limit: u64) -> Self {
        Self {
            limit,
            header: [0; HEADER_MAX],
            header_len: 0,
            payload_left: 0,
            message_len: 0,
        }
    }

    /// Reads the next `bytes` of the stream; an error once it holds a message too long.
    pub fn feed(&mut self, mut bytes: &[u8]) -> Result<(), FrameError> {
        while let Some((&first, rest)) = bytes.split_first() {
            if self.payload_left > 0 {
                let skip = usize::try_from(self.payload_left)
                    .map_or(bytes.len(), |left| left.min(bytes.len()));
                self.payload_left -= skip as u64;
                bytes = &bytes[skip..];
                continue;
            }
            self.header[self.header_len] = first;
            self.header_len += 1;
            bytes = rest;
            if let Some(header) = parse_header(&self.header[..self.header_len]) {
                self.header_len = 0;
                self.on_header(header)?;
            }
        }
        Ok(())
    }

    fn on_header(&mut self, h: Header) -> Result<(), FrameError> {
        let control = h.opcode & 0x8 != 0;
        if control {
            if h.payload > 125 {
                return Err(FrameError::LongControl(h.payload));
            }
        } else {
            // A data frame that is not a continuation starts a new message.
            if h.opcode != 0 {
                self.message_len = 0;
            }
            self.message_len = self.message_len.saturating_add(h.payload);
            if self.message_len > self.limit {
                return Err(FrameError::TooLong {
                    length: self.message_len,
                    limit: self.limit,
                });
            }
            if h.fin {
                self.message_len = 0;
            }
        }
        self.payload_left = h.payload;
        Ok(())
    }
}

/// The header at the start of `b`, once `b` holds all of it.
fn parse_header(b: &[u8]) -> Option<Header> {
    let [first, second, ..] = *b else {
        return None;
    };
    let masked = second & 0x80 != 0;
    let short = u64::from(second & 0x7f);
    let extended = match short {
        126 => 2,
        127 => 8,
        _ => 0,
    };
    let need = 2 + extended + if masked { 4 } else { 0 };
    if b.len() < need {
        return None;
    }
    let payload = match extended {
        0 => short,
        _ => b[2..2 + extended]
            .iter()
            .fold(0u64, |n, &byte| (n << 8) | u64::from(byte)),
    };
    Some(Header {
        fin: first & 0x80 != 0,
        opcode: first & 0x0f,
        payload,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A masked frame from a client, as bytes.
    fn frame(fin: bool, opcode: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![if fin { 0x80 } else { 0 } | opcode];
        match payload.len() {
            n @ 0..=125 => f.push(0x80 | n as u8),
            n @ 126..=0xffff => {
                f.push(0x80 | 126);
                f.extend_from_slice(&(n as u16).to_be_bytes());
            }
            n => {
                f.push(0x80 | 127);
                f.extend_from_slice(&(n as u64).to_be_bytes());
            }
        }
        f.extend_from_slice(&[1, 2, 3, 4]);
        f.extend_from_slice(payload);
        f
    }

    #[test]
    fn messages_within_the_limit_pass_fed_whole_or_byte_by_byte() {
        let mut stream = frame(true, 1, b"{\"op\":\"subscribe\"}");
        stream.extend(frame(false, 2, &[0; 300]));
        stream.extend(frame(true, 9, b"ping"));
        stream.extend(frame(true, 0, &[0; 70_000]));
        stream.extend(frame(true, 1, &[0; 100_000]));
        assert_eq!(ClientFrames::new(100_300).feed(&stream), Ok(()));
        let mut one_by_one = ClientFrames::new(100_300);
        for b in &stream {
            assert_eq!(one_by_one.feed(std::slice::from_ref(b)), Ok(()));
        }
    }

    #[test]
    fn fragments_adding_up_past_the_limit_are_caught_at_the_header_that_passes_it() {
        let mut frames = ClientFrames::new(1000);
        assert_eq!(frames.feed(&frame(false, 2, &[0; 600])), Ok(()));
        // Only the header of the second fragment: its announced length is enough.
        let second = frame(false, 0, &[0; 600]);
        assert_eq!(
            frames.feed(&second[..8]),
            Err(FrameError::TooLong {
                length: 1200,
                limit: 1000
            })
        );
    }

    #[test]
    fn a_huge_announced_length_is_caught_before_any_payload() {
        let mut header = vec![0x02, 0x80 | 127];
        header.extend_from_slice(&(56u64 << 20).to_be_bytes());
        header.extend_from_slice(&[9, 9, 9, 9]);
        assert!(matches!(
            ClientFrames::new(65_536).feed(&header),
            Err(FrameError::TooLong { .. })
        ));
    }

    #[test]
    fn a_long_control_frame_is_refused() {
        let mut close = vec![0x88, 0x80 | 126];
        close.extend_from_slice(&200u16.to_be_bytes());
        close.extend_from_slice(&[1, 2, 3, 4]);
        assert_eq!(
            ClientFrames::new(65_536).feed(&close),
            Err(FrameError::LongControl(200))
        );
    }
}
