//! The paper's targets, the test that judges each, and the verdict: `holds`, `fails` or
//! `undecided` — or a note that the run is too small or too partial to judge.
//!
//! A claim about rewards is judged by a paired test over runs, never by means alone:
//!
//! * per task, a paired t-test of each run's difference, with Holm's correction over the
//!   tasks of the family ([`TaskDecisions`]); a count target ("ahead on at least 12 of 15")
//!   holds when the tasks decided ahead reach it, fails when even every undecided task could
//!   not, and is undecided in between;
//! * across tasks, one pooled Wilcoxon signed-rank test over the per-task mean differences;
//! * on one environment, a paired t-test (or, for wins and losses of first episodes, the
//!   sign test), with Holm's correction over the comparisons of one claim.
//!
//! A `--quick` run is a first look: a smaller task, a few runs, short training. Its figures
//! cannot confirm or refute the paper's claims, so it reports [`Verdict::QuickRun`] in place of
//! a verdict, in the printed output and in `summary.json` alike.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::stats::{self, ALPHA, SignedRank, Summary};

/// What a quick run says in place of a verdict.
pub const QUICK_RUN_NOTE: &str =
    "quick run: too small to judge the paper's targets; run without --quick";

/// What a run that left out some of the paper's cases says in place of a verdict.
pub const PARTIAL_RUN_NOTE: &str =
    "partial run: the target counts every test task; run them all to judge it";

/// What a run that left out a method a target compares says in place of a verdict.
pub const NOT_RUN_NOTE: &str = "not run: the run left out a method this target compares";

/// Whether a run meets one of the paper's targets. Serialised as its [`text`](Self::text).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Verdict {
    /// The test decides for the target.
    #[serde(rename = "holds")]
    Holds,
    /// The test decides against the target.
    #[serde(rename = "fails")]
    Fails,
    /// The test decides neither way: more runs would.
    #[serde(rename = "undecided")]
    Undecided,
    /// A `--quick` run: too small to judge.
    #[serde(rename = "quick run: too small to judge the paper's targets; run without --quick")]
    QuickRun,
    /// A full-size run over only some of the cases the target counts.
    #[serde(rename = "partial run: the target counts every test task; run them all to judge it")]
    PartialRun,
    /// A run without one of the methods the target compares (`--methods`).
    #[serde(rename = "not run: the run left out a method this target compares")]
    NotRun,
}

impl Verdict {
    /// The verdict on a target that `holds` (or fails) in a run that was `quick` or not.
    pub fn judge(quick: bool, holds: bool) -> Self {
        Self::Holds.or_fails(holds).unless_quick(quick)
    }

    /// The verdict of a test that came out on `side` of a target that wants
    /// [`Side::Ahead`].
    pub fn of_side(side: Side) -> Self {
        match side {
            Side::Ahead => Self::Holds,
            Side::Behind => Self::Fails,
            Side::Undecided => Self::Undecided,
        }
    }

    /// The verdict on "ahead on at least `needed` cases" with `ahead` cases decided ahead and
    /// `undecided` cases decided neither way.
    pub fn of_count(ahead: usize, undecided: usize, needed: usize) -> Self {
        if ahead >= needed {
            Self::Holds
        } else if ahead + undecided >= needed {
            Self::Undecided
        } else {
            Self::Fails
        }
    }

    /// This verdict, or `QuickRun` for a quick run.
    pub fn unless_quick(self, quick: bool) -> Self {
        if quick { Self::QuickRun } else { self }
    }

    /// The verdict on "at most `bound`" by the 95 % interval `s`: holds when it lies at or
    /// below the bound, fails when it lies above it.
    pub fn at_most(s: &Summary, bound: f64) -> Self {
        if s.hi <= bound {
            Self::Holds
        } else if s.lo > bound {
            Self::Fails
        } else {
            Self::Undecided
        }
    }

    /// The verdict on "at least `bound`" by the 95 % interval `s`.
    pub fn at_least(s: &Summary, bound: f64) -> Self {
        if s.lo >= bound {
            Self::Holds
        } else if s.hi < bound {
            Self::Fails
        } else {
            Self::Undecided
        }
    }

    /// Holds if every verdict of `all` holds, fails if any fails, else undecided.
    pub fn all(all: impl IntoIterator<Item = Self>) -> Self {
        let all: Vec<Self> = all.into_iter().collect();
        if all.iter().all(|v| *v == Self::Holds) {
            Self::Holds
        } else if all.contains(&Self::Fails) {
            Self::Fails
        } else {
            Self::Undecided
        }
    }

    fn or_fails(self, holds: bool) -> Self {
        if holds { self } else { Self::Fails }
    }

    /// The verdict in words, as printed and as `summary.json` records it.
    pub fn text(self) -> &'static str {
        match self {
            Verdict::Holds => "holds",
            Verdict::Fails => "fails",
            Verdict::Undecided => "undecided",
            Verdict::QuickRun => QUICK_RUN_NOTE,
            Verdict::PartialRun => PARTIAL_RUN_NOTE,
            Verdict::NotRun => NOT_RUN_NOTE,
        }
    }

    /// Whether this is a judgement (holds, fails, undecided) rather than a note that none can
    /// be made.
    pub fn is_judged(self) -> bool {
        matches!(self, Verdict::Holds | Verdict::Fails | Verdict::Undecided)
    }
}

/// One of the paper's targets, the test that judges it, what a run measured, and the verdict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TargetCheck {
    /// The target, in words (e.g. "loreRL / fEpsG time per episode <= 2.5 (paper: 2.2)").
    pub target: String,
    /// The test that judges it, in words.
    #[serde(default)]
    pub test: String,
    /// What this run measured, in words and numbers.
    pub measured: String,
    /// Holds, fails, undecided, or why it cannot be judged.
    pub verdict: Verdict,
}

impl TargetCheck {
    /// A check of `target` by `test` against `measured`, with `verdict` (a quick run's
    /// replaced by [`Verdict::QuickRun`]).
    pub fn new(
        target: impl Into<String>,
        test: impl Into<String>,
        measured: impl Into<String>,
        quick: bool,
        verdict: Verdict,
    ) -> Self {
        Self {
            target: target.into(),
            test: test.into(),
            measured: measured.into(),
            verdict: verdict.unless_quick(quick),
        }
    }
}

/// The lines that print a run's targets: each target with what was measured and its verdict —
/// or, for a quick run, the measurements under one note that they are too small to judge.
pub fn lines(targets: &[TargetCheck]) -> Vec<String> {
    let quick = targets.iter().any(|t| t.verdict == Verdict::QuickRun);
    let mut lines = vec![if quick {
        format!("targets ({QUICK_RUN_NOTE}):")
    } else {
        "targets:".to_owned()
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

/// Which way a comparison "A beats B" came out, at 5 % (family-wise where corrected).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// A decided ahead.
    Ahead,
    /// A decided behind.
    Behind,
    /// Not decided either way.
    Undecided,
}

impl Side {
    /// The side of a difference `A − B` with mean `mean` whose test rejected "no difference"
    /// (`decided`) or not.
    pub fn of(mean: f64, decided: bool) -> Self {
        match (decided, mean > 0.0) {
            (false, _) => Self::Undecided,
            (true, true) => Self::Ahead,
            (true, false) => Self::Behind,
        }
    }
}

/// A paired comparison `A − B` over runs: its mean and 95 % interval, the paired t-test's
/// p-value, the p-value after Holm's correction over its family, and the side decided.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Paired {
    /// Mean difference and its (uncorrected) 95 % interval.
    pub difference: Summary,
    /// Two-sided paired t-test.
    #[serde(deserialize_with = "crate::stats::f64_or_nan")]
    pub p: f64,
    /// `p` after Holm's correction over the family (`p` itself for a family of one).
    #[serde(deserialize_with = "crate::stats::f64_or_nan")]
    pub p_holm: f64,
    /// Which side the corrected test decides.
    pub side: Side,
}

/// Paired comparisons of one family (each a list of per-run differences `A − B`), decided
/// with Holm's correction over the family.
pub fn paired_family(differences: &[Vec<f64>]) -> Vec<Paired> {
    let p: Vec<f64> = differences.iter().map(|d| stats::paired_t(d)).collect();
    let adjusted = stats::holm(&p);
    differences
        .iter()
        .zip(p.iter().zip(adjusted))
        .map(|(d, (&p, p_holm))| {
            let difference = stats::summarise(d);
            Paired {
                difference,
                p,
                p_holm,
                side: Side::of(difference.mean, p_holm < ALPHA),
            }
        })
        .collect()
}

/// One paired comparison, a family of its own.
pub fn paired(differences: &[f64]) -> Paired {
    paired_family(&[differences.to_vec()])[0]
}

/// A claim over tasks "A beats B on each task": every task's paired comparison, Holm over
/// the tasks, the tasks sorted by side, and the pooled signed-rank test over the per-task
/// mean differences.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskDecisions {
    /// Per task (suite index), its comparison.
    pub tasks: BTreeMap<usize, Paired>,
    /// Tasks decided ahead (A beats B).
    pub ahead: Vec<usize>,
    /// Tasks decided behind.
    pub behind: Vec<usize>,
    /// Tasks decided neither way.
    pub undecided: Vec<usize>,
    /// Wilcoxon's signed-rank test over the tasks' mean differences.
    pub pooled: SignedRank,
    /// The side the pooled test decides (two-sided, 5 %).
    pub pooled_side: Side,
    /// Tasks whose mean difference is above 0 (as the paper counts).
    pub ahead_on_means: usize,
}

impl TaskDecisions {
    /// Decides each task of `per_task` (task → per-run differences `A − B`).
    pub fn new(per_task: &BTreeMap<usize, Vec<f64>>) -> Self {
        let lists: Vec<Vec<f64>> = per_task.values().cloned().collect();
        let tasks: BTreeMap<usize, Paired> = per_task
            .keys()
            .copied()
            .zip(paired_family(&lists))
            .collect();
        let with = |side| {
            tasks
                .iter()
                .filter(|(_, p)| p.side == side)
                .map(|(&t, _)| t)
                .collect()
        };
        let means: Vec<f64> = tasks.values().map(|p| p.difference.mean).collect();
        let pooled = stats::signed_rank(&means);
        Self {
            ahead: with(Side::Ahead),
            behind: with(Side::Behind),
            undecided: with(Side::Undecided),
            pooled_side: Side::of(pooled.w_plus - pooled.w_minus, pooled.p < ALPHA),
            ahead_on_means: means.iter().filter(|&&m| m > 0.0).count(),
            pooled,
            tasks,
        }
    }

    /// The count target "ahead on at least `needed` tasks".
    pub fn count_verdict(&self, needed: usize) -> Verdict {
        Verdict::of_count(self.ahead.len(), self.undecided.len(), needed)
    }

    /// In words, e.g. "10 ahead, 1 behind (task 0), 4 undecided (tasks 3, 6, 10, 12)".
    pub fn describe(&self) -> String {
        format!(
            "{} ahead, {} behind{}, {} undecided{}",
            self.ahead.len(),
            self.behind.len(),
            named(&self.behind),
            self.undecided.len(),
            named(&self.undecided)
        )
    }

    /// The pooled test in words, e.g. "W+ 110, W- 10 over 15 tasks, p = 0.0012".
    pub fn describe_pooled(&self) -> String {
        format!(
            "W+ {}, W- {} over {} tasks, p {}",
            self.pooled.w_plus,
            self.pooled.w_minus,
            self.pooled.n,
            p_value(self.pooled.p)
        )
    }
}

/// A paired difference for a reader: "+51.1 [+45.0, +57.2] (p = 0.0001)"; with Holm's
/// p-value where it differs.
pub fn difference(p: &Paired) -> String {
    let holm = if p.p_holm != p.p {
        format!(", Holm p {}", p_value(p.p_holm))
    } else {
        String::new()
    };
    format!("{} (p {}{holm})", interval(&p.difference), p_value(p.p))
}

/// A mean with its interval, signed, all three to the precision the mean's size needs:
/// "+2.86 [-0.82, +6.54]".
pub fn interval(d: &Summary) -> String {
    let m = d.mean.abs();
    let digits = if m >= 10.0 {
        1
    } else if m >= 0.1 {
        2
    } else {
        3
    };
    format!(
        "{:+.digits$} [{:+.digits$}, {:+.digits$}]",
        d.mean, d.lo, d.hi
    )
}

/// A ratio's mean and interval for a reader: "1.48 [1.45, 1.51]".
pub fn ratio(s: &Summary) -> String {
    format!("{:.2} [{:.2}, {:.2}]", s.mean, s.lo, s.hi)
}

/// A p-value for a reader, after "p": `= 0.0151`, or `< 0.0001` below that.
pub fn p_value(p: f64) -> String {
    if p < 1e-4 {
        "< 0.0001".to_owned()
    } else {
        format!("= {p:.4}")
    }
}

/// " (task 0)", " (tasks 3, 6)" or nothing.
fn named(tasks: &[usize]) -> String {
    match tasks {
        [] => String::new(),
        [t] => format!(" (task {t})"),
        _ => format!(
            " (tasks {})",
            tasks
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// The test a per-task count target is judged by, in words.
pub const PER_TASK_TEST: &str =
    "per task a paired t-test over runs, Holm's correction over the tasks, family-wise 5 %";

/// The test a target on times is judged by, in words: such a target's figure and verdict
/// depend on the machine.
pub const TIME_RATIO_TEST: &str = "the per-run time ratio's 95 % interval against the bound";

/// The test a pooled target is judged by, in words.
pub const POOLED_TEST: &str =
    "Wilcoxon signed-rank test over the tasks' mean paired differences, two-sided 5 %";

#[cfg(test)]
mod tests {
    use super::*;

    fn checks(quick: bool) -> Vec<TargetCheck> {
        vec![
            TargetCheck::new("a <= 2.5", "ratio", "3.10", quick, Verdict::Fails),
            TargetCheck::new("b >= 10", "ratio", "16.0", quick, Verdict::Holds),
        ]
    }

    #[test]
    fn a_quick_run_prints_its_numbers_but_no_verdict() {
        let lines = lines(&checks(true));
        let text = lines.join("\n");
        assert!(lines[0].contains(QUICK_RUN_NOTE), "{text}");
        assert!(!text.contains("hold") && !text.contains("fails"), "{text}");
        assert!(text.contains("a <= 2.5: 3.10") && text.contains("b >= 10: 16.0"));
    }

    #[test]
    fn a_full_run_prints_a_verdict_per_target() {
        let lines = lines(&checks(false));
        assert_eq!(lines[0], "targets:");
        assert_eq!(lines[1], "  a <= 2.5: 3.10 — fails");
        assert_eq!(lines[2], "  b >= 10: 16.0 — holds");
    }

    #[test]
    fn a_quick_run_never_gives_a_verdict() {
        for holds in [true, false] {
            let v = Verdict::judge(true, holds);
            assert_eq!(v, Verdict::QuickRun);
            assert!(!v.is_judged());
        }
        assert_eq!(Verdict::judge(false, true).text(), "holds");
        assert_eq!(Verdict::judge(false, false).text(), "fails");
    }

    #[test]
    fn summary_json_records_the_same_words_as_the_printout() {
        for v in [
            Verdict::Holds,
            Verdict::Fails,
            Verdict::Undecided,
            Verdict::QuickRun,
            Verdict::PartialRun,
            Verdict::NotRun,
        ] {
            let json = serde_json::to_string(&v).unwrap();
            assert_eq!(json, format!("\"{}\"", v.text()));
            assert_eq!(serde_json::from_str::<Verdict>(&json).unwrap(), v);
        }
    }

    #[test]
    fn counts_hold_fail_or_stay_undecided() {
        assert_eq!(Verdict::of_count(12, 0, 12), Verdict::Holds);
        assert_eq!(Verdict::of_count(10, 4, 12), Verdict::Undecided);
        assert_eq!(Verdict::of_count(8, 1, 10), Verdict::Fails);
        assert_eq!(Verdict::of_side(Side::Behind), Verdict::Fails);
    }

    #[test]
    fn tasks_are_decided_with_holms_correction() {
        // Task 1 clearly ahead, task 2 clearly behind, task 3 a coin flip, task 4 ahead
        // at p ≈ 0.03 alone — which Holm's correction over four tasks does not decide.
        let runs = |shift: f64, spread: f64| -> Vec<f64> {
            (0..20)
                .map(|i| {
                    shift
                        + spread * if i % 2 == 0 { 1.0 } else { -1.0 } * (1.0 + f64::from(i) / 20.0)
                })
                .collect()
        };
        let per_task: BTreeMap<usize, Vec<f64>> = [
            (1, runs(1.0, 0.5)),
            (2, runs(-1.0, 0.5)),
            (3, runs(0.0, 1.0)),
            (4, runs(0.55, 0.7)),
        ]
        .into();
        let alone = stats::paired_t(&per_task[&4]);
        assert!(alone < ALPHA && alone * 2.0 >= ALPHA, "{alone}");
        let d = TaskDecisions::new(&per_task);
        assert_eq!(d.ahead, [1]);
        assert_eq!(d.behind, [2]);
        assert_eq!(d.undecided, [3, 4]);
        assert_eq!(d.ahead_on_means, 2);
        assert_eq!(
            d.describe(),
            "1 ahead, 1 behind (task 2), 2 undecided (tasks 3, 4)"
        );
        assert_eq!(d.count_verdict(1), Verdict::Holds);
        assert_eq!(d.count_verdict(3), Verdict::Undecided);
        assert_eq!(d.count_verdict(4), Verdict::Fails);
        // Three of four mean differences above 0 do not decide the pooled test.
        assert_eq!(d.pooled_side, Side::Undecided);
    }
}
