use std::time::Duration;

use tes_topics::{Command, KEEP_ALIVE_ACTION, motor_flags};

use super::*;
use crate::brick::SimBrick;
use crate::clock::{Clock, ManualClock};
use crate::config::BridgeConfig;
use crate::nxt::{Port, Telegram};
use crate::transport::SimTransport;

const TICK: Duration = Duration::from_millis(5);

fn setup(cfg: &BridgeConfig) -> (Bridge<SimTransport<ManualClock>>, ManualClock) {
    let clock = ManualClock::new();
    let brick = SimBrick::new(cfg.brick.clone(), cfg.seed).expect("valid brick");
    (
        Bridge::new(SimTransport::new(brick, clock.clone()), cfg),
        clock,
    )
}

fn cmd(seq: u64, action: u32) -> Command {
    Command {
        seq,
        action,
        ..Command::default()
    }
}

/// Ticks every 5 ms until a state with all of `flags` appears (or `limit` passes).
fn until(
    bridge: &mut Bridge<SimTransport<ManualClock>>,
    clock: &ManualClock,
    flags: u32,
    limit: Duration,
) -> (MotorState, Vec<MotorState>) {
    let end = clock.now() + limit;
    let mut seen = vec![];
    while clock.now() < end {
        clock.advance(TICK);
        if let Some(s) = bridge.tick(clock.now()) {
            seen.push(s);
            if s.flags & flags == flags {
                return (s, seen);
            }
        }
    }
    panic!(
        "no state with flags {flags:#x} within {limit:?}; last {:?}",
        seen.last()
    );
}

#[test]
fn paper_actions_settle_at_their_targets() {
    let cfg = BridgeConfig::default();
    let (mut bridge, clock) = setup(&cfg);
    let (l, r) = (Port::B.index(), Port::C.index());
    // Forward: both wheels +246°.
    bridge.on_command(&cmd(1, 0), clock.now()).expect("sent");
    assert!(bridge.is_moving());
    let (s, seen) = until(
        &mut bridge,
        &clock,
        motor_flags::SETTLED,
        Duration::from_secs(3),
    );
    assert_eq!(s.after_command, 1);
    assert!(
        (246..=262).contains(&s.tacho_count[l]) && (246..=262).contains(&s.tacho_count[r]),
        "{s:?}"
    );
    assert_eq!(s.run_state, [0, 0, 0]);
    assert!(s.battery_mv > 7000);
    assert!(seen.len() > 3, "states are published while moving");
    assert!(seen.windows(2).all(|w| w[1].seq == w[0].seq + 1));
    assert!(
        seen[..seen.len() - 1]
            .iter()
            .all(|s| s.flags & motor_flags::SETTLED == 0)
    );
    // Turn left: left +90°, right −90°; the targets accumulate (336, 156).
    bridge.on_command(&cmd(2, 1), clock.now()).expect("sent");
    let (s, _) = until(
        &mut bridge,
        &clock,
        motor_flags::SETTLED,
        Duration::from_secs(3),
    );
    assert_eq!(s.after_command, 2);
    assert!((336..=352).contains(&s.tacho_count[l]), "{s:?}");
    assert!((140..=156).contains(&s.tacho_count[r]), "{s:?}");
    // Turn right: the left wheel alone.
    bridge.on_command(&cmd(3, 2), clock.now()).expect("sent");
    let (s2, _) = until(
        &mut bridge,
        &clock,
        motor_flags::SETTLED,
        Duration::from_secs(3),
    );
    assert!((426..=442).contains(&s2.tacho_count[l]), "{s2:?}");
    assert_eq!(s2.tacho_count[r], s.tacho_count[r]);
    assert_eq!(bridge.watchdog().trips(), 0);
    // At rest: heartbeats, still settled.
    let (hb, _) = until(
        &mut bridge,
        &clock,
        motor_flags::SETTLED,
        Duration::from_secs(2),
    );
    assert!(hb.seq > s2.seq);
}

#[test]
fn watchdog_brakes_a_long_move_when_commands_stop() {
    let mut cfg = BridgeConfig::from_toml_str(
        "[watchdog]\ndeadline_ms = 300\n[[actions]]\nid = 0\nleft_deg = 3600\nright_deg = 3600",
    )
    .expect("valid");
    cfg.brick.speed_noise = 0.0;
    let (mut bridge, clock) = setup(&cfg);
    bridge.on_command(&cmd(1, 0), clock.now()).expect("sent");
    let (s, _) = until(
        &mut bridge,
        &clock,
        motor_flags::WATCHDOG_BRAKED,
        Duration::from_secs(2),
    );
    let t = clock.now();
    // Tripped at the deadline, not before, and no later than one tick after it.
    assert!(
        t >= Duration::from_millis(300) && t <= Duration::from_millis(300) + TICK,
        "tripped at {t:?}"
    );
    assert_eq!(bridge.watchdog().trips(), 1);
    assert!(bridge.watchdog().silence(t) >= Duration::from_millis(300));
    assert!(s.tacho_count[Port::B.index()] < 3600);
    // The motors actually stop, and the bridge reports settled-and-braked.
    let (s, _) = until(
        &mut bridge,
        &clock,
        motor_flags::SETTLED | motor_flags::WATCHDOG_BRAKED,
        Duration::from_secs(1),
    );
    let brick = bridge.transport_mut().brick();
    assert_eq!(brick.motor(Port::B).speed_dps, 0.0);
    assert_eq!(brick.motor(Port::C).speed_dps, 0.0);
    assert!(s.tacho_count[Port::B.index()] < 1000, "{s:?}");
    // The next command clears the flag.
    bridge.on_command(&cmd(2, 0), clock.now()).expect("sent");
    assert!(!bridge.watchdog().is_tripped());
    assert_eq!(bridge.last_state().flags & motor_flags::WATCHDOG_BRAKED, 0);
}

#[test]
fn keep_alives_hold_the_watchdog_off() {
    let mut cfg = BridgeConfig::from_toml_str(
        "[watchdog]\ndeadline_ms = 300\n[[actions]]\nid = 0\nleft_deg = 1200\nright_deg = 1200",
    )
    .expect("valid");
    cfg.brick.speed_noise = 0.0;
    let (mut bridge, clock) = setup(&cfg);
    bridge.on_command(&cmd(1, 0), clock.now()).expect("sent");
    let mut settled = None;
    for i in 0..1000u64 {
        clock.advance(TICK);
        if i % 40 == 0 {
            bridge
                .on_command(&cmd(2 + i, KEEP_ALIVE_ACTION), clock.now())
                .expect("keep-alive");
        }
        if let Some(s) = bridge.tick(clock.now()) {
            assert_eq!(s.flags & motor_flags::WATCHDOG_BRAKED, 0);
            if s.flags & motor_flags::SETTLED != 0 {
                settled = Some(s);
                break;
            }
        }
    }
    let s = settled.expect("the long move completes");
    assert!(
        (1200..=1216).contains(&s.tacho_count[Port::B.index()]),
        "{s:?}"
    );
    assert_eq!(s.after_command, 1, "keep-alives are not moves");
    assert_eq!(bridge.watchdog().trips(), 0);
}

#[test]
fn unknown_actions_are_refused_and_move_nothing() {
    let (mut bridge, clock) = setup(&BridgeConfig::default());
    assert!(matches!(
        bridge.on_command(&cmd(1, 9), clock.now()),
        Err(BridgeError::UnknownAction(_))
    ));
    assert!(!bridge.is_moving());
    assert_eq!(bridge.stats().unknown_actions, 1);
    assert!(!bridge.transport_mut().brick().is_active());
}

#[test]
fn command_degrees_mode_uses_the_commands_targets() {
    let cfg = BridgeConfig {
        use_command_degrees: true,
        ..BridgeConfig::default()
    };
    let (mut bridge, clock) = setup(&cfg);
    let c = Command {
        seq: 1,
        action: 42,
        left_deg: -120,
        right_deg: 60,
        ..Command::default()
    };
    bridge.on_command(&c, clock.now()).expect("sent");
    let (s, _) = until(
        &mut bridge,
        &clock,
        motor_flags::SETTLED,
        Duration::from_secs(3),
    );
    assert!(
        (-136..=-120).contains(&s.tacho_count[Port::B.index()]),
        "{s:?}"
    );
    assert!((60..=76).contains(&s.tacho_count[Port::C.index()]), "{s:?}");
}

/// A transport whose link can be cut.
struct Flaky {
    inner: SimTransport<ManualClock>,
    down: bool,
}

impl Transport for Flaky {
    fn transact(&mut self, t: &Telegram) -> Result<Option<Telegram>, TransportError> {
        if self.down {
            return Err(TransportError::Timeout(Duration::from_millis(1)));
        }
        self.inner.transact(t)
    }
    fn describe(&self) -> String {
        "flaky".into()
    }
}

#[test]
fn link_failures_are_flagged_and_clear_on_recovery() {
    let cfg = BridgeConfig::default();
    let clock = ManualClock::new();
    let brick = SimBrick::new(cfg.brick.clone(), 0).expect("valid");
    let flaky = Flaky {
        inner: SimTransport::new(brick, clock.clone()),
        down: false,
    };
    let mut bridge = Bridge::new(flaky, &cfg);
    bridge.on_command(&cmd(1, 0), clock.now()).expect("sent");
    clock.advance(Duration::from_millis(100));
    bridge.transport_mut().down = true;
    clock.advance(Duration::from_millis(20));
    let s = bridge.tick(clock.now()).expect("a poll is due");
    assert_ne!(s.flags & motor_flags::LINK_DOWN, 0);
    assert!(bridge.on_command(&cmd(2, 0), clock.now()).is_err());
    bridge.transport_mut().down = false;
    let mut last = s;
    for _ in 0..400 {
        clock.advance(TICK);
        if let Some(s) = bridge.tick(clock.now()) {
            last = s;
            if s.flags & motor_flags::SETTLED != 0 {
                break;
            }
        }
    }
    assert_eq!(last.flags & motor_flags::LINK_DOWN, 0);
    assert_ne!(last.flags & motor_flags::SETTLED, 0);
    assert!(bridge.stats().transport_errors >= 2);
}

#[test]
fn next_wakeup_is_bounded_by_the_poll_period_while_moving() {
    let cfg = BridgeConfig::default();
    let (mut bridge, clock) = setup(&cfg);
    assert_eq!(
        bridge.next_wakeup(clock.now()),
        Duration::ZERO,
        "first heartbeat is due at once"
    );
    bridge.tick(clock.now());
    assert!(bridge.next_wakeup(clock.now()) <= cfg.poll.idle_period());
    bridge.on_command(&cmd(1, 0), clock.now()).expect("sent");
    assert!(bridge.next_wakeup(clock.now()) <= cfg.poll.moving_period());
}
