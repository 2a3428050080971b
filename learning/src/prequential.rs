//! Prequential fitting of mDAGL over a labelled CSV stream: the engine of `tes fit`, usable
//! without the command line.
//!
//! The rows ([`labelled_csv`](crate::labelled_csv) format) are read twice. The first pass,
//! [`scan`], checks every row — so a bad row stops the run before anything is learned — and
//! learns the stream's [`Shape`]: row count, feature count, largest label, and whether every
//! feature is 0/1 (then mDAGL's fast sparse-binary input is used). The second pass, [`fit`],
//! feeds the rows in order, each predicted before it is learned from, and returns a
//! [`FitResult`]: the prequential mean log-loss and accuracy, the features kept, and the
//! update throughput. Rows are parsed in chunks and only the model's work is timed.
//! [`fit_file`] runs both passes over a file.
//!
//! Errors ([`FitError`]) name the file and line, with the same text `tes fit` prints. Progress
//! is reported through a callback given the bytes of each line read, so a caller can draw a
//! bar (or not) as it likes.
//!
//! ```
//! use std::path::Path;
//! use tes_learning::mdagl::MdaglParams;
//! use tes_learning::prequential::{FitSettings, fit, scan};
//!
//! // Label = feature 0; features 1 and 2 are noise (and the intercept learns the class
//! // balance, which otherwise they would).
//! let csv: String = (0..2000)
//!     .map(|i| format!("{},{},{},{}\n", i % 2, i % 2, (i / 2) % 2, (i / 4) % 2))
//!     .collect();
//! let name = Path::new("in-memory.csv");
//! let shape = scan(csv.as_bytes(), name, None, |_| {})?;
//! assert_eq!((shape.rows, shape.features, shape.max_label, shape.binary), (2000, 3, 1, true));
//!
//! let settings = FitSettings {
//!     params: MdaglParams { intercept: true, ..MdaglParams::default() },
//!     ..FitSettings::default()
//! };
//! let result = fit(csv.as_bytes(), name, &shape, &settings, |_| {})?;
//! assert_eq!(result.classes, 2);
//! assert!(result.accuracy > 0.95, "{}", result.accuracy);
//! assert_eq!(result.selected, [0]);
//! # Ok::<(), tes_learning::prequential::FitError>(())
//! ```

use std::fs::File;
use std::io::{self, BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use thiserror::Error;

use crate::labelled_csv::{RowError, is_blank, parse_row, row_text};
use crate::mdagl::{Features, Mdagl, MdaglConfigError, MdaglError, MdaglParams, Prequential};
use crate::tuning::{MdaglRace, RaceSchedule, Standing, auto_grid};

/// Rows parsed before each timed batch of updates.
const CHUNK_ROWS: usize = 4096;

/// What the first pass ([`scan`]) learns about a stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    /// Rows (non-blank lines).
    pub rows: u64,
    /// Features per row (columns after the label).
    pub features: usize,
    /// The largest label seen.
    pub max_label: usize,
    /// Whether every feature value is 0 or 1 (then the sparse-binary input is used).
    pub binary: bool,
}

/// How to fit: mDAGL's hyper-parameters and the class count.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FitSettings {
    /// λ, α and the intercept switch (`--lambda`, `--alpha`, `--intercept`); a λ or α chosen
    /// by `auto` is ignored here.
    pub params: MdaglParams,
    /// `--lambda auto`: race the λ values of [`AUTO_LAMBDAS`](crate::tuning::AUTO_LAMBDAS).
    pub auto_lambda: bool,
    /// `--alpha auto`: race the α values of [`AUTO_ALPHAS`](crate::tuning::AUTO_ALPHAS).
    pub auto_alpha: bool,
    /// Number of classes K (`--classes`); `None` for the largest label + 1. With `Some(k)`,
    /// [`scan`] refuses a label ≥ `k`.
    pub classes: Option<usize>,
}

/// What a fit found: the prequential figures and the features kept.
#[derive(Debug, Clone, PartialEq)]
pub struct FitResult {
    /// The stream's shape, from the first pass (`shape.rows` rows were learned).
    pub shape: Shape,
    /// Classes of the model.
    pub classes: usize,
    /// Mean of `−log p(label)` over the rows, each predicted before it was learned, in nats.
    pub mean_log_loss: f64,
    /// Share of rows whose most likely class, predicted before learning, was the label.
    pub accuracy: f64,
    /// The selected features (0-based feature columns, the label not counted), increasing.
    pub selected: Vec<usize>,
    /// The setting of the model reported: the one asked for, or the race's winner.
    pub params: MdaglParams,
    /// With `auto`, every raced setting's standing, best first (the winner, then the
    /// runner-up, …); empty for a fixed setting.
    pub standings: Vec<Standing>,
    /// Rows learned per second of the model's work (0 when too quick to measure).
    pub updates_per_sec: f64,
    /// Seconds spent in the model's work (predicting and learning; not reading or parsing).
    pub seconds: f64,
}

/// Which pass a [`fit_file`] progress report belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pass {
    /// The first pass, [`scan`].
    Checking,
    /// The second pass, [`fit`].
    Fitting,
}

/// Why a fit stopped. The messages are those `tes fit` prints (the source, if any, follows
/// after `": "`).
#[derive(Debug, Error)]
pub enum FitError {
    /// The file could not be opened.
    #[error("cannot open {}", path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// Reading a line failed.
    #[error("{}:{line}: cannot read the line", path.display())]
    Read {
        /// The file (or stream name).
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// A line is not a row.
    #[error("{}:{line}: malformed row", path.display())]
    Malformed {
        /// The file (or stream name).
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// What is wrong with it.
        #[source]
        source: RowError,
    },
    /// A label is not below the class count asked for ([`FitSettings::classes`]).
    #[error(
        "{}:{line}: label {label} is out of range for --classes {classes} ({})",
        path.display(),
        label_range(*classes)
    )]
    LabelOutOfRange {
        /// The file (or stream name).
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// The row's label.
        label: usize,
        /// The class count asked for.
        classes: usize,
    },
    /// A row has a different number of features than the first.
    #[error(
        "{}:{line}: expected {} columns (label + {expected} features) like the first row, found {}",
        path.display(),
        expected + 1,
        found + 1
    )]
    WrongWidth {
        /// The file (or stream name).
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// The first row's feature count.
        expected: usize,
        /// This row's feature count.
        found: usize,
    },
    /// Only blank lines.
    #[error("{}: no rows to learn from", path.display())]
    NoRows {
        /// The file (or stream name).
        path: PathBuf,
    },
    /// Fewer than two classes: every label is 0 and no larger class count was asked for.
    #[error(
        "{}: every row has label 0, and a classifier needs at least 2 classes (pass --classes K)",
        path.display()
    )]
    OneClass {
        /// The file (or stream name).
        path: PathBuf,
    },
    /// The model could not be built (bad λ or α, too many weights, …).
    #[error("cannot build an mDAGL model for {classes} classes and {features} features")]
    Model {
        /// Classes asked for.
        classes: usize,
        /// Features of the stream.
        features: usize,
        /// Why.
        #[source]
        source: MdaglConfigError,
    },
    /// The model refused a row.
    #[error("row {row} could not be learned")]
    Update {
        /// 1-based row number (blank lines not counted).
        row: u64,
        /// Why.
        #[source]
        source: MdaglError,
    },
    /// The second pass did not see the rows the first did.
    #[error(
        "{}: the file changed while it was read ({before} rows, then {after})",
        path.display()
    )]
    Changed {
        /// The file (or stream name).
        path: PathBuf,
        /// Rows in the first pass.
        before: u64,
        /// Rows in the second pass.
        after: u64,
    },
}

/// The labels `--classes k` allows, for [`FitError::LabelOutOfRange`].
fn label_range(classes: usize) -> String {
    match classes.checked_sub(1) {
        Some(last) => format!("labels are 0..{last}"),
        None => "there are no labels".to_owned(),
    }
}

/// Opens a file for [`scan`] or [`fit`], buffered.
pub fn open(path: &Path) -> Result<BufReader<File>, FitError> {
    let file = File::open(path).map_err(|source| FitError::Open {
        path: path.to_owned(),
        source,
    })?;
    Ok(BufReader::with_capacity(1 << 16, file))
}

/// Calls `row(line_number, label, features)` for every non-blank line of `reader`, stopping at
/// the first malformed one with an error naming it (`name` is the file named in errors), or
/// at the first error `row` returns. `progress` is given the length in bytes of each line read.
pub fn for_each_row<E: From<FitError>>(
    mut reader: impl BufRead,
    name: &Path,
    mut progress: impl FnMut(u64),
    mut row: impl FnMut(u64, usize, &[f64]) -> Result<(), E>,
) -> Result<(), E> {
    // Lines are read as bytes, so that one that is not UTF-8 text is a malformed row naming
    // the byte, not an I/O error.
    let mut bytes = Vec::new();
    let mut features = Vec::new();
    let mut number = 0u64;
    loop {
        bytes.clear();
        let read = reader
            .read_until(b'\n', &mut bytes)
            .map_err(|source| FitError::Read {
                path: name.to_owned(),
                line: number + 1,
                source,
            })?;
        if read == 0 {
            return Ok(());
        }
        number += 1;
        progress(read as u64);
        let malformed = |source| FitError::Malformed {
            path: name.to_owned(),
            line: number,
            source,
        };
        let line = row_text(&bytes).map_err(malformed)?;
        if is_blank(line) {
            continue;
        }
        let label = parse_row(line, &mut features).map_err(malformed)?;
        row(number, label, &features)?;
    }
}

/// The first pass: checks every row of `reader` and learns the stream's [`Shape`].
///
/// With `classes` given, a label ≥ `classes` is an error. `name` is the file named in errors;
/// `progress` is given the length in bytes of each line read.
pub fn scan(
    reader: impl BufRead,
    name: &Path,
    classes: Option<usize>,
    progress: impl FnMut(u64),
) -> Result<Shape, FitError> {
    let mut shape: Option<Shape> = None;
    for_each_row(reader, name, progress, |line, label, x| {
        if let Some(k) = classes
            && label >= k
        {
            return Err(FitError::LabelOutOfRange {
                path: name.to_owned(),
                line,
                label,
                classes: k,
            });
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
                    return Err(FitError::WrongWidth {
                        path: name.to_owned(),
                        line,
                        expected: s.features,
                        found: x.len(),
                    });
                }
                s.rows += 1;
                s.max_label = s.max_label.max(label);
                s.binary &= binary;
            }
        }
        Ok(())
    })?;
    shape.ok_or_else(|| FitError::NoRows {
        path: name.to_owned(),
    })
}

/// The prequential record of one pass.
#[derive(Debug, Default)]
struct Tally {
    rows: u64,
    log_loss: f64,
    correct: u64,
    updating: Duration,
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
    fn learn(&mut self, model: &mut Learner, tally: &mut Tally) -> Result<(), FitError> {
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
            let pre = model.update(x, label).map_err(|source| FitError::Update {
                row: tally.rows + 1,
                source,
            })?;
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

/// What a fit learns with: one model, or a race of settings (`auto`).
enum Learner {
    /// A fixed setting.
    Fixed(Mdagl),
    /// A race of settings; its leader predicts.
    Race(MdaglRace),
}

impl Learner {
    fn update(&mut self, x: Features<'_>, label: usize) -> Result<Prequential, MdaglError> {
        match self {
            Learner::Fixed(model) => model.update(x, label),
            Learner::Race(race) => race.update(x, label),
        }
    }

    /// The model reported, and the race's standings (none for a fixed setting).
    fn finish(self) -> (Mdagl, Vec<Standing>) {
        match self {
            Learner::Fixed(model) => (model, Vec::new()),
            Learner::Race(race) => {
                let standings = race.standings();
                (race.into_model(), standings)
            }
        }
    }
}

/// What a fit learns with: `settings.classes` classes (else the largest label + 1), one model
/// or, with `auto`, a race of settings.
fn build_learner(
    name: &Path,
    shape: &Shape,
    settings: &FitSettings,
) -> Result<(Learner, usize), FitError> {
    let classes = settings.classes.unwrap_or(shape.max_label + 1);
    if classes < 2 {
        return Err(FitError::OneClass {
            path: name.to_owned(),
        });
    }
    let model_error = |source| FitError::Model {
        classes,
        features: shape.features,
        source,
    };
    let p = settings.params;
    let learner = if settings.auto_lambda || settings.auto_alpha {
        let grid = auto_grid(
            (!settings.auto_lambda).then_some(p.lambda),
            (!settings.auto_alpha).then_some(p.alpha),
            p.intercept,
        );
        let race = MdaglRace::new(classes, shape.features, &grid, RaceSchedule::default())
            .map_err(model_error)?;
        Learner::Race(race)
    } else {
        Learner::Fixed(Mdagl::new(classes, shape.features, p).map_err(model_error)?)
    };
    Ok((learner, classes))
}

/// The second pass: runs mDAGL over the rows of `reader` in order, predicting each before
/// learning it.
///
/// `shape` is what [`scan`] found in the same rows; a different row count is
/// [`FitError::Changed`]. `name` is the file named in errors; `progress` is given the length
/// in bytes of each line read.
pub fn fit(
    reader: impl BufRead,
    name: &Path,
    shape: &Shape,
    settings: &FitSettings,
    progress: impl FnMut(u64),
) -> Result<FitResult, FitError> {
    let (mut model, classes) = build_learner(name, shape, settings)?;
    let mut tally = Tally::default();
    let mut chunk = Chunk::new(shape.features, shape.binary);
    for_each_row(reader, name, progress, |_, label, x| {
        chunk.push(label, x);
        if chunk.is_full() {
            chunk.learn(&mut model, &mut tally)?;
        }
        Ok::<_, FitError>(())
    })?;
    chunk.learn(&mut model, &mut tally)?;
    if tally.rows != shape.rows {
        return Err(FitError::Changed {
            path: name.to_owned(),
            before: shape.rows,
            after: tally.rows,
        });
    }
    let n = tally.rows as f64;
    let seconds = tally.updating.as_secs_f64();
    let (model, standings) = model.finish();
    Ok(FitResult {
        shape: *shape,
        classes,
        mean_log_loss: tally.log_loss / n,
        accuracy: tally.correct as f64 / n,
        selected: model.selected_features().collect(),
        params: model.params(),
        standings,
        updates_per_sec: if seconds > 0.0 { n / seconds } else { 0.0 },
        seconds,
    })
}

/// Both passes over a file: [`scan`], then [`fit`] — what `tes fit FILE` runs.
///
/// `progress` is given the pass and the length in bytes of each line read (each pass reads
/// the whole file, so the total is twice its size).
///
/// ```
/// use std::io::Write;
/// use tes_learning::mdagl::MdaglParams;
/// use tes_learning::prequential::{FitSettings, fit_file};
///
/// let mut file = tempfile::NamedTempFile::new()?;
/// for i in 0..1000 {
///     // Label = feature 1; feature 0 is noise.
///     writeln!(file, "{},{},{}", i % 2, (i / 2) % 2, i % 2)?;
/// }
/// let mut bytes = 0;
/// let settings = FitSettings {
///     params: MdaglParams { intercept: true, ..MdaglParams::default() },
///     classes: Some(2),
///     ..FitSettings::default()
/// };
/// let result = fit_file(file.path(), &settings, |_, n| bytes += n)?;
/// assert_eq!((result.shape.rows, result.classes), (1000, 2));
/// assert_eq!(result.selected, [1]);
/// assert_eq!(bytes, 2 * file.as_file().metadata()?.len());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn fit_file(
    path: &Path,
    settings: &FitSettings,
    mut progress: impl FnMut(Pass, u64),
) -> Result<FitResult, FitError> {
    let shape = scan(open(path)?, path, settings.classes, |n| {
        progress(Pass::Checking, n)
    })?;
    fit(open(path)?, path, &shape, settings, |n| {
        progress(Pass::Fitting, n)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn name() -> &'static Path {
        Path::new("t.csv")
    }

    fn scan_str(csv: &str, classes: Option<usize>) -> Result<Shape, FitError> {
        scan(csv.as_bytes(), name(), classes, |_| {})
    }

    /// The error's message with its sources, as `tes fit` prints it.
    fn chain(err: &FitError) -> String {
        let mut text = err.to_string();
        let mut source = std::error::Error::source(err);
        while let Some(s) = source {
            text.push_str(&format!(": {s}"));
            source = s.source();
        }
        text
    }

    #[test]
    fn scan_learns_the_shape_skipping_blank_lines() {
        let shape = scan_str("0,1,0\n\n  \n2,0,1\r\n1,1,1", None).unwrap();
        assert_eq!(
            shape,
            Shape {
                rows: 3,
                features: 2,
                max_label: 2,
                binary: true
            }
        );
        assert!(!scan_str("0,1,0\n1,0.5,1\n", None).unwrap().binary);
    }

    #[test]
    fn errors_name_the_line_as_tes_fit_prints_them() {
        let cases = [
            (
                scan_str("0,1,0\n1,x,1\n", None),
                r#"t.csv:2: malformed row: column 2: "x" is not a number"#,
            ),
            (
                scan_str("0,1,0\n3,0,1\n", Some(2)),
                "t.csv:2: label 3 is out of range for --classes 2 (labels are 0..1)",
            ),
            (
                scan_str("0,1\n", Some(0)),
                "t.csv:1: label 0 is out of range for --classes 0 (there are no labels)",
            ),
            (
                scan_str("0,1,0\n1,0\n", None),
                "t.csv:2: expected 3 columns (label + 2 features) like the first row, found 2",
            ),
            (scan_str("\n \n", None), "t.csv: no rows to learn from"),
            (
                scan(&b"0,1\n1,\xff\n"[..], name(), None, |_| {}),
                "t.csv:2: malformed row: byte 0xFF at position 3 is not UTF-8 text (is this a CSV file?)",
            ),
        ];
        for (result, expected) in cases {
            assert_eq!(chain(&result.unwrap_err()), expected);
        }
        let missing = Path::new("/nonexistent/missing.csv");
        let err = fit_file(missing, &FitSettings::default(), |_, _| {}).unwrap_err();
        assert!(
            chain(&err).starts_with("cannot open /nonexistent/missing.csv: "),
            "{err}"
        );
    }

    #[test]
    fn fit_refuses_one_class_bad_settings_and_a_changed_stream() {
        let csv = "0,1\n0,0\n";
        let shape = scan_str(csv, None).unwrap();
        let run = |csv: &str, settings: &FitSettings| {
            fit(csv.as_bytes(), name(), &shape, settings, |_| {}).map_err(|e| chain(&e))
        };
        assert_eq!(
            run(csv, &FitSettings::default()).unwrap_err(),
            "t.csv: every row has label 0, and a classifier needs at least 2 classes (pass --classes K)"
        );
        let mut settings = FitSettings {
            classes: Some(2),
            ..FitSettings::default()
        };
        settings.params.lambda = -1.0;
        assert_eq!(
            run(csv, &settings).unwrap_err(),
            "cannot build an mDAGL model for 2 classes and 1 features: lambda must be a finite number >= 0, got -1"
        );
        settings.params.lambda = 0.05;
        assert_eq!(run(csv, &settings).unwrap().shape.rows, 2);
        assert_eq!(
            run("0,1\n0,0\n1,1\n", &settings).unwrap_err(),
            "t.csv: the file changed while it was read (2 rows, then 3)"
        );
    }

    /// `auto` races the grid and reports the winner's setting and every standing; a fixed
    /// λ with `--alpha auto` races α alone.
    #[test]
    fn auto_reports_the_winning_setting_and_the_standings() {
        // The class is feature 0, on in one row of 25: the paper's λ keeps nothing.
        let csv: String = (0..20_000)
            .map(|i| {
                let on = i % 25 == 0;
                format!("{},{},{}\n", u8::from(on), u8::from(on), (i / 2) % 2)
            })
            .collect();
        let shape = scan_str(&csv, None).unwrap();
        let mut settings = FitSettings {
            auto_lambda: true,
            auto_alpha: true,
            ..FitSettings::default()
        };
        settings.params.intercept = true;
        let raced = fit(csv.as_bytes(), name(), &shape, &settings, |_| {}).unwrap();
        assert_eq!(raced.standings.len(), 15);
        assert_eq!(raced.standings[0].params, raced.params);
        assert!(raced.params.lambda < 0.05, "{:?}", raced.params);
        assert_eq!(raced.selected, [0]);
        let paper = FitSettings {
            params: settings.params,
            ..FitSettings::default()
        };
        let fixed = fit(csv.as_bytes(), name(), &shape, &paper, |_| {}).unwrap();
        assert!(fixed.standings.is_empty() && fixed.selected.is_empty());
        assert!(raced.mean_log_loss < fixed.mean_log_loss);
        settings.auto_lambda = false;
        let alphas = fit(csv.as_bytes(), name(), &shape, &settings, |_| {}).unwrap();
        assert_eq!(alphas.standings.len(), 3);
        assert!(alphas.standings.iter().all(|s| s.params.lambda == 0.05));
    }

    #[test]
    fn chunks_learn_every_row_in_order_in_both_input_forms() {
        // More rows than a chunk, so a full chunk and a partial one are learned.
        let rows = CHUNK_ROWS + 123;
        let binary: String = (0..rows)
            .map(|i| format!("{},{},{}\n", i % 2, i % 2, (i / 3) % 2))
            .collect();
        // The same stream with a non-binary constant column: the dense path.
        let dense: String = (0..rows)
            .map(|i| format!("{},{},{},0.5\n", i % 2, i % 2, (i / 3) % 2))
            .collect();
        let settings = FitSettings::default();
        let mut results = Vec::new();
        for csv in [&binary, &dense] {
            let mut read = 0;
            let shape = scan(csv.as_bytes(), name(), None, |n| read += n).unwrap();
            let result = fit(csv.as_bytes(), name(), &shape, &settings, |n| read += n).unwrap();
            assert_eq!(read, 2 * csv.len() as u64);
            assert_eq!((result.shape.rows, result.classes), (rows as u64, 2));
            assert!(result.accuracy > 0.95, "{}", result.accuracy);
            assert!(result.mean_log_loss > 0.0 && result.mean_log_loss < 2f64.ln());
            assert!(result.seconds >= 0.0 && result.updates_per_sec >= 0.0);
            results.push(result);
        }
        assert!(results[0].shape.binary && !results[1].shape.binary);
        assert_eq!(results[0].selected, [0]);
        assert!(results[1].selected.starts_with(&[0]), "{:?}", results[1]);
    }
}
