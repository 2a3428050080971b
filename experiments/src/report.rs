//! `report.md`: every table and figure of the whole study (`tes experiment all`) in one page.
//!
//! Written beside the three result folders it links to (`grid/`, `transfer/`, `robot/`),
//! from their reports alone, so a merged study gives the same page as an unsharded one
//! (timings aside).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;

use crate::episode::write_file;
use crate::grid::GridReport;
use crate::method::Method;
use crate::robot::RobotReport;
use crate::stats::Summary;
use crate::transfer::TransferReport;
use crate::verdict::TargetCheck;

fn ci(s: &Summary) -> String {
    format!("{:.2} [{:.2}, {:.2}]", s.mean, s.lo, s.hi)
}

fn ci3(s: &Summary) -> String {
    format!("{:.3} [{:.2}, {:.2}]", s.mean, s.lo, s.hi)
}

fn targets(md: &mut String, targets: &[TargetCheck]) {
    md.push_str("| target | measured | verdict |\n|---|---|---|\n");
    for t in targets {
        let _ = writeln!(
            md,
            "| {} | {} | {} |",
            t.target,
            t.measured,
            t.verdict.text()
        );
    }
    md.push('\n');
}

/// The page, as Markdown.
pub fn markdown(grid: &GridReport, transfer: &TransferReport, robot: &RobotReport) -> String {
    let mut md = String::from("# The study: every table and figure\n\n");
    let _ = writeln!(
        md,
        "Written by `tes experiment all`; the numbers with their seeds are in \
         `grid/summary.json`, `transfer/summary.json` and `robot/summary.json`. Brackets are \
         95 % intervals over runs (Student's t). Wall clock: grid {:.0} s, transfer {:.0} s, \
         robot {:.0} s.\n",
        grid.wall_seconds, transfer.wall_seconds, robot.wall_seconds
    );
    grid_section(&mut md, grid);
    transfer_section(&mut md, transfer);
    robot_section(&mut md, robot);
    md
}

/// §5.1: the grid's targets, Figs. 3a–c and Table 1.
fn grid_section(md: &mut String, grid: &GridReport) {
    let _ = writeln!(
        md,
        "## Grid (§5.1): Fig. 3 and Table 1\n\n{}, {} runs × {} episodes, seeds {}…, world seed {}.\n",
        grid.task, grid.config.runs, grid.config.episodes, grid.config.seed, grid.config.world_seed
    );
    targets(md, &grid.targets);
    for (title, file, finals) in [
        ("Fig. 3a — 10 features", "fig3a.svg", &grid.fig3a_final),
        ("Fig. 3b — 210 features", "fig3b.svg", &grid.fig3b_final),
    ] {
        let _ = writeln!(
            md,
            "### {title}\n\n![{title}](grid/{file})\n\n| algorithm | accumulated reward |\n|---|---|"
        );
        let mut rows: Vec<_> = finals.iter().collect();
        rows.sort_by(|a, b| b.1.mean.total_cmp(&a.1.mean));
        for (name, s) in rows {
            let _ = writeln!(md, "| {name} | {} |", ci(s));
        }
        md.push('\n');
    }
    grid_fig3c(md, grid);
    grid_table1(md, grid);
}

/// Fig. 3c's final rewards by irrelevant features.
fn grid_fig3c(md: &mut String, grid: &GridReport) {
    md.push_str(
        "### Fig. 3c — accumulated reward by irrelevant features\n\n![Fig. 3c](grid/fig3c.svg)\n\n",
    );
    let levels = &grid.config.irrelevant_levels;
    let _ = writeln!(
        md,
        "| algorithm | {} |\n|---|{}",
        levels
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join(" | "),
        "---|".repeat(levels.len())
    );
    for (name, by_level) in &grid.fig3c {
        let cells: Vec<String> = levels
            .iter()
            .map(|l| {
                by_level
                    .get(l)
                    .map_or("-".into(), |s| format!("{:.1}", s.mean))
            })
            .collect();
        let _ = writeln!(md, "| {name} | {} |", cells.join(" | "));
    }
}

/// Table 1, fastest first, and the time ratios the paper gives.
fn grid_table1(md: &mut String, grid: &GridReport) {
    md.push_str("\n### Table 1 — agent seconds per episode\n\n| algorithm | features | s / episode |\n|---|---|---|\n");
    let mut rows: Vec<_> = grid.table1.iter().collect();
    rows.sort_by(|a, b| {
        a.1.seconds_per_episode
            .mean
            .total_cmp(&b.1.seconds_per_episode.mean)
    });
    for (name, t) in rows {
        let _ = writeln!(
            md,
            "| {name} | {} | {:.5} |",
            t.features, t.seconds_per_episode.mean
        );
    }
    let _ = writeln!(
        md,
        "\nloreRL / fEpsG = {:.2}; RL-DT / loreRL = {:.1}.\n",
        grid.lore_over_fepsg_time, grid.rldt_over_lore_time
    );
}

/// §5.1.2–5.1.3: transfer's targets, Table 2 and Fig. 4b.
fn transfer_section(md: &mut String, transfer: &TransferReport) {
    let c = &transfer.config;
    let _ = writeln!(
        md,
        "## Transfer (§5.1.2–5.1.3): Table 2 and Fig. 4b\n\nLeave-one-out over tasks {:?}, {} runs each, training on {} tasks × {} episodes, {} test episodes, seed {}, world seed {}.\n",
        c.test_tasks,
        c.runs,
        c.training_tasks,
        c.train_episodes,
        c.test_episodes,
        c.seed,
        c.world_seed
    );
    targets(md, &transfer.targets);
    let _ = writeln!(
        md,
        "TES's accumulated reward beats every random view combination on {} / {} tasks.\n",
        transfer.tes_beats_all_rands,
        transfer.tasks.len()
    );
    md.push_str("### Table 2 — reward of the first test episode (jumpstart)\n\n![Table 2](transfer/table2.svg)\n\n");
    md.push_str("| task (size) | TES | LWT | loreRL | fEpsG | loreRL − TES over all test episodes | LWT − TES |\n|---|---|---|---|---|---|---|\n");
    for t in &transfer.tasks {
        let j = |m: Method| t.jumpstart.get(&*m.name()).map_or("-".into(), ci3);
        let d = |m: Method| t.difference_to_tes.get(&*m.name()).map_or("-".into(), ci);
        let _ = writeln!(
            md,
            "| {} ({}) | {} | {} | {} | {} | {} | {} |",
            t.task,
            t.size,
            j(Method::Tes),
            j(Method::Lwt),
            j(Method::LoreRl),
            j(Method::FEpsG),
            d(Method::LoreRl),
            d(Method::Lwt)
        );
    }
    md.push_str("\n### Fig. 4b — accumulated reward minus TES's, per test task\n\n");
    for t in &transfer.tasks {
        let _ = writeln!(
            md,
            "![Fig. 4b, task {0}](transfer/fig4b-task{0}.svg)",
            t.task
        );
    }
    md.push_str("\n### Agent seconds per test episode\n\n| method | s / episode |\n|---|---|\n");
    for (m, s) in &transfer.seconds_per_episode {
        let _ = writeln!(md, "| {m} | {:.4} |", s.mean);
    }
}

/// §5.2: the robot study's targets, Figs. 8–9 and Tables 5–6.
fn robot_section(md: &mut String, robot: &RobotReport) {
    let c = &robot.config;
    let _ = writeln!(
        md,
        "\n## Robot arenas (§5.2): Figs. 8–9, Tables 5–6\n\n{} runs, {} episodes on Env 3 after {} per earlier arena, seeds {}….\n",
        c.runs, c.episodes, c.train_episodes, c.seed
    );
    targets(md, &robot.targets);
    md.push_str("![Fig. 8](robot/fig8.svg)\n\n![Fig. 9](robot/fig9.svg)\n\n");
    md.push_str("| method | accumulated reward | difference to TES | agent s / episode (Table 6) |\n|---|---|---|---|\n");
    for (name, s) in &robot.accumulated {
        let d = robot.difference_to_tes.get(name).map_or("—".into(), ci);
        let secs = robot
            .seconds_per_episode
            .get(name)
            .map_or(f64::NAN, |t| t.mean);
        let _ = writeln!(md, "| {name} | {} | {d} | {secs:.4} |", ci(s));
    }
    md.push_str("\n### Table 5 — reward of the first Env 3 episode, first 10 repeats\n\n");
    let shown = robot
        .first_episode
        .values()
        .map(Vec::len)
        .max()
        .unwrap_or(0)
        .min(10);
    let _ = writeln!(
        md,
        "| repeat | {} |\n|---|{}",
        (1..=shown)
            .map(|r| r.to_string())
            .collect::<Vec<_>>()
            .join(" | "),
        "---|".repeat(shown)
    );
    for m in [Method::LoreRl, Method::Lwt, Method::TesWoRi, Method::Tes] {
        if let Some(firsts) = robot.first_episode.get(&*m.name()) {
            let cells: Vec<String> = firsts
                .iter()
                .take(shown)
                .map(|r| format!("{r:.2}"))
                .collect();
            let _ = writeln!(md, "| {m} | {} |", cells.join(" | "));
        }
    }
}

/// Writes [`markdown`] to `path`.
pub fn write(
    path: &Path,
    grid: &GridReport,
    transfer: &TransferReport,
    robot: &RobotReport,
) -> Result<()> {
    write_file(path, &markdown(grid, transfer, robot))
}
