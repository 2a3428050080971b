//! `tes fit`: mDAGL over a labelled CSV stream, prequentially.
//!
//! The file is read twice: a first pass checks every row (so a bad row stops the run before
//! anything is reported) and learns the shape — row count, feature count, class count, and
//! whether every feature is 0/1 (then the fast sparse-binary path is used); the second pass
//! feeds the rows in order, each predicted before it is learned from. Rows are parsed in
//! chunks and only the model's work is timed for the throughput figure.

use std::fs::File;
use std::io::{BufRead, BufReader, IsTerminal};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tes_learning::labelled_csv::{is_blank, parse_row, row_text};
use tes_learning::mdagl::{Features, Mdagl, MdaglParams};

/// Rows parsed before each timed batch of updates.
const CHUNK_ROWS: usize = 4096;

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

/// What the first pass learns about the file.
#[derive(Debug)]
struct Shape {
    rows: u64,
    features: usize,
    max_label: usize,
    binary: bool,
}

/// The prequential record of one pass.
#[derive(Debug, Default)]
struct Tally {
    rows: u64,
    log_loss: f64,
    correct: u64,
    updating: Duration,
}

fn open(path: &Path) -> Result<BufReader<File>> {
    let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    Ok(BufReader::with_capacity(1 << 16, file))
}

/// Calls `row(line_number, label, features)` for every non-blank line, stopping at the first
/// malformed one with an error naming it.
fn for_each_row(
    path: &Path,
    progress: &ProgressBar,
    mut row: impl FnMut(u64, usize, &[f64]) -> Result<()>,
) -> Result<()> {
    let mut reader = open(path)?;
    // Lines are read as bytes, so that one that is not UTF-8 text is a malformed row naming
    // the byte, not an I/O error.
    let mut bytes = Vec::new();
    let mut features = Vec::new();
    let mut number = 0u64;
    loop {
        bytes.clear();
        let read = reader
            .read_until(b'\n', &mut bytes)
            .with_context(|| format!("{}:{}: cannot read the line", path.display(), number + 1))?;
        if read == 0 {
            return Ok(());
        }
        number += 1;
        progress.inc(read as u64);
        let malformed = || format!("{}:{number}: malformed row", path.display());
        let line = row_text(&bytes).with_context(malformed)?;
        if is_blank(line) {
            continue;
        }
        let label = parse_row(line, &mut features).with_context(malformed)?;
        row(number, label, &features)?;
    }
}

fn scan(path: &Path, classes: Option<usize>, progress: &ProgressBar) -> Result<Shape> {
    let mut shape: Option<Shape> = None;
    for_each_row(path, progress, |number, label, x| {
        if let Some(k) = classes
            && label >= k
        {
            bail!(
                "{}:{number}: label {label} is out of range for --classes {k} (labels are 0..{})",
                path.display(),
                k - 1
            );
        }
        let binary = x.iter().all(|&v| v == 0.0 || v == 1.0);
        match &mut shape {
            None => {
                shape = Some(Shape {
                    rows: 1,
                    features: x.len(),
                    max_label: label,
                    binary,
                })
            }
            Some(s) => {
                if x.len() != s.features {
                    bail!(
                        "{}:{number}: expected {} columns (label + {} features) like the first row, found {}",
                        path.display(),
                        s.features + 1,
                        s.features,
                        x.len() + 1
                    );
                }
                s.rows += 1;
                s.max_label = s.max_label.max(label);
                s.binary &= binary;
            }
        }
        Ok(())
    })?;
    shape.with_context(|| format!("{}: no rows to learn from", path.display()))
}

/// Rows parsed ahead of a timed batch of updates, in either input form.
struct Chunk {
    labels: Vec<usize>,
    dense: Vec<f64>,
    sparse: Vec<u32>,
    sparse_ends: Vec<usize>,
    width: usize,
    binary: bool,
}

impl Chunk {
    fn new(width: usize, binary: bool) -> Self {
        Self {
            labels: Vec::with_capacity(CHUNK_ROWS),
            dense: Vec::with_capacity(if binary { 0 } else { CHUNK_ROWS * width }),
            sparse: Vec::new(),
            sparse_ends: Vec::with_capacity(CHUNK_ROWS),
            width,
            binary,
        }
    }

    fn push(&mut self, label: usize, x: &[f64]) {
        self.labels.push(label);
        if self.binary {
            self.sparse.extend(
                x.iter()
                    .enumerate()
                    .filter(|(_, v)| **v != 0.0)
                    .map(|(i, _)| i as u32),
            );
            self.sparse_ends.push(self.sparse.len());
        } else {
            self.dense.extend_from_slice(x);
        }
    }

    fn is_full(&self) -> bool {
        self.labels.len() >= CHUNK_ROWS
    }

    /// Predicts then learns every row, timing only the model's work.
    fn learn(&mut self, model: &mut Mdagl, tally: &mut Tally) -> Result<()> {
        let start = Instant::now();
        let mut begin = 0;
        for (i, &label) in self.labels.iter().enumerate() {
            let x = if self.binary {
                let end = self.sparse_ends[i];
                let x = Features::SparseBinary(&self.sparse[begin..end]);
                begin = end;
                x
            } else {
                Features::Dense(&self.dense[i * self.width..(i + 1) * self.width])
            };
            let pre = model
                .update(x, label)
                .with_context(|| format!("row {} could not be learned", tally.rows + 1))?;
            tally.rows += 1;
            tally.log_loss -= pre.log_prob;
            tally.correct += u64::from(pre.predicted == label);
        }
        tally.updating += start.elapsed();
        self.labels.clear();
        self.dense.clear();
        self.sparse.clear();
        self.sparse_ends.clear();
        Ok(())
    }
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

/// Runs `tes fit`.
pub fn run(args: &FitArgs) -> Result<()> {
    let path = args.data.as_path();
    let progress = progress_bar(path);
    progress.set_message("checking");
    let shape = scan(path, args.classes, &progress)?;
    let classes = args.classes.unwrap_or(shape.max_label + 1);
    if classes < 2 {
        bail!(
            "{}: every row has label 0, and a classifier needs at least 2 classes (pass --classes K)",
            path.display()
        );
    }
    let params = MdaglParams {
        lambda: args.lambda,
        alpha: args.alpha,
        intercept: args.intercept,
    };
    let mut model = Mdagl::new(classes, shape.features, params).with_context(|| {
        format!(
            "cannot build an mDAGL model for {} classes and {} features",
            classes, shape.features
        )
    })?;

    progress.set_message("fitting");
    let mut tally = Tally::default();
    let mut chunk = Chunk::new(shape.features, shape.binary);
    for_each_row(path, &progress, |_, label, x| {
        chunk.push(label, x);
        if chunk.is_full() {
            chunk.learn(&mut model, &mut tally)?;
        }
        Ok(())
    })?;
    chunk.learn(&mut model, &mut tally)?;
    progress.finish_and_clear();
    if tally.rows != shape.rows {
        bail!(
            "{}: the file changed while it was read ({} rows, then {})",
            path.display(),
            shape.rows,
            tally.rows
        );
    }

    let n = tally.rows as f64;
    let mean_log_loss = tally.log_loss / n;
    let accuracy = tally.correct as f64 / n;
    let seconds = tally.updating.as_secs_f64();
    let updates_per_sec = if seconds > 0.0 { n / seconds } else { 0.0 };
    let selected: Vec<usize> = model.selected_features().collect();

    if args.json {
        let report = serde_json::json!({
            "n": tally.rows,
            "mean_logloss": mean_log_loss,
            "accuracy": accuracy,
            "selected": selected,
            "updates_per_sec": updates_per_sec,
            "classes": classes,
            "features": shape.features,
            "binary": shape.binary,
            "lambda": args.lambda,
            "alpha": args.alpha,
            "intercept": args.intercept,
        });
        println!("{report}");
        return Ok(());
    }

    let input = if shape.binary {
        "binary features, sparse path"
    } else {
        "real-valued features, dense path"
    };
    println!(
        "{}: {} rows, {} {input}, {classes} classes",
        path.display(),
        tally.rows,
        shape.features
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
        "  prequential mean log-loss  {mean_log_loss:.4} nats   (uniform guess: {:.4})",
        (classes as f64).ln()
    );
    println!("  prequential accuracy       {:.2} %", 100.0 * accuracy);
    println!(
        "  selected features          {} of {} (0-based feature columns)",
        selected.len(),
        shape.features
    );
    for line in selected.chunks(16) {
        let cols: Vec<String> = line.iter().map(usize::to_string).collect();
        println!("    {}", cols.join(" "));
    }
    println!(
        "  update throughput          {:.0} updates/s ({:.1} ms learning)",
        updates_per_sec,
        seconds * 1e3
    );
    Ok(())
}
