//! The command watchdog: brake when the controller falls silent while a motor runs.
//!
//! A plain struct driven by times you pass in. Each command or keep-alive from the
//! controller [`feed`](Watchdog::feed)s it; [`check`](Watchdog::check) trips once when a motor
//! is running and nothing was fed for the deadline, and re-arms at the next feed.
//!
//! ```
//! use std::time::Duration;
//! use tes_bridge::watchdog::{Verdict, Watchdog};
//!
//! let ms = Duration::from_millis;
//! let mut wd = Watchdog::new(ms(500));
//! wd.feed(ms(0));
//! assert_eq!(wd.check(ms(499), true), Verdict::Ok);
//! assert_eq!(wd.check(ms(500), false), Verdict::Ok); // nothing runs: nothing to stop
//! assert_eq!(wd.check(ms(500), true), Verdict::Brake);
//! assert_eq!(wd.check(ms(600), true), Verdict::Ok); // trips once
//! assert!(wd.is_tripped());
//! wd.feed(ms(700));
//! assert!(!wd.is_tripped());
//! ```

use std::time::Duration;

/// What the watchdog asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Nothing to do.
    Ok,
    /// Brake all motors now.
    Brake,
}

/// The watchdog.
#[derive(Debug, Clone, Copy)]
pub struct Watchdog {
    deadline: Duration,
    last_feed: Duration,
    tripped: bool,
    trips: u64,
}

impl Watchdog {
    /// A watchdog with this deadline, fed at time 0.
    pub fn new(deadline: Duration) -> Self {
        Self {
            deadline,
            last_feed: Duration::ZERO,
            tripped: false,
            trips: 0,
        }
    }

    /// The deadline.
    pub fn deadline(&self) -> Duration {
        self.deadline
    }

    /// A command or keep-alive arrived at `now`.
    pub fn feed(&mut self, now: Duration) {
        self.last_feed = now;
        self.tripped = false;
    }

    /// Decides at `now`, given whether any motor is running.
    pub fn check(&mut self, now: Duration, motor_running: bool) -> Verdict {
        if self.tripped || !motor_running || now.saturating_sub(self.last_feed) < self.deadline {
            return Verdict::Ok;
        }
        self.tripped = true;
        self.trips += 1;
        Verdict::Brake
    }

    /// How long it has been at `now` since the last command or keep-alive.
    pub fn silence(&self, now: Duration) -> Duration {
        now.saturating_sub(self.last_feed)
    }

    /// Time left before the deadline passes (zero once it has).
    pub fn remaining(&self, now: Duration) -> Duration {
        (self.last_feed + self.deadline).saturating_sub(now)
    }

    /// Whether it has tripped since the last feed.
    pub fn is_tripped(&self) -> bool {
        self.tripped
    }

    /// How many times it has tripped.
    pub fn trips(&self) -> u64 {
        self.trips
    }
}
