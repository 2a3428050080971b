//! The link's round trip, measured: how long each exchange with the brick takes, from the
//! request's write to its reply, whatever the transport.

use std::time::Instant;

use serde::{Deserialize, Serialize};
use tes_runtime::latency::LatencyRecorder;

use crate::nxt::Telegram;

use super::{Transport, TransportError};

/// Round trips of one link, in wall-clock µs: the exchanges that got their reply.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkReport {
    /// The transport, as the bridge describes it (`usb`, `bluetooth:…@1`, `sim (seed 7)`).
    pub transport: String,
    /// Exchanges that got their reply (requests without a reply are not timed).
    pub exchanges: u64,
    /// Exchanges that failed (no reply in time, a link down, a refused request).
    pub failed: u64,
    /// Median round trip.
    pub p50_us: u64,
    /// 90th percentile.
    pub p90_us: u64,
    /// 99th percentile.
    pub p99_us: u64,
    /// Slowest.
    pub max_us: u64,
    /// All exchanges' round trips added up (failed ones included, to their failure).
    #[serde(default)]
    pub busy_us: u64,
}

impl std::fmt::Display for LinkReport {
    /// `link usb: 812 exchanges, round trip p50 2.1 ms p99 3.9 ms max 6.0 ms, 0 failed`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "link {}: {} exchanges", self.transport, self.exchanges)?;
        if self.exchanges > 0 {
            write!(
                f,
                ", round trip p50 {} p99 {} max {}",
                in_words(self.p50_us),
                in_words(self.p99_us),
                in_words(self.max_us)
            )?;
        }
        write!(f, ", {} failed", self.failed)
    }
}

/// A duration of `us` µs for a person: `85 us` below a millisecond, `2.1 ms` from there.
pub fn in_words(us: u64) -> String {
    if us < 1000 {
        format!("{us} us")
    } else {
        format!("{:.1} ms", us as f64 / 1000.0)
    }
}

/// A transport whose exchanges (telegrams that ask for a reply) are timed.
#[derive(Debug)]
pub struct TimedTransport<T> {
    inner: T,
    round_trips: LatencyRecorder,
    failed: u64,
    busy_ns: u64,
}

impl<T: Transport> TimedTransport<T> {
    /// Times `inner`'s exchanges.
    pub fn new(inner: T) -> Self {
        Self {
            inner,
            // No budget of its own: the read timeout bounds an exchange.
            round_trips: LatencyRecorder::new(u64::MAX / 1000, 0),
            failed: 0,
            busy_ns: 0,
        }
    }

    /// The round trips so far.
    pub fn report(&self) -> LinkReport {
        let r = self.round_trips.report();
        LinkReport {
            transport: self.inner.describe(),
            exchanges: r.count,
            failed: self.failed,
            p50_us: r.p50_us,
            p90_us: r.p90_us,
            p99_us: r.p99_us,
            max_us: r.max_us,
            busy_us: self.busy_ns / 1000,
        }
    }
}

impl<T: Transport> Transport for TimedTransport<T> {
    fn transact(&mut self, telegram: &Telegram) -> Result<Option<Telegram>, TransportError> {
        if !telegram.reply_required() {
            return self.inner.transact(telegram);
        }
        let start = Instant::now();
        let reply = self.inner.transact(telegram);
        let ns = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.busy_ns = self.busy_ns.saturating_add(ns);
        match &reply {
            Ok(Some(_)) => self.round_trips.record_ns(ns),
            _ => self.failed += 1,
        }
        reply
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::brick::{SimBrick, SimBrickConfig};
    use crate::clock::ManualClock;
    use crate::nxt::Request;
    use crate::transport::{DelayedTransport, LinkDelay, SimTransport};

    /// A 5 ms link delay shows in the round trip; a request without a reply is not timed.
    #[test]
    fn exchanges_are_timed_and_one_way_telegrams_are_not() {
        let brick = SimBrick::new(SimBrickConfig::default(), 1).expect("brick");
        let sim = SimTransport::new(brick, ManualClock::new());
        let delayed = DelayedTransport::new(
            sim,
            LinkDelay::new(Duration::from_millis(5), Duration::ZERO, 1),
        );
        let mut link = TimedTransport::new(delayed);
        for _ in 0..3 {
            link.request(&Request::GetBatteryLevel).expect("reply");
        }
        link.send(&Request::KeepAlive).expect("sent");
        let report = link.report();
        assert_eq!((report.exchanges, report.failed), (3, 0), "{report:?}");
        assert!(report.p50_us >= 5_000, "{report:?}");
        let said = report.to_string();
        assert!(
            said.starts_with("link sim (seed 1)")
                && said.contains(": 3 exchanges, round trip p50 "),
            "{said}"
        );
    }
}
