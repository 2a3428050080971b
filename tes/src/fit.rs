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
    /// Group-lasso strength λ (larger keeps fewer features).
    #[arg(long, default_value_t = 0.05)]
    lambda: f64,
    /// Step-size scale α of β_t = α√t (smaller learns faster).
    #[arg(long, default_value_t = 1.5)]
    alpha: f64,
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

/// Runs `tes fit`: the file checked, mDAGL run over it once, the report printed.
pub fn run(args: &FitArgs) -> Result<()> {
    let path = args.data.as_path();
    let progress = progress_bar(path);
    progress.set_message("checking");
    let settings = FitSettings {
        params: MdaglParams {
            lambda: args.lambda,
            alpha: args.alpha,
            intercept: args.intercept,
        },
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
        "lambda": args.lambda,
        "alpha": args.alpha,
        "intercept": args.intercept,
    });
    println!("{report}");
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
        args.lambda,
        args.alpha,
        if args.intercept {
            "with intercept"
        } else {
            "no intercept"
        }
    );
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
