//! The iceoryx2 bridge loop: publish a Command, receive MotorStates.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use tes_bridge::brick::SimBrick;
use tes_bridge::bridge::Bridge;
use tes_bridge::clock::MonotonicClock;
use tes_bridge::config::BridgeConfig;
use tes_bridge::ipc::{self as bridge_ipc, RunOptions, RunSummary, ServiceNames};
use tes_bridge::nxt::Port;
use tes_bridge::transport::SimTransport;
use tes_runtime::channel::LatestOutbox;
use tes_topics::{Command, MotorState, motor_flags};

/// Runs the bridge loop on a thread; stops and joins it on drop, even if the test panics.
struct BridgeThread {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<RunSummary>>,
}

impl BridgeThread {
    fn start(names: ServiceNames) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let opts = RunOptions {
            handle_signals: false,
            stop: Some(Arc::clone(&stop)),
        };
        let handle = std::thread::spawn(move || {
            let cfg = BridgeConfig::default();
            let clock = MonotonicClock::new();
            let brick = SimBrick::new(cfg.brick.clone(), 5).expect("valid brick");
            let mut bridge = Bridge::new(SimTransport::new(brick, clock), &cfg);
            bridge_ipc::run(&mut bridge, &clock, &names, &opts).expect("bridge loop")
        });
        Self {
            stop,
            handle: Some(handle),
        }
    }

    fn finish(mut self) -> RunSummary {
        self.stop.store(true, Ordering::SeqCst);
        self.handle
            .take()
            .expect("running")
            .join()
            .expect("bridge thread panicked")
    }
}

impl Drop for BridgeThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

fn unique_prefix() -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "tes-bridge-test-{}-{}/",
        std::process::id(),
        N.fetch_add(1, Ordering::SeqCst)
    )
}

/// `open_or_create`, retried while the other side is mid-creation.
fn retry<T, E: std::fmt::Debug>(mut f: impl FnMut() -> Result<T, E>) -> T {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match f() {
            Ok(v) => return v,
            Err(e) if Instant::now() > deadline => panic!("iceoryx2: {e:?}"),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

#[test]
fn bridge_loop_turns_commands_into_motor_states() {
    let prefix = unique_prefix();
    let names = ServiceNames::with_prefix(&prefix);
    let bridge = BridgeThread::start(names.clone());

    let node = NodeBuilder::new()
        .config(&Config::default())
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .expect("node");
    let sn = |s: &str| ServiceName::new(s).expect("valid name");
    // The shared settings every TES process opens its publish-subscribe services with.
    // Commands travel on a blackboard entry, as the controller sends them.
    let commands =
        retry(|| LatestOutbox::<Command>::open(&node, &names.command, &names.command_event));
    let state_service =
        retry(|| tes_runtime::channel::pubsub::<MotorState, _>(&node, &names.motor_state, 0));
    let subscriber = state_service
        .subscriber_builder()
        .create()
        .expect("subscriber");
    let state_event = retry(|| {
        node.service_builder(&sn(&names.motor_state_event))
            .event()
            .open_or_create()
    });
    let listener = state_event.listener_builder().create().expect("listener");

    // Wait until the bridge is up: its heartbeats arrive.
    let next = |limit: Duration| -> Option<MotorState> {
        let deadline = Instant::now() + limit;
        while Instant::now() < deadline {
            if let Some(s) = subscriber.receive().expect("receive") {
                return Some(*s);
            }
            let _ = listener.timed_wait(|_| {}, Duration::from_millis(50));
        }
        None
    };
    let first = next(Duration::from_secs(10)).expect("a heartbeat from the bridge");
    assert_ne!(first.flags & motor_flags::SETTLED, 0, "at rest: {first:?}");
    assert!(first.stamp_ns > 0);

    let cmd = Command {
        seq: 1,
        action: 0,
        left_deg: 246,
        right_deg: 246,
        ..Command::default()
    };
    commands.send(cmd).expect("send");

    let mut last_seq = first.seq;
    let settled = loop {
        let s = next(Duration::from_secs(10)).expect("motor states keep coming");
        assert!(
            s.seq > last_seq,
            "seq increases: {} then {}",
            last_seq,
            s.seq
        );
        last_seq = s.seq;
        if s.after_command == 1 && s.flags & motor_flags::SETTLED != 0 {
            break s;
        }
    };
    for p in [Port::B, Port::C] {
        assert!(
            (246..=262).contains(&settled.tacho_count[p.index()]),
            "{settled:?}"
        );
    }
    assert_eq!(
        settled.flags & (motor_flags::WATCHDOG_BRAKED | motor_flags::LINK_DOWN),
        0
    );

    // A duplicate and an older command move nothing: refused by sequence number.
    for seq in [1, 0] {
        commands
            .send(Command {
                seq,
                left_deg: 90 + seq as i32,
                ..cmd
            })
            .expect("send");
        // The bridge sees the board's latest value: give it time to take each one.
        std::thread::sleep(Duration::from_millis(200));
    }
    // The second heartbeat from now was published after the bridge took both (it drains
    // every pending command when woken); the wheels stayed where the first command left them.
    next(Duration::from_secs(10)).expect("a heartbeat");
    let after = next(Duration::from_secs(10)).expect("another heartbeat");
    assert_eq!(after.tacho_count, settled.tacho_count, "{after:?}");

    let summary = bridge.finish();
    assert_eq!(summary.commands, 3);
    assert_eq!(summary.refused, 2);
    assert_eq!(summary.last_seq, 1);
    assert!(summary.published >= 3);
}
