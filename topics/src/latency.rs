//! Latency recording that never allocates once built: an HDR histogram in microseconds, a
//! budget whose overruns are counted, a warm-up that is left out, and the report every
//! process of the loop (and `tes bench latency`) writes and reads as JSON.
//!
//! ```
//! use tes_topics::latency::LatencyRecorder;
//!
//! let mut rec = LatencyRecorder::new(1000, 1); // 1 ms budget, the first sample is warm-up
//! for us in [5_000, 40, 60, 2_000] {
//!     rec.record_ns(us * 1000);
//! }
//! let report = rec.report();
//! assert_eq!((report.count, report.misses, report.warmup), (3, 1, 1));
//! assert!(report.p50_us >= 59 && report.p50_us <= 61);
//! ```

use std::path::Path;

use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

/// The largest latency recorded as itself (60 s); longer ones are recorded as 60 s.
const MAX_US: u64 = 60_000_000;

/// Percentiles, budget overruns and counts of one series of latencies, µs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LatencyReport {
    /// Latencies recorded (after the warm-up).
    pub count: u64,
    /// Samples left out as warm-up.
    pub warmup: u64,
    /// Median.
    pub p50_us: u64,
    /// 90th percentile.
    pub p90_us: u64,
    /// 99th percentile.
    pub p99_us: u64,
    /// 99.9th percentile.
    pub p999_us: u64,
    /// Largest.
    pub max_us: u64,
    /// Recorded latencies over the budget.
    pub misses: u64,
    /// The budget, µs.
    pub budget_us: u64,
}

impl LatencyReport {
    /// Reads a report written by [`LatencyReport::save`].
    pub fn load(path: &Path) -> std::io::Result<Self> {
        let text = std::fs::read_to_string(path)?;
        serde_json::from_str(&text).map_err(std::io::Error::other)
    }

    /// Writes the report as one JSON object.
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        std::fs::write(path, text + "\n")
    }
}

/// Records latencies against a budget, leaving out the first `warmup` samples.
#[derive(Debug, Clone)]
pub struct LatencyRecorder {
    histogram: Histogram<u64>,
    budget_ns: u64,
    warmup: u64,
    seen: u64,
    misses: u64,
}

impl LatencyRecorder {
    /// A recorder for a `budget_us` budget that leaves out the first `warmup` samples.
    pub fn new(budget_us: u64, warmup: u64) -> Self {
        Self {
            histogram: Histogram::new_with_bounds(1, MAX_US, 3)
                .expect("the bounds are valid constants"),
            budget_ns: budget_us.saturating_mul(1000),
            warmup,
            seen: 0,
            misses: 0,
        }
    }

    /// Records one latency, ns. Allocation-free: values are clamped into the histogram's
    /// range, so recording cannot fail or grow it.
    #[inline]
    pub fn record_ns(&mut self, ns: u64) {
        self.seen += 1;
        if self.seen <= self.warmup {
            return;
        }
        if ns > self.budget_ns {
            self.misses += 1;
        }
        let _ = self.histogram.record((ns / 1000).clamp(1, MAX_US));
    }

    /// Whether the warm-up is over (the next sample is recorded).
    pub fn warmed_up(&self) -> bool {
        self.seen >= self.warmup
    }

    /// Recorded latencies over the budget.
    pub fn misses(&self) -> u64 {
        self.misses
    }

    /// The `q` quantile, µs (0 when nothing is recorded).
    pub fn quantile_us(&self, q: f64) -> u64 {
        if self.histogram.is_empty() {
            0
        } else {
            self.histogram.value_at_quantile(q)
        }
    }

    /// Forgets every sample (the warm-up stays done).
    pub fn reset(&mut self) {
        self.histogram.reset();
        self.misses = 0;
    }

    /// The report of what was recorded.
    pub fn report(&self) -> LatencyReport {
        LatencyReport {
            count: self.histogram.len(),
            warmup: self.seen.min(self.warmup),
            p50_us: self.quantile_us(0.5),
            p90_us: self.quantile_us(0.9),
            p99_us: self.quantile_us(0.99),
            p999_us: self.quantile_us(0.999),
            max_us: if self.histogram.is_empty() {
                0
            } else {
                self.histogram.max()
            },
            misses: self.misses,
            budget_us: self.budget_ns / 1000,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warm_up_is_left_out_and_overruns_are_counted() {
        let mut r = LatencyRecorder::new(100, 2);
        assert!(!r.warmed_up());
        r.record_ns(1_000_000_000);
        r.record_ns(1_000_000_000);
        assert!(r.warmed_up());
        for us in [10, 20, 30, 200] {
            r.record_ns(us * 1000);
        }
        let rep = r.report();
        assert_eq!(
            (rep.count, rep.warmup, rep.misses, rep.budget_us),
            (4, 2, 1, 100)
        );
        assert_eq!(rep.max_us, 200);
        assert!((19..=21).contains(&rep.p50_us), "{rep:?}");
    }

    #[test]
    fn huge_values_are_clamped_not_refused() {
        let mut r = LatencyRecorder::new(1, 0);
        r.record_ns(u64::MAX);
        assert!(r.report().max_us >= MAX_US - MAX_US / 1000);
        assert_eq!(r.report().misses, 1);
    }

    #[test]
    fn reports_round_trip_through_json() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.json");
        let mut r = LatencyRecorder::new(1000, 0);
        r.record_ns(42_000);
        r.report().save(&path).unwrap();
        assert_eq!(LatencyReport::load(&path).unwrap(), r.report());
        assert!(LatencyReport::load(&dir.path().join("missing.json")).is_err());
    }
}
