//! Clocks passed into the brick, the watchdog and the bridge, so tests control time.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// A monotonic clock: time elapsed since some fixed origin.
pub trait Clock {
    /// Time since the clock's origin.
    fn now(&self) -> Duration;

    /// How long to wait in wall time for `d` of this clock's time to pass (identity for a
    /// clock that runs at wall speed).
    fn real_duration(&self, d: Duration) -> Duration {
        d
    }
}

/// The wall clock sped up `scale` times: the simulated brick's time at a real-time factor
/// (`[brick] time_scale`).
///
/// [`now`](Clock::now) is the wall-clock time since construction × `scale`;
/// [`real_duration`](Clock::real_duration) is the inverse, clock time ÷ `scale`. Both
/// saturate at [`Duration::MAX`] instead of overflowing. At `scale = 1` it is the
/// [`MonotonicClock`].
///
/// ```
/// use std::time::Duration;
/// use tes_bridge::clock::{Clock, ScaledClock};
///
/// let clock = ScaledClock::new(200.0);
/// // Half a second of brick time passes in 2.5 ms of wall time.
/// assert_eq!(clock.real_duration(Duration::from_millis(500)), Duration::from_micros(2500));
/// assert_eq!(clock.to_clock(Duration::from_micros(2500)), Duration::from_millis(500));
/// ```
#[derive(Debug, Clone, Copy)]
pub struct ScaledClock {
    origin: Instant,
    scale: f64,
}

impl ScaledClock {
    /// A clock whose origin is now, running `scale` (finite, > 0) times faster than the wall
    /// clock; other scales fall back to 1 (the config refuses them before this is reached).
    pub fn new(scale: f64) -> Self {
        Self {
            origin: Instant::now(),
            scale: if scale.is_finite() && scale > 0.0 {
                scale
            } else {
                1.0
            },
        }
    }

    /// The speed-up.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// How much of this clock's time passes in `real` of wall time (`real` × scale).
    pub fn to_clock(&self, real: Duration) -> Duration {
        Duration::try_from_secs_f64(real.as_secs_f64() * self.scale).unwrap_or(Duration::MAX)
    }
}

impl Clock for ScaledClock {
    fn now(&self) -> Duration {
        self.to_clock(self.origin.elapsed())
    }

    fn real_duration(&self, d: Duration) -> Duration {
        Duration::try_from_secs_f64(d.as_secs_f64() / self.scale).unwrap_or(Duration::MAX)
    }
}

/// The real monotonic clock (`std::time::Instant`), origin at construction.
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    origin: Instant,
}

impl MonotonicClock {
    /// A clock whose origin is now.
    pub fn new() -> Self {
        Self {
            origin: Instant::now(),
        }
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }
}

/// A clock that moves only when told to; clones share the same time.
#[derive(Debug, Clone, Default)]
pub struct ManualClock {
    ns: Arc<AtomicU64>,
}

impl ManualClock {
    /// A clock at time 0.
    pub fn new() -> Self {
        Self::default()
    }

    /// Moves the clock forward by `dt`.
    pub fn advance(&self, dt: Duration) {
        let dt = u64::try_from(dt.as_nanos()).unwrap_or(u64::MAX);
        self.ns.fetch_add(dt, Ordering::SeqCst);
    }

    /// Sets the clock to `t`.
    pub fn set(&self, t: Duration) {
        self.ns.store(
            u64::try_from(t.as_nanos()).unwrap_or(u64::MAX),
            Ordering::SeqCst,
        );
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Duration {
        Duration::from_nanos(self.ns.load(Ordering::SeqCst))
    }
}

impl<C: Clock + ?Sized> Clock for &C {
    fn now(&self) -> Duration {
        (**self).now()
    }

    fn real_duration(&self, d: Duration) -> Duration {
        (**self).real_duration(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: fn(u64) -> Duration = Duration::from_millis;

    #[test]
    fn identity_clocks_wait_what_they_measure() {
        assert_eq!(MonotonicClock::new().real_duration(MS(700)), MS(700));
        assert_eq!(ManualClock::new().real_duration(MS(700)), MS(700));
        assert_eq!(ScaledClock::new(1.0).real_duration(MS(700)), MS(700));
        assert_eq!(ScaledClock::new(1.0).to_clock(MS(700)), MS(700));
    }

    #[test]
    fn scaled_clock_converts_both_ways() {
        let fast = ScaledClock::new(200.0);
        assert_eq!(fast.scale(), 200.0);
        assert_eq!(fast.real_duration(MS(1000)), MS(5));
        assert_eq!(fast.real_duration(MS(500)), Duration::from_micros(2500));
        assert_eq!(fast.real_duration(MS(20)), Duration::from_micros(100));
        assert_eq!(fast.to_clock(MS(5)), MS(1000));
        let slow = ScaledClock::new(0.5);
        assert_eq!(slow.real_duration(MS(100)), MS(200));
        assert_eq!(slow.to_clock(MS(200)), MS(100));
        // Round trips agree within a nanosecond of rounding.
        for k in [0.25, 1.0, 3.0, 200.0, 1e4] {
            let c = ScaledClock::new(k);
            for d in [
                Duration::ZERO,
                Duration::from_nanos(1),
                MS(1),
                MS(246),
                MS(60_000),
            ] {
                let back = c.to_clock(c.real_duration(d));
                assert!(
                    back.abs_diff(d) <= Duration::from_nanos(1),
                    "{k}: {d:?} -> {back:?}"
                );
            }
        }
    }

    #[test]
    fn scaled_clock_saturates_and_refuses_bad_scales() {
        assert_eq!(ScaledClock::new(1e300).to_clock(MS(1)), Duration::MAX);
        assert_eq!(ScaledClock::new(1e-300).real_duration(MS(1)), Duration::MAX);
        for bad in [0.0, -3.0, f64::NAN, f64::INFINITY] {
            assert_eq!(ScaledClock::new(bad).scale(), 1.0, "{bad}");
        }
    }

    #[test]
    fn scaled_clock_runs_scale_times_faster_than_the_wall() {
        let before = Instant::now();
        let clock = ScaledClock::new(100.0);
        std::thread::sleep(MS(5));
        let t0 = clock.now();
        let wall = before.elapsed();
        // At least the 5 ms slept × 100; at most all the wall time that passed × 100.
        assert!(t0 >= MS(500), "{t0:?}");
        assert!(t0 <= wall * 100, "{t0:?} after {wall:?}");
        assert!(clock.now() >= t0, "monotonic");
    }

    #[test]
    fn references_forward_the_conversion() {
        fn wait_for<C: Clock>(c: C, d: Duration) -> Duration {
            c.real_duration(d)
        }
        let fast = ScaledClock::new(4.0);
        // Generic code holding `&ScaledClock` (or `&&`) must not fall back to the identity.
        let by_ref: &ScaledClock = &fast;
        let by_ref_ref: &&ScaledClock = &by_ref;
        assert_eq!(wait_for(by_ref, MS(8)), MS(2));
        assert_eq!(wait_for(by_ref_ref, MS(8)), MS(2));
        let by_dyn: &dyn Clock = &fast;
        assert_eq!(wait_for(by_dyn, MS(8)), MS(2));
    }
}
