//! Latency recording that never allocates once built: an HDR histogram in microseconds, a
//! budget whose overruns are counted, a warm-up that is left out, and the report every
//! process of the loop (and `tes bench latency`) writes and reads as JSON.
//!
//! ```
//! use tes_runtime::latency::LatencyRecorder;
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

    /// Writes `windows` (e.g. [`LatencyRecorder::windows`]) as CSV, one window per row:
    /// `window,count,p50_us,p90_us,p99_us,p999_us,max_us,misses`.
    pub fn save_windows_csv(windows: &[Self], path: &Path) -> std::io::Result<()> {
        let mut text = String::from("window,count,p50_us,p90_us,p99_us,p999_us,max_us,misses\n");
        for (i, w) in windows.iter().enumerate() {
            text += &format!(
                "{i},{},{},{},{},{},{},{}\n",
                w.count, w.p50_us, w.p90_us, w.p99_us, w.p999_us, w.max_us, w.misses
            );
        }
        std::fs::write(path, text)
    }

    /// Writes the report as one JSON object.
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        std::fs::write(path, text + "\n")
    }
}

/// Records latencies against a budget, leaving out the first `warmup` samples; optionally
/// also in consecutive windows of a fixed number of samples ([`LatencyRecorder::with_windows`]),
/// to show whether the percentiles drift over a long run.
#[derive(Debug, Clone)]
pub struct LatencyRecorder {
    histogram: Histogram<u64>,
    budget_ns: u64,
    warmup: u64,
    seen: u64,
    misses: u64,
    window: Option<Window>,
}

/// The window being filled and the reports of the finished ones.
#[derive(Debug, Clone)]
struct Window {
    size: u64,
    histogram: Histogram<u64>,
    misses: u64,
    finished: Vec<LatencyReport>,
}

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, MAX_US, 3).expect("the bounds are valid constants")
}

fn report_of(
    histogram: &Histogram<u64>,
    misses: u64,
    warmup: u64,
    budget_ns: u64,
) -> LatencyReport {
    let q = |q: f64| {
        if histogram.is_empty() {
            0
        } else {
            histogram.value_at_quantile(q)
        }
    };
    LatencyReport {
        count: histogram.len(),
        warmup,
        p50_us: q(0.5),
        p90_us: q(0.9),
        p99_us: q(0.99),
        p999_us: q(0.999),
        max_us: if histogram.is_empty() {
            0
        } else {
            histogram.max()
        },
        misses,
        budget_us: budget_ns / 1000,
    }
}

impl LatencyRecorder {
    /// A recorder for a `budget_us` budget that leaves out the first `warmup` samples.
    pub fn new(budget_us: u64, warmup: u64) -> Self {
        Self {
            histogram: histogram(),
            budget_ns: budget_us.saturating_mul(1000),
            warmup,
            seen: 0,
            misses: 0,
            window: None,
        }
    }

    /// A recorder of another quantity with the same budget and warm-up (and no windows).
    pub fn alike(&self) -> Self {
        Self::new(self.budget_ns / 1000, self.warmup)
    }

    /// Also reports every consecutive `size` samples after the warm-up as a window of their
    /// own ([`LatencyRecorder::windows`]); `size` 0 turns windows off. A finished window's
    /// report is kept in a list (one small allocation per window, none per sample).
    ///
    /// ```
    /// use tes_runtime::latency::LatencyRecorder;
    ///
    /// let mut rec = LatencyRecorder::new(1000, 0).with_windows(2);
    /// for us in [10, 20, 300, 400, 5] {
    ///     rec.record_ns(us * 1000);
    /// }
    /// let w = rec.windows();
    /// assert_eq!(w.len(), 2); // the fifth sample waits in an unfinished window
    /// assert!(w[0].max_us < 25 && w[1].p50_us >= 299);
    /// ```
    pub fn with_windows(mut self, size: u64) -> Self {
        self.window = (size > 0).then(|| Window {
            size,
            histogram: histogram(),
            misses: 0,
            finished: Vec::new(),
        });
        self
    }

    /// The reports of the finished windows, oldest first (empty without windows).
    pub fn windows(&self) -> &[LatencyReport] {
        self.window.as_ref().map_or(&[], |w| w.finished.as_slice())
    }

    /// Records one latency, ns. Allocation-free: values are clamped into the histogram's
    /// range, so recording cannot fail or grow it.
    #[inline]
    pub fn record_ns(&mut self, ns: u64) {
        self.seen += 1;
        if self.seen <= self.warmup {
            return;
        }
        let miss = ns > self.budget_ns;
        let us = (ns / 1000).clamp(1, MAX_US);
        self.misses += u64::from(miss);
        let _ = self.histogram.record(us);
        if let Some(w) = &mut self.window {
            w.misses += u64::from(miss);
            let _ = w.histogram.record(us);
            if w.histogram.len() >= w.size {
                w.finished
                    .push(report_of(&w.histogram, w.misses, 0, self.budget_ns));
                w.histogram.reset();
                w.misses = 0;
            }
        }
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

    /// The largest recorded latency, µs (0 when nothing is recorded).
    pub fn max_us(&self) -> u64 {
        if self.histogram.is_empty() {
            0
        } else {
            self.histogram.max()
        }
    }

    /// Forgets every sample and window (the warm-up stays done).
    pub fn reset(&mut self) {
        self.histogram.reset();
        self.misses = 0;
        if let Some(w) = &mut self.window {
            w.histogram.reset();
            w.misses = 0;
            w.finished.clear();
        }
    }

    /// The report of what was recorded.
    pub fn report(&self) -> LatencyReport {
        report_of(
            &self.histogram,
            self.misses,
            self.seen.min(self.warmup),
            self.budget_ns,
        )
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
    fn windows_split_the_samples_after_the_warm_up() {
        let mut r = LatencyRecorder::new(100, 1).with_windows(3);
        r.record_ns(9_000_000); // warm-up: in no window
        for us in [10, 10, 500, 20, 20, 20, 30] {
            r.record_ns(us * 1000);
        }
        let w = r.windows();
        assert_eq!(w.len(), 2);
        assert_eq!((w[0].count, w[0].misses, w[0].max_us), (3, 1, 500));
        assert_eq!((w[1].count, w[1].misses, w[1].max_us), (3, 0, 20));
        assert_eq!(r.report().count, 7);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.csv");
        LatencyReport::save_windows_csv(w, &path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().count(), 3);
        assert!(text.lines().nth(1).unwrap().starts_with("0,3,"), "{text}");
        r.reset();
        assert!(r.windows().is_empty());
        assert!(
            LatencyRecorder::new(1, 0)
                .with_windows(0)
                .windows()
                .is_empty()
        );
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
