use std::time::Duration;

use super::*;
use crate::nxt::{Mode, PortSelector, RegulationMode, RunState, SetOutputState};
use proptest::prelude::*;

fn run(port: Port, power: i8, limit: u32, brake: bool) -> Request {
    let mut mode = Mode::MOTOR_ON | Mode::REGULATED;
    if brake {
        mode = mode | Mode::BRAKE;
    }
    Request::SetOutputState(SetOutputState {
        port: PortSelector::One(port),
        power,
        mode,
        regulation: RegulationMode::Speed,
        turn_ratio: 0,
        run_state: RunState::Running,
        tacho_limit: limit,
    })
}

fn brick(seed: u64) -> SimBrick {
    SimBrick::new(SimBrickConfig::default(), seed).expect("default config is valid")
}

fn ask(b: &mut SimBrick, req: Request) -> Reply {
    let t = b
        .handle(req.encode(true).as_bytes())
        .expect("a reply was requested");
    Reply::decode(t.as_bytes()).expect("the brick's replies decode")
}

fn state(b: &mut SimBrick, port: Port) -> OutputState {
    match ask(b, Request::GetOutputState { port }) {
        Reply::OutputState {
            status: Status::Success,
            state,
        } => state,
        other => panic!("unexpected reply {other:?}"),
    }
}

#[test]
fn tacho_limit_is_reached_with_a_small_overshoot() {
    let mut b = brick(1);
    assert!(
        b.handle(run(Port::B, 75, 246, true).encode(false).as_bytes())
            .is_none()
    );
    b.advance(Duration::from_millis(100));
    let mid = state(&mut b, Port::B);
    assert_eq!(mid.run_state, RunState::Running);
    assert!(
        mid.tacho_count > 0 && mid.tacho_count < 246,
        "mid-move count {}",
        mid.tacho_count
    );
    b.advance(Duration::from_secs(1));
    let s = state(&mut b, Port::B);
    assert_eq!(s.run_state, RunState::Idle);
    assert!(
        (246..=262).contains(&s.tacho_count),
        "braked stop at {}",
        s.tacho_count
    );
    assert_eq!(s.tacho_limit, 246);
    assert_eq!(s.power, 75);
    assert_eq!(b.motor(Port::B).speed_dps, 0.0);
    // Other ports never moved.
    assert_eq!(state(&mut b, Port::A).tacho_count, 0);
    assert_eq!(state(&mut b, Port::C).tacho_count, 0);
}

#[test]
fn coasting_overshoots_more_than_braking() {
    let mut braked = brick(2);
    let mut coasting = brick(2);
    braked.execute(&run(Port::A, 75, 360, true));
    coasting.execute(&run(Port::A, 75, 360, false));
    braked.advance(Duration::from_secs(2));
    coasting.advance(Duration::from_secs(2));
    let ob = state(&mut braked, Port::A).tacho_count - 360;
    let oc = state(&mut coasting, Port::A).tacho_count - 360;
    assert!(
        ob >= 0 && oc > ob,
        "brake overshoot {ob}, coast overshoot {oc}"
    );
    assert!(oc < 60, "coast overshoot {oc} implausibly large");
}

#[test]
fn the_next_move_absorbs_the_last_overshoot() {
    let mut b = brick(3);
    for k in 1..=4 {
        b.execute(&run(Port::C, 75, 246, true));
        b.advance(Duration::from_secs(1));
        let s = state(&mut b, Port::C);
        let target = 246 * k;
        // The target accumulates: the error never grows beyond one overshoot.
        assert!(
            (target..=target + 16).contains(&s.tacho_count),
            "move {k}: {}",
            s.tacho_count
        );
    }
    // Back the other way: power negative, limit positive.
    b.execute(&run(Port::C, -75, 984, true));
    b.advance(Duration::from_secs(2));
    let s = state(&mut b, Port::C);
    assert!(
        (-16..=0).contains(&s.tacho_count),
        "back near 0, at {}",
        s.tacho_count
    );
}

#[test]
fn speed_follows_power() {
    let cfg = SimBrickConfig {
        speed_noise: 0.0,
        ..SimBrickConfig::default()
    };
    let mut b = SimBrick::new(cfg, 4).expect("valid");
    b.execute(&run(Port::A, 50, 0, false));
    b.advance(Duration::from_secs(1));
    let v = b.motor(Port::A).speed_dps;
    assert!((v - 475.0).abs() < 1.0, "speed {v}");
    let c = state(&mut b, Port::A).tacho_count;
    assert!((430..=475).contains(&c), "count after 1 s: {c}");
    assert_eq!(state(&mut b, Port::A).run_state, RunState::Running);
    // Brake and hold.
    b.execute(&Request::SetOutputState(SetOutputState::BRAKE_ALL));
    b.advance(Duration::from_millis(200));
    assert_eq!(b.motor(Port::A).speed_dps, 0.0);
    assert!(!b.is_active());
}

#[test]
fn reset_position_resets_block_or_rotation_count() {
    let mut b = brick(5);
    b.execute(&run(Port::B, 60, 100, true));
    b.advance(Duration::from_secs(1));
    let before = state(&mut b, Port::B);
    assert!(matches!(
        ask(
            &mut b,
            Request::ResetMotorPosition {
                port: Port::B,
                relative: true
            }
        ),
        Reply::Status {
            status: Status::Success,
            ..
        }
    ));
    let s = state(&mut b, Port::B);
    assert_eq!(
        (s.block_tacho_count, s.rotation_count, s.tacho_count),
        (0, before.tacho_count, before.tacho_count)
    );
    b.execute(&Request::ResetMotorPosition {
        port: Port::B,
        relative: false,
    });
    let s = state(&mut b, Port::B);
    assert_eq!(
        (s.block_tacho_count, s.rotation_count, s.tacho_count),
        (0, 0, before.tacho_count)
    );
}

#[test]
fn error_statuses_for_bad_ports_and_opcodes() {
    let mut b = brick(6);
    let r = b.handle(&[0x00, 0x06, 0x03]).expect("reply");
    let mut expected = vec![0x02, 0x06, 0xC0];
    expected.extend([0u8; 22]);
    assert_eq!(r.as_bytes(), &expected[..]);
    let r = b
        .handle(&[0x00, 0x04, 0x05, 75, 7, 1, 0, 0x20, 0, 0, 0, 0])
        .expect("reply");
    assert_eq!(r.as_bytes(), &[0x02, 0x04, 0xC0]);
    let r = b.handle(&[0x00, 0x7E]).expect("reply");
    assert_eq!(r.as_bytes(), &[0x02, 0x7E, 0xBE]);
    let r = b.handle(&[0x01, 0xFE]).expect("reply");
    assert_eq!(r.as_bytes(), &[0x02, 0xFE, 0xBE]);
    let r = b.handle(&[0x00, 0x06]).expect("reply");
    assert_eq!(r.as_bytes(), &[0x02, 0x06, 0xBF]);
    // No reply requested, reply telegrams and garbage types: silence.
    assert!(b.handle(&[0x80, 0x7E]).is_none());
    assert!(b.handle(&[0x02, 0x06, 0x00]).is_none());
    assert!(b.handle(&[0x42, 0x06, 0x00]).is_none());
    assert!(b.handle(&[0x00]).is_none());
    assert!(b.stats().errors >= 7);
    // A rejected SETOUTPUTSTATE changed nothing.
    assert_eq!(b.output_state(Port::B).mode, Mode::IDLE);
}

#[test]
fn battery_keepalive_versions_and_device_info() {
    let mut b = brick(7);
    match ask(&mut b, Request::GetBatteryLevel) {
        Reply::BatteryLevel { millivolts, .. } => assert!((8100..=8300).contains(&millivolts)),
        other => panic!("{other:?}"),
    }
    assert_eq!(
        ask(&mut b, Request::KeepAlive),
        Reply::KeepAlive {
            status: Status::Success,
            sleep_timeout_ms: 600_000
        }
    );
    match ask(&mut b, Request::GetFirmwareVersion) {
        Reply::FirmwareVersion {
            firmware, protocol, ..
        } => {
            assert_eq!(
                (
                    firmware.major,
                    firmware.minor,
                    protocol.major,
                    protocol.minor
                ),
                (1, 28, 1, 124)
            )
        }
        other => panic!("{other:?}"),
    }
    match ask(&mut b, Request::GetDeviceInfo) {
        Reply::DeviceInfo { info, .. } => {
            assert_eq!(info.name_str(), "NXT");
            assert_eq!(&info.address[..3], &[0x00, 0x16, 0x53]);
        }
        other => panic!("{other:?}"),
    }
    assert!(
        b.handle(
            Request::PlayTone {
                frequency_hz: 440,
                duration_ms: 100
            }
            .encode(false)
            .as_bytes()
        )
        .is_none()
    );
    assert_eq!((b.stats().tones, b.stats().keep_alives), (1, 1));
}

#[test]
fn deterministic_for_a_seed() {
    let script = |seed: u64| {
        let mut b = brick(seed);
        let mut out = vec![];
        for (i, p) in [40i8, -60, 75, 90].into_iter().enumerate() {
            b.execute(&run(Port::ALL[i % 3], p, 200, i % 2 == 0));
            b.advance(Duration::from_millis(150 + 37 * i as u64));
            for port in Port::ALL {
                out.push(b.handle(Request::GetOutputState { port }.encode(true).as_bytes()));
            }
            out.push(b.handle(Request::GetBatteryLevel.encode(true).as_bytes()));
        }
        out
    };
    assert_eq!(script(9), script(9));
    assert_ne!(script(9), script(10));
}

#[test]
fn bad_configs_name_the_key() {
    let cfg = SimBrickConfig {
        time_constant_s: 0.0,
        ..SimBrickConfig::default()
    };
    let e = SimBrick::new(cfg, 0).expect_err("zero time constant");
    assert!(e.to_string().starts_with("brick.time_constant_s"), "{e}");
    let cfg = SimBrickConfig {
        name: "a-very-long-brick-name".into(),
        ..SimBrickConfig::default()
    };
    assert_eq!(SimBrick::new(cfg, 0).expect_err("long name").key, "name");
}

proptest! {
    /// The simulated brick survives any telegram sequence and only ever answers with
    /// well-formed replies to the opcode it was asked.
    #[test]
    fn brick_handles_arbitrary_telegrams(
        telegrams in prop::collection::vec(
            prop_oneof![
                prop::collection::vec(any::<u8>(), 0..70),
                (crate::nxt::proptests::request(), any::<bool>()).prop_map(|(r, rr)| r.encode(rr).as_bytes().to_vec()),
            ],
            1..30,
        ),
        steps_ms in prop::collection::vec(0u64..300, 30),
    ) {
        let mut brick = SimBrick::new(SimBrickConfig::default(), 0).map_err(|e| TestCaseError::fail(e.to_string()))?;
        for (t, dt) in telegrams.iter().zip(steps_ms) {
            brick.advance(std::time::Duration::from_millis(dt));
            if let Some(reply) = brick.handle(t) {
                prop_assert!(t.first().is_some_and(|ty| ty & 0x80 == 0));
                let decoded = crate::nxt::Reply::decode(reply.as_bytes());
                prop_assert!(decoded.is_ok(), "brick sent undecodable {:?}: {:?}", reply, decoded);
                prop_assert_eq!(reply.opcode(), t[1]);
            }
        }
    }
}
