//! A decorator that delays replies like a Bluetooth link.

use std::time::Duration;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::clock::ManualClock;
use crate::nxt::Telegram;

use super::{Transport, TransportError};

/// How long a simulated link takes per reply: uniform in `mean ± jitter`, seeded.
#[derive(Debug, Clone)]
pub struct LinkDelay {
    mean: Duration,
    jitter: Duration,
    rng: ChaCha8Rng,
}

impl LinkDelay {
    /// The delay a real NXT Bluetooth link adds per reply: 30 ms ± 10 ms.
    pub fn bluetooth(seed: u64) -> Self {
        Self::new(Duration::from_millis(30), Duration::from_millis(10), seed)
    }

    /// A delay uniform in `mean ± jitter` (jitter is capped at `mean`).
    pub fn new(mean: Duration, jitter: Duration, seed: u64) -> Self {
        Self {
            mean,
            jitter: jitter.min(mean),
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Draws the next delay.
    pub fn sample(&mut self) -> Duration {
        let j = self.jitter.as_nanos() as u64;
        if j == 0 {
            return self.mean;
        }
        let offset = self.rng.random_range(0..=2 * j);
        (self.mean + Duration::from_nanos(offset)).saturating_sub(self.jitter)
    }
}

/// Something that waits.
pub trait Sleep {
    /// Waits for `d`.
    fn sleep(&mut self, d: Duration);
}

/// Waits with `std::thread::sleep`.
#[derive(Debug, Clone, Copy, Default)]
pub struct ThreadSleep;

impl Sleep for ThreadSleep {
    fn sleep(&mut self, d: Duration) {
        std::thread::sleep(d);
    }
}

/// "Waiting" on a manual clock moves it forward (deterministic tests).
impl Sleep for ManualClock {
    fn sleep(&mut self, d: Duration) {
        self.advance(d);
    }
}

/// Wraps a transport and delays each reply by a [`LinkDelay`] draw.
#[derive(Debug)]
pub struct DelayedTransport<T, S = ThreadSleep> {
    inner: T,
    delay: LinkDelay,
    sleeper: S,
    total: Duration,
}

impl<T: Transport> DelayedTransport<T, ThreadSleep> {
    /// Delays `inner`'s replies in real time.
    pub fn new(inner: T, delay: LinkDelay) -> Self {
        Self::with_sleeper(inner, delay, ThreadSleep)
    }
}

impl<T: Transport, S: Sleep> DelayedTransport<T, S> {
    /// Delays `inner`'s replies with `sleeper`.
    pub fn with_sleeper(inner: T, delay: LinkDelay, sleeper: S) -> Self {
        Self {
            inner,
            delay,
            sleeper,
            total: Duration::ZERO,
        }
    }

    /// Total delay added so far.
    pub fn total_delay(&self) -> Duration {
        self.total
    }

    /// The wrapped transport.
    pub fn inner_mut(&mut self) -> &mut T {
        &mut self.inner
    }
}

impl<T: Transport, S: Sleep> Transport for DelayedTransport<T, S> {
    fn transact(&mut self, telegram: &Telegram) -> Result<Option<Telegram>, TransportError> {
        if !telegram.reply_required() {
            return self.inner.transact(telegram);
        }
        // The brick acts on the command when it arrives (half-way), the reply arrives later.
        let d = self.delay.sample();
        let half = d / 2;
        self.sleeper.sleep(half);
        let reply = self.inner.transact(telegram)?;
        self.sleeper.sleep(d - half);
        self.total += d;
        Ok(reply)
    }

    fn describe(&self) -> String {
        format!(
            "{} + link delay {:?} ± {:?}",
            self.inner.describe(),
            self.delay.mean,
            self.delay.jitter
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brick::{SimBrick, SimBrickConfig};
    use crate::clock::Clock;
    use crate::nxt::Request;
    use crate::transport::SimTransport;

    #[test]
    fn delay_stays_within_mean_plus_minus_jitter() {
        let mut d = LinkDelay::bluetooth(3);
        let samples: Vec<_> = (0..1000).map(|_| d.sample()).collect();
        assert!(samples.iter().all(|s| (20..=40).contains(&s.as_millis())));
        let mean = samples.iter().sum::<Duration>() / 1000;
        assert!((28..=32).contains(&mean.as_millis()), "mean {mean:?}");
        assert_eq!(
            LinkDelay::new(Duration::from_millis(5), Duration::ZERO, 0).sample(),
            Duration::from_millis(5)
        );
    }

    #[test]
    fn replies_are_delayed_commands_are_not() {
        let clock = ManualClock::new();
        let brick = SimBrick::new(SimBrickConfig::default(), 1).expect("valid");
        let sim = SimTransport::new(brick, clock.clone());
        let mut link = DelayedTransport::with_sleeper(sim, LinkDelay::bluetooth(1), clock.clone());
        link.send(&Request::KeepAlive).expect("send");
        assert_eq!(clock.now(), Duration::ZERO);
        link.request(&Request::GetBatteryLevel).expect("reply");
        let t = clock.now();
        assert!(
            t >= Duration::from_millis(20) && t == link.total_delay(),
            "{t:?}"
        );
        assert!(link.describe().starts_with("sim"));
    }
}
