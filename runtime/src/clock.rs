//! The one clock every TES process stamps its messages with.

/// `CLOCK_MONOTONIC` in ns: the stamp every TES process uses, comparable across processes.
pub fn monotonic_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map(|t| {
            (t.tv_sec() as u64)
                .saturating_mul(1_000_000_000)
                .saturating_add(t.tv_nsec() as u64)
        })
        .unwrap_or(0)
}

/// A source of time in ns on the [`monotonic_ns`] scale, passed into loops so that they never
/// read the clock themselves: a test drives them with a fake one.
pub trait Clock {
    /// Now, in ns.
    fn now_ns(&self) -> u64;
}

/// The system's monotonic clock ([`monotonic_ns`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct MonotonicClock;

impl Clock for MonotonicClock {
    #[inline]
    fn now_ns(&self) -> u64 {
        monotonic_ns()
    }
}

/// A clock that moves only when told to — or by a fixed step after every reading — for tests
/// of time accounting.
///
/// ```
/// use tes_runtime::clock::{Clock, ManualClock};
///
/// let clock = ManualClock::new(1_000);
/// clock.advance(250);
/// assert_eq!(clock.now_ns(), 1_250);
/// let ticking = ManualClock::new(0).stepping(10);
/// assert_eq!((ticking.now_ns(), ticking.now_ns()), (0, 10));
/// ```
#[derive(Debug, Default)]
pub struct ManualClock {
    now: std::cell::Cell<u64>,
    step: u64,
}

impl ManualClock {
    /// A clock reading `ns`.
    pub fn new(ns: u64) -> Self {
        Self {
            now: std::cell::Cell::new(ns),
            step: 0,
        }
    }

    /// The same clock, moving `ns` forward after every reading.
    pub fn stepping(self, ns: u64) -> Self {
        Self { step: ns, ..self }
    }

    /// Moves the clock `ns` forward.
    pub fn advance(&self, ns: u64) {
        self.now.set(self.now.get().saturating_add(ns));
    }

    /// Sets the clock to `ns`.
    pub fn set(&self, ns: u64) {
        self.now.set(ns);
    }
}

impl Clock for ManualClock {
    fn now_ns(&self) -> u64 {
        let now = self.now.get();
        self.now.set(now.saturating_add(self.step));
        now
    }
}
