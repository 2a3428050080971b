//! An experiment's progress as lines, for a log without a terminal (a batch job, `nohup`):
//! where a terminal gets a progress bar, a log gets a line at most every
//! [`PROGRESS_LINE_EVERY`] and at the end, with the time left estimated from the runs
//! finished in this invocation (not those found written on resume).

use std::time::{Duration, Instant};

/// How often a log without a terminal gets a progress line.
pub const PROGRESS_LINE_EVERY: Duration = Duration::from_secs(30);

/// The state of an experiment's progress lines.
#[derive(Debug, Clone)]
pub struct ProgressLines {
    what: String,
    started: Instant,
    /// The runs already written when this invocation began (on resume).
    found: Option<u64>,
    /// When the last line was due.
    last_line: Instant,
}

impl ProgressLines {
    /// The progress of `what` (`grid experiment`), started at `started`.
    pub fn new(what: impl Into<String>, started: Instant) -> Self {
        Self {
            what: what.into(),
            started,
            found: None,
            last_line: started,
        }
    }

    /// Prints the line due now, if one is, on stderr.
    pub fn update(&mut self, done: u64, total: u64) {
        if let Some(line) = self.line(done, total, Instant::now()) {
            eprintln!("{line}");
        }
    }

    /// The line to print when `done` of `total` runs are written at `now`, if one is due:
    /// the first call's runs are those found on resume (said once, if any); then a line
    /// every [`PROGRESS_LINE_EVERY`], and one for the last run.
    ///
    /// ```
    /// use std::time::{Duration, Instant};
    /// use tes_experiments::progress::ProgressLines;
    ///
    /// let t0 = Instant::now();
    /// let mut lines = ProgressLines::new("grid experiment", t0);
    /// assert_eq!(lines.line(0, 4, t0), None);
    /// let line = lines.line(4, 4, t0 + Duration::from_secs(90));
    /// assert_eq!(line.as_deref(), Some("grid experiment: 4/4 runs (1m30s elapsed, ~0s left)"));
    /// ```
    pub fn line(&mut self, done: u64, total: u64, now: Instant) -> Option<String> {
        let found = *self.found.get_or_insert(done);
        if done == found {
            return (found > 0)
                .then(|| format!("{}: {found}/{total} runs already written", self.what));
        }
        if done < total && now.duration_since(self.last_line) < PROGRESS_LINE_EVERY {
            return None;
        }
        self.last_line = now;
        let elapsed = now.duration_since(self.started);
        let per_run = elapsed.as_secs_f64() / (done - found) as f64;
        let left = per_run * total.saturating_sub(done) as f64;
        Some(format!(
            "{}: {done}/{total} runs ({} elapsed, ~{} left)",
            self.what,
            clock(elapsed.as_secs_f64()),
            clock(left)
        ))
    }
}

/// `1h02m03s`, `4m05s`, `7s`.
pub fn clock(seconds: f64) -> String {
    let s = seconds.round() as u64;
    match (s / 3600, s / 60 % 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, s) => format!("{h}h{m:02}m{s:02}s"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_a_terminal_progress_is_a_line_every_so_often_with_an_estimate_from_this_invocation()
    {
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let mut p = ProgressLines::new("transfer experiment", t0);
        // Resumed with 40 of 100 runs written: said once, not estimated from.
        assert_eq!(
            p.line(40, 100, t0).as_deref(),
            Some("transfer experiment: 40/100 runs already written")
        );
        // A run 10 s later: too soon for a line.
        assert_eq!(p.line(41, 100, at(10)), None);
        // 60 s in, 2 runs done here: 30 s a run, 58 to go.
        assert_eq!(
            p.line(42, 100, at(60)).as_deref(),
            Some("transfer experiment: 42/100 runs (1m00s elapsed, ~29m00s left)")
        );
        assert_eq!(p.line(43, 100, at(70)), None);
        // The last run always gets its line.
        assert_eq!(
            p.line(100, 100, at(1830)).as_deref(),
            Some("transfer experiment: 100/100 runs (30m30s elapsed, ~0s left)")
        );
        assert_eq!(clock(3723.0), "1h02m03s");
        // A fresh run says nothing before its first run is done.
        let mut fresh = ProgressLines::new("grid experiment", t0);
        assert_eq!(fresh.line(0, 5, at(0)), None);
    }
}
