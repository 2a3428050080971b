//! Property tests: every command and reply round-trips; no byte string panics a decoder.

use proptest::prelude::*;

use std::time::{Duration, Instant};

use super::frame::{FrameDecoder, PARTIAL_FRAME_TIMEOUT, decode_frame};
use super::*;

fn port() -> impl Strategy<Value = Port> {
    prop::sample::select(Port::ALL.to_vec())
}

fn mode() -> impl Strategy<Value = Mode> {
    (0u8..8).prop_map(|b| Mode::from_bits(b).unwrap_or_default())
}

fn regulation() -> impl Strategy<Value = RegulationMode> {
    prop::sample::select(vec![
        RegulationMode::Idle,
        RegulationMode::Speed,
        RegulationMode::Sync,
    ])
}

fn run_state() -> impl Strategy<Value = RunState> {
    prop::sample::select(vec![
        RunState::Idle,
        RunState::RampUp,
        RunState::Running,
        RunState::RampDown,
    ])
}

fn status() -> impl Strategy<Value = Status> {
    prop::sample::select(Status::ALL.to_vec())
}

fn set_output_state() -> impl Strategy<Value = SetOutputState> {
    (
        prop_oneof![port().prop_map(PortSelector::One), Just(PortSelector::All)],
        any::<i8>(),
        mode(),
        regulation(),
        any::<i8>(),
        run_state(),
        any::<u32>(),
    )
        .prop_map(
            |(port, power, mode, regulation, turn_ratio, run_state, tacho_limit)| SetOutputState {
                port,
                power,
                mode,
                regulation,
                turn_ratio,
                run_state,
                tacho_limit,
            },
        )
}

/// Any well-formed request (also the simulated brick's property tests' input).
pub(crate) fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        (any::<u16>(), any::<u16>()).prop_map(|(frequency_hz, duration_ms)| Request::PlayTone {
            frequency_hz,
            duration_ms
        }),
        set_output_state().prop_map(Request::SetOutputState),
        port().prop_map(|port| Request::GetOutputState { port }),
        (port(), any::<bool>())
            .prop_map(|(port, relative)| Request::ResetMotorPosition { port, relative }),
        Just(Request::GetBatteryLevel),
        Just(Request::KeepAlive),
        Just(Request::GetFirmwareVersion),
        Just(Request::GetDeviceInfo),
    ]
}

fn output_state() -> impl Strategy<Value = OutputState> {
    (
        (
            port(),
            any::<i8>(),
            mode(),
            regulation(),
            any::<i8>(),
            run_state(),
        ),
        (any::<u32>(), any::<i32>(), any::<i32>(), any::<i32>()),
    )
        .prop_map(
            |((port, power, mode, regulation, turn_ratio, run_state), (tl, tc, bc, rc))| {
                OutputState {
                    port,
                    power,
                    mode,
                    regulation,
                    turn_ratio,
                    run_state,
                    tacho_limit: tl,
                    tacho_count: tc,
                    block_tacho_count: bc,
                    rotation_count: rc,
                }
            },
        )
}

fn version() -> impl Strategy<Value = Version> {
    (any::<u8>(), any::<u8>()).prop_map(|(major, minor)| Version { major, minor })
}

fn reply() -> impl Strategy<Value = Reply> {
    let status_only = (any::<u8>(), status()).prop_filter_map(
        "successful body-bearing opcodes need a body",
        |(opcode, status)| {
            let bodiless = Opcode::from_u8(opcode).is_some_and(|op| op.reply_len() == 3);
            (bodiless || !status.is_success()).then_some(Reply::Status { opcode, status })
        },
    );
    prop_oneof![
        status_only,
        (status(), output_state()).prop_map(|(status, state)| Reply::OutputState { status, state }),
        (status(), any::<u16>())
            .prop_map(|(status, millivolts)| Reply::BatteryLevel { status, millivolts }),
        (status(), any::<u32>()).prop_map(|(status, sleep_timeout_ms)| Reply::KeepAlive {
            status,
            sleep_timeout_ms
        }),
        (status(), version(), version()).prop_map(|(status, protocol, firmware)| {
            Reply::FirmwareVersion {
                status,
                protocol,
                firmware,
            }
        }),
        (
            status(),
            any::<[u8; 15]>(),
            any::<[u8; 7]>(),
            any::<[u8; 4]>(),
            any::<u32>()
        )
            .prop_map(|(status, name, address, signal_strength, free_flash)| {
                Reply::DeviceInfo {
                    status,
                    info: DeviceInfo {
                        name,
                        address,
                        signal_strength,
                        free_flash,
                    },
                }
            }),
    ]
}

/// Junk as a stream meets it: random bytes, mixed with the pieces that fool a decoder most —
/// truncated real frames (an abandoned half frame), plausible headers, zero and oversized lengths.
fn junk() -> impl Strategy<Value = Vec<u8>> {
    let piece = prop_oneof![
        prop::collection::vec(any::<u8>(), 0..40),
        (request(), any::<bool>(), 0usize..14).prop_map(|(r, rr, cut)| {
            let f = r.encode(rr).to_frame();
            let b = f.as_bytes();
            b[..cut.min(b.len().saturating_sub(1))].to_vec()
        }),
        (
            1u8..=64,
            prop::sample::select(vec![0x00u8, 0x01, 0x02, 0x80, 0x81])
        )
            .prop_map(|(n, ty)| vec![n, 0x00, ty]),
        Just(vec![0x00, 0x00]),
        (65u16..).prop_map(|n| n.to_le_bytes().to_vec()),
    ];
    prop::collection::vec(piece, 0..12).prop_map(|ps| {
        let mut v: Vec<u8> = ps.concat();
        v.truncate(400);
        v
    })
}

/// Feeds `bytes` at `now`; returns the outputs.
fn feed_at(d: &mut FrameDecoder, bytes: &[u8], now: Instant) -> Vec<Result<Telegram, FrameError>> {
    bytes.iter().filter_map(|&b| d.push_at(b, now)).collect()
}

/// Junk, then the frame of `t`: `d` yields exactly `t` — at once, or, if the junk ended inside
/// a plausible frame's body, when `t` is sent again after the partial-frame timeout.
fn junk_then_yields(
    mut d: FrameDecoder,
    junk: &[u8],
    t: Telegram,
) -> Result<(), proptest::test_runner::TestCaseError> {
    let frame = t.to_frame();
    let t0 = Instant::now();
    let _ = feed_at(&mut d, junk, t0);
    if d.is_in_body() {
        let _ = feed_at(&mut d, frame.as_bytes(), t0);
        let retry = t0 + PARTIAL_FRAME_TIMEOUT + Duration::from_millis(1);
        yields_exactly(&mut d, frame.as_bytes(), t, retry)
    } else {
        yields_exactly(&mut d, frame.as_bytes(), t, t0)
    }
}

/// Asserts that feeding `frame` yields exactly `t`, at its last byte, and no other telegram.
fn yields_exactly(
    d: &mut FrameDecoder,
    frame: &[u8],
    t: Telegram,
    now: Instant,
) -> Result<(), TestCaseError> {
    let (last, head) = frame
        .split_last()
        .ok_or_else(|| TestCaseError::fail("empty frame"))?;
    let early = feed_at(d, head, now);
    prop_assert!(
        early.iter().all(|r| r.is_err()),
        "telegram before the frame ended: {:?}",
        early
    );
    prop_assert_eq!(d.push_at(*last, now), Some(Ok(t)));
    prop_assert!(d.is_idle());
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn requests_round_trip(req in request(), reply_required in any::<bool>()) {
        let t = req.encode(reply_required);
        prop_assert_eq!(t.len(), req.opcode().request_len());
        prop_assert_eq!(t.reply_required(), reply_required);
        prop_assert_eq!(Request::decode(t.as_bytes()), Ok((req, reply_required)));
        let f = t.to_frame();
        prop_assert_eq!(decode_frame(f.as_bytes()), Ok(t));
    }

    #[test]
    fn replies_round_trip(reply in reply()) {
        let t = reply.encode();
        prop_assert_eq!(Reply::decode(t.as_bytes()), Ok(reply));
        prop_assert_eq!(decode_frame(t.to_frame().as_bytes()), Ok(t));
    }

    /// Arbitrary bytes never panic a decoder, and whatever decodes is canonical:
    /// it re-encodes to exactly the input.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..80)) {
        if let Ok((req, reply_required)) = Request::decode(&bytes) {
            prop_assert_eq!(req.encode(reply_required).as_bytes().to_vec(), bytes.clone());
        }
        if let Ok(reply) = Reply::decode(&bytes) {
            prop_assert_eq!(reply.encode().as_bytes().to_vec(), bytes.clone());
        }
        if let Ok(t) = decode_frame(&bytes) {
            prop_assert_eq!(t.to_frame().as_bytes().to_vec(), bytes.clone());
        }
        let mut d = FrameDecoder::new();
        for &b in &bytes {
            if let Some(Ok(t)) = d.push(b) {
                prop_assert!(!t.is_empty() && t.len() <= MAX_TELEGRAM_LEN);
            }
        }
        let _ = Telegram::from_bytes(&bytes);
    }

    /// Mostly-valid telegrams (a real type byte and opcode, random tail) reach deeper.
    #[test]
    fn near_valid_bytes_never_panic(
        ty in prop::sample::select(vec![0x00u8, 0x01, 0x02, 0x80, 0x81]),
        op in prop::sample::select(Opcode::ALL.iter().map(|o| *o as u8).chain([0x00, 0x7F, 0xFF]).collect::<Vec<_>>()),
        tail in prop::collection::vec(any::<u8>(), 0..40),
    ) {
        let mut bytes = vec![ty, op];
        bytes.extend(tail);
        if let Ok((req, reply_required)) = Request::decode(&bytes) {
            prop_assert_eq!(req.encode(reply_required).as_bytes().to_vec(), bytes.clone());
        }
        if let Ok(reply) = Reply::decode(&bytes) {
            prop_assert_eq!(reply.encode().as_bytes().to_vec(), bytes.clone());
        }
    }

    /// Any junk, then — after a quiet time longer than the partial-frame timeout, as a client's
    /// retry or the next client brings — a valid request: the decoder yields exactly that
    /// request. Holds with the type check (`requests`) and with framing only (`new`).
    #[test]
    fn junk_then_a_request_after_the_timeout_yields_the_request(
        junk in junk(),
        req in request(),
        reply_required in any::<bool>(),
    ) {
        let t = req.encode(reply_required);
        let t0 = Instant::now();
        let later = t0 + PARTIAL_FRAME_TIMEOUT + Duration::from_millis(1);
        for mut d in [FrameDecoder::requests(), FrameDecoder::new()] {
            let _ = feed_at(&mut d, &junk, t0);
            yields_exactly(&mut d, t.to_frame().as_bytes(), t, later)?;
        }
    }

    /// Any junk immediately followed by a valid request: unless the junk ended inside the body
    /// of a plausible frame (which takes the next bytes as its own until the timeout), the
    /// request decoder yields exactly the request; and in that case the request sent again
    /// after the timeout is yielded.
    #[test]
    fn junk_then_a_request_yields_the_request(
        junk in junk(),
        req in request(),
        reply_required in any::<bool>(),
    ) {
        junk_then_yields(FrameDecoder::requests(), &junk, req.encode(reply_required))?;
    }

    /// The same for a client reading replies after junk.
    #[test]
    fn junk_then_a_reply_yields_the_reply(junk in junk(), reply in reply()) {
        junk_then_yields(FrameDecoder::replies(), &junk, reply.encode())?;
    }
}
