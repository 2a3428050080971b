//! The serial transport, end to end, against `tes-bridge brick --pty`.

use std::time::Duration;

use tes_bridge::bridge::Bridge;
use tes_bridge::clock::{Clock, MonotonicClock};
use tes_bridge::config::BridgeConfig;
use tes_bridge::nxt::{
    Mode, Port, PortSelector, RegulationMode, Reply, Request, RunState, SetOutputState, Status,
    Telegram,
};
use tes_bridge::transport::{SerialConfig, SerialTransport, Transport, TransportError};
use tes_topics::{Command, motor_flags};

use crate::util::{BrickProcess, eventually};

fn output_state(link: &mut SerialTransport, port: Port) -> tes_bridge::nxt::OutputState {
    match link.request(&Request::GetOutputState { port }) {
        Ok(Reply::OutputState { state, .. }) => state,
        other => panic!("unexpected {other:?}"),
    }
}

#[test]
fn serial_transport_drives_the_pty_brick() {
    let dir = tempfile::tempdir().expect("tempdir");
    let brick = BrickProcess::spawn(&dir.path().join("nxt"), 11);
    let mut link =
        SerialTransport::open_serial(SerialConfig::new(&brick.link)).expect("open the pty");

    match link
        .request(&Request::GetFirmwareVersion)
        .expect("firmware version")
    {
        Reply::FirmwareVersion { firmware, .. } => {
            assert_eq!((firmware.major, firmware.minor), (1, 28))
        }
        other => panic!("{other:?}"),
    }
    match link.request(&Request::GetDeviceInfo).expect("device info") {
        Reply::DeviceInfo { info, .. } => assert_eq!(info.name_str(), "NXT"),
        other => panic!("{other:?}"),
    }
    link.send(&Request::SetOutputState(SetOutputState {
        port: PortSelector::One(Port::B),
        power: 75,
        mode: Mode::MOTOR_ON | Mode::BRAKE | Mode::REGULATED,
        regulation: RegulationMode::Speed,
        turn_ratio: 0,
        run_state: RunState::Running,
        tacho_limit: 360,
    }))
    .expect("send");
    let s = eventually(Duration::from_secs(10), || {
        let s = output_state(&mut link, Port::B);
        (s.run_state == RunState::Idle && s.tacho_count > 0).then_some(s)
    })
    .expect("the motor reaches its tacho limit");
    assert!((360..=380).contains(&s.tacho_count), "{s:?}");
    assert_eq!(output_state(&mut link, Port::A).tacho_count, 0);
    // IDLE is reported the moment the limit is reached, while the brake is still
    // stopping the wheel (as on the real brick): wait for it to rest before the reset
    // below, or the last degree of the stop lands after it.
    eventually(Duration::from_secs(10), || {
        let before = output_state(&mut link, Port::B).tacho_count;
        std::thread::sleep(Duration::from_millis(50));
        (output_state(&mut link, Port::B).tacho_count == before).then_some(())
    })
    .expect("the braked motor comes to rest");

    // Malformed requests get the firmware's error statuses through the link.
    let bad_port = Telegram::from_bytes(&[0x00, 0x06, 0x05]).expect("fits");
    let r = link
        .transact(&bad_port)
        .expect("reply")
        .expect("reply required");
    assert_eq!(&r.as_bytes()[..3], &[0x02, 0x06, 0xC0]);
    assert_eq!(r.len(), 25);
    let unknown = Telegram::from_bytes(&[0x00, 0x7E]).expect("fits");
    let r = link
        .transact(&unknown)
        .expect("reply")
        .expect("reply required");
    assert_eq!(r.as_bytes(), &[0x02, 0x7E, 0xBE]);
    let r = link.request(&Request::ResetMotorPosition {
        port: Port::B,
        relative: false,
    });
    assert!(
        matches!(
            r,
            Ok(Reply::Status {
                status: Status::Success,
                ..
            })
        ),
        "{r:?}"
    );
    assert_eq!(output_state(&mut link, Port::B).rotation_count, 0);
}

#[test]
fn bridge_runs_over_the_serial_link() {
    let dir = tempfile::tempdir().expect("tempdir");
    let brick = BrickProcess::spawn(&dir.path().join("nxt"), 12);
    let cfg =
        BridgeConfig::from_toml_str(&format!("transport = \"serial:{}\"", brick.link.display()))
            .expect("valid");
    let clock = MonotonicClock::new();
    let link = SerialTransport::serial(cfg.serial_config(&brick.link));
    let mut bridge = Bridge::new(link, &cfg);
    bridge
        .on_command(
            &Command {
                seq: 1,
                action: 0,
                ..Command::default()
            },
            clock.now(),
        )
        .expect("sent");
    let settled = eventually(Duration::from_secs(10), || {
        bridge
            .tick(clock.now())
            .filter(|s| s.flags & motor_flags::SETTLED != 0 && s.after_command == 1)
    })
    .expect("the move settles");
    for p in [Port::B, Port::C] {
        assert!(
            (246..=262).contains(&settled.tacho_count[p.index()]),
            "{settled:?}"
        );
    }
    assert_eq!(settled.flags & motor_flags::LINK_DOWN, 0);
    assert!(settled.battery_mv > 7000);
}

#[test]
fn serial_transport_reconnects_after_the_brick_restarts() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("nxt");
    let first = BrickProcess::spawn(&path, 13);
    let mut cfg = SerialConfig::new(&path);
    cfg.read_timeout = Duration::from_millis(300);
    cfg.reconnect_backoff = Duration::from_millis(100);
    let mut link = SerialTransport::open_serial(cfg).expect("open");
    link.request(&Request::KeepAlive)
        .expect("first brick answers");

    // SIGTERM stops the server cleanly and removes its link.
    let status = first.terminate();
    assert!(status.success(), "brick server exit: {status}");
    assert!(
        std::fs::symlink_metadata(&path).is_err(),
        "the link is removed on exit"
    );

    let err = eventually(Duration::from_secs(5), || {
        link.request(&Request::KeepAlive).err()
    })
    .expect("requests fail while the brick is gone");
    assert!(err.is_link_failure(), "{err}");

    let _second = BrickProcess::spawn(&path, 14);
    let reply = eventually(Duration::from_secs(10), || {
        match link.request(&Request::KeepAlive) {
            Ok(r) => Some(r),
            Err(
                TransportError::Backoff { .. }
                | TransportError::Open { .. }
                | TransportError::Io { .. }
                | TransportError::Timeout(_),
            ) => None,
            Err(e) => panic!("unexpected error {e}"),
        }
    })
    .expect("the transport reconnects to the new brick");
    assert!(matches!(
        reply,
        Reply::KeepAlive {
            sleep_timeout_ms: 600_000,
            ..
        }
    ));
    assert!(link.stats().connects >= 2, "{:?}", link.stats());
}
