//! `tes fit`: mDAGL over a labelled CSV stream, prequentially.
//!
//! The work — checking the file, then feeding its rows in order, each predicted before it is
//! learned from — is [`tes_learning::prequential`]; this is its command line: the arguments,
//! a progress bar for large files, and the report.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tes_learning::mdagl::MdaglParams;
use tes_learning::prequential::{FitResult, FitSettings, Pass, fit_file};

/// Files at least this large get a progress bar (when stderr is a terminal).
const PROGRESS_MIN_BYTES: u64 = 1 << 20;

/// Arguments of `tes fit`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct FitArgs {
    /// CSV file: no header; first column the class label 0..K-1, then the features.
    data: PathBuf,
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
    /// Print one JSON object instead of the text report.
    #[arg(long)]
    json: bool,
}

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

fn progress_bar(path: &Path) -> ProgressBar {
    let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    if bytes < PROGRESS_MIN_BYTES || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(2 * bytes), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template(
        "{msg:>10} [{bar:40}] {bytes}/{total_bytes} ({bytes_per_sec}, {eta} left)",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
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
    let path = args.data.as_path();
    let progress = progress_bar(path);
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
    };
    let mut fitting = false;
    let fit = fit_file(path, &settings, |pass, bytes| {
        if pass == Pass::Fitting && !fitting {
            fitting = true;
            progress.set_message("fitting");
        }
        progress.inc(bytes);
    })?;
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
        "lambda": fit.params.lambda,
        "alpha": fit.params.alpha,
        "intercept": args.intercept,
        "auto": auto_json(args, fit),
    });
    println!("{report}");
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
    let input = if fit.shape.binary {
        "binary features, sparse path"
    } else {
        "real-valued features, dense path"
    };
    println!(
        "{}: {} rows, {} {input}, {} classes",
        args.data.display(),
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
    println!(
        "  selected features          {} of {} (0-based feature columns)",
        fit.selected.len(),
        fit.shape.features
    );
    if fit.selected.is_empty() && fit.standings.is_empty() {
        println!(
            "    none: no column's average gradient reached lambda x sqrt(K); \
             `--lambda auto --alpha auto` races smaller settings"
        );
    }
    for line in fit.selected.chunks(16) {
        let cols: Vec<String> = line.iter().map(usize::to_string).collect();
        println!("    {}", cols.join(" "));
    }
    println!(
        "  update throughput          {:.0} updates/s ({:.1} ms learning)",
        fit.updates_per_sec,
        fit.seconds * 1e3
    );
}
