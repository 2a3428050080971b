//! The paper's targets and whether a run meets them — or is too small to tell.
//!
//! A `--quick` run is a first look: a smaller task, a few runs, short training. Its figures
//! cannot confirm or refute the paper's claims, so it reports [`Verdict::QuickRun`] in place of
//! "holds" or "does not hold", in the printed output and in `summary.json` alike; full-size runs
//! keep their verdicts.

use serde::Serialize;

/// What a quick run says in place of a verdict.
pub const QUICK_RUN_NOTE: &str =
    "quick run: too small to judge the paper's targets; run without --quick";

/// What a run that left out some of the paper's cases says in place of a verdict.
pub const PARTIAL_RUN_NOTE: &str =
    "partial run: the target counts every test task; run them all to judge it";

/// What a target counted over intervals says when the intervals leave the count on both
/// sides of it.
pub const UNDECIDED_NOTE: &str =
    "undecided: the 95 % intervals leave the count on both sides of the target";

/// Whether a run meets one of the paper's targets. Serialised as its [`text`](Self::text).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Verdict {
    /// The target is met.
    #[serde(rename = "holds")]
    Holds,
    /// The target is missed.
    #[serde(rename = "does not hold")]
    DoesNotHold,
    /// A `--quick` run: too small to judge.
    #[serde(rename = "quick run: too small to judge the paper's targets; run without --quick")]
    QuickRun,
    /// A full-size run over only some of the cases the target counts.
    #[serde(rename = "partial run: the target counts every test task; run them all to judge it")]
    PartialRun,
    /// A count of cases each decided by its interval, where the undecided cases could put the
    /// count on either side of the target: more runs would decide it.
    #[serde(rename = "undecided: the 95 % intervals leave the count on both sides of the target")]
    Undecided,
}

impl Verdict {
    /// The verdict on a target that `holds` in a run that was `quick` or not.
    pub fn judge(quick: bool, holds: bool) -> Self {
        match (quick, holds) {
            (true, _) => Verdict::QuickRun,
            (false, true) => Verdict::Holds,
            (false, false) => Verdict::DoesNotHold,
        }
    }

    /// The verdict in words, as printed and as `summary.json` records it.
    pub fn text(self) -> &'static str {
        match self {
            Verdict::Holds => "holds",
            Verdict::DoesNotHold => "does not hold",
            Verdict::QuickRun => QUICK_RUN_NOTE,
            Verdict::PartialRun => PARTIAL_RUN_NOTE,
            Verdict::Undecided => UNDECIDED_NOTE,
        }
    }

    /// Whether this is a judgement (holds or not) rather than a note that none can be made.
    pub fn is_judged(self) -> bool {
        matches!(self, Verdict::Holds | Verdict::DoesNotHold)
    }
}

/// One of the paper's targets, what a run measured against it, and the verdict.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetCheck {
    /// The target, in words (e.g. "loreRL / fEpsG time per episode <= 2.5 (paper: 2.2)").
    pub target: String,
    /// What this run measured, in words and numbers.
    pub measured: String,
    /// Holds, does not hold, or why it cannot be judged.
    pub verdict: Verdict,
}

impl TargetCheck {
    /// A check of `target` against `measured`, judged by [`Verdict::judge`].
    pub fn new(
        target: impl Into<String>,
        measured: impl Into<String>,
        quick: bool,
        holds: bool,
    ) -> Self {
        Self {
            target: target.into(),
            measured: measured.into(),
            verdict: Verdict::judge(quick, holds),
        }
    }
}

/// The lines that print a run's targets: each target with what was measured and its verdict —
/// or, for a quick run, the measurements under one note that they are too small to judge.
pub fn lines(targets: &[TargetCheck]) -> Vec<String> {
    let quick = targets.iter().any(|t| t.verdict == Verdict::QuickRun);
    let mut lines = vec![if quick {
        format!("the paper's targets ({QUICK_RUN_NOTE}):")
    } else {
        "the paper's targets:".to_owned()
    }];
    for t in targets {
        lines.push(if t.verdict == Verdict::QuickRun {
            format!("  {}: {}", t.target, t.measured)
        } else {
            format!("  {}: {} — {}", t.target, t.measured, t.verdict.text())
        });
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checks(quick: bool) -> Vec<TargetCheck> {
        vec![
            TargetCheck::new("a <= 2.5", "3.10", quick, false),
            TargetCheck::new("b >= 10", "16.0", quick, true),
        ]
    }

    #[test]
    fn a_quick_run_prints_its_numbers_but_no_verdict() {
        let lines = lines(&checks(true));
        let text = lines.join("\n");
        assert!(lines[0].contains(QUICK_RUN_NOTE), "{text}");
        assert!(!text.contains("hold"), "{text}");
        assert!(text.contains("a <= 2.5: 3.10") && text.contains("b >= 10: 16.0"));
    }

    #[test]
    fn a_full_run_prints_a_verdict_per_target() {
        let lines = lines(&checks(false));
        assert_eq!(lines[0], "the paper's targets:");
        assert_eq!(lines[1], "  a <= 2.5: 3.10 — does not hold");
        assert_eq!(lines[2], "  b >= 10: 16.0 — holds");
    }

    #[test]
    fn a_quick_run_never_gives_a_verdict() {
        for holds in [true, false] {
            let v = Verdict::judge(true, holds);
            assert_eq!(v, Verdict::QuickRun);
            assert!(!v.is_judged());
            assert!(!v.text().contains("hold"), "{}", v.text());
        }
        assert_eq!(Verdict::judge(false, true).text(), "holds");
        assert_eq!(Verdict::judge(false, false).text(), "does not hold");
        assert!(Verdict::judge(false, false).is_judged());
    }

    #[test]
    fn summary_json_records_the_same_words_as_the_printout() {
        for v in [
            Verdict::Holds,
            Verdict::DoesNotHold,
            Verdict::QuickRun,
            Verdict::PartialRun,
            Verdict::Undecided,
        ] {
            let json = serde_json::to_string(&v).unwrap();
            assert_eq!(json, format!("\"{}\"", v.text()));
        }
        let check = TargetCheck::new("a <= 2.5", "3.1", true, false);
        let json = serde_json::to_string(&check).unwrap();
        assert!(json.contains(QUICK_RUN_NOTE) && !json.contains("does not hold"));
    }
}
