//! What the channels allocate per message once the ports exist: the publish–subscribe
//! [`Outbox`] / [`Inbox`] receive and wait for nothing but send one small object inside
//! iceoryx2 0.10; the blackboard [`LatestOutbox`] / [`LatestInbox`] the controller sends its
//! commands through allocate nothing at all.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use tes_runtime::channel::{self, Inbox, LatestInbox, LatestOutbox, Outbox, WaitStrategy};
use tes_topics::Command;

struct Counting;
static ON: AtomicBool = AtomicBool::new(false);
static COUNT: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to `System`; counting touches only atomics.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if ON.load(Ordering::Relaxed) {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: the caller's contract is passed on.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: `p` came from `System`.
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static A: Counting = Counting;

/// The counter is process-wide: the tests take turns.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn count(f: impl FnOnce()) -> u64 {
    COUNT.store(0, Ordering::SeqCst);
    ON.store(true, Ordering::SeqCst);
    f();
    ON.store(false, Ordering::SeqCst);
    COUNT.load(Ordering::SeqCst)
}

#[test]
fn sending_and_receiving_allocate_nothing_after_warm_up() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = format!("alloc-test-{}/", std::process::id());
    let node = channel::node(false).unwrap();
    let name = format!("{prefix}cmd");
    let event = format!("{prefix}cmd/event");
    let inbox: Inbox<Command> = Inbox::open(&node, &name, &event, 0, WaitStrategy::Block).unwrap();
    let outbox: Outbox<Command> = Outbox::open(&node, &name, &event, 0).unwrap();
    let stop = AtomicBool::new(false);
    for seq in 1..=10 {
        outbox
            .send(Command {
                seq,
                ..Command::default()
            })
            .unwrap();
        inbox.next(Duration::from_secs(1), &stop).unwrap().unwrap();
    }
    let sends = count(|| {
        for seq in 11..=1010 {
            outbox
                .send(Command {
                    seq,
                    ..Command::default()
                })
                .unwrap();
            inbox.try_next().unwrap().unwrap();
        }
    });
    let waits = count(|| {
        for seq in 1011..=2010 {
            outbox
                .send(Command {
                    seq,
                    ..Command::default()
                })
                .unwrap();
            inbox.next(Duration::from_secs(1), &stop).unwrap().unwrap();
        }
    });
    // iceoryx2 0.10 allocates one small shared-state object per loaned sample
    // (`ChunkMutSharedState::new` in `Publisher::loan_uninit`): one per message sent, none
    // per message received or waited for. Everything else on the path is allocation-free.
    assert_eq!(sends, 1000, "1000 sends + receives");
    assert_eq!(waits, 1000, "1000 sends + blocking receives");
    let receives = count(|| {
        for _ in 0..1000 {
            assert!(inbox.try_next().unwrap().is_none());
        }
    });
    assert_eq!(receives, 0, "polling an empty inbox");
}

#[test]
fn the_latest_value_channel_allocates_nothing_after_warm_up() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = format!("alloc-test-latest-{}/", std::process::id());
    let node = channel::node(false).unwrap();
    let name = format!("{prefix}cmd");
    let event = format!("{prefix}cmd/event");
    let inbox: LatestInbox<Command> =
        LatestInbox::open(&node, &name, &event, WaitStrategy::Block).unwrap();
    let outbox: LatestOutbox<Command> = LatestOutbox::open(&node, &name, &event).unwrap();
    let stop = AtomicBool::new(false);
    let command = |seq| Command {
        seq,
        ..Command::default()
    };
    for seq in 1..=10 {
        outbox.send(command(seq)).unwrap();
        assert_eq!(
            inbox
                .next(Duration::from_secs(1), &stop)
                .unwrap()
                .unwrap()
                .seq,
            seq
        );
    }
    let mut received = Vec::with_capacity(2000);
    let n = count(|| {
        for seq in 11..=1010 {
            outbox.send(command(seq)).unwrap();
            received.push(inbox.try_next().unwrap().map(|c| c.seq));
        }
        for seq in 1011..=2010 {
            outbox.send(command(seq)).unwrap();
            received.push(
                inbox
                    .next(Duration::from_secs(1), &stop)
                    .unwrap()
                    .ok()
                    .map(|c| c.seq),
            );
        }
        for _ in 0..1000 {
            assert!(inbox.try_next().unwrap().is_none());
        }
    });
    assert_eq!(n, 0, "2000 sends, receives and 1000 empty polls");
    // Every value was seen exactly once, in order.
    let expected: Vec<Option<u64>> = (11..=2010).map(Some).collect();
    assert_eq!(received, expected);
}
