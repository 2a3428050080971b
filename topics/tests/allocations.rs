//! What the channel allocates per message once the ports exist (the controller's acting path
//! publishes a command per decision): receiving and waiting nothing, sending one small
//! object inside iceoryx2 0.10.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use tes_topics::Command;
use tes_topics::channel::{self, Inbox, Outbox, WaitStrategy};

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

fn count(f: impl FnOnce()) -> u64 {
    COUNT.store(0, Ordering::SeqCst);
    ON.store(true, Ordering::SeqCst);
    f();
    ON.store(false, Ordering::SeqCst);
    COUNT.load(Ordering::SeqCst)
}

#[test]
fn sending_and_receiving_allocate_nothing_after_warm_up() {
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
