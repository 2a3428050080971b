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
use tes_learning::prequential::report::{self, Asked, Hyper};
use tes_learning::prequential::{FitSettings, Pass, RowFormat, fit_file, fit_stream, is_gzip};

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
    #[arg(long, default_value_t = Hyper::Value(MdaglParams::default().lambda))]
    lambda: Hyper,
    /// Step-size scale α of β_t = α√t (smaller learns faster), or `auto`: race α = 1.5 (the
    /// paper's), 0.3 and 0.05.
    #[arg(long, default_value_t = Hyper::Value(MdaglParams::default().alpha))]
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
    let asked = Asked {
        lambda: args.lambda,
        alpha: args.alpha,
        intercept: args.intercept,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report::summary(&fit, asked))?);
    } else {
        print!("{}", report::text(&fit, &input_name(args), asked));
    }
    Ok(())
}
