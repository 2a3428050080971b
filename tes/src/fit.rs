//! `tes fit`: mDAGL over a labelled stream (CSV or libsvm rows, a file or standard input,
//! plain or gzip-compressed), prequentially.
//!
//! The work — checking the file, then feeding its rows in order, each predicted before it is
//! learned from — is [`tes_learning::prequential`]; this is its command line: the arguments,
//! a progress bar for large files, and the report.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tes_learning::mdagl::MdaglParams;
use tes_learning::prequential::{
    FitResult, FitSettings, Pass, RowFormat, fit_file, fit_stream, is_gzip,
};

/// Files at least this large get a progress bar (when stderr is a terminal).
const PROGRESS_MIN_BYTES: u64 = 1 << 20;

/// Arguments of `tes fit`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct FitArgs {
    /// The rows, or `-` for standard input; gzip-compressed or not. CSV: the class label
    /// 0..K-1, then the features, under an optional header line naming the columns. Sparse
    /// (libsvm or Vowpal Wabbit style): the label, then `column:value` for each non-zero
    /// feature.
    data: PathBuf,
    /// How the rows are written [default: told from the first row: sparse if it has a `:` or
    /// `|`].
    #[arg(long, value_enum)]
    format: Option<Format>,
    /// Group-lasso strength λ (larger keeps fewer features), or `auto`: race λ = 0.05 (the
    /// paper's), 0.015, 0.005, 0.0015 and 0.0005 in one pass and keep the best so far.
    #[arg(long, default_value = "0.05", value_parser = hyper)]
    lambda: Hyper,
    /// Step-size scale α of β_t = α√t (smaller learns faster), or `auto`: race α = 1.5 (the
    /// paper's), 0.3 and 0.05.
    #[arg(long, default_value = "1.5", value_parser = hyper)]
    alpha: Hyper,
    /// Number of classes K [default: largest label + 1].
    #[arg(long)]
    classes: Option<usize>,
    /// Add an unregularised intercept column.
    #[arg(long)]
    intercept: bool,
    /// Threads `auto`'s settings learn on [default: one per core]. The fit is the same on
    /// any number.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(1..))]
    threads: Option<u16>,
    /// Print one JSON object instead of the text report.
    #[arg(long)]
    json: bool,
}

/// `--format`: how the rows are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Format {
    /// `label,x1,…,xd`, with or without a header line.
    Csv,
    /// `label column:value …` (libsvm; Vowpal Wabbit's bare `|` and value-less columns too).
    Sparse,
}

impl From<Format> for RowFormat {
    fn from(format: Format) -> Self {
        match format {
            Format::Csv => RowFormat::Csv,
            Format::Sparse => RowFormat::Sparse,
        }
    }
}

/// The name `-` gives standard input in reports and errors.
const STDIN_NAME: &str = "standard input";

/// A hyper-parameter on the command line: a number, or `auto`.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Hyper {
    /// Race the grid's values.
    Auto,
    /// This value.
    Value(f64),
}

impl Hyper {
    fn value(self) -> Option<f64> {
        match self {
            Hyper::Auto => None,
            Hyper::Value(v) => Some(v),
        }
    }
}

impl std::fmt::Display for Hyper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Hyper::Auto => f.write_str("auto"),
            Hyper::Value(v) => write!(f, "{v}"),
        }
    }
}

fn hyper(text: &str) -> Result<Hyper, String> {
    if text == "auto" {
        return Ok(Hyper::Auto);
    }
    text.parse()
        .map(Hyper::Value)
        .map_err(|_| format!("expected a number or `auto`, got {text:?}"))
}

/// A bar over both passes for a large plain file; a counter of the rows' bytes for standard
/// input or a compressed file, whose size does not say how much text it holds; nothing when
/// stderr is not a terminal or the file is small.
fn progress_bar(input: Option<&Path>) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let plain_size = input
        .filter(|path| !is_gzip(path))
        .map(|path| std::fs::metadata(path).map(|m| m.len()).unwrap_or(0));
    let (bar, template) = match plain_size {
        Some(bytes) if bytes < PROGRESS_MIN_BYTES => return ProgressBar::hidden(),
        Some(bytes) => (
            ProgressBar::with_draw_target(Some(2 * bytes), ProgressDrawTarget::stderr()),
            "{msg:>10} [{bar:40}] {bytes}/{total_bytes} ({bytes_per_sec}, {eta} left)",
        ),
        None => (
            ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr()),
            "{msg:>10} {spinner} {bytes} of rows read ({bytes_per_sec})",
        ),
    };
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

/// The input's name in reports: its path, or [`STDIN_NAME`].
fn input_name(args: &FitArgs) -> PathBuf {
    if reads_stdin(args) {
        PathBuf::from(STDIN_NAME)
    } else {
        args.data.clone()
    }
}

fn reads_stdin(args: &FitArgs) -> bool {
    args.data.as_os_str() == "-"
}

/// `auto (chose 0.005)` or the value given.
fn chosen(asked: Hyper, used: f64) -> String {
    match asked {
        Hyper::Auto => format!("auto (chose {used})"),
        Hyper::Value(v) => v.to_string(),
    }
}

/// Runs `tes fit`: the file checked, mDAGL run over it once, the report printed.
pub fn run(args: &FitArgs) -> Result<()> {
    let stdin = reads_stdin(args);
    let progress = progress_bar((!stdin).then_some(args.data.as_path()));
    progress.set_message("checking");
    let defaults = MdaglParams::default();
    let settings = FitSettings {
        params: MdaglParams {
            lambda: args.lambda.value().unwrap_or(defaults.lambda),
            alpha: args.alpha.value().unwrap_or(defaults.alpha),
            intercept: args.intercept,
        },
        auto_lambda: args.lambda == Hyper::Auto,
        auto_alpha: args.alpha == Hyper::Auto,
        classes: args.classes,
        format: args.format.map(RowFormat::from),
        threads: args.threads.map_or(0, usize::from),
    };
    let mut fitting = false;
    let report = |pass, bytes| {
        if pass == Pass::Fitting && !fitting {
            fitting = true;
            progress.set_message("fitting");
        }
        progress.inc(bytes);
    };
    let fit = if stdin {
        fit_stream(
            std::io::stdin().lock(),
            Path::new(STDIN_NAME),
            &settings,
            report,
        )?
    } else {
        fit_file(&args.data, &settings, report)?
    };
    progress.finish_and_clear();
    if args.json {
        print_json(args, &fit);
    } else {
        print_report(args, &fit);
    }
    Ok(())
}

/// `--json`: the fit as one JSON object.
fn print_json(args: &FitArgs, fit: &FitResult) {
    let report = serde_json::json!({
        "n": fit.shape.rows,
        "mean_logloss": fit.mean_log_loss,
        "accuracy": fit.accuracy,
        "selected": fit.selected,
        "updates_per_sec": fit.updates_per_sec,
        "classes": fit.classes,
        "features": fit.shape.features,
        "binary": fit.shape.binary,
        "format": match fit.shape.format {
            RowFormat::Csv => "csv",
            RowFormat::Sparse => "sparse",
        },
        "selected_names": selected_names(fit),
        "lambda": fit.params.lambda,
        "alpha": fit.params.alpha,
        "intercept": args.intercept,
        "auto": auto_json(args, fit),
    });
    println!("{report}");
}

/// The selected features' header names, or `null` without a header.
fn selected_names(fit: &FitResult) -> serde_json::Value {
    if fit.shape.names.is_empty() {
        return serde_json::Value::Null;
    }
    fit.selected
        .iter()
        .map(|&column| fit.shape.feature_name(column))
        .collect()
}

/// With `auto`: what was raced and how each setting stood; `null` for a fixed setting.
fn auto_json(args: &FitArgs, fit: &FitResult) -> serde_json::Value {
    if fit.standings.is_empty() {
        return serde_json::Value::Null;
    }
    let standings: Vec<serde_json::Value> = fit
        .standings
        .iter()
        .map(|s| {
            serde_json::json!({
                "lambda": s.params.lambda,
                "alpha": s.params.alpha,
                "mean_logloss": s.mean_log_loss,
                "rows": s.rows,
                "racing": s.racing,
            })
        })
        .collect();
    serde_json::json!({
        "lambda": args.lambda.to_string(),
        "alpha": args.alpha.to_string(),
        "standings": standings,
    })
}

/// The fit as a table for people.
fn print_report(args: &FitArgs, fit: &FitResult) {
    let input = match (fit.shape.binary, fit.shape.format) {
        (true, RowFormat::Csv) => "binary CSV features, sparse path",
        (true, RowFormat::Sparse) => "binary sparse-row features, sparse path",
        (false, RowFormat::Csv) => "real-valued CSV features, dense path",
        (false, RowFormat::Sparse) => "real-valued sparse-row features, sparse path",
    };
    println!(
        "{}: {} rows, {} {input}, {} classes",
        input_name(args).display(),
        fit.shape.rows,
        fit.shape.features,
        fit.classes
    );
    println!(
        "mDAGL  lambda = {}  alpha = {}  {}",
        chosen(args.lambda, fit.params.lambda),
        chosen(args.alpha, fit.params.alpha),
        if args.intercept {
            "with intercept"
        } else {
            "no intercept"
        }
    );
    if let [_, runner_up, ..] = fit.standings.as_slice() {
        println!(
            "  raced {} settings in one pass; the runner-up, lambda = {} alpha = {}, scored {:.4} \
             nats ({} rows)",
            fit.standings.len(),
            runner_up.params.lambda,
            runner_up.params.alpha,
            runner_up.mean_log_loss,
            runner_up.rows
        );
    }
    println!(
        "  prequential mean log-loss  {:.4} nats   (uniform guess: {:.4})",
        fit.mean_log_loss,
        (fit.classes as f64).ln()
    );
    println!("  prequential accuracy       {:.2} %", 100.0 * fit.accuracy);
    let columns = match (fit.shape.names.is_empty(), fit.shape.format) {
        (false, _) => "named by the header",
        (true, RowFormat::Csv) => "0-based feature columns",
        (true, RowFormat::Sparse) => "columns as numbered in the rows",
    };
    println!(
        "  selected features          {} of {} ({columns})",
        fit.selected.len(),
        fit.shape.features
    );
    if fit.selected.is_empty() && fit.standings.is_empty() {
        println!(
            "    none: no column's average gradient reached lambda x sqrt(K); \
             `--lambda auto --alpha auto` races smaller settings"
        );
    }
    let per_line = if fit.shape.names.is_empty() { 16 } else { 6 };
    for line in fit.selected.chunks(per_line) {
        let cols: Vec<String> = line.iter().map(|&c| fit.shape.feature_name(c)).collect();
        println!("    {}", cols.join(" "));
    }
    println!(
        "  update throughput          {:.0} updates/s ({:.1} ms learning)",
        fit.updates_per_sec,
        fit.seconds * 1e3
    );
}
