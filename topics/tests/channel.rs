//! An Outbox → Inbox round trip over real iceoryx2 services, for every wait strategy.

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use tes_topics::Command;
use tes_topics::channel::{self, Idle, Inbox, Outbox, WaitStrategy};

fn names(tag: &str) -> (String, String) {
    let base = format!("tes-test/{}/{tag}", std::process::id());
    (format!("{base}/payload"), format!("{base}/event"))
}

fn round_trip(strategy: WaitStrategy, tag: &str) {
    let (payload, event) = names(tag);
    let node = channel::node(false).unwrap();
    let inbox: Inbox<Command> = Inbox::open(&node, &payload, &event, 0, strategy).unwrap();
    let stop = AtomicBool::new(false);
    // Nothing sent yet: the wait times out.
    assert_eq!(
        inbox.next(Duration::from_millis(20), &stop).unwrap(),
        Err(Idle::Timeout)
    );
    let sender = {
        let (payload, event) = (payload.clone(), event.clone());
        std::thread::spawn(move || {
            // Ports are not Send: the sender has its own node and ports on its thread.
            let node = channel::node(false).unwrap();
            let outbox: Outbox<Command> = Outbox::open(&node, &payload, &event, 0).unwrap();
            for seq in 1..=50u64 {
                outbox
                    .send(Command {
                        seq,
                        ..Command::default()
                    })
                    .unwrap();
                std::thread::sleep(Duration::from_micros(300));
            }
        })
    };
    let mut seen = Vec::new();
    while seen.len() < 50 {
        match inbox.next(Duration::from_secs(5), &stop).unwrap() {
            Ok(cmd) => seen.push(cmd.seq),
            Err(idle) => panic!("{strategy}: no command within 5 s ({idle:?}) after {seen:?}"),
        }
        inbox.update_connections().unwrap();
    }
    sender.join().unwrap();
    // Every command once, in order (the subscriber connects before the first send, since the
    // publisher's creation connects to existing subscribers).
    assert_eq!(seen, (1..=50).collect::<Vec<_>>(), "{strategy}");
    // A raised stop flag ends a wait at once.
    let stop = AtomicBool::new(true);
    assert_eq!(
        inbox.next(Duration::from_secs(5), &stop).unwrap(),
        Err(Idle::Stopped)
    );
}

#[test]
fn block_round_trip() {
    round_trip(WaitStrategy::Block, "block");
}

#[test]
fn spin_round_trip() {
    round_trip(WaitStrategy::Spin, "spin");
}

#[test]
fn spin_then_block_round_trip() {
    round_trip(
        WaitStrategy::SpinThenBlock(Duration::from_micros(100)),
        "spin-then-block",
    );
}
