//! `tes experiment`: rerun the paper's experiments and write tables and plots.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tes_experiments::console;
use tes_experiments::experiment::Experiment;
use tes_experiments::fig4::{self, Fig4Config};
use tes_experiments::grid::{self, GridConfig};
use tes_experiments::jobs::{self, JobOptions, Manifest, Shard};
use tes_experiments::lifelong::{self, LifelongConfig};
use tes_experiments::method::Method;
use tes_experiments::progress::ProgressLines;
use tes_experiments::report::Results;
use tes_experiments::robot::{self, RobotConfig};
use tes_experiments::study::{self, Study, StudyConfigs};
use tes_experiments::transfer::{self, TransferConfig};
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
    let manifest = Manifest::read(dir)?;
    match manifest.experiment.as_str() {
        GridConfig::NAME => summarise::<GridConfig>(dir),
        TransferConfig::NAME => summarise::<TransferConfig>(dir),
        RobotConfig::NAME => summarise::<RobotConfig>(dir),
        Fig4Config::NAME => summarise::<Fig4Config>(dir),
        LifelongConfig::NAME => summarise::<LifelongConfig>(dir),
        other => bail!("unknown experiment {other:?} in {}", dir.display()),
    }
}

fn summarise<E: Experiment>(dir: &Path) -> Result<()> {
    print_summary(E::console(&E::summarise_dir(dir)?, dir))
}

#[derive(Debug, Args)]
struct ReportArgs {
    /// A result folder (it holds manifest.json and summary.json).
    #[arg(required_unless_present_any = ["sync", "check"], conflicts_with_all = ["sync", "check"])]
    dir: Option<PathBuf>,
    /// Only this table (the folder's experiment names them; all by default).
    #[arg(long)]
    table: Option<String>,
    /// A run of the same experiment and seeds to compare with, paired by run.
    #[arg(long, value_name = "BASE")]
    against: Option<PathBuf>,
    /// Rewrite every generated block of FILE (`<!-- generated by: tes experiment report …
    /// -->` … `<!-- end of generated table -->`) from its folders.
    #[arg(long, value_name = "FILE", conflicts_with = "check")]
    sync: Option<PathBuf>,
    /// Fail, naming them, if FILE's generated blocks no longer say what their folders hold.
    #[arg(long, value_name = "FILE")]
    check: Option<PathBuf>,
    /// The folder the blocks' paths are relative to.
    #[arg(long, default_value = ".")]
    root: PathBuf,
}

fn run_report(args: &ReportArgs) -> Result<()> {
    use tes_experiments::report;
    if let Some(file) = args.sync.as_ref().or(args.check.as_ref()) {
        let doc = std::fs::read_to_string(file)
            .with_context(|| format!("cannot read {}", file.display()))?;
        if args.sync.is_some() {
            let synced = report::sync(&doc, &args.root)?;
            std::fs::write(file, &synced)
                .with_context(|| format!("cannot write {}", file.display()))?;
            println!("rewrote the generated blocks of {}", file.display());
        } else {
            let stale = report::stale_blocks(&doc, &args.root)?;
            if !stale.is_empty() {
                bail!(
                    "{} block(s) of {} no longer say what their folders hold (run `tes experiment report --sync {}`): {}",
                    stale.len(),
                    file.display(),
                    file.display(),
                    stale.join("; ")
                );
            }
            println!("every generated block of {} holds", file.display());
        }
        return Ok(());
    }
    let dir = args.dir.as_ref().context("a result folder is needed")?;
    let this = Results::read(dir)?;
    let md = match (&args.against, &args.table) {
        (Some(base), _) => report::against(&this, &Results::read(base)?)?,
        (None, Some(table)) => this.table(table)?,
        (None, None) => this.all_tables()?,
    };
    print!("{md}");
    Ok(())
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
    /// Base seed; run r uses seed + r [default: 1].
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
}

#[derive(Debug, Args)]
struct LifelongArgs {
    /// Independent runs of the whole sequence [default: 20; --quick: 2].
    #[arg(long)]
    runs: Option<usize>,
    /// Episodes on each task of the sequence [default: 50; --quick: 8].
    #[arg(long)]
    episodes: Option<usize>,
    /// Shuffled passes over every world [default: 4; --quick: 2].
    #[arg(long)]
    rounds: Option<usize>,
    /// The recency decay μ of the library's track record [default: 0.1].
    #[arg(long)]
    recency: Option<f64>,
    /// Directory for summary.json and the SVG plots.
    #[arg(long, default_value = "results/lifelong")]
    out: PathBuf,
    /// Small settings for a first look: seconds.
    #[arg(long)]
    quick: bool,
    /// Base agent seed [default: 1].
    #[arg(long)]
    seed: Option<u64>,
    /// Seed of the worlds and of the sequence [default: 2017].
    #[arg(long)]
    world_seed: Option<u64>,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
}

impl LifelongArgs {
    fn settings_given(&self) -> bool {
        self.runs.is_some()
            || self.episodes.is_some()
            || self.rounds.is_some()
            || self.recency.is_some()
            || self.quick
            || self.seed.is_some()
            || self.world_seed.is_some()
    }

    fn config(&self) -> LifelongConfig {
        let mut config = if self.quick {
            LifelongConfig::quick()
        } else {
            LifelongConfig::standard()
        };
        if let Some(runs) = self.runs {
            config.runs = runs;
        }
        if let Some(n) = self.episodes {
            config.episodes = n;
        }
        if let Some(n) = self.rounds {
            config.rounds = n;
        }
        if let Some(mu) = self.recency {
            config.recency = mu;
        }
        if let Some(seed) = self.seed {
            config.seed = seed;
        }
        if let Some(seed) = self.world_seed {
            config.world_seed = seed;
        }
        config
    }
}

fn run_lifelong(args: &LifelongArgs) -> Result<()> {
    run_experiment(
        &args.out,
        args.threads,
        &args.jobs,
        args.settings_given(),
        || args.config(),
    )?;
    Ok(())
}

#[derive(Debug, Args)]
struct Fig4Args {
    /// Independent runs of each pair and of the long run [default: 20; --quick: 2].
    #[arg(long)]
    runs: Option<usize>,
    /// Episodes of the long run (Fig. 4c) [default: 500; --quick: 40].
    #[arg(long)]
    long_episodes: Option<usize>,
    /// Directory for summary.json, episodes.csv and the SVG plots.
    #[arg(long, default_value = "results/fig4")]
    out: PathBuf,
    /// Small settings for a first look: seconds.
    #[arg(long)]
    quick: bool,
    /// Base seed, as the transfer experiment's [default: 1].
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
}

impl Fig4Args {
    fn settings_given(&self) -> bool {
        self.runs.is_some() || self.long_episodes.is_some() || self.quick || self.seed.is_some()
    }

    fn config(&self) -> Fig4Config {
        let mut config = if self.quick {
            Fig4Config::quick()
        } else {
            Fig4Config::paper()
        };
        if let Some(runs) = self.runs {
            config.runs = runs;
        }
        if let Some(n) = self.long_episodes {
            config.convergence_episodes = n;
        }
        if let Some(seed) = self.seed {
            config.seed = seed;
        }
        config
    }
}

fn run_fig4(args: &Fig4Args) -> Result<()> {
    run_experiment(
        &args.out,
        args.threads,
        &args.jobs,
        args.settings_given(),
        || args.config(),
    )?;
    Ok(())
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
    /// Base seed; the job of (task t, run r) uses seed + 1000 r + t [default: 1].
    #[arg(long)]
    seed: Option<u64>,
    /// Seed of the grid suite (layouts, dynamics, irrelevant features) [default: 2017].
    #[arg(long)]
    world_seed: Option<u64>,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
    /// Plan every re-plan to the tolerance, instead of stopping it once no value moves by
    /// more than the model change that triggered it (see `tes_learning::plan`).
    #[arg(long)]
    converge_plans: bool,
    /// The most views the library keeps (M) [default: 20, the paper's]; a larger M prunes
    /// less, an ablation of the library's pruning.
    #[arg(long)]
    max_views: Option<usize>,
    /// Prune one view per task as Algorithm 2 writes it (`if |T| > M then remove the least
    /// valuable`), which lets a task that adds several views leave the library above M,
    /// instead of pruning down to M (the default).
    #[arg(long)]
    prune_one_per_task: bool,
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
    /// First agent seed; run r uses seed + r [default: 1].
    #[arg(long)]
    seed: Option<u64>,
    /// Seed of the grid suite (layouts, dynamics, irrelevant features) [default: 2017].
    #[arg(long)]
    world_seed: Option<u64>,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    jobs: JobArgs,
    /// Plan every re-plan to the tolerance, instead of stopping it once no value moves by
    /// more than the model change that triggered it (see `tes_learning::plan`).
    #[arg(long)]
    converge_plans: bool,
    /// RL-DT keeps per-state effect counts instead of the list of all examples: the same
    /// trees and rewards, induced in time bounded by the states rather than the steps (our
    /// shortcut; the default list is Hester & Stone's and what Table 1 compares against).
    #[arg(long)]
    rl_dt_per_state_counts: bool,
    /// fEpsG's exploration ε [default: 0.1, the paper's; loreRL explores with 0.05].
    #[arg(long, value_name = "EPSILON", value_parser = epsilon)]
    fepsg_epsilon: Option<f64>,
    /// Only these algorithms, comma-separated names as in the figures (e.g. `loreRL,fEpsG`)
    /// [default: every figure's].
    #[arg(long, value_delimiter = ',', value_parser = method)]
    methods: Option<Vec<Method>>,
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

impl TransferArgs {
    fn settings_given(&self) -> bool {
        self.runs.is_some()
            || self.quick
            || self.tasks.is_some()
            || self.train_episodes.is_some()
            || self.test_episodes.is_some()
            || self.seed.is_some()
            || self.world_seed.is_some()
            || self.converge_plans
            || self.max_views.is_some()
            || self.prune_one_per_task
    }

    fn config(&self) -> TransferConfig {
        let mut config = if self.quick {
            TransferConfig::quick()
        } else {
            TransferConfig::paper()
        };
        if let Some(runs) = self.runs {
            config.runs = runs;
        }
        if let Some(tasks) = &self.tasks {
            config.test_tasks.clone_from(tasks);
        }
        if let Some(n) = self.train_episodes {
            config.train_episodes = n;
        }
        if let Some(n) = self.test_episodes {
            config.test_episodes = n;
        }
        if let Some(seed) = self.seed {
            config.seed = seed;
        }
        if let Some(seed) = self.world_seed {
            config.world_seed = seed;
        }
        config.stop_at_drift = !self.converge_plans;
        if let Some(m) = self.max_views {
            config.max_views = m;
        }
        config.prune_one_per_task = self.prune_one_per_task;
        config
    }
}

fn run_transfer(args: &TransferArgs) -> Result<()> {
    run_experiment(
        &args.out,
        args.threads,
        &args.jobs,
        args.settings_given(),
        || args.config(),
    )?;
    Ok(())
}

/// Runs one experiment from its command line: the settings given (or a resumed folder's),
/// the jobs with progress, and the console summary of a complete run. Returns the settings
/// that ran.
fn run_experiment<E: Experiment>(
    out: &Path,
    threads: Option<usize>,
    jobs: &JobArgs,
    settings_given: bool,
    config: impl FnOnce() -> E,
) -> Result<E> {
    set_threads(threads)?;
    let (options, out, resumed) = jobs.resolve(out, E::NAME, settings_given)?;
    stop_on_interrupt(&out, E::NAME, std::slice::from_ref(&out))?;
    let config = match &resumed {
        Some(m) => m.settings()?,
        None => config(),
    };
    if let Some(report) = with_progress(&config, &out, options, options.resume)? {
        print_summary(E::console(&report, &out))?;
    }
    Ok(config)
}

/// Runs (a share of) an experiment with a line saying what runs (`resuming`: an interrupted
/// run goes on) and a progress bar; `None` for a shard.
fn with_progress<E: Experiment>(
    config: &E,
    out: &Path,
    options: JobOptions,
    resuming: bool,
) -> Result<Option<E::Report>> {
    eprintln!(
        "{} experiment: {}{} -> {}",
        E::NAME,
        config.describe(),
        shard_note(options, resuming),
        out.display()
    );
    let bar = progress_bar(E::NAME);
    let report = config.run_with(out, options, &bar.callback())?;
    bar.finish(out, E::NAME, options);
    Ok(report)
}

/// Ctrl-C or SIGTERM stops the run at once and says how to go on: every finished run is
/// already on disk in one of `folders` (its record is written whole or not at all), and
/// `tes experiment WHICH --resume OUT` runs the rest. Installed by the command itself, so a
/// run started with SIGINT ignored (a script's background job) still stops when told to.
fn stop_on_interrupt(out: &Path, which: &str, folders: &[PathBuf]) -> Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM])
        .context("cannot install the signal handlers")?;
    let (out, which, folders) = (out.to_owned(), which.to_owned(), folders.to_owned());
    std::thread::Builder::new()
        .name("interrupt".into())
        .spawn(move || {
            let Some(signal) = signals.forever().next() else {
                return;
            };
            let kept: usize = folders
                .iter()
                .map(|f| jobs::recorded(f).map_or(0, |r| r.len()))
                .sum();
            eprintln!(
                "\nexperiment {which}: interrupted; the {kept} runs recorded in {} are kept; \
                 run the rest with `tes experiment {which} --resume {}`",
                out.display(),
                out.display()
            );
            std::process::exit(128 + signal);
        })
        .context("cannot start the signal thread")?;
    Ok(())
}

fn shard_note(options: JobOptions, resuming: bool) -> String {
    let mut note = String::new();
    if !options.shard.is_all() {
        note.push_str(&format!(", shard {}", options.shard));
    }
    if resuming {
        note.push_str(", resuming");
    }
    note
}

/// Progress on stderr: a bar (runs done, elapsed, the time left) on a terminal; elsewhere (a
/// batch job's log, `nohup`) a plain line at most every [`PROGRESS_LINE_EVERY`](tes_experiments::progress::PROGRESS_LINE_EVERY) and at the
/// end. The estimate is made from the runs finished in this invocation, not those found on
/// resume.
struct Progress {
    bar: ProgressBar,
    first: Once,
    plain: Option<std::sync::Mutex<ProgressLines>>,
}

impl Progress {
    /// The `progress(done, total)` callback the experiments call.
    fn callback(&self) -> impl Fn(u64, u64) + Sync + '_ {
        move |done, total| {
            self.bar.set_length(total);
            self.bar.set_position(done);
            // The first call reports the runs found on resume: the estimate starts after it.
            self.first.call_once(|| self.bar.reset_eta());
            if let Some(plain) = &self.plain
                && let Ok(mut plain) = plain.lock()
            {
                plain.update(done, total);
            }
        }
    }

    fn finish(&self, out: &Path, experiment: &str, options: JobOptions) {
        self.bar.finish_and_clear();
        if !options.shard.is_all() {
            println!(
                "shard {} of the {experiment} experiment written to {}; combine the shards with `tes experiment merge DIR... --out DIR`",
                options.shard,
                out.display()
            );
        }
    }
}

fn progress_bar(what: &str) -> Progress {
    if std::io::stderr().is_terminal() {
        let bar = ProgressBar::with_draw_target(Some(1), ProgressDrawTarget::stderr());
        if let Ok(style) = ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} runs ({elapsed} elapsed, ~{eta} left)",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(what.to_owned());
        Progress {
            bar,
            first: Once::new(),
            plain: None,
        }
    } else {
        let now = std::time::Instant::now();
        Progress {
            bar: ProgressBar::hidden(),
            first: Once::new(),
            plain: Some(std::sync::Mutex::new(ProgressLines::new(
                format!("{what} experiment"),
                now,
            ))),
        }
    }
}

impl GridArgs {
    fn settings_given(&self) -> bool {
        self.runs.is_some()
            || self.episodes.is_some()
            || self.quick
            || self.seed.is_some()
            || self.world_seed.is_some()
            || self.converge_plans
            || self.rl_dt_per_state_counts
            || self.fepsg_epsilon.is_some()
            || self.methods.is_some()
    }

    fn config(&self) -> GridConfig {
        let mut config = if self.quick {
            GridConfig::quick()
        } else {
            GridConfig::paper(20, 800)
        };
        if let Some(runs) = self.runs {
            config.runs = runs;
        }
        if let Some(episodes) = self.episodes {
            config.episodes = episodes;
        }
        if let Some(seed) = self.seed {
            config.seed = seed;
        }
        if let Some(seed) = self.world_seed {
            config.world_seed = seed;
        }
        config.stop_at_drift = !self.converge_plans;
        if self.rl_dt_per_state_counts {
            config.rl_dt_examples = ExampleStore::PerStateCounts;
        }
        if let Some(e) = self.fepsg_epsilon {
            config.fepsg_epsilon = e;
        }
        config.methods.clone_from(&self.methods);
        config
    }
}

/// An exploration probability, in [0, 1].
fn epsilon(text: &str) -> Result<f64, String> {
    let e: f64 = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number"))?;
    if (0.0..=1.0).contains(&e) {
        Ok(e)
    } else {
        Err(format!("{e} is not a probability in [0, 1]"))
    }
}

/// A method by the name the figures give it.
fn method(text: &str) -> Result<Method, String> {
    Method::from_name(text).ok_or_else(|| {
        format!(
            "{text:?} is no method; the grid's are {}",
            grid::METHODS.map(|m| m.name().into_owned()).join(", ")
        )
    })
}

fn run_grid(args: &GridArgs) -> Result<()> {
    let config = run_experiment(
        &args.out,
        args.threads,
        &args.jobs,
        args.settings_given(),
        || args.config(),
    )?;
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

impl RobotArgs {
    fn settings_given(&self) -> bool {
        self.runs.is_some()
            || self.episodes.is_some()
            || self.train_episodes.is_some()
            || self.quick
            || self.seed.is_some()
    }

    fn config(&self) -> RobotConfig {
        let mut config = if self.quick {
            RobotConfig::quick()
        } else {
            RobotConfig::paper()
        };
        if let Some(n) = self.runs {
            config.runs = n;
        }
        if let Some(n) = self.episodes {
            config.episodes = n;
        }
        if let Some(n) = self.train_episodes {
            config.train_episodes = n;
        }
        if let Some(seed) = self.seed {
            config.seed = seed;
        }
        config
    }
}

fn run_robot(args: &RobotArgs) -> Result<()> {
    run_experiment(
        &args.out,
        args.threads,
        &args.jobs,
        args.settings_given(),
        || args.config(),
    )?;
    Ok(())
}

fn run_all(args: &AllArgs) -> Result<()> {
    set_threads(args.threads)?;
    let study = match &args.jobs.resume {
        Some(dir) => {
            if args.jobs.shard.is_some() || args.runs.is_some() || args.quick {
                bail!(
                    "--resume takes the settings and shard from the manifests in {}; give no other setting",
                    dir.display()
                );
            }
            Study::resume(dir)?
        }
        None => {
            let configs = if args.quick {
                StudyConfigs::quick()
            } else {
                StudyConfigs::paper()
            };
            let configs = match args.runs {
                Some(runs) => configs.with_runs(runs),
                None => configs,
            };
            Study::prepare(&args.out, configs, args.jobs.shard.unwrap_or(Shard::ALL))?
        }
    };
    let folders: Vec<PathBuf> = study::EXPERIMENTS.map(|e| study.dir(e)).into();
    stop_on_interrupt(&study.out, "all", &folders)?;
    // Every experiment of a study skips the runs its folder already holds (none in a
    // fresh folder); only `--resume` is said to be resuming.
    let options = JobOptions {
        shard: study.shard,
        resume: true,
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
