//! What `tes experiment` prints when an experiment ends: each report's figures and tables in
//! a few lines, its verdicts on the paper's targets, and where its files went.

use std::fmt::{self, Write as _};
use std::path::Path;

use crate::experiment::Console;
use crate::fig4::Fig4Report;
use crate::grid::GridReport;
use crate::lifelong::LifelongReport;
use crate::robot::RobotReport;
use crate::transfer::TransferReport;

impl Console for GridReport {
    fn console(&self, out: &Path) -> Result<String, fmt::Error> {
        grid(self, out)
    }
}

impl Console for TransferReport {
    fn console(&self, out: &Path) -> Result<String, fmt::Error> {
        transfer(self, out)
    }
}

impl Console for RobotReport {
    fn console(&self, out: &Path) -> Result<String, fmt::Error> {
        robot(self, out)
    }
}

impl Console for Fig4Report {
    fn console(&self, out: &Path) -> Result<String, fmt::Error> {
        fig4(self, out)
    }
}

impl Console for LifelongReport {
    fn console(&self, out: &Path) -> Result<String, fmt::Error> {
        lifelong(self, out)
    }
}

/// What `tes experiment grid` prints of `report`, written to `out`: Fig. 3a–c's final
/// rewards, Table 1's times and the paper's targets.
pub fn grid(report: &GridReport, out: &Path) -> Result<String, fmt::Error> {
    let mut text = String::new();
    writeln!(
        text,
        "{}; {:.1} s wall clock",
        report.task, report.wall_seconds
    )?;
    for (title, finals) in [
        (
            "Fig. 3a  accumulated reward after the last episode, 10 features (95% CI)",
            &report.fig3a_final,
        ),
        (
            "Fig. 3b  accumulated reward after the last episode, 210 features (95% CI)",
            &report.fig3b_final,
        ),
    ] {
        writeln!(text, "{title}")?;
        for (name, s) in finals {
            writeln!(
                text,
                "  {name:<8} {:>9.2}  [{:.2}, {:.2}]",
                s.mean, s.lo, s.hi
            )?;
        }
    }
    writeln!(
        text,
        "Fig. 3c  accumulated reward after the last episode by irrelevant features"
    )?;
    for (name, by_level) in &report.fig3c {
        let cells: Vec<String> = by_level
            .iter()
            .map(|(level, s)| format!("{level}: {:.2}", s.mean))
            .collect();
        writeln!(text, "  {name:<8} {}", cells.join("  "))?;
    }
    writeln!(text, "Table 1  agent seconds per episode")?;
    for (name, t) in &report.table1 {
        writeln!(
            text,
            "  {name:<8} {:>9.4} s  ({} features)",
            t.seconds_per_episode.mean, t.features
        )?;
    }
    for line in crate::verdict::lines(&report.targets) {
        writeln!(text, "{line}")?;
    }
    writeln!(
        text,
        "wrote summary.json, episodes.csv, fig3a.svg, fig3b.svg, fig3c.svg to {}",
        out.display()
    )?;
    Ok(text)
}

/// What `tes experiment transfer` prints of `report`, written to `out`: Table 2's
/// jumpstarts, the paper's targets and the agents' times.
pub fn transfer(report: &TransferReport, out: &Path) -> Result<String, fmt::Error> {
    let mut text = String::new();
    let config = &report.config;
    writeln!(
        text,
        "{:.1} s wall clock. Table 2: reward of the first test episode (mean over {} runs)",
        report.wall_seconds, config.runs
    )?;
    let shown = ["TES", "LWT", "loreRL", "fEpsG"];
    writeln!(
        text,
        "  task  size    {}",
        shown.map(|m| format!("{m:>8}")).join("")
    )?;
    for t in &report.tasks {
        let cells: String = shown
            .iter()
            .map(|m| {
                t.jumpstart
                    .get(*m)
                    .map_or("       -".into(), |s| format!("{:>8.3}", s.mean))
            })
            .collect();
        writeln!(text, "  {:>4}  {:<6}{cells}", t.task, t.size)?;
    }
    let n = report.tasks.len();
    for line in crate::verdict::lines(&report.targets) {
        writeln!(text, "{line}")?;
    }
    writeln!(
        text,
        "TES's accumulated reward beats every random view combination on {}/{n} tasks",
        report.tes_beats_all_rands
    )?;
    writeln!(text, "agent seconds per test episode:")?;
    for (m, s) in &report.seconds_per_episode {
        writeln!(text, "  {m:<8} {:>9.4} s", s.mean)?;
    }
    writeln!(
        text,
        "wrote summary.json, episodes.csv, table2.svg, fig4b-task*.svg to {}",
        out.display()
    )?;
    Ok(text)
}

/// What `tes experiment robot` prints of `report`, written to `out`: the accumulated
/// rewards on Env 3 with their difference to TES and times, and the paper's targets.
pub fn robot(report: &RobotReport, out: &Path) -> Result<String, fmt::Error> {
    let mut text = String::new();
    writeln!(
        text,
        "{:.1} s wall clock. Accumulated reward on Env 3 after {} episodes (95% CI), difference to TES, seconds per episode:",
        report.wall_seconds, report.config.episodes
    )?;
    for (name, s) in &report.accumulated {
        let diff = report
            .difference_to_tes
            .get(name)
            .map_or("        ".to_owned(), |d| format!("{:>+8.2}", d.mean));
        let secs = report
            .seconds_per_episode
            .get(name)
            .map_or(f64::NAN, |t| t.mean);
        writeln!(
            text,
            "  {name:<10} {:>8.2} [{:.2}, {:.2}]  {diff}  {secs:.4} s",
            s.mean, s.lo, s.hi
        )?;
    }
    for line in crate::verdict::lines(&report.targets) {
        writeln!(text, "{line}")?;
    }
    writeln!(
        text,
        "wrote summary.json, episodes.csv, fig8.svg, fig9.svg to {}",
        out.display()
    )?;
    Ok(text)
}

/// What `tes experiment fig4` prints of `report`, written to `out`: each case's accumulated
/// rewards and the paper's targets.
pub fn fig4(report: &Fig4Report, out: &Path) -> Result<String, fmt::Error> {
    let mut text = String::new();
    let c = &report.config;
    writeln!(
        text,
        "{:.1} s wall clock. Accumulated reward (95% CI over {} runs):",
        report.wall_seconds, c.runs
    )?;
    let cases = report
        .same_dynamics
        .iter()
        .map(|case| {
            (
                format!(
                    "Fig. 4a, task {} after task {:?} (dynamics set {}), {} episodes",
                    case.test_task, case.trained_on, case.dynamics_set, c.test_episodes
                ),
                case,
            )
        })
        .chain(std::iter::once((
            format!(
                "Fig. 4c, task {}, {} episodes",
                report.convergence.test_task, c.convergence_episodes
            ),
            &report.convergence,
        )));
    for (title, case) in cases {
        writeln!(text, "  {title}:")?;
        for (name, s) in &case.accumulated {
            writeln!(
                text,
                "    {name:<8} {:>9.2} [{:.2}, {:.2}]",
                s.mean, s.lo, s.hi
            )?;
        }
    }
    for line in crate::verdict::lines(&report.targets) {
        writeln!(text, "{line}")?;
    }
    writeln!(
        text,
        "wrote summary.json, episodes.csv, fig4a-task*.svg, fig4c.svg to {}",
        out.display()
    )?;
    Ok(text)
}

/// What `tes experiment lifelong` prints of `report`, written to `out`: the accumulated reward
/// over the whole sequence per method, the libraries' final sizes, and our questions.
pub fn lifelong(report: &LifelongReport, out: &Path) -> Result<String, fmt::Error> {
    let mut text = String::new();
    let c = &report.config;
    writeln!(
        text,
        "{:.1} s wall clock. {} tasks ({} worlds, {} not logistic{}), {} episodes each; over the whole sequence (mean over {} runs):",
        report.wall_seconds,
        report.tasks(),
        c.worlds(),
        c.table_worlds,
        if c.same_worlds {
            "; the same for every run"
        } else {
            "; each run's own"
        },
        c.episodes,
        c.runs
    )?;
    for (name, tasks) in &report.per_task {
        let total: f64 = tasks.iter().map(|s| s.mean).sum();
        let secs = report
            .seconds_per_episode
            .get(name)
            .map_or(f64::NAN, |s| s.mean);
        writeln!(text, "  {name:<14} {total:>9.2}  {secs:.4} s / episode")?;
    }
    for (name, sizes) in &report.library_views {
        if let Some(last) = sizes.last() {
            writeln!(
                text,
                "  {name}'s library after the last task: {:.1} views",
                last.mean
            )?;
        }
    }
    for line in crate::verdict::lines(&report.targets) {
        writeln!(text, "{line}")?;
    }
    writeln!(
        text,
        "wrote summary.json, lifelong-reward.svg, lifelong-lead.svg, lifelong-library.svg to {}",
        out.display()
    )?;
    Ok(text)
}
