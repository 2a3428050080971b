//! Prequential fitting of mDAGL over a labelled stream: the engine of `tes fit`, usable
//! without the command line.
//!
//! The rows are CSV ([`labelled_csv`](crate::labelled_csv), with or without a header line
//! naming the columns) or sparse, libsvm or Vowpal Wabbit style
//! ([`labelled_sparse`](crate::labelled_sparse)); the first row tells which
//! ([`RowFormat::detect`]), and a file that starts as a gzip file does is decompressed. They
//! are read twice. The first pass, [`scan`], checks every row — so a bad row stops the run
//! before anything is learned — and learns the stream's [`Shape`]: row count, feature count,
//! largest label, and whether every feature is 0/1 (then mDAGL's fast sparse-binary input is
//! used). The second pass, [`fit`], feeds the rows in order, each predicted before it is
//! learned from, and returns a [`FitResult`]: the prequential mean log-loss and accuracy, the
//! features kept, and the update throughput. Rows are parsed in chunks and only the model's
//! work is timed. [`fit_file`] runs both passes over a file, [`fit_stream`] over a stream
//! that can be read only once (standard input).
//!
//! What a stream can make it hold is bounded: a file must be a regular file (a FIFO or a
//! device such as `/dev/zero` is refused before a byte is read), a line longer than
//! [`MAX_LINE_BYTES`] is refused, a gzip stream that inflates past [`INFLATION_BOUND`] is
//! refused as a likely decompression bomb, and the buffers grow with the rows read — a batch
//! holds at most 4 096 rows and 2^22 values — never with the width a row claims.
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
//! let settings = FitSettings {
//!     params: MdaglParams { intercept: true, ..MdaglParams::default() },
//!     ..FitSettings::default()
//! };
//! let shape = scan(csv.as_bytes(), name, &settings, |_| {})?;
//! assert_eq!((shape.rows, shape.features, shape.max_label, shape.binary), (2000, 3, 1, true));
//!
//! let result = fit(csv.as_bytes(), name, &shape, &settings, |_| {})?;
//! assert_eq!(result.classes, 2);
//! assert!(result.accuracy > 0.95, "{}", result.accuracy);
//! assert_eq!(result.selected, [0]);
//! # Ok::<(), tes_learning::prequential::FitError>(())
//! ```

use std::io::{self, BufRead, BufReader, Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use flate2::read::MultiGzDecoder;
use tes_files::{FileProblem, InflationBound, InflationGuard};
use thiserror::Error;

use crate::labelled_csv::{RowError, header_names, is_blank, parse_row, row_text};
use crate::labelled_sparse::parse_sparse_row;
use crate::mdagl::{Features, Mdagl, MdaglConfigError, MdaglError, MdaglParams, Prequential};
use crate::tuning::{MdaglRace, RaceSchedule, Standing, auto_grid};

pub mod report;

/// Rows parsed before each timed batch of updates, at most.
const CHUNK_ROWS: usize = 4096;

/// Feature values (dense) or non-zero entries (sparse) held by a batch, at most: a batch of
/// wide rows ends sooner, so its buffers stay within 32 MiB whatever the rows' width.
const CHUNK_VALUES: usize = 1 << 22;

/// The longest line read, in bytes. The widest model ([`crate::mdagl::MAX_WEIGHTS`] weights,
/// two classes) has 2^23 features, written in 16 MiB as CSV of 0s and 1s; a line with no
/// newline in 64 MiB (`/dev/zero` on standard input, a sparse file, a bomb that inflates to
/// one line) is refused instead of being held whole.
pub const MAX_LINE_BYTES: usize = 64 << 20;

/// How far a gzip-compressed stream may inflate: 256 MiB, plus 200 bytes per compressed
/// byte read. Rows of real data compress some 3 to 30 to 1; a decompression bomb (deflate
/// reaches 1032 to 1) is refused once its output passes the bound.
pub const INFLATION_BOUND: InflationBound = InflationBound {
    allowance: 256 << 20,
    ratio: 200,
};

/// How a stream's rows are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowFormat {
    /// `label,x1,…,xd` ([`labelled_csv`](crate::labelled_csv)), optionally under a header line
    /// that names the columns.
    Csv,
    /// `label column:value …`, libsvm or Vowpal Wabbit style
    /// ([`labelled_sparse`](crate::labelled_sparse)).
    Sparse,
}

impl RowFormat {
    /// The format a line is written in: sparse when it has a `column:value` feature or a `|`,
    /// CSV when it has a comma, and `None` when it could be either (a label alone).
    pub fn detect(line: &str) -> Option<Self> {
        if line.contains([':', '|']) {
            Some(RowFormat::Sparse)
        } else if line.contains(',') {
            Some(RowFormat::Csv)
        } else {
            None
        }
    }
}

/// What the first pass ([`scan`]) learns about a stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Shape {
    /// Rows (non-blank lines, the header not counted).
    pub rows: u64,
    /// Features per row: the columns after the label, or for sparse rows the largest column
    /// used + 1.
    pub features: usize,
    /// The largest label seen.
    pub max_label: usize,
    /// Whether every feature value is 0 or 1 (then the sparse-binary input is used).
    pub binary: bool,
    /// How the rows are written.
    pub format: RowFormat,
    /// The header's names for the features, in column order; empty without a header.
    pub names: Vec<String>,
}

impl Shape {
    /// Feature `column`'s name from the header, or its number.
    pub fn feature_name(&self, column: usize) -> String {
        self.names
            .get(column)
            .cloned()
            .unwrap_or_else(|| column.to_string())
    }
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
    /// How the rows are written (`--format`); `None` to tell from the first row
    /// ([`RowFormat::detect`]).
    pub format: Option<RowFormat>,
    /// Threads a race's settings learn on (`--threads`); 0 for one per core the machine
    /// gives this process. The fit is the same to the bit on any number.
    pub threads: usize,
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
    /// A stream that can be read only once (standard input) could not be kept for the
    /// second pass.
    #[error("cannot keep a copy of {} for the second pass", path.display())]
    Spool {
        /// The stream's name.
        path: PathBuf,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// The file could not be opened: missing, unreadable, or not a regular file (a FIFO, a
    /// device such as `/dev/zero`, a directory), which is refused without reading from it.
    #[error("cannot open {}", path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: FileProblem,
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
    /// The first row has a different number of features than the header names.
    #[error(
        "{}:{line}: the header names {} columns (label + {names} features) but the first row has {}",
        path.display(),
        names + 1,
        found + 1
    )]
    HeaderWidth {
        /// The file (or stream name).
        path: PathBuf,
        /// 1-based line number of the first row.
        line: u64,
        /// Feature names in the header.
        names: usize,
        /// The first row's feature count.
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

/// A decoded stream: `reader`'s bytes, decompressed when they start as a gzip file does (up
/// to [`INFLATION_BOUND`]).
fn decoded<'a>(reader: impl Read + 'a) -> io::Result<Box<dyn BufRead + 'a>> {
    let mut buffered = BufReader::with_capacity(1 << 16, reader);
    let gzip = buffered.fill_buf()?.starts_with(&GZIP_MAGIC);
    Ok(if gzip {
        let inflated = InflationGuard::new(buffered, MultiGzDecoder::new, INFLATION_BOUND);
        Box::new(BufReader::with_capacity(1 << 16, inflated))
    } else {
        Box::new(buffered)
    })
}

/// The first two bytes of every gzip file.
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// Opens a file for [`scan`] or [`fit`], buffered, and decompressed if it is gzip-compressed
/// (told by its first bytes, not its name). Anything but a regular file is refused without
/// being read ([`tes_files::open_regular`]).
pub fn open(path: &Path) -> Result<Box<dyn BufRead>, FitError> {
    let open_error = |source: FileProblem| FitError::Open {
        path: path.to_owned(),
        source,
    };
    let file = tes_files::open_regular(path).map_err(open_error)?.file;
    decoded(file).map_err(|e| open_error(e.into()))
}

/// Whether the file at `path` is a regular file that is gzip-compressed (then its size says
/// little of its rows).
pub fn is_gzip(path: &Path) -> bool {
    let mut magic = [0u8; 2];
    tes_files::open_regular(path)
        .is_ok_and(|mut opened| opened.file.read_exact(&mut magic).is_ok() && magic == GZIP_MAGIC)
}

/// One row as read: its label and features, borrowed from the reader.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row<'a> {
    /// 1-based line number.
    pub line: u64,
    /// The class label.
    pub label: usize,
    /// The features.
    pub values: RowValues<'a>,
}

/// A row's features, as written.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RowValues<'a> {
    /// A CSV row: one value per column.
    Dense(&'a [f64]),
    /// A sparse row: the non-zero `(column, value)` pairs, columns increasing.
    Sparse(&'a [(u32, f64)]),
}

impl RowValues<'_> {
    /// Whether every value is 0 or 1.
    fn is_binary(&self) -> bool {
        match *self {
            RowValues::Dense(x) => x.iter().all(|&v| v == 0.0 || v == 1.0),
            RowValues::Sparse(x) => x.iter().all(|&(_, v)| v == 1.0),
        }
    }

    /// The feature count this row implies: its width, or its largest column + 1.
    fn width(&self) -> usize {
        match *self {
            RowValues::Dense(x) => x.len(),
            RowValues::Sparse(x) => x.last().map_or(0, |&(c, _)| c as usize + 1),
        }
    }
}

/// Reads the rows of a labelled stream one at a time: lines as bytes (so a line that is not
/// UTF-8 text is a malformed row naming the byte, not an I/O error), blank lines skipped, the
/// format told by the first row that tells ([`RowFormat::detect`]) unless given, and a CSV
/// header line kept as the column names.
pub struct RowReader<R> {
    reader: R,
    name: PathBuf,
    format: Option<RowFormat>,
    line: u64,
    bytes: Vec<u8>,
    dense: Vec<f64>,
    sparse: Vec<(u32, f64)>,
    names: Vec<String>,
    seen_row: bool,
}

impl<R: BufRead> RowReader<R> {
    /// A reader of `reader`'s rows; `name` is the file named in errors, `format` the rows'
    /// format, or `None` to tell it from the first row.
    pub fn new(reader: R, name: &Path, format: Option<RowFormat>) -> Self {
        Self {
            reader,
            name: name.to_owned(),
            format,
            line: 0,
            bytes: Vec::new(),
            dense: Vec::new(),
            sparse: Vec::new(),
            names: Vec::new(),
            seen_row: false,
        }
    }

    /// The next row, `None` at the end of the stream, or the first malformed line's error.
    /// `progress` is given the length in bytes of each line read.
    pub fn next_row(&mut self, mut progress: impl FnMut(u64)) -> Result<Option<Row<'_>>, FitError> {
        loop {
            self.bytes.clear();
            let read =
                tes_files::read_until_capped(&mut self.reader, &mut self.bytes, MAX_LINE_BYTES)
                    .map_err(|source| FitError::Read {
                        path: self.name.clone(),
                        line: self.line + 1,
                        source,
                    })?;
            if read == 0 {
                return Ok(None);
            }
            self.line += 1;
            progress(read as u64);
            let malformed = |source| FitError::Malformed {
                path: self.name.clone(),
                line: self.line,
                source,
            };
            let text = row_text(&self.bytes).map_err(malformed)?;
            if is_blank(text) {
                continue;
            }
            if self.format.is_none() {
                self.format = RowFormat::detect(text);
            }
            // A label alone reads the same in either format.
            let format = self.format.unwrap_or(RowFormat::Csv);
            if format == RowFormat::Csv
                && !self.seen_row
                && let Some(names) = header_names(text)
            {
                // The label's name is not a feature's.
                self.names = names.into_iter().skip(1).collect();
                self.seen_row = true;
                continue;
            }
            self.seen_row = true;
            let (label, values) = match format {
                RowFormat::Csv => (
                    parse_row(text, &mut self.dense).map_err(malformed)?,
                    RowValues::Dense(&self.dense),
                ),
                RowFormat::Sparse => (
                    parse_sparse_row(text, &mut self.sparse).map_err(malformed)?,
                    RowValues::Sparse(&self.sparse),
                ),
            };
            return Ok(Some(Row {
                line: self.line,
                label,
                values,
            }));
        }
    }

    /// The rows' format: as given, or as told by the first row that tells (`None` before
    /// one: no row yet, or only labels without features).
    pub fn format(&self) -> Option<RowFormat> {
        self.format
    }

    /// The header's feature names, once the header is read; empty without one.
    pub fn names(&self) -> &[String] {
        &self.names
    }
}

/// The first pass: checks every row of `reader` and learns the stream's [`Shape`].
///
/// With `settings.classes` given, a label ≥ it is an error. `name` is the file named in
/// errors; `progress` is given the length in bytes of each line read.
pub fn scan(
    reader: impl BufRead,
    name: &Path,
    settings: &FitSettings,
    mut progress: impl FnMut(u64),
) -> Result<Shape, FitError> {
    let mut rows = RowReader::new(reader, name, settings.format);
    let mut shape: Option<Shape> = None;
    while let Some(row) = rows.next_row(&mut progress)? {
        check_label(name, &row, settings.classes)?;
        let width = row.values.width();
        let binary = row.values.is_binary();
        let (line, label) = (row.line, row.label);
        // Labels alone read as CSV until a row tells the format.
        let dense = rows.format() != Some(RowFormat::Sparse);
        match &mut shape {
            None => {
                let names = rows.names().to_vec();
                if !names.is_empty() && names.len() != width {
                    return Err(FitError::HeaderWidth {
                        path: name.to_owned(),
                        line,
                        names: names.len(),
                        found: width,
                    });
                }
                shape = Some(Shape {
                    rows: 1,
                    features: width,
                    max_label: label,
                    binary,
                    format: RowFormat::Csv,
                    names,
                })
            }
            Some(s) => {
                if dense && width != s.features {
                    return Err(FitError::WrongWidth {
                        path: name.to_owned(),
                        line,
                        expected: s.features,
                        found: width,
                    });
                }
                s.rows += 1;
                s.features = s.features.max(width);
                s.max_label = s.max_label.max(label);
                s.binary &= binary;
            }
        }
    }
    let mut shape = shape.ok_or_else(|| FitError::NoRows {
        path: name.to_owned(),
    })?;
    shape.format = rows.format().unwrap_or(RowFormat::Csv);
    Ok(shape)
}

/// A label ≥ the class count asked for is an error naming its line.
fn check_label(name: &Path, row: &Row<'_>, classes: Option<usize>) -> Result<(), FitError> {
    match classes {
        Some(k) if row.label >= k => Err(FitError::LabelOutOfRange {
            path: name.to_owned(),
            line: row.line,
            label: row.label,
            classes: k,
        }),
        _ => Ok(()),
    }
}

/// The prequential record of one pass.
#[derive(Debug, Default)]
struct Tally {
    rows: u64,
    log_loss: f64,
    correct: u64,
    updating: Duration,
}

impl Tally {
    /// One more row, predicted as `pre`, whose label was `label`.
    fn count(&mut self, pre: Prequential, label: usize) {
        self.rows += 1;
        self.log_loss -= pre.log_prob;
        self.correct += u64::from(pre.predicted == label);
    }
}

/// How a chunk hands its rows to the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Input {
    /// One value per feature: real-valued CSV.
    Dense,
    /// The indices of the features that are 1: any stream whose values are all 0 or 1.
    SparseBinary,
    /// The non-zero `(column, value)` pairs: real-valued sparse rows.
    Sparse,
}

/// Rows parsed ahead of a timed batch of updates, in the model's input form.
struct Chunk {
    labels: Vec<usize>,
    dense: Vec<f64>,
    indices: Vec<u32>,
    values: Vec<f64>,
    ends: Vec<usize>,
    width: usize,
    input: Input,
}

impl Chunk {
    fn new(shape: &Shape) -> Self {
        let input = match (shape.binary, shape.format) {
            (true, _) => Input::SparseBinary,
            (false, RowFormat::Csv) => Input::Dense,
            (false, RowFormat::Sparse) => Input::Sparse,
        };
        // Sized by the rows pushed, not by the width the scan found: a few rows of a million
        // columns need a few million values, not a batch's worth.
        Self {
            labels: Vec::new(),
            dense: Vec::new(),
            indices: Vec::new(),
            values: Vec::new(),
            ends: Vec::new(),
            width: shape.features,
            input,
        }
    }

    fn push(&mut self, label: usize, x: RowValues<'_>) {
        self.labels.push(label);
        match (self.input, x) {
            (Input::Dense, RowValues::Dense(x)) => self.dense.extend_from_slice(x),
            (_, RowValues::Dense(x)) => {
                for (i, &v) in x.iter().enumerate().filter(|(_, v)| **v != 0.0) {
                    self.push_entry(i as u32, v);
                }
            }
            (_, RowValues::Sparse(x)) => {
                for &(i, v) in x {
                    self.push_entry(i, v);
                }
            }
        }
        self.ends.push(self.indices.len());
    }

    /// One non-zero feature; its value is kept only where the model reads it (the
    /// sparse-binary input knows every value is 1).
    fn push_entry(&mut self, index: u32, value: f64) {
        self.indices.push(index);
        if self.input == Input::Sparse {
            self.values.push(value);
        }
    }

    fn is_full(&self) -> bool {
        self.labels.len() >= CHUNK_ROWS || self.dense.len().max(self.indices.len()) >= CHUNK_VALUES
    }

    /// Row `i`'s features.
    fn features(&self, i: usize) -> Features<'_> {
        let begin = i.checked_sub(1).map_or(0, |before| self.ends[before]);
        let end = self.ends[i];
        match self.input {
            Input::Dense => Features::Dense(&self.dense[i * self.width..(i + 1) * self.width]),
            Input::SparseBinary => Features::SparseBinary(&self.indices[begin..end]),
            Input::Sparse => Features::Sparse {
                indices: &self.indices[begin..end],
                values: &self.values[begin..end],
            },
        }
    }

    /// Predicts then learns every row, timing only the model's work.
    fn learn(&mut self, model: &mut Learner, tally: &mut Tally) -> Result<(), FitError> {
        let start = Instant::now();
        let learned = match model {
            Learner::Fixed(model) => self.learn_fixed(model, tally),
            Learner::Race(race) => self.learn_raced(race, tally),
        };
        tally.updating += start.elapsed();
        learned?;
        self.labels.clear();
        self.dense.clear();
        self.indices.clear();
        self.values.clear();
        self.ends.clear();
        Ok(())
    }
}

impl Chunk {
    /// One model learns the rows one by one.
    fn learn_fixed(&self, model: &mut Mdagl, tally: &mut Tally) -> Result<(), FitError> {
        for (i, &label) in self.labels.iter().enumerate() {
            let pre = model
                .update(self.features(i), label)
                .map_err(|source| FitError::Update {
                    row: tally.rows + 1,
                    source,
                })?;
            tally.count(pre, label);
        }
        Ok(())
    }

    /// A race learns the rows as one block (each setting a run of rows at a time).
    fn learn_raced(&self, race: &mut MdaglRace, tally: &mut Tally) -> Result<(), FitError> {
        let rows: Vec<(Features<'_>, usize)> = (0..self.labels.len())
            .map(|i| (self.features(i), self.labels[i]))
            .collect();
        let mut records = Vec::with_capacity(rows.len());
        let learned = race.update_block(&rows, &mut records);
        for (pre, &(_, label)) in records.iter().zip(&rows) {
            tally.count(*pre, label);
        }
        learned.map_err(|refused| FitError::Update {
            row: tally.rows + 1,
            source: refused.source,
        })
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
        let mut race = MdaglRace::new(classes, shape.features, &grid, RaceSchedule::default())
            .map_err(model_error)?;
        race.set_threads(match settings.threads {
            0 => std::thread::available_parallelism().map_or(1, usize::from),
            n => n,
        });
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
    mut progress: impl FnMut(u64),
) -> Result<FitResult, FitError> {
    let (mut model, classes) = build_learner(name, shape, settings)?;
    let mut tally = Tally::default();
    let mut chunk = Chunk::new(shape);
    let mut rows = RowReader::new(reader, name, Some(shape.format));
    while let Some(row) = rows.next_row(&mut progress)? {
        chunk.push(row.label, row.values);
        if chunk.is_full() {
            chunk.learn(&mut model, &mut tally)?;
        }
    }
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
        shape: shape.clone(),
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
    let shape = scan(open(path)?, path, settings, |n| progress(Pass::Checking, n))?;
    fit(open(path)?, path, &shape, settings, |n| {
        progress(Pass::Fitting, n)
    })
}

/// Both passes over a stream that can be read only once, such as standard input: the first
/// pass keeps a copy of its bytes in an anonymous temporary file (removed when done), which
/// the second pass reads. `name` is the stream named in errors; the stream may be
/// gzip-compressed.
///
/// ```
/// use std::path::Path;
/// use tes_learning::mdagl::MdaglParams;
/// use tes_learning::prequential::{FitSettings, fit_stream};
///
/// // Sparse rows: the label is column 3; column 8 is noise.
/// let rows: String = (0..1000)
///     .map(|i| format!("{} 3:{} 8:{}\n", i % 2, i % 2, (i / 2) % 2))
///     .collect();
/// let settings = FitSettings {
///     params: MdaglParams { intercept: true, ..MdaglParams::default() },
///     ..FitSettings::default()
/// };
/// let result = fit_stream(rows.as_bytes(), Path::new("piped rows"), &settings, |_, _| {})?;
/// assert_eq!((result.shape.rows, result.shape.features), (1000, 9));
/// assert_eq!(result.selected, [3]);
/// # Ok::<(), tes_learning::prequential::FitError>(())
/// ```
pub fn fit_stream(
    stream: impl Read,
    name: &Path,
    settings: &FitSettings,
    mut progress: impl FnMut(Pass, u64),
) -> Result<FitResult, FitError> {
    let spool_error = |source| FitError::Spool {
        path: name.to_owned(),
        source,
    };
    let copy = tempfile::tempfile().map_err(spool_error)?;
    let tee = Tee {
        stream,
        copy: io::BufWriter::new(copy.try_clone().map_err(spool_error)?),
    };
    let shape = {
        let mut tee = tee;
        let reader = decoded(&mut tee).map_err(spool_error)?;
        let shape = scan(reader, name, settings, |n| progress(Pass::Checking, n))?;
        // The scan stops at the end of the rows; anything after (a gzip trailer) is kept too.
        io::copy(&mut tee, &mut io::sink()).map_err(spool_error)?;
        tee.copy.flush().map_err(spool_error)?;
        shape
    };
    let mut copy = copy;
    copy.rewind().map_err(spool_error)?;
    fit(
        decoded(copy).map_err(spool_error)?,
        name,
        &shape,
        settings,
        |n| progress(Pass::Fitting, n),
    )
}

/// A reader that writes a copy of every byte it reads.
struct Tee<R, W: Write> {
    stream: R,
    copy: W,
}

impl<R: Read, W: Write> Read for Tee<R, W> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.stream.read(buf)?;
        self.copy.write_all(&buf[..n])?;
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn name() -> &'static Path {
        Path::new("t.csv")
    }

    fn scan_str(csv: &str, classes: Option<usize>) -> Result<Shape, FitError> {
        let settings = FitSettings {
            classes,
            ..FitSettings::default()
        };
        scan(csv.as_bytes(), name(), &settings, |_| {})
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
                binary: true,
                format: RowFormat::Csv,
                names: Vec::new(),
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
                scan(
                    &b"0,1\n1,\xff\n"[..],
                    name(),
                    &FitSettings::default(),
                    |_| {},
                ),
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
            let shape = scan(csv.as_bytes(), name(), &settings, |n| read += n).unwrap();
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

    /// The same stream, as CSV under a header, as sparse rows, and gzip-compressed, fits to
    /// the same figures; the header names the columns.
    #[test]
    fn every_format_of_one_stream_fits_alike() {
        let rows = 3000;
        let csv: String = (0..rows)
            .map(|i| format!("{},{},{},{}\n", i % 3, (i / 3) % 2, i % 3 % 2, i % 3 / 2))
            .collect();
        let header = format!("effect, noise, odd, two\n{csv}");
        let sparse: String = (0..rows)
            .map(|i| {
                let on: Vec<String> = [(i / 3) % 2, i % 3 % 2, i % 3 / 2]
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| **v == 1)
                    .map(|(c, _)| format!("{c}:1"))
                    .collect();
                format!("{} {}\n", i % 3, on.join(" "))
            })
            .collect();
        let mut gzip = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gzip.write_all(sparse.as_bytes()).unwrap();
        let gzip = gzip.finish().unwrap();
        let settings = FitSettings {
            params: MdaglParams {
                intercept: true,
                ..MdaglParams::default()
            },
            ..FitSettings::default()
        };
        let fit_bytes =
            |bytes: &[u8]| fit_stream(bytes, name(), &settings, |_, _| {}).map_err(|e| chain(&e));
        let plain = fit_bytes(csv.as_bytes()).unwrap();
        let named = fit_bytes(header.as_bytes()).unwrap();
        let libsvm = fit_bytes(sparse.as_bytes()).unwrap();
        let packed = fit_bytes(&gzip).unwrap();
        assert_eq!(plain.selected, [1, 2]);
        assert_eq!(named.shape.names, ["noise", "odd", "two"]);
        assert_eq!(named.shape.feature_name(2), "two");
        assert_eq!(libsvm.shape.format, RowFormat::Sparse);
        for other in [&named, &libsvm, &packed] {
            assert_eq!(other.shape.rows, rows);
            assert_eq!(other.selected, plain.selected);
            assert!((other.mean_log_loss - plain.mean_log_loss).abs() < 1e-12);
        }
    }

    /// Real-valued sparse rows take the sparse path and learn as their dense CSV does.
    #[test]
    fn real_valued_sparse_rows_learn_as_their_dense_twins() {
        let rows = 2000;
        let value = |i: u64| 0.5 + (i % 7) as f64 / 4.0;
        let csv: String = (0..rows)
            .map(|i| format!("{},{},0,{}\n", i % 2, value(i) * (i % 2) as f64, value(i)))
            .collect();
        let sparse: String = (0..rows)
            .map(|i| match i % 2 {
                0 => format!("0 2:{}\n", value(i)),
                _ => format!("1 0:{} 2:{}\n", value(i), value(i)),
            })
            .collect();
        let settings = FitSettings::default();
        let dense = fit_stream(csv.as_bytes(), name(), &settings, |_, _| {}).unwrap();
        let sparse = fit_stream(sparse.as_bytes(), name(), &settings, |_, _| {}).unwrap();
        assert!(!sparse.shape.binary && sparse.shape.format == RowFormat::Sparse);
        assert_eq!(sparse.shape.features, 3);
        assert!(sparse.selected.starts_with(&[0]), "{:?}", sparse.selected);
        assert_eq!(dense.selected, sparse.selected);
        assert!((dense.mean_log_loss - sparse.mean_log_loss).abs() < 1e-9);
    }

    #[test]
    fn malformed_headers_and_sparse_rows_name_their_line() {
        let fails = |text: &str| {
            let err = fit_stream(text.as_bytes(), name(), &FitSettings::default(), |_, _| {})
                .unwrap_err();
            chain(&err)
        };
        assert_eq!(
            fails("label,a,b\n1,0\n"),
            "t.csv:2: the header names 3 columns (label + 2 features) but the first row has 2"
        );
        // Only the first line may be a header.
        assert_eq!(
            fails("1,0\nlabel,a\n"),
            r#"t.csv:2: malformed row: the label "label" is not a whole number >= 0"#
        );
        assert_eq!(
            fails("1 3:1\n\n0 4:1 4:0.5\n"),
            "t.csv:3: malformed row: column 4 is given twice"
        );
        assert_eq!(
            fails("1 | 2\n0 |f 4\n"),
            r#"t.csv:2: malformed row: "|f" names a namespace; only a bare `|` is read (columns are numbers)"#
        );
        let mut cut = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        cut.write_all("1,0\n0,1\n".repeat(500).as_bytes()).unwrap();
        let mut cut = cut.finish().unwrap();
        cut.truncate(cut.len() / 2);
        let err = fit_stream(&cut[..], name(), &FitSettings::default(), |_, _| {}).unwrap_err();
        assert!(
            matches!(err, FitError::Read { .. }),
            "a cut gzip stream is a read error naming its line: {}",
            chain(&err)
        );
    }

    /// A file and the same bytes as a stream give the same fit, and gzip is told by content.
    #[test]
    fn files_and_streams_fit_alike() {
        let csv: String = (0..500).map(|i| format!("{},{}\n", i % 2, i % 2)).collect();
        let mut file = tempfile::NamedTempFile::new().unwrap();
        file.write_all(csv.as_bytes()).unwrap();
        assert!(!is_gzip(file.path()));
        let settings = FitSettings::default();
        let from_file = fit_file(file.path(), &settings, |_, _| {}).unwrap();
        let from_stream = fit_stream(csv.as_bytes(), name(), &settings, |_, _| {}).unwrap();
        assert_eq!(from_file.shape, from_stream.shape);
        assert_eq!(from_file.selected, from_stream.selected);
        assert_eq!(from_file.mean_log_loss, from_stream.mean_log_loss);
        let mut packed = tempfile::NamedTempFile::new().unwrap();
        let mut gzip = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gzip.write_all(csv.as_bytes()).unwrap();
        packed.write_all(&gzip.finish().unwrap()).unwrap();
        assert!(is_gzip(packed.path()));
        let from_gzip = fit_file(packed.path(), &settings, |_, _| {}).unwrap();
        assert_eq!(from_gzip.selected, from_file.selected);
        assert_eq!(from_gzip.mean_log_loss, from_file.mean_log_loss);
    }
}
