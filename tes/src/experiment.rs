//! `tes experiment`: rerun the paper's experiments and write tables and plots.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tes_experiments::grid::{self, GridConfig};
use tes_experiments::robot::{self, RobotConfig};
use tes_experiments::transfer::{self, TransferConfig};
use tes_experiments::verdict::{QUICK_RUN_NOTE, TargetCheck, Verdict};
use tes_learning::agents::ExampleStore;

/// Arguments of `tes experiment`.
#[derive(Debug, Args)]
pub struct ExperimentArgs {
    #[command(subcommand)]
    which: Which,
}

#[derive(Debug, Subcommand)]
enum Which {
    /// §5.1 grid tasks: Fig. 3a–c and Table 1 (loreRL against its baselines).
    Grid(GridArgs),
    /// §5.1.2–5.1.3 transfer: leave-one-out over the 15 grid tasks, Table 2 and Fig. 4b
    /// (TES against LWT, random view combinations, loreRL and fEpsG).
    Transfer(TransferArgs),
    /// §5.2 robot study on the simulated arenas: Fig. 8, Fig. 9, Tables 5 and 6 (in-process).
    Robot(RobotArgs),
    /// Redraw the figures a result folder's summary.json holds the data of (grid: fig3c.svg;
    /// transfer: table2.svg), without rerunning anything.
    Replot(ReplotArgs),
}

#[derive(Debug, Args)]
struct ReplotArgs {
    /// A folder an experiment wrote (it holds summary.json).
    dir: PathBuf,
}

#[derive(Debug, Args)]
struct RobotArgs {
    /// Independent repeats [default: 20; --quick: 3].
    #[arg(long)]
    runs: Option<usize>,
    /// Episodes on Env 3 [default: 50; --quick: 15].
    #[arg(long)]
    episodes: Option<usize>,
    /// Episodes in each arena experienced before Env 3 [default: 50; --quick: 15].
    #[arg(long)]
    train_episodes: Option<usize>,
    /// Directory for summary.json, episodes.csv and the SVG plots.
    #[arg(long, default_value = "results/robot")]
    out: PathBuf,
    /// Small settings for a first look: seconds.
    #[arg(long)]
    quick: bool,
    /// Base seed; run r uses seed + r.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(Debug, Args)]
struct TransferArgs {
    /// Independent runs per test task [default: 20; --quick: 2].
    #[arg(long)]
    runs: Option<usize>,
    /// Directory for summary.json, episodes.csv and the SVG plots.
    #[arg(long, default_value = "results/transfer")]
    out: PathBuf,
    /// Small settings for a first look (and CI): finishes in under two minutes on two cores.
    #[arg(long)]
    quick: bool,
    /// Held-out test tasks, comma-separated suite indices [default: all 15; --quick: 1,2,10].
    #[arg(long, value_delimiter = ',')]
    tasks: Option<Vec<usize>>,
    /// Episodes on each training task [default: 100; --quick: 25].
    #[arg(long)]
    train_episodes: Option<usize>,
    /// Episodes on the test task [default: 50; --quick: 12].
    #[arg(long)]
    test_episodes: Option<usize>,
    /// Base seed; the job of (task t, run r) uses seed + 1000 r + t.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Seed of the grid suite (layouts, dynamics, irrelevant features).
    #[arg(long, default_value_t = 2017)]
    world_seed: u64,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(Debug, Args)]
struct GridArgs {
    /// Independent runs per algorithm and feature count [default: 20; --quick: 3].
    #[arg(long)]
    runs: Option<usize>,
    /// Episodes per run [default: 800; --quick: 60].
    #[arg(long)]
    episodes: Option<usize>,
    /// Directory for summary.json, episodes.csv and the SVG plots.
    #[arg(long, default_value = "results/grid")]
    out: PathBuf,
    /// Small settings for a first look (and CI): finishes in about two minutes on two cores.
    #[arg(long)]
    quick: bool,
    /// First agent seed; run r uses seed + r.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Seed of the grid suite (layouts, dynamics, irrelevant features).
    #[arg(long, default_value_t = 2017)]
    world_seed: u64,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    /// Plan every re-plan to the tolerance, instead of stopping it once no value moves by
    /// more than the model change that triggered it (see `tes_learning::plan`).
    #[arg(long)]
    converge_plans: bool,
    /// RL-DT keeps per-state effect counts instead of the list of all examples: the same
    /// trees and rewards, induced in time bounded by the states rather than the steps (our
    /// shortcut; the default list is Hester & Stone's and what Table 1 compares against).
    #[arg(long)]
    rl_dt_per_state_counts: bool,
}

/// Runs `tes experiment`.
pub fn run(args: &ExperimentArgs) -> Result<()> {
    match &args.which {
        Which::Grid(g) => run_grid(g),
        Which::Transfer(t) => run_transfer(t),
        Which::Robot(r) => run_robot(r),
        Which::Replot(r) => run_replot(r),
    }
}

fn run_replot(args: &ReplotArgs) -> Result<()> {
    let done = tes_experiments::replot::replot(&args.dir)?;
    for file in &done.written {
        println!("redrew {}", file.display());
    }
    if !done.not_redrawn.is_empty() {
        println!(
            "{} not redrawn: drawn from every episode, which summary.json does not keep (rerun `tes experiment {}`)",
            done.not_redrawn.join(", "),
            done.experiment
        );
    }
    Ok(())
}

/// The lines printing a run's targets: each target with what was measured and its verdict —
/// or, for a quick run, the measurements under one note that they are too small to judge.
fn target_lines(targets: &[TargetCheck]) -> Vec<String> {
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

fn print_targets(targets: &[TargetCheck]) {
    for line in target_lines(targets) {
        println!("{line}");
    }
}

fn set_threads(threads: Option<usize>) -> Result<()> {
    if let Some(threads) = threads {
        if threads == 0 {
            bail!("--threads must be at least 1");
        }
        // Only the first call in a process can size the global pool; a failure means it was
        // already built, which is harmless.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global();
    }
    Ok(())
}

fn run_transfer(args: &TransferArgs) -> Result<()> {
    let mut config = if args.quick {
        TransferConfig::quick()
    } else {
        TransferConfig::paper()
    };
    if let Some(runs) = args.runs {
        config.runs = runs;
    }
    if let Some(tasks) = &args.tasks {
        config.test_tasks.clone_from(tasks);
    }
    if let Some(n) = args.train_episodes {
        config.train_episodes = n;
    }
    if let Some(n) = args.test_episodes {
        config.test_episodes = n;
    }
    config.seed = args.seed;
    config.world_seed = args.world_seed;
    set_threads(args.threads)?;
    eprintln!(
        "transfer experiment: test tasks {:?}, {} runs, training on {} tasks x {} episodes, {} test episodes, seed {}, world seed {} -> {}",
        config.test_tasks,
        config.runs,
        config.training_tasks,
        config.train_episodes,
        config.test_episodes,
        config.seed,
        config.world_seed,
        args.out.display()
    );
    let bar = progress_bar("transfer");
    let report = transfer::run(&config, &args.out, &|done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();

    println!(
        "{:.1} s wall clock. Table 2: reward of the first test episode (mean over {} runs)",
        report.wall_seconds, config.runs
    );
    let shown = ["TES", "LWT", "loreRL", "fEpsG"];
    println!(
        "  task  size    {}",
        shown.map(|m| format!("{m:>8}")).join("")
    );
    for t in &report.tasks {
        let cells: String = shown
            .iter()
            .map(|m| {
                t.jumpstart
                    .get(*m)
                    .map_or("       -".into(), |s| format!("{:>8.3}", s.mean))
            })
            .collect();
        println!("  {:>4}  {:<6}{cells}", t.task, t.size);
    }
    let n = report.tasks.len();
    print_targets(&report.targets);
    println!(
        "TES's accumulated reward beats every random view combination on {}/{n} tasks",
        report.tes_beats_all_rands
    );
    println!("agent seconds per test episode:");
    for (m, s) in &report.seconds_per_episode {
        println!("  {m:<8} {:>9.4} s", s.mean);
    }
    println!(
        "wrote summary.json, episodes.csv, table2.svg, fig4b-task*.svg to {}",
        args.out.display()
    );
    Ok(())
}

fn progress_bar(total_hint: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(1), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template(
        "{msg} [{bar:40}] {pos}/{len} episodes ({elapsed}, {eta} left)",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(total_hint.to_owned());
    bar
}

fn run_grid(args: &GridArgs) -> Result<()> {
    let mut config = if args.quick {
        GridConfig::quick()
    } else {
        GridConfig::paper(20, 800)
    };
    if let Some(runs) = args.runs {
        config.runs = runs;
    }
    if let Some(episodes) = args.episodes {
        config.episodes = episodes;
    }
    if config.runs == 0 || config.episodes == 0 {
        bail!("--runs and --episodes must be at least 1");
    }
    config.seed = args.seed;
    config.world_seed = args.world_seed;
    config.stop_at_drift = !args.converge_plans;
    if args.rl_dt_per_state_counts {
        config.rl_dt_examples = ExampleStore::PerStateCounts;
    }
    set_threads(args.threads)?;
    eprintln!(
        "grid experiment: {} runs x {} episodes, irrelevant features {:?}, seeds {}.., world seed {} -> {}",
        config.runs,
        config.episodes,
        config.irrelevant_levels,
        config.seed,
        config.world_seed,
        args.out.display()
    );
    let bar = progress_bar("grid");
    let report = grid::run(&config, &args.out, &|done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();

    println!("{}; {:.1} s wall clock", report.task, report.wall_seconds);
    let show = |title: &str, finals: &std::collections::BTreeMap<String, grid::Summary>| {
        println!("{title}");
        for (name, s) in finals {
            println!("  {name:<8} {:>9.2}  [{:.2}, {:.2}]", s.mean, s.lo, s.hi);
        }
    };
    show(
        "Fig. 3a  accumulated reward after the last episode, 10 features (95% CI)",
        &report.fig3a_final,
    );
    show(
        "Fig. 3b  accumulated reward after the last episode, 210 features (95% CI)",
        &report.fig3b_final,
    );
    println!("Fig. 3c  accumulated reward after the last episode by irrelevant features");
    for (name, by_level) in &report.fig3c {
        let cells: Vec<String> = by_level
            .iter()
            .map(|(level, s)| format!("{level}: {:.2}", s.mean))
            .collect();
        println!("  {name:<8} {}", cells.join("  "));
    }
    println!("Table 1  agent seconds per episode");
    for (name, t) in &report.table1 {
        println!(
            "  {name:<8} {:>9.4} s  ({} features)",
            t.seconds_per_episode.mean, t.features
        );
    }
    print_targets(&report.targets);
    println!(
        "wrote summary.json, episodes.csv, fig3a.svg, fig3b.svg, fig3c.svg to {}",
        args.out.display()
    );
    Ok(())
}

fn run_robot(args: &RobotArgs) -> Result<()> {
    let mut config = if args.quick {
        RobotConfig::quick()
    } else {
        RobotConfig::paper()
    };
    if let Some(n) = args.runs {
        config.runs = n;
    }
    if let Some(n) = args.episodes {
        config.episodes = n;
    }
    if let Some(n) = args.train_episodes {
        config.train_episodes = n;
    }
    config.seed = args.seed;
    set_threads(args.threads)?;
    eprintln!(
        "robot experiment: {} runs, {} episodes on Env 3 after {} per earlier arena, seeds {}.. -> {}",
        config.runs,
        config.episodes,
        config.train_episodes,
        config.seed,
        args.out.display()
    );
    let bar = progress_bar("robot");
    let report = robot::run(&config, &args.out, &|done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();
    println!(
        "{:.1} s wall clock. Accumulated reward on Env 3 after {} episodes (95% CI), difference to TES, seconds per episode:",
        report.wall_seconds, config.episodes
    );
    for (name, s) in &report.accumulated {
        let diff = report
            .difference_to_tes
            .get(name)
            .map_or("        ".to_owned(), |d| format!("{:>+8.2}", d.mean));
        let secs = report
            .seconds_per_episode
            .get(name)
            .map_or(f64::NAN, |t| t.mean);
        println!(
            "  {name:<10} {:>8.2} [{:.2}, {:.2}]  {diff}  {secs:.4} s",
            s.mean, s.lo, s.hi
        );
    }
    print_targets(&report.targets);
    println!(
        "wrote summary.json, episodes.csv, fig8.svg, fig9.svg to {}",
        args.out.display()
    );
    Ok(())
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
        let lines = target_lines(&checks(true));
        let text = lines.join("\n");
        assert!(lines[0].contains(QUICK_RUN_NOTE), "{text}");
        assert!(!text.contains("hold"), "{text}");
        assert!(text.contains("a <= 2.5: 3.10") && text.contains("b >= 10: 16.0"));
    }

    #[test]
    fn a_full_run_prints_a_verdict_per_target() {
        let lines = target_lines(&checks(false));
        assert_eq!(lines[0], "the paper's targets:");
        assert_eq!(lines[1], "  a <= 2.5: 3.10 — does not hold");
        assert_eq!(lines[2], "  b >= 10: 16.0 — holds");
    }

    #[test]
    fn replot_takes_a_result_folder() {
        use clap::Parser;
        #[derive(Debug, Parser)]
        struct Cli {
            #[command(flatten)]
            args: ExperimentArgs,
        }
        let cli = Cli::try_parse_from(["tes", "replot", "docs/results/transfer"]).unwrap();
        assert!(
            matches!(&cli.args.which, Which::Replot(r) if r.dir == std::path::Path::new("docs/results/transfer"))
        );
        assert!(Cli::try_parse_from(["tes", "replot"]).is_err());
    }
}
