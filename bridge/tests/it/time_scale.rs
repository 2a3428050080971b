//! The simulated brick at a real-time factor: motion runs `time_scale` times faster than the
//! wall clock through the whole bridge loop.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use tes_bridge::config::BridgeConfig;
use tes_bridge::ipc::RunOptions;
use tes_runtime::channel::{self, Inbox, LatestOutbox, WaitStrategy};
use tes_topics::{Command, MotorState, motor_flags};

/// Runs a bridge at `time_scale` through [`tes_bridge::process::run`], sends action 0 (both
/// wheels 246°, about 0.5 s of physical motion) and returns the wall time until a SETTLED
/// motor state for it arrives, or `None` within `limit`.
fn settle_time(time_scale: f64, tag: &str, limit: Duration) -> Option<Duration> {
    let prefix = format!("tes-it/{}/{tag}/", std::process::id());
    // The watchdog deadline is brick time: scale it as `tes launch` does, so a bridge thread
    // descheduled for a few ms on a busy machine is not taken for a dead controller.
    let deadline_ms = (1000.0 * time_scale).round() as u64;
    let mut cfg = BridgeConfig::from_toml_str(&format!(
        "[brick]\ntime_scale = {time_scale}\n[ipc]\nservice_prefix = \"{prefix}\"\n\
         [watchdog]\ndeadline_ms = {deadline_ms}\n"
    ))
    .expect("valid config");
    cfg.seed = 3;
    let stop = Arc::new(AtomicBool::new(false));
    let opts = RunOptions {
        handle_signals: false,
        stop: Some(stop.clone()),
    };
    let bridge = std::thread::spawn(move || tes_bridge::process::run(&cfg, &opts));
    let node = channel::node(false).expect("node");
    let names = tes_topics::ServiceNames::with_prefix(&prefix);
    let states: Inbox<MotorState> = Inbox::open(
        &node,
        &names.motor_state,
        &names.motor_state_event,
        0,
        WaitStrategy::Block,
    )
    .expect("motor states");
    let commands: LatestOutbox<Command> =
        LatestOutbox::open(&node, &names.command, &names.command_event).expect("commands");
    let never = AtomicBool::new(false);
    // Wait for the bridge's first heartbeat, so it is connected.
    let up = Instant::now();
    loop {
        states.update_connections().expect("connect");
        if states
            .next(Duration::from_millis(50), &never)
            .expect("receive")
            .is_ok()
        {
            break;
        }
        assert!(
            up.elapsed() < Duration::from_secs(20),
            "no heartbeat from the bridge"
        );
    }
    let sent = Instant::now();
    commands
        .send(Command {
            seq: 1,
            action: 0,
            ..Command::default()
        })
        .expect("send");
    let mut settled = None;
    while sent.elapsed() < limit {
        if let Ok(m) = states
            .next(Duration::from_millis(10), &never)
            .expect("receive")
            && m.after_command == 1
            && m.flags & motor_flags::SETTLED != 0
        {
            settled = Some(sent.elapsed());
            // The move ended by itself: the watchdog (brick time, like the move) did not brake.
            assert_eq!(m.flags & motor_flags::WATCHDOG_BRAKED, 0, "{m:?}");
            assert!(m.tacho_count[1] >= 200 && m.tacho_count[2] >= 200, "{m:?}");
            break;
        }
    }
    stop.store(true, Ordering::SeqCst);
    bridge.join().expect("bridge thread").expect("bridge ran");
    settled
}

#[test]
fn a_fast_brick_settles_in_milliseconds_and_a_physical_one_does_not() {
    // ~0.5 s of motion at 200x: a few ms of wall time (very loose bound: shared machine).
    let fast = settle_time(200.0, "fast", Duration::from_secs(5)).expect("settled at 200x");
    assert!(fast < Duration::from_secs(1), "took {fast:?} at 200x");
    // At physical speed the same move is still going after 20 ms (wall time can only be
    // longer than the physics, so this bound is safe on a busy machine).
    let slow = settle_time(1.0, "slow", Duration::from_millis(20));
    assert!(slow.is_none(), "settled in {slow:?} at 1x");
}

#[test]
fn a_physical_brick_settles_in_physical_time() {
    let slow = settle_time(1.0, "physical", Duration::from_secs(10)).expect("settled at 1x");
    assert!(
        slow > Duration::from_millis(100),
        "settled in {slow:?} at 1x"
    );
}
