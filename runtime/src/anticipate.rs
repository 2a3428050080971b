//! The `anticipate` wait: sleep until shortly before the next message is due, poll for a
//! bounded window then, and fall back to a plain blocking wait when it is late.
//!
//! At the robot's own pace an observation follows the last command by the motion, the link
//! and the settle time — hundreds of milliseconds in which the receiver's CPU goes idle. A
//! receiver that blocks then pays the CPU's (in a VM, the hypervisor's) wake-up on every
//! message, ~100 µs; one that spins pays a whole core. An anticipating receiver knows when
//! the next message is due and sleeps until just before:
//!
//! * **announced** — the sender publishes a [`HeadsUp`] when it knows (perception as the
//!   robot starts to settle: the observation follows the settle time later), and the receiver
//!   learns how late after the announced time its messages really come (for the controller,
//!   perception's own oversleep; for the bridge, that plus the controller's decision);
//! * **learned** — with no heads-up (a sender that gives none, or one behind a link), the
//!   receiver learns the time between messages and expects the next after the shortest recent
//!   gap. Once its sender has announced a message, a receiver expects only announced ones:
//!   anything else (a keep-alive, a re-publication) is waited for by blocking.
//!
//! Either way it also learns how late its own timed wake-ups are, and wakes twice that much
//! earlier (at least 300 µs, at most 1 ms). The poll window is bounded ([`MAX_WINDOW_NS`], and a twentieth of the gap when
//! learned), so a jittery sender costs little CPU; a message outside the window is waited for
//! by blocking, exactly as `block` would, so a late or lost message costs nothing extra.
//!
//! [`ArrivalModel`] is the pure part — what is known and what to do next — and is tested
//! with made-up times; the channels' anticipation adds the heads-up channel.

use std::cell::{Cell, RefCell};
use std::fmt;

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::Service;
use tes_topics::HeadsUp;

use crate::clock::monotonic_ns;
use crate::ipc::{IpcError, ipc_err, listener, pubsub};

/// The longest an anticipating receiver polls for one message, ns: beyond it, it blocks.
pub const MAX_WINDOW_NS: u64 = 2_000_000;

/// The least a receiver wakes before the earliest recent arrival, ns. Waking a halted
/// virtual CPU by a timer takes 30-150 µs here, and the timer's own wake-up is not all of
/// it; at the robot's pace 300 µs of polling an action is 0.05 % of a core.
const MIN_GUARD_NS: u64 = 300_000;

/// The most it wakes before, ns.
const MAX_GUARD_NS: u64 = 1_000_000;

/// Polling goes on this long past the latest recent arrival, ns.
const SLACK_NS: u64 = 50_000;

/// Recent values kept per quantity.
const RECENT: usize = 64;

/// The last [`RECENT`] values of a quantity, with their least and greatest. Fixed size: no
/// allocation.
#[derive(Debug, Clone, Copy)]
struct Recent {
    values: [u64; RECENT],
    len: usize,
    next: usize,
}

impl Recent {
    const EMPTY: Self = Self {
        values: [0; RECENT],
        len: 0,
        next: 0,
    };

    fn push(&mut self, value: u64) {
        self.values[self.next] = value;
        self.next = (self.next + 1) % RECENT;
        self.len = (self.len + 1).min(RECENT);
    }

    fn min(&self) -> Option<u64> {
        self.values[..self.len].iter().copied().min()
    }

    fn max(&self) -> Option<u64> {
        self.values[..self.len].iter().copied().max()
    }
}

/// What an anticipating receiver does next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Sleep (woken early by a message or a heads-up) until this time, ns.
    SleepUntil(u64),
    /// Poll without sleeping until this time, ns.
    PollUntil(u64),
    /// Nothing is expected soon: block until a message or a heads-up comes.
    Block,
}

/// How many messages came inside, before and after their poll window: the anticipation's
/// score, for reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Catches {
    /// Messages that came while the receiver polled.
    pub polled: u64,
    /// Messages that came while it slept or blocked (early, late, or unexpected).
    pub woken: u64,
    /// Poll windows that passed with no message (the message came later, or never).
    pub missed_windows: u64,
    /// Poll windows polled under `SCHED_FIFO` (a receiver alone on its CPU, where the
    /// system lets it).
    #[serde(default)]
    pub realtime_windows: u64,
}

/// What a receiver has learned of its sender's timing, and what it expects next. Times are
/// ns on the [`monotonic_ns`] scale.
///
/// ```
/// use tes_runtime::anticipate::{ArrivalModel, Step};
///
/// let mut model = ArrivalModel::default();
/// assert_eq!(model.step(0), Step::Block); // nothing known yet
/// model.announce(1_000_000); // a heads-up: the next message is due at 1 ms
/// let Step::SleepUntil(wake) = model.step(0) else { panic!() };
/// assert!(wake < 1_000_000); // wakes before it is due, to poll
/// assert!(matches!(model.step(wake), Step::PollUntil(end) if end > 1_000_000));
/// model.arrived(1_030_000, true); // came 30 µs after the announced time
/// ```
#[derive(Debug, Clone, Copy)]
pub struct ArrivalModel {
    /// How late after its announced time each recent announced message came.
    lateness: Recent,
    /// The time between recent arrivals.
    gaps: Recent,
    /// How late the receiver's own timed wake-ups were.
    oversleep: Recent,
    last_arrival_ns: Option<u64>,
    /// The announced time of the next message, if announced.
    due_ns: Option<u64>,
    /// Whether the sender announces its messages: then an unannounced message (a
    /// keep-alive, a re-publication) is not expected, and gaps are not learned.
    announces: bool,
    /// Whether messages are expected from the gaps between them when none is announced
    /// (`anticipate`); `auto` left unresolved expects announced messages only.
    learns_gaps: bool,
    /// The current expectation's window passed with no message.
    window_spent: bool,
    catches: Catches,
}

impl Default for ArrivalModel {
    fn default() -> Self {
        Self {
            lateness: Recent::EMPTY,
            gaps: Recent::EMPTY,
            oversleep: Recent::EMPTY,
            last_arrival_ns: None,
            due_ns: None,
            announces: false,
            learns_gaps: true,
            window_spent: false,
            catches: Catches::default(),
        }
    }
}

impl ArrivalModel {
    /// A model that expects announced messages only: with no heads-up, it always blocks
    /// (the `auto` wait of a receiver outside a launch).
    pub fn announced_only() -> Self {
        Self {
            learns_gaps: false,
            ..Self::default()
        }
    }

    /// A heads-up: the next message is due at `due_ns`.
    pub fn announce(&mut self, due_ns: u64) {
        self.due_ns = Some(due_ns);
        self.announces = true;
        self.window_spent = false;
    }

    /// The poll window of the next message, `(from, until)`, if one is expected.
    pub fn window(&self) -> Option<(u64, u64)> {
        // Twice the worst recent oversleep of its own timed wake-ups, within bounds.
        let guard = self
            .oversleep
            .max()
            .map_or(MIN_GUARD_NS, |o| 2 * o)
            .clamp(MIN_GUARD_NS, MAX_GUARD_NS);
        let (earliest, latest, cap) = match (self.due_ns, self.last_arrival_ns) {
            (Some(due), _) => (
                due + self.lateness.min().unwrap_or(0),
                due + self.lateness.max().unwrap_or(0),
                MAX_WINDOW_NS,
            ),
            (None, Some(last)) if !self.announces && self.learns_gaps => {
                let (shortest, longest) = (self.gaps.min()?, self.gaps.max()?);
                (
                    last + shortest,
                    last + longest,
                    MAX_WINDOW_NS.min(shortest / 20),
                )
            }
            (None, _) => return None,
        };
        let from = earliest.saturating_sub(guard);
        let until = (latest + SLACK_NS).min(from + guard + cap).max(from);
        Some((from, until))
    }

    /// What to do at `now_ns`.
    pub fn step(&mut self, now_ns: u64) -> Step {
        if self.window_spent {
            return Step::Block;
        }
        match self.window() {
            Some((from, _)) if now_ns < from => Step::SleepUntil(from),
            Some((_, until)) if now_ns < until => Step::PollUntil(until),
            Some(_) => {
                self.window_spent = true;
                self.catches.missed_windows += 1;
                Step::Block
            }
            None => Step::Block,
        }
    }

    /// A message came at `now_ns`; `polled` says whether the receiver was polling for it.
    pub fn arrived(&mut self, now_ns: u64, polled: bool) {
        if polled {
            self.catches.polled += 1;
        } else {
            self.catches.woken += 1;
        }
        match self.due_ns {
            // A message well before its announced time is another one (a keep-alive): the
            // announced one is still to come.
            Some(due) if now_ns + MAX_WINDOW_NS < due => return,
            Some(due) => {
                let late = now_ns.saturating_sub(due);
                // Late beyond any window: waited for by blocking, not learned from.
                if late <= MAX_WINDOW_NS {
                    self.lateness.push(late);
                }
                self.due_ns = None;
            }
            None if self.announces => {}
            None => {
                if let Some(last) = self.last_arrival_ns {
                    self.gaps.push(now_ns.saturating_sub(last));
                }
            }
        }
        self.last_arrival_ns = Some(now_ns);
        self.window_spent = false;
    }

    /// A poll window is polled under `SCHED_FIFO`.
    pub fn polled_realtime(&mut self) {
        self.catches.realtime_windows += 1;
    }

    /// A timed wake-up asked for `asked_ns` came at `now_ns`.
    pub fn woke(&mut self, asked_ns: u64, now_ns: u64) {
        self.oversleep.push(now_ns.saturating_sub(asked_ns));
    }

    /// How messages came against their windows so far.
    pub fn catches(&self) -> Catches {
        self.catches
    }
}

/// An anticipating receiver's state: its [`ArrivalModel`] and, if its sender announces,
/// the heads-up channel's subscriber and listener.
pub(crate) struct Anticipation<S: Service = ipc::Service> {
    pub(crate) model: RefCell<ArrivalModel>,
    /// The receiver has its CPU to itself (pinned, everything else kept off it): its poll
    /// spins instead of yielding, since a yield would only hand the CPU to whatever else
    /// wakes there (a kernel thread, a log follower) when the message comes; and it polls
    /// under `SCHED_FIFO` where the system lets it, so that nothing else that wakes there
    /// (a kernel worker, page reclaim) takes the CPU from it mid-window.
    pub(crate) alone: bool,
    /// The receiving thread's scheduling policy, as this anticipation set it.
    priority: Cell<PollPriority>,
    heads_up: Option<HeadsUpPorts<S>>,
}

/// Where a receiver alone on its CPU stands with `SCHED_FIFO`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PollPriority {
    /// The normal policy.
    Normal,
    /// Raised for a poll window, until the thread next sleeps.
    Raised,
    /// The system refused it once: not asked again.
    Refused,
}

struct HeadsUpPorts<S: Service> {
    subscriber: iceoryx2::port::subscriber::Subscriber<S, HeadsUp, ()>,
    listener: iceoryx2::port::listener::Listener<S>,
}

impl<S: Service> fmt::Debug for Anticipation<S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Anticipation")
            .field("model", &self.model)
            .field("alone", &self.alone)
            .field("priority", &self.priority.get())
            .field("heads_up", &self.heads_up.is_some())
            .finish()
    }
}

impl<S: Service> Anticipation<S> {
    /// What a receiver waiting by `strategy` keeps: an anticipation with `anticipate`, one
    /// of announced messages only with `auto`, nothing with any other.
    pub(crate) fn for_strategy(strategy: crate::wait::WaitStrategy) -> Option<Box<Self>> {
        use crate::wait::WaitStrategy;
        match strategy {
            WaitStrategy::Anticipate => Some(Box::new(Self::new(ArrivalModel::default()))),
            WaitStrategy::Auto => Some(Box::new(Self::new(ArrivalModel::announced_only()))),
            _ => None,
        }
    }

    /// `model`'s timing only, until [`listen`](Self::listen) adds a heads-up channel.
    fn new(model: ArrivalModel) -> Self {
        set_fine_timer_slack();
        Self {
            model: RefCell::new(model),
            alone: false,
            priority: Cell::new(PollPriority::Normal),
            heads_up: None,
        }
    }

    /// Also takes heads-ups from the service `name` and its event `event`.
    pub(crate) fn listen(
        &mut self,
        node: &Node<S>,
        name: &str,
        event: &str,
    ) -> Result<(), IpcError> {
        let service = pubsub::<HeadsUp, S>(node, name, 0)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(2)
            .create()
            .map_err(ipc_err("create a heads-up subscriber"))?;
        subscriber
            .update_connections()
            .map_err(ipc_err("connect a heads-up subscriber"))?;
        self.heads_up = Some(HeadsUpPorts {
            subscriber,
            listener: listener(node, event)?,
        });
        Ok(())
    }

    /// Raises the receiving thread to `SCHED_FIFO` for its poll window, if it polls alone and
    /// the system lets it; it stays raised through what it does with the message (the
    /// decision, the command) until [`lower_to_sleep`](Self::lower_to_sleep). A refusal is
    /// logged once and the thread polls at normal priority from then on.
    pub(crate) fn raise_for_window(&self) {
        if !self.alone || self.priority.get() != PollPriority::Normal {
            return;
        }
        match crate::affinity::set_this_thread_realtime(true) {
            Ok(()) => {
                self.priority.set(PollPriority::Raised);
                self.model.borrow_mut().polled_realtime();
            }
            Err(e) => {
                tracing::info!(error = %e, "polling at normal priority: SCHED_FIFO refused");
                self.priority.set(PollPriority::Refused);
            }
        }
    }

    /// Back to the normal policy before the thread sleeps or blocks.
    pub(crate) fn lower_to_sleep(&self) {
        if self.priority.get() != PollPriority::Raised {
            return;
        }
        if let Err(e) = crate::affinity::set_this_thread_realtime(false) {
            // Cannot happen (lowering needs no privilege); not asked again either way.
            tracing::warn!(error = %e, "could not return to the normal policy");
            self.priority.set(PollPriority::Refused);
            return;
        }
        self.priority.set(PollPriority::Normal);
    }

    /// The heads-up listener, to sleep on beside the message's own.
    pub(crate) fn heads_up_listener(&self) -> Option<&iceoryx2::port::listener::Listener<S>> {
        self.heads_up.as_ref().map(|h| &h.listener)
    }

    /// Takes every pending heads-up; the latest is announced to the model.
    pub(crate) fn take_heads_ups(&self) -> Result<(), IpcError> {
        let Some(h) = &self.heads_up else {
            return Ok(());
        };
        h.listener
            .try_wait(|_| {})
            .map_err(ipc_err("drain the heads-up listener"))?;
        while let Some(sample) = h
            .subscriber
            .receive()
            .map_err(ipc_err("receive a heads-up"))?
        {
            self.model.borrow_mut().announce(sample.due_ns);
        }
        Ok(())
    }
}

/// A receiver dropped mid-decision leaves its thread as it found it.
impl<S: Service> Drop for Anticipation<S> {
    fn drop(&mut self) {
        self.lower_to_sleep();
    }
}

/// Sleeps until `due_ns`, then returns as close to it as this machine allows: a plain sleep
/// until 300 µs before, then a poll of the clock. A sender that announced `due_ns`
/// keeps its word this way — a bare sleep of a halted virtual CPU comes back 0.1-1.5 ms late,
/// at random — for 0.3 ms of polling.
pub fn sleep_until(due_ns: u64) {
    set_fine_timer_slack();
    let now = monotonic_ns();
    let early = due_ns.saturating_sub(MIN_GUARD_NS);
    if early > now {
        std::thread::sleep(std::time::Duration::from_nanos(early - now));
    }
    while monotonic_ns() < due_ns {
        std::thread::yield_now();
    }
}

/// Timed wake-ups as precise as the kernel makes them: a normal thread's timers may fire up
/// to 50 µs late by default (its timer slack), which the guard would have to absorb.
fn set_fine_timer_slack() {
    // SAFETY: PR_SET_TIMERSLACK takes a plain integer and changes only this thread.
    let _ = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong) };
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;
    const US: u64 = 1_000;

    #[test]
    fn an_announced_message_is_polled_for_from_just_before_it_is_due() {
        let mut m = ArrivalModel::default();
        // Teach it: our wake-ups are 200 µs late, messages come 100-150 µs after their time.
        for i in 0..10u64 {
            let due = (i + 1) * 300 * MS;
            m.announce(due);
            m.woke(due - MS, due - MS + 200 * US);
            m.arrived(due + 100 * US + (i % 2) * 50 * US, true);
        }
        let due = 5_000 * MS;
        m.announce(due);
        let Step::SleepUntil(from) = m.step(due - 10 * MS) else {
            panic!("sleeps first")
        };
        // Earliest arrival 100 µs late, minus twice the 200 µs oversleep.
        assert_eq!(from, due + 100 * US - 400 * US);
        let Step::PollUntil(until) = m.step(from) else {
            panic!("then polls")
        };
        assert_eq!(until, due + 150 * US + SLACK_NS);
        // The window passes with no message: block, once, and count it.
        assert_eq!(m.step(until), Step::Block);
        assert_eq!(m.step(until + MS), Step::Block);
        assert_eq!(m.catches().missed_windows, 1);
        assert_eq!(m.catches().polled, 10);
    }

    #[test]
    fn without_heads_ups_the_gap_is_learned_and_the_window_kept_small() {
        let mut m = ArrivalModel::default();
        assert_eq!(m.step(0), Step::Block);
        // Messages every 10 ms, ± 1 ms.
        let mut t = 0;
        for i in 0..20u64 {
            t += 9 * MS + (i % 3) * MS;
            m.arrived(t, false);
        }
        let (from, until) = m.window().expect("a gap was learned");
        assert_eq!(from, t + 9 * MS - MIN_GUARD_NS);
        // A twentieth of the shortest gap, not the 2 ms spread.
        assert_eq!(until - from, MIN_GUARD_NS + 9 * MS / 20);
        assert!(matches!(m.step(t + MS), Step::SleepUntil(f) if f == from));
        assert!(matches!(m.step(from), Step::PollUntil(u) if u == until));
    }

    #[test]
    fn a_sender_that_announces_is_not_expected_between_its_announcements() {
        let mut m = ArrivalModel::default();
        // Announced messages every 800 ms, with unannounced keep-alives between them.
        for i in 1..=5u64 {
            m.arrived(i * 800 * MS - 400 * MS, false);
            m.announce(i * 800 * MS);
            m.arrived(i * 800 * MS + 20 * US, true);
        }
        // No heads-up yet for the next: nothing to poll for, however short the gaps were.
        assert_eq!(m.window(), None);
        assert_eq!(m.step(4_100 * MS), Step::Block);
        assert_eq!(m.catches().missed_windows, 0);
        assert_eq!(m.gaps.len, 0);
    }

    #[test]
    fn announced_only_never_expects_an_unannounced_message_but_polls_for_an_announced_one() {
        let mut m = ArrivalModel::announced_only();
        // Regular messages, none announced: nothing is learned to poll for.
        for i in 1..=20u64 {
            m.arrived(i * 10 * MS, false);
        }
        assert_eq!(m.window(), None);
        assert_eq!(m.step(205 * MS), Step::Block);
        // Once announced, it polls for it as `anticipate` does.
        m.announce(400 * MS);
        assert!(matches!(m.step(300 * MS), Step::SleepUntil(f) if f < 400 * MS));
        assert_eq!(m.catches().missed_windows, 0);
    }

    #[test]
    fn an_early_message_leaves_the_announced_one_expected_and_outliers_are_not_learned() {
        let mut m = ArrivalModel::default();
        m.announce(500 * MS);
        m.arrived(100 * MS, false); // a keep-alive, long before
        assert!(m.window().is_some_and(|(from, _)| from > 400 * MS));
        m.arrived(700 * MS, false); // 200 ms late: blocked for, not learned
        assert_eq!(m.lateness.len, 0);
        assert_eq!(m.catches().woken, 2);
        // A window never exceeds the cap, whatever was learned.
        for late in [0, MAX_WINDOW_NS] {
            m.announce(MS * 1000);
            m.arrived(MS * 1000 + late, true);
        }
        m.announce(MS * 2000);
        let (from, until) = m.window().unwrap();
        assert!(
            until - from <= MIN_GUARD_NS + MAX_WINDOW_NS,
            "{from} {until}"
        );
    }
}
