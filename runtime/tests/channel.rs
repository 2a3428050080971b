//! An Outbox → Inbox round trip over real iceoryx2 services, for every wait strategy.

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use tes_runtime::channel::{self, Idle, Inbox, Outbox, WaitStrategy};
use tes_runtime::clock::monotonic_ns;
use tes_topics::{Command, HeadsUp};

fn names(tag: &str) -> (String, String) {
    let base = format!("tes-test/{}/{tag}", std::process::id());
    (format!("{base}/payload"), format!("{base}/event"))
}

fn round_trip(strategy: WaitStrategy, tag: &str) -> Inbox<Command> {
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
    inbox
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

#[test]
fn anticipate_round_trip() {
    round_trip(WaitStrategy::Anticipate, "anticipate");
}

/// `auto` outside a launch, with no heads-up: it never polls for an unannounced message
/// (no window opened, none missed), so it waits as `block` does.
#[test]
fn auto_without_heads_ups_round_trip_never_polls() {
    let inbox = round_trip(WaitStrategy::Auto, "auto");
    let catches = inbox.catches().expect("an auto inbox keeps score");
    assert_eq!(
        (catches.polled, catches.missed_windows),
        (0, 0),
        "{catches:?}"
    );
    assert_eq!(catches.woken, 50, "{catches:?}");
}

/// `auto` with heads-ups anticipates them as `anticipate` does.
#[test]
fn auto_catches_announced_messages_polling() {
    announced_messages("heads-up-auto", false, WaitStrategy::Auto);
}

/// A sender that announces each message 20 ms ahead: the anticipating receiver sleeps, then
/// polls, and catches most messages polling (a loaded machine may make a few late, which it
/// still receives by blocking).
#[test]
fn announced_messages_are_caught_polling() {
    announced_messages("heads-up", false, WaitStrategy::Anticipate);
}

/// The same with a sender that loans each message's sample just before it is due.
#[test]
fn announced_messages_are_caught_polling_sent_in_samples_loaned_ahead() {
    announced_messages("heads-up-loaned", true, WaitStrategy::Anticipate);
}

fn announced_messages(tag: &str, loan_ahead: bool, strategy: WaitStrategy) {
    let base = format!("tes-test/{}/{tag}", std::process::id());
    let (payload, event, due, due_event) = (
        format!("{base}/payload"),
        format!("{base}/event"),
        format!("{base}/due"),
        format!("{base}/due/event"),
    );
    let node = channel::node(false).unwrap();
    let inbox: Inbox<Command> = Inbox::open(&node, &payload, &event, 0, strategy)
        .unwrap()
        .with_heads_up(&node, &due, &due_event)
        .unwrap();
    let stop = AtomicBool::new(false);
    const MESSAGES: u64 = 30;
    let sender = std::thread::spawn(move || {
        let node = channel::node(false).unwrap();
        let outbox: Outbox<Command> = Outbox::open(&node, &payload, &event, 0).unwrap();
        let heads_up: Outbox<HeadsUp> = Outbox::open(&node, &due, &due_event, 0).unwrap();
        for seq in 1..=MESSAGES {
            let due_ns = monotonic_ns() + 20_000_000;
            heads_up.send(HeadsUp { seq, due_ns }).unwrap();
            let loan = if loan_ahead {
                let loan = tes_runtime::channel::sleep_until_with_loan(due_ns, &outbox);
                Some(loan.unwrap())
            } else {
                tes_runtime::anticipate::sleep_until(due_ns);
                None
            };
            assert!(monotonic_ns() >= due_ns, "the due time is kept");
            let command = Command {
                seq,
                ..Command::default()
            };
            outbox.send_in(loan, command).unwrap();
        }
    });
    let mut seen = Vec::new();
    while seen.len() < MESSAGES as usize {
        match inbox.next(Duration::from_secs(5), &stop).unwrap() {
            Ok(cmd) => seen.push(cmd.seq),
            Err(idle) => panic!("no command within 5 s ({idle:?}) after {seen:?}"),
        }
    }
    sender.join().unwrap();
    assert_eq!(seen, (1..=MESSAGES).collect::<Vec<_>>());
    let catches = inbox.catches().expect("an anticipating inbox keeps score");
    assert_eq!(catches.polled + catches.woken, MESSAGES);
    // The first few teach it the lateness; most of the rest are caught polling.
    assert!(catches.polled >= MESSAGES / 2, "{catches:?}");
}

/// `next_or_work` does the caller's work between polls while it spins, never while it
/// blocks, and still returns a payload that arrives meanwhile.
#[test]
fn work_is_done_between_polls_only_while_spinning() {
    let stop = AtomicBool::new(false);
    let node = channel::node(false).unwrap();
    for (strategy, tag) in [
        (WaitStrategy::Block, "work-block"),
        (WaitStrategy::Spin, "work-spin"),
        (
            WaitStrategy::SpinThenBlock(Duration::from_millis(2)),
            "work-spin-then-block",
        ),
    ] {
        let (payload, event) = names(tag);
        let inbox: Inbox<Command> = Inbox::open(&node, &payload, &event, 0, strategy).unwrap();
        let mut slices = 0u32;
        // Work for 100 slices, then none left.
        let idle = inbox
            .next_or_work(Duration::from_millis(20), &stop, || {
                slices += 1;
                slices < 100
            })
            .unwrap();
        assert_eq!(idle, Err(Idle::Timeout), "{strategy}");
        if strategy == WaitStrategy::Block {
            assert_eq!(slices, 0, "{strategy}: no work while blocked");
        } else {
            // Called on every poll: more than 100 times in a spin of 2 ms or more.
            assert!(slices > 100, "{strategy}: {slices} calls");
        }
        if strategy != WaitStrategy::Spin {
            continue;
        }
        // Work that never runs out does not keep a payload from being taken.
        let outbox: Outbox<Command> = Outbox::open(&node, &payload, &event, 0).unwrap();
        inbox.update_connections().unwrap();
        outbox
            .send(Command {
                seq: 7,
                ..Command::default()
            })
            .unwrap();
        let got = inbox
            .next_or_work(Duration::from_secs(5), &stop, || true)
            .unwrap();
        assert_eq!(got.map(|c| c.seq), Ok(7));
    }
}

/// A receiver alone on its CPU polls each window under `SCHED_FIFO` where the system lets it
/// (root, or an `RLIMIT_RTPRIO`), counts those windows, and is back under the normal policy
/// whenever it sleeps or blocks; where the system refuses, it polls as before and counts none.
#[test]
fn a_receiver_alone_on_its_cpu_polls_under_sched_fifo_and_sleeps_normal() {
    use std::sync::{Arc, Barrier};
    use tes_runtime::affinity;
    let Some((acting, other)) = affinity::auto_pair() else {
        return; // one CPU: no receiver is alone
    };
    let allowed = std::thread::spawn(|| affinity::set_this_thread_realtime(true).is_ok())
        .join()
        .unwrap();
    let base = format!("tes-test/{}/alone-fifo", std::process::id());
    let (payload, event, due, due_event) = (
        format!("{base}/payload"),
        format!("{base}/event"),
        format!("{base}/due"),
        format!("{base}/due/event"),
    );
    const MESSAGES: u64 = 20;
    // The receiver's ports exist before the first message is sent.
    let ready = Arc::new(Barrier::new(2));
    let receiver = {
        let (payload, event, due, due_event) = (
            payload.clone(),
            event.clone(),
            due.clone(),
            due_event.clone(),
        );
        let ready = ready.clone();
        std::thread::spawn(move || {
            affinity::pin_this_thread(acting).unwrap();
            let node = channel::node(false).unwrap();
            let mut inbox: Inbox<Command> =
                Inbox::open(&node, &payload, &event, 0, WaitStrategy::Anticipate)
                    .unwrap()
                    .with_heads_up(&node, &due, &due_event)
                    .unwrap();
            inbox.poll_alone(true);
            ready.wait();
            let stop = AtomicBool::new(false);
            for seq in 1..=MESSAGES {
                let got = inbox.next(Duration::from_secs(5), &stop).unwrap();
                assert_eq!(got.map(|c| c.seq), Ok(seq));
            }
            // Nothing more comes: it blocks, under the normal policy, and times out.
            assert_eq!(
                inbox.next(Duration::from_millis(5), &stop).unwrap(),
                Err(Idle::Timeout)
            );
            // SAFETY: reads the calling thread's own policy.
            let policy = unsafe { libc::sched_getscheduler(0) };
            (inbox.catches().unwrap(), policy)
        })
    };
    let sender = std::thread::spawn(move || {
        affinity::pin_this_thread(other).unwrap();
        let node = channel::node(false).unwrap();
        let outbox: Outbox<Command> = Outbox::open(&node, &payload, &event, 0).unwrap();
        let heads_up: Outbox<HeadsUp> = Outbox::open(&node, &due, &due_event, 0).unwrap();
        ready.wait();
        for seq in 1..=MESSAGES {
            let due_ns = monotonic_ns() + 20_000_000;
            heads_up.send(HeadsUp { seq, due_ns }).unwrap();
            tes_runtime::anticipate::sleep_until(due_ns);
            outbox
                .send(Command {
                    seq,
                    ..Command::default()
                })
                .unwrap();
        }
    });
    sender.join().unwrap();
    let (catches, policy_asleep) = receiver.join().unwrap();
    assert_eq!(policy_asleep, libc::SCHED_OTHER, "{catches:?}");
    assert!(catches.polled >= MESSAGES / 2, "{catches:?}");
    if allowed {
        // One raise per window, and every message caught polling was caught in one.
        assert!(catches.realtime_windows >= catches.polled, "{catches:?}");
    } else {
        assert_eq!(catches.realtime_windows, 0, "{catches:?}");
    }
}
