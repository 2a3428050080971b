//! Bluetooth framing: a 2-byte little-endian length, then the telegram.

use core::fmt;
use std::time::{Duration, Instant};

use super::{MAX_TELEGRAM_LEN, Telegram, telegram_type};

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
    /// A plausible length header is followed by a byte that is not a type byte of the stream
    /// (see [`Accept`]): it was no header, the stream decoder skips one byte.
    #[error("bad telegram type byte 0x{0:02X} after a length header")]
    BadType(u8),
    /// A partial frame waited longer than the decoder's timeout for its remaining bytes and was
    /// dropped.
    #[error("partial frame of {bytes} bytes dropped after the timeout")]
    Stale {
        /// Bytes dropped (header included).
        bytes: usize,
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

/// How long a partial frame may wait for its remaining bytes before a [`FrameDecoder`] fed
/// with [`FrameDecoder::push_at`] drops it.
///
/// A sender writes each frame in one `write` (the NXT clients do, and so do the bridge and the
/// simulated brick), so its bytes arrive within microseconds on a pseudo-terminal and within a
/// few milliseconds over Bluetooth (66 bytes at 115200 baud take under 6 ms). A partial frame
/// older than this is the remains of a half-written frame (a client killed mid-write, line
/// noise), and the next bytes belong to a new frame.
pub const PARTIAL_FRAME_TIMEOUT: Duration = Duration::from_millis(100);

/// Which first telegram bytes (type bytes) a [`FrameDecoder`] takes as the start of a real frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accept {
    /// Any type byte: framing only, every well-framed telegram is yielded.
    Any,
    /// Requests, what a brick receives: 0x00, 0x01, 0x80, 0x81.
    Requests,
    /// Replies, what a client receives: 0x02.
    Replies,
}

impl Accept {
    /// Whether `type_byte` may start a telegram of this stream.
    pub fn accepts(self, type_byte: u8) -> bool {
        match self {
            Accept::Any => true,
            Accept::Requests => matches!(
                type_byte,
                telegram_type::DIRECT | telegram_type::SYSTEM | DIRECT_NO_REPLY | SYSTEM_NO_REPLY
            ),
            Accept::Replies => type_byte == telegram_type::REPLY,
        }
    }
}

const DIRECT_NO_REPLY: u8 = telegram_type::DIRECT | telegram_type::NO_REPLY;
const SYSTEM_NO_REPLY: u8 = telegram_type::SYSTEM | telegram_type::NO_REPLY;

/// Reassembles frames from a byte stream that arrives in arbitrary pieces, and finds the frames
/// again after junk.
///
/// A byte stream of NXT frames has no delimiter, so after a stray byte, a half-written frame or
/// line noise the decoder must guess where the next frame starts. It takes a position as a frame
/// start only if the frame is *plausible* there: the 2-byte length is in 1..=[`MAX_TELEGRAM_LEN`]
/// and the byte after it is a type byte of this stream (see [`Accept`]). Anything else is skipped
/// **one byte at a time** — the decoder reports the error ([`FrameError::BadLength`] or
/// [`FrameError::BadType`]) and tries the next byte as the start of a header — so a valid frame
/// that follows junk is found at its own first byte.
///
/// Why the type check: the first byte of a real frame is its length (2..=64 for any request or
/// reply), never a type byte of the stream, so when junk ends with what looks like a header, the
/// next real frame's length byte shows at once that it was not one, and the frame is found. Without
/// the check such a dangling header would swallow the next frame. The cost: a well-framed telegram
/// with a foreign type byte is skipped as junk instead of being yielded (a brick ignores those
/// anyway) and its inner bytes are scanned for frames like any junk. [`Accept::Any`] keeps
/// framing only.
///
/// Junk that ends *inside* a plausible frame's body cannot be told from a frame in progress by its
/// bytes: such a partial frame takes the next frame's bytes as its own. Time tells them apart:
/// fed through [`push_at`](Self::push_at), the decoder drops a partial frame whose first byte is
/// older than its timeout ([`PARTIAL_FRAME_TIMEOUT`] by default) and reports
/// [`FrameError::Stale`], so a request sent after that quiet time (a retry, or a new client) always
/// decodes. Allocation-free; never panics.
#[derive(Debug, Clone)]
pub struct FrameDecoder {
    header: [u8; 2],
    header_len: u8,
    want: u8,
    body: Telegram,
    accept: Accept,
    timeout: Duration,
    started: Option<Instant>,
    skipped: u64,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// A framing-only decoder ([`Accept::Any`]) waiting for a header.
    pub const fn new() -> Self {
        Self::accepting(Accept::Any)
    }

    /// A decoder of requests ([`Accept::Requests`]): what a brick reads.
    pub const fn requests() -> Self {
        Self::accepting(Accept::Requests)
    }

    /// A decoder of replies ([`Accept::Replies`]): what a client reads.
    pub const fn replies() -> Self {
        Self::accepting(Accept::Replies)
    }

    /// A decoder that starts frames only at type bytes `accept` allows.
    pub const fn accepting(accept: Accept) -> Self {
        Self {
            header: [0; 2],
            header_len: 0,
            want: 0,
            body: Telegram::EMPTY,
            accept,
            timeout: PARTIAL_FRAME_TIMEOUT,
            started: None,
            skipped: 0,
        }
    }

    /// The same decoder with another partial-frame timeout (see [`push_at`](Self::push_at)).
    pub const fn with_timeout(mut self, timeout: Duration) -> Self {
        self.timeout = timeout;
        self
    }

    /// The partial-frame timeout.
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    /// Whether the decoder is between frames.
    pub fn is_idle(&self) -> bool {
        self.header_len == 0
    }

    /// Whether the decoder holds a plausible frame's header and type byte and waits for the rest
    /// of its body: the only state in which bytes that follow are taken as that frame's, whatever
    /// they are (until the timeout).
    pub fn is_in_body(&self) -> bool {
        !self.body.is_empty()
    }

    /// Bytes held of a partial frame (header included).
    pub fn pending(&self) -> usize {
        usize::from(self.header_len) + self.body.len()
    }

    /// Bytes skipped so far: junk, bad headers, and partial frames dropped by
    /// [`reset`](Self::reset) or the timeout.
    pub fn skipped_bytes(&self) -> u64 {
        self.skipped
    }

    /// Discards any partial frame (say, because its sender went away); returns how many bytes
    /// were dropped.
    pub fn reset(&mut self) -> usize {
        let n = self.pending();
        self.skipped += n as u64;
        self.clear();
        n
    }

    /// Drops a partial frame whose first byte came longer than the timeout before `now`.
    pub fn expire(&mut self, now: Instant) -> Option<FrameError> {
        let t0 = self.started?;
        if self.is_idle() || now.saturating_duration_since(t0) <= self.timeout {
            return None;
        }
        Some(FrameError::Stale {
            bytes: self.reset(),
        })
    }

    /// Feeds one byte received at `now`: first drops a partial frame older than the timeout
    /// (reported as [`FrameError::Stale`]), then decodes the byte as [`push`](Self::push) does.
    pub fn push_at(&mut self, byte: u8, now: Instant) -> Option<Result<Telegram, FrameError>> {
        let stale = self.expire(now);
        let out = self.step(byte, Some(now));
        match (stale, out) {
            // After a drop the byte is the first of a header: it cannot complete anything.
            (Some(e), None) => Some(Err(e)),
            (_, out) => out,
        }
    }

    /// Feeds one byte without a time (partial frames never expire); yields a telegram when a
    /// frame completes, or the error that made the decoder skip a byte.
    pub fn push(&mut self, byte: u8) -> Option<Result<Telegram, FrameError>> {
        self.step(byte, None)
    }

    fn step(&mut self, byte: u8, now: Option<Instant>) -> Option<Result<Telegram, FrameError>> {
        if self.header_len < 2 {
            if self.header_len == 0 {
                self.started = now;
            }
            self.header[usize::from(self.header_len)] = byte;
            self.header_len += 1;
            return if self.header_len == 2 {
                self.check_header(now).map(Err)
            } else {
                None
            };
        }
        if self.body.is_empty() && !self.accept.accepts(byte) {
            // Not a frame start after all: slide by one byte and try [header[1], byte] as the
            // header (a second error there only counts as a skipped byte).
            self.skipped += 1;
            self.header = [self.header[1], byte];
            self.started = now;
            let _ = self.check_header(now);
            return Some(Err(FrameError::BadType(byte)));
        }
        self.body.push(byte);
        if self.body.len() >= usize::from(self.want) {
            let t = self.body;
            self.clear();
            return Some(Ok(t));
        }
        None
    }

    /// Checks a complete header; on a bad length slides by one byte.
    fn check_header(&mut self, now: Option<Instant>) -> Option<FrameError> {
        match parse_header(self.header) {
            Ok(n) => {
                self.want = n as u8;
                self.body = Telegram::EMPTY;
                None
            }
            Err(e) => {
                self.skipped += 1;
                self.header = [self.header[1], 0];
                self.header_len = 1;
                self.started = now;
                Some(e)
            }
        }
    }

    fn clear(&mut self) {
        self.header = [0; 2];
        self.header_len = 0;
        self.want = 0;
        self.body = Telegram::EMPTY;
        self.started = None;
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
        // Slid by one byte: the second 0xFF may still start a header.
        assert_eq!(d.pending(), 1);
        assert_eq!(d.skipped_bytes(), 1);
    }

    /// Feeds `bytes` and collects every output.
    fn feed(d: &mut FrameDecoder, bytes: &[u8]) -> Vec<Result<Telegram, FrameError>> {
        bytes.iter().filter_map(|&b| d.push(b)).collect()
    }

    fn battery_request() -> Telegram {
        Telegram::from_bytes(&[0x00, 0x0B]).expect("fits")
    }

    /// Feeds `junk` then the frame of `t` to `d`.
    fn junk_then(
        d: &mut FrameDecoder,
        junk: &[u8],
        t: &Telegram,
    ) -> Vec<Result<Telegram, FrameError>> {
        let mut bytes = junk.to_vec();
        bytes.extend_from_slice(t.to_frame().as_bytes());
        feed(d, &bytes)
    }

    #[test]
    fn a_stray_byte_before_a_frame_is_skipped() {
        let t = battery_request();
        for stray in 0..=u8::MAX {
            let mut d = FrameDecoder::requests();
            let out = junk_then(&mut d, &[stray], &t);
            assert_eq!(out.last(), Some(&Ok(t)), "stray 0x{stray:02X}: {out:?}");
            assert_eq!(out.iter().filter(|r| r.is_ok()).count(), 1);
            assert!(d.is_idle());
        }
    }

    #[test]
    fn a_zero_length_header_is_skipped_byte_by_byte() {
        let t = battery_request();
        let mut d = FrameDecoder::requests();
        let out = junk_then(&mut d, &[0x00, 0x00], &t);
        assert_eq!(out.first(), Some(&Err(FrameError::BadLength(0))));
        assert_eq!(out.last(), Some(&Ok(t)));
        // The two zero bytes and nothing of the frame were skipped.
        assert_eq!(d.skipped_bytes(), 2, "{out:?}");
    }

    #[test]
    fn a_length_over_64_is_skipped_byte_by_byte() {
        let t = battery_request();
        for junk in [[0x41, 0x00], [0xFF, 0xFF], [0x00, 0x01]] {
            let mut d = FrameDecoder::requests();
            let out = junk_then(&mut d, &junk, &t);
            assert!(
                matches!(out.first(), Some(Err(FrameError::BadLength(n))) if *n == 0 || *n > 64),
                "{out:?}"
            );
            assert_eq!(out.last(), Some(&Ok(t)), "{junk:02X?}: {out:?}");
        }
    }

    #[test]
    fn a_dangling_header_does_not_swallow_the_next_frame() {
        // Junk ending in a plausible length (3): the request's own length byte (2) is no
        // request type byte, so the decoder slides and finds the request.
        let t = battery_request();
        let mut d = FrameDecoder::requests();
        let mut bytes = vec![0x03, 0x00];
        bytes.extend_from_slice(t.to_frame().as_bytes());
        let out = feed(&mut d, &bytes);
        assert_eq!(out.first(), Some(&Err(FrameError::BadType(0x02))));
        assert_eq!(out.last(), Some(&Ok(t)));
        // Framing only, the same junk takes the request's bytes as its body.
        let mut d = FrameDecoder::new();
        let out = feed(&mut d, &bytes);
        assert_eq!(
            out,
            vec![Ok(Telegram::from_bytes(&[0x02, 0x00, 0x00]).expect("fits"))]
        );
    }

    #[test]
    fn an_abandoned_half_frame_is_dropped_after_the_timeout() {
        let t0 = Instant::now();
        let t = Telegram::from_bytes(&[0x00, 0x06, 0x02]).expect("fits");
        let frame = t.to_frame();
        let mut d = FrameDecoder::requests();
        // Half a GETOUTPUTSTATE frame, then nothing.
        for &b in &frame.as_bytes()[..4] {
            assert_eq!(d.push_at(b, t0), None);
        }
        assert!(d.is_in_body());
        // Within the timeout the next bytes still belong to it.
        assert_eq!(d.expire(t0 + PARTIAL_FRAME_TIMEOUT), None);
        // After it, the next frame starts clean.
        let later = t0 + PARTIAL_FRAME_TIMEOUT + Duration::from_millis(1);
        let out: Vec<_> = frame
            .as_bytes()
            .iter()
            .filter_map(|&b| d.push_at(b, later))
            .collect();
        assert_eq!(out, vec![Err(FrameError::Stale { bytes: 4 }), Ok(t)]);
        // `expire` alone drops it too, and `reset` at once.
        for &b in &frame.as_bytes()[..3] {
            d.push_at(b, later);
        }
        assert_eq!(
            d.expire(later + PARTIAL_FRAME_TIMEOUT * 2),
            Some(FrameError::Stale { bytes: 3 })
        );
        assert!(d.is_idle());
        d.push_at(0x03, later);
        assert_eq!(d.reset(), 1);
        assert!(d.is_idle());
        // Without a time (`push`), nothing expires.
        d.push(0x03);
        assert_eq!(d.expire(later + Duration::from_secs(60)), None);
    }

    #[test]
    fn replies_decoder_accepts_only_reply_telegrams() {
        let reply = Telegram::from_bytes(&[0x02, 0x0B, 0x00, 0x40, 0x1F]).expect("fits");
        let mut d = FrameDecoder::replies();
        let mut bytes = battery_request().to_frame().as_bytes().to_vec();
        bytes.extend_from_slice(reply.to_frame().as_bytes());
        let out = feed(&mut d, &bytes);
        assert_eq!(
            out.iter().filter(|r| r.is_ok()).collect::<Vec<_>>(),
            vec![&Ok(reply)]
        );
        assert!(Accept::Requests.accepts(0x81) && !Accept::Requests.accepts(0x02));
        assert!(Accept::Replies.accepts(0x02) && !Accept::Replies.accepts(0x00));
    }
}
