//! `tes experiment`: rerun the paper's experiments and write tables and plots.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use tes_experiments::console;
use tes_experiments::experiment::Experiment;
use tes_experiments::fig4::{self, Fig4Config};
use tes_experiments::grid::{self, GridConfig};
use tes_experiments::jobs::{self, JobOptions, Manifest, Shard};
use tes_experiments::lifelong::{self, LifelongConfig};
use tes_experiments::report::Results;
use tes_experiments::robot::{self, RobotConfig};
use tes_experiments::settings::{Settings, SettingsArgs};
use tes_experiments::study::{self, Study};
use tes_experiments::transfer::{self, TransferConfig};

mod full;
mod progress;
use progress::{stop_on_interrupt, with_progress};

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
    /// §5.2 robot study on the simulated arenas: Fig. 8, Fig. 9, Tables 3, 5 and 6
    /// (in-process).
    Robot(RobotArgs),
    /// §5.1.2 and §5.1.4: transfer between tasks of the same dynamics (Fig. 4a: TES against
    /// loreRL, fRmax and fEpsG) and a long run on a held-out task (Fig. 4c: TES against fRmax
    /// and Rmax).
    Fig4(Fig4Args),
    /// Beyond the paper: a long, non-stationary sequence of grid tasks from more worlds than
    /// the library holds (some not logistic, returning after long gaps): TES (M = 20,
    /// recency), TES with an unbounded library, LWT and loreRL.
    Lifelong(LifelongArgs),
    /// The whole study: grid, transfer, robot, fig4 and lifelong at their default settings
    /// into OUT/grid, OUT/transfer, OUT/robot, OUT/fig4 and OUT/lifelong, then OUT/report.md
    /// with every table and figure.
    All(AllArgs),
    /// Combine the shard folders of one run (`--shard K/N`) into one result folder, refusing
    /// shards that overlap, miss jobs, or come from other settings, seeds or code.
    Merge(MergeArgs),
    /// Recompute a complete result folder's summary.json, tables and figures from its job
    /// records (jobs/), without rerunning a job: after a change of what summaries hold.
    Summarise(SummariseArgs),
    /// Tables of result folders, from their summary.json: one folder's (`--table NAME`, or
    /// all), its paired differences from a default run (`--against BASE`), or every generated
    /// block of a document rewritten (`--sync FILE`) or checked (`--check FILE`).
    Report(ReportArgs),
    /// Every experiment's settings as Markdown tables: each flag, its default, its value
    /// under `--quick` and what it sets (docs/experiments.md is this).
    Settings,
    /// Redraw the figures a result folder's summary.json holds the data of (grid: fig3c.svg;
    /// transfer: table2.svg), without rerunning anything.
    Replot(ReplotArgs),
}

/// How to split and continue a run: shared by every experiment.
#[derive(Debug, Args)]
struct JobArgs {
    /// Run only share K of N of the experiment's independent jobs (job i when i mod N = K-1),
    /// e.g. one task of a Slurm array; combine the folders with `tes experiment merge`.
    #[arg(long, value_name = "K/N")]
    shard: Option<Shard>,
    /// Continue an interrupted run in DIR: keep the jobs it recorded, run the rest, with the
    /// settings, seeds and shard DIR's manifest.json records (no other setting may be given).
    #[arg(long, value_name = "DIR")]
    resume: Option<PathBuf>,
    /// Write a full run although this binary was built from a tree with uncommitted changes
    /// (refused otherwise; every table of such a folder says so).
    #[arg(long)]
    allow_dirty: bool,
}

impl JobArgs {
    /// The options, out folder and (on resume) manifest; `settings_given` says whether any
    /// setting was passed on the command line.
    fn resolve(
        &self,
        out: &Path,
        experiment: &str,
        settings_given: bool,
    ) -> Result<(JobOptions, PathBuf, Option<Manifest>)> {
        match &self.resume {
            None => Ok((
                JobOptions {
                    shard: self.shard.unwrap_or(Shard::ALL),
                    resume: false,
                    allow_dirty: self.allow_dirty,
                },
                out.to_owned(),
                None,
            )),
            Some(dir) => {
                if self.shard.is_some() || settings_given {
                    bail!(
                        "--resume takes the settings and shard from {}/manifest.json; give no other setting",
                        dir.display()
                    );
                }
                let manifest = Manifest::read(dir)?;
                if manifest.experiment != experiment {
                    bail!(
                        "{} holds a {} run, not a {experiment} run",
                        dir.display(),
                        manifest.experiment
                    );
                }
                Ok((
                    JobOptions {
                        shard: manifest.shard,
                        resume: true,
                        allow_dirty: self.allow_dirty,
                    },
                    dir.clone(),
                    Some(manifest),
                ))
            }
        }
    }
}

#[derive(Debug, Args)]
struct AllArgs {
    /// Repeats of every experiment [default: each experiment's own, 20; --quick: its quick
    /// value].
    #[arg(long)]
    runs: Option<usize>,
    /// Directory for grid/, transfer/, robot/ and report.md.
    #[arg(long, default_value = "results")]
    out: PathBuf,
    /// Each experiment's --quick settings.
    #[arg(long)]
    quick: bool,
    /// Regenerate every committed result folder of --from (the 100-run, ablation and
    /// converged ones too), each from its manifest's settings, into OUT/NAME; `--resume OUT`
    /// (or the same --out again) goes on where it stopped.
    #[arg(long, conflicts_with_all = ["quick", "runs", "shard"])]
    full: bool,
    /// The committed result folders --full regenerates [default: docs/results; on
    /// `--resume OUT`, the folder OUT was regenerating from].
    #[arg(long, requires = "full")]
    from: Option<PathBuf>,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: AllJobArgs,
}

/// `--shard` and `--resume` of `tes experiment all`.
#[derive(Debug, Args)]
struct AllJobArgs {
    /// Run only share K of N of each experiment's jobs; merge the folders with
    /// `tes experiment merge`.
    #[arg(long, value_name = "K/N")]
    shard: Option<Shard>,
    /// Continue an interrupted `tes experiment all` in DIR with its recorded settings.
    #[arg(long, value_name = "DIR")]
    resume: Option<PathBuf>,
    /// Write full runs although this binary was built from a tree with uncommitted changes.
    #[arg(long)]
    allow_dirty: bool,
}

#[derive(Debug, Args)]
struct MergeArgs {
    /// Shard folders of one run (each holds manifest.json and jobs/), or folders that
    /// `tes experiment all --shard` wrote (each holds grid/, transfer/ and robot/).
    #[arg(required = true)]
    dirs: Vec<PathBuf>,
    /// The merged result folder.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Debug, Args)]
struct SummariseArgs {
    /// A complete result folder (manifest.json and every job's record in jobs/).
    dir: PathBuf,
}

/// Summarises the complete folder `dir` of whichever experiment its manifest names, printing
/// what the experiment prints.
fn summarise_folder(dir: &Path) -> Result<()> {
    print!("{}", study::summarise_folder(dir)?);
    Ok(())
}

#[derive(Debug, Args)]
struct ReportArgs {
    /// A result folder (it holds manifest.json and summary.json).
    #[arg(
        required_unless_present_any = ["sync", "check", "changes"],
        conflicts_with_all = ["sync", "check", "changes"]
    )]
    dir: Option<PathBuf>,
    /// Only this table (the folder's experiment names them; all by default).
    #[arg(long)]
    table: Option<String>,
    /// A run of the same experiment and seeds to compare with, paired by run.
    #[arg(long, value_name = "BASE", conflicts_with = "beside")]
    against: Option<PathBuf>,
    /// With `--table verdicts`: a run of the same experiment at other settings (e.g. 100
    /// runs) whose verdicts go in a column beside the folder's.
    #[arg(long, value_name = "OTHER")]
    beside: Option<PathBuf>,
    /// Rewrite every generated block of FILE (`<!-- generated by: tes experiment report …
    /// -->` … `<!-- end of generated table -->`) from its folders.
    #[arg(long, value_name = "FILE", conflicts_with = "check")]
    sync: Option<PathBuf>,
    /// Fail, naming them, if FILE's generated blocks no longer say what their folders hold.
    #[arg(long, value_name = "FILE")]
    check: Option<PathBuf>,
    /// Every change made after a result existed (a target's earlier form, a world or default
    /// changed), with the verdicts before and after and why, from the preregistration.
    #[arg(long, conflicts_with_all = ["sync", "check"])]
    changes: bool,
    /// The folder the blocks' paths are relative to.
    #[arg(long, default_value = ".")]
    root: PathBuf,
}

fn run_report(args: &ReportArgs) -> Result<()> {
    use tes_experiments::report;
    if let Some(file) = &args.sync {
        report::sync_file(file, &args.root)?;
        println!("rewrote the generated blocks of {}", file.display());
        return Ok(());
    }
    if let Some(file) = &args.check {
        report::check_file(file, &args.root)?;
        println!("every generated block of {} holds", file.display());
        return Ok(());
    }
    if args.changes {
        print!("{}", tes_experiments::ledger::changes_table());
        return Ok(());
    }
    let request = report::Request {
        dir: args.dir.clone().context("a result folder is needed")?,
        table: args.table.clone(),
        against: args.against.clone(),
        beside: args.beside.clone(),
    };
    print!("{}", request.render(Path::new(""))?);
    Ok(())
}

#[derive(Debug, Args)]
struct ReplotArgs {
    /// A folder an experiment wrote (it holds summary.json).
    dir: PathBuf,
}

#[derive(Debug, Args)]
struct RobotArgs {
    #[command(flatten)]
    settings: SettingsArgs<RobotConfig>,
    /// Directory for summary.json, episodes.csv and the SVG plots.
    #[arg(long, default_value = "results/robot")]
    out: PathBuf,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
}

#[derive(Debug, Args)]
struct LifelongArgs {
    #[command(flatten)]
    settings: SettingsArgs<LifelongConfig>,
    /// Directory for summary.json and the SVG plots.
    #[arg(long, default_value = "results/lifelong")]
    out: PathBuf,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
}

fn run_lifelong(args: &LifelongArgs) -> Result<()> {
    run_experiment(&args.out, args.threads, &args.jobs, &args.settings)?;
    Ok(())
}

#[derive(Debug, Args)]
struct Fig4Args {
    #[command(flatten)]
    settings: SettingsArgs<Fig4Config>,
    /// Directory for summary.json, episodes.csv and the SVG plots.
    #[arg(long, default_value = "results/fig4")]
    out: PathBuf,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
}

fn run_fig4(args: &Fig4Args) -> Result<()> {
    run_experiment(&args.out, args.threads, &args.jobs, &args.settings)?;
    Ok(())
}

#[derive(Debug, Args)]
struct TransferArgs {
    #[command(flatten)]
    settings: SettingsArgs<TransferConfig>,
    /// Directory for summary.json, episodes.csv and the SVG plots.
    #[arg(long, default_value = "results/transfer")]
    out: PathBuf,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
}

#[derive(Debug, Args)]
struct GridArgs {
    #[command(flatten)]
    settings: SettingsArgs<GridConfig>,
    /// Directory for summary.json, episodes.csv and the SVG plots.
    #[arg(long, default_value = "results/grid")]
    out: PathBuf,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
    /// Also draw the study's run 0 of loreRL at the first feature count (the same task and
    /// seed, so the same episodes) to this MCAP file, as Foxglove and Rerun show a run of the
    /// group: the grid, the agent moving, its path, decisions and episode rewards.
    #[arg(long, value_name = "FILE.mcap")]
    draw: Option<PathBuf>,
    /// With `--draw`: the episodes drawn (from the first).
    #[arg(long, default_value_t = 20, value_name = "N")]
    draw_episodes: usize,
}

/// Runs `tes experiment`.
pub fn run(args: &ExperimentArgs) -> Result<()> {
    match &args.which {
        Which::Grid(g) => run_grid(g),
        Which::Transfer(t) => run_transfer(t),
        Which::Robot(r) => run_robot(r),
        Which::Fig4(f) => run_fig4(f),
        Which::Lifelong(l) => run_lifelong(l),
        Which::All(a) => run_all(a),
        Which::Merge(m) => run_merge(m),
        Which::Replot(r) => run_replot(r),
        Which::Report(r) => run_report(r),
        Which::Summarise(s) => summarise_folder(&s.dir),
        Which::Settings => {
            print!("{}", study::settings_reference());
            Ok(())
        }
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

/// Prints what an experiment's `summary` says (its [`console`] text); a summary that cannot
/// be written is a bug of the experiments' crate, said as such.
fn print_summary(summary: Result<String, std::fmt::Error>) -> Result<()> {
    print!(
        "{}",
        summary.context("cannot write the experiment's summary")?
    );
    Ok(())
}

fn run_transfer(args: &TransferArgs) -> Result<()> {
    run_experiment(&args.out, args.threads, &args.jobs, &args.settings)?;
    Ok(())
}

/// Runs one experiment from its command line: the settings given (or a resumed folder's),
/// the jobs with progress, and the console summary of a complete run. Returns the settings
/// that ran.
fn run_experiment<E: Experiment + Settings>(
    out: &Path,
    threads: Option<usize>,
    jobs: &JobArgs,
    settings: &SettingsArgs<E>,
) -> Result<E> {
    jobs::use_threads(threads)?;
    let (options, out, resumed) = jobs.resolve(out, E::NAME, settings.any_given())?;
    stop_on_interrupt(&out, E::NAME, std::slice::from_ref(&out))?;
    let config = match &resumed {
        Some(m) => m.settings()?,
        None => settings.config().map_err(anyhow::Error::msg)?,
    };
    if let Some(report) = with_progress(&config, &out, options, options.resume)? {
        print_summary(E::console(&report, &out))?;
    }
    Ok(config)
}

fn run_grid(args: &GridArgs) -> Result<()> {
    let config = run_experiment(&args.out, args.threads, &args.jobs, &args.settings)?;
    if let Some(path) = &args.draw {
        draw_grid_run(&config, path, args.draw_episodes)?;
    }
    Ok(())
}

/// `--draw`: the study's loreRL run 0, drawn for Foxglove and Rerun.
fn draw_grid_run(config: &GridConfig, path: &Path, episodes: usize) -> Result<()> {
    if episodes == 0 {
        bail!("--draw-episodes must be at least 1");
    }
    let drawn = grid::draw_run(config, path, episodes)
        .with_context(|| format!("cannot draw a grid run to {}", path.display()))?;
    let rewards: Vec<String> = drawn
        .episodes
        .iter()
        .map(|e| format!("{:.2}", e.reward))
        .collect();
    eprintln!(
        "grid experiment: drew {} episodes of {} (run 0, {} irrelevant features, seed {}; rewards {}) to {}: {} messages for Foxglove and Rerun (docs/recording.md)",
        drawn.episodes.len(),
        drawn.method,
        drawn.irrelevant,
        drawn.seed,
        rewards.join(" "),
        path.display(),
        drawn.messages
    );
    Ok(())
}

fn run_robot(args: &RobotArgs) -> Result<()> {
    run_experiment(&args.out, args.threads, &args.jobs, &args.settings)?;
    Ok(())
}

fn run_all(args: &AllArgs) -> Result<()> {
    jobs::use_threads(args.threads)?;
    if args.full {
        let out = args.jobs.resume.as_ref().unwrap_or(&args.out);
        return full::run_full(args.from.as_deref(), out, args.jobs.allow_dirty);
    }
    let study = Study::open(
        &args.out,
        args.jobs.resume.as_deref(),
        args.quick,
        args.runs,
        args.jobs.shard,
    )?;
    let folders: Vec<PathBuf> = study::EXPERIMENTS.map(|e| study.dir(e)).into();
    stop_on_interrupt(&study.out, "all", &folders)?;
    // Every experiment of a study skips the runs its folder already holds (none in a
    // fresh folder); only `--resume` is said to be resuming.
    let options = JobOptions {
        shard: study.shard,
        resume: true,
        allow_dirty: args.jobs.allow_dirty,
    };
    let resuming = args.jobs.resume.is_some();
    let started = std::time::Instant::now();
    let c = &study.configs;
    let g = with_progress(&c.grid, &study.dir(grid::EXPERIMENT), options, resuming)?;
    let t = with_progress(
        &c.transfer,
        &study.dir(transfer::EXPERIMENT),
        options,
        resuming,
    )?;
    let r = with_progress(&c.robot, &study.dir(robot::EXPERIMENT), options, resuming)?;
    let f = with_progress(&c.fig4, &study.dir(fig4::EXPERIMENT), options, resuming)?;
    let l = with_progress(
        &c.lifelong,
        &study.dir(lifelong::EXPERIMENT),
        options,
        resuming,
    )?;
    let (Some(g), Some(t), Some(r), Some(f), Some(l)) = (g, t, r, f, l) else {
        println!(
            "shard {} of the study written to {}; combine the shards with `tes experiment merge DIR... --out DIR`",
            study.shard,
            study.out.display()
        );
        return Ok(());
    };
    print_summary(console::grid(&g, &study.dir(grid::EXPERIMENT)))?;
    print_summary(console::transfer(&t, &study.dir(transfer::EXPERIMENT)))?;
    print_summary(console::robot(&r, &study.dir(robot::EXPERIMENT)))?;
    print_summary(console::fig4(&f, &study.dir(fig4::EXPERIMENT)))?;
    print_summary(console::lifelong(&l, &study.dir(lifelong::EXPERIMENT)))?;
    let path = study.write_report(&[
        Results::Grid(g),
        Results::Transfer(t),
        Results::Robot(r),
        Results::Fig4(f),
        Results::Lifelong(l),
    ])?;
    println!(
        "the whole study took {:.1} s; wrote {}",
        started.elapsed().as_secs_f64(),
        path.display()
    );
    Ok(())
}

fn run_merge(args: &MergeArgs) -> Result<()> {
    if study::are_studies(&args.dirs) {
        let merged = study::merge(&args.dirs, &args.out)?;
        println!(
            "merged {} study shards; wrote {}",
            args.dirs.len(),
            merged.report.display()
        );
        return Ok(());
    }
    let manifest = jobs::merge(&args.dirs, &args.out).context("cannot merge the shards")?;
    summarise_folder(&args.out)?;
    println!(
        "merged {} shards of {} jobs into {}",
        args.dirs.len(),
        manifest.jobs,
        args.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

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
