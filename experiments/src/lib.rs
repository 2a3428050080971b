//! The paper's experiments, reproduced: agents on episodic tasks, with tables and plots.
//!
//! * [`grid`] — §5.1: the 15 grid tasks, loreRL against the baselines (Fig. 3, Table 1);
//! * [`transfer`] — §5.1: leave-one-out transfer with TES (Table 2, Fig. 4b);
//! * [`fig4`] — §5.1: transfer between tasks of the same dynamics (Fig. 4a) and TES over a
//!   long run against the converging methods (Fig. 4c);
//! * [`robot`] — §5.2: the robot arenas, TES against loreRL, LWT and the baselines
//!   (Figs. 8–9, Tables 5–6);
//! * [`lifelong`] — beyond the paper: a long, non-stationary sequence of grid tasks from more
//!   worlds than the library holds, some not logistic, returning after long gaps;
//! * [`episode`] — what they share: a task, building the agents, running an episode;
//! * [`experiment`] — the trait each experiment's settings implement, so the command line
//!   and the study run, resume and summarise every one the same way;
//! * [`method`] — every method compared: its name in every output, its colour in every figure,
//!   its order;
//! * [`stats`], [`svg`] — confidence intervals and dependency-free SVG charts for the reports,
//!   every method in one colour across all of them;
//! * [`verdict`] — the paper's targets and whether a run meets them (a `--quick` run is too
//!   small to judge);
//! * [`prereg`] — the preregistration: every target's sentence of the paper, test and
//!   threshold, with the earlier forms of any changed after results existed, and the worlds and
//!   defaults the results depend on, each fingerprinted so a change without a record fails a
//!   test;
//! * [`claims`] — the paper's claims the experiments' own targets leave out, judged from a
//!   committed `summary.json` alone, with a run-level sign-flip test beside the pooled ones;
//! * [`jobs`] — every experiment as a list of independent jobs: `--shard K/N`, `--resume`,
//!   merging shard folders;
//! * [`report`] — `report.md`, every table and figure of the whole study in one page;
//! * [`replot`] — redraws the figures a result folder's `summary.json` holds the data of;
//! * [`write_labelled_csv`], [`write_labelled_sparse`] and the `make-fit-demo` binary — the seeded demo stream that
//!   `tes fit` runs on in the README (`data/fit-demo.csv`).
//!
//! Every run is seeded and records its seeds; the same settings give the same numbers.

pub mod claims;
pub mod console;
pub mod episode;
pub mod experiment;
pub mod fig4;
pub mod grid;
pub mod jobs;
pub mod ledger;
pub mod lifelong;
pub mod method;
pub mod prereg;
pub mod progress;
pub mod replot;
pub mod report;
pub mod robot;
pub mod settings;
pub mod stats;
pub mod study;
pub mod svg;
pub mod transfer;
pub mod verdict;

use std::io::{self, Write};

use tes_learning::mdagl::synthetic::{SparseMultinomialStream, SyntheticSpec};

/// Writes `rows` rows of a synthetic sparse multinomial stream as labelled CSV
/// (`label,x_0,…,x_{d-1}`, no header) and returns the stream's relevant features.
///
/// ```
/// use tes_experiments::write_labelled_csv;
/// use tes_learning::mdagl::synthetic::SyntheticSpec;
///
/// let mut out = Vec::new();
/// let spec = SyntheticSpec { features: 8, relevant: 2, ..SyntheticSpec::default() };
/// let relevant = write_labelled_csv(&mut out, spec, 42, 3)?;
/// let text = String::from_utf8(out)?;
/// assert_eq!(text.lines().count(), 3);
/// assert!(text.lines().all(|l| l.split(',').count() == 9));
/// assert_eq!(relevant.len(), 2);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn write_labelled_csv(
    out: &mut impl Write,
    spec: SyntheticSpec,
    seed: u64,
    rows: usize,
) -> io::Result<Vec<u32>> {
    write_rows(out, spec, seed, rows, |line, label, active| {
        line.push_str(&label.to_string());
        let mut next = active.iter().peekable();
        for i in 0..spec.features as u32 {
            let on = next.next_if_eq(&&i).is_some();
            line.push_str(if on { ",1" } else { ",0" });
        }
    })
}

/// The same rows as [`write_labelled_csv`], as sparse `label column:1 …` lines (columns
/// from 0, the row's on features only): the form `tes fit` reads for wide streams, where a
/// CSV of thousands of zeros per row would dwarf the data.
///
/// ```
/// use tes_experiments::{write_labelled_csv, write_labelled_sparse};
/// use tes_learning::mdagl::synthetic::SyntheticSpec;
///
/// let spec = SyntheticSpec { features: 8, relevant: 2, ..SyntheticSpec::default() };
/// let (mut csv, mut sparse) = (Vec::new(), Vec::new());
/// write_labelled_csv(&mut csv, spec, 42, 3)?;
/// write_labelled_sparse(&mut sparse, spec, 42, 3)?;
/// for (dense, sparse) in String::from_utf8(csv)?.lines().zip(String::from_utf8(sparse)?.lines()) {
///     let mut fields = dense.split(',');
///     let label = fields.next().unwrap_or_default();
///     let on: Vec<String> = fields
///         .enumerate()
///         .filter(|(_, v)| *v == "1")
///         .map(|(i, _)| format!("{i}:1"))
///         .collect();
///     assert_eq!(sparse, [label.to_owned()].into_iter().chain(on).collect::<Vec<_>>().join(" "));
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn write_labelled_sparse(
    out: &mut impl Write,
    spec: SyntheticSpec,
    seed: u64,
    rows: usize,
) -> io::Result<Vec<u32>> {
    write_rows(out, spec, seed, rows, |line, label, active| {
        line.push_str(&label.to_string());
        for column in active {
            line.push_str(&format!(" {column}:1"));
        }
    })
}

/// Draws `rows` rows of the seeded stream, each written as a line by `format`; returns the
/// true model's relevant columns.
fn write_rows(
    out: &mut impl Write,
    spec: SyntheticSpec,
    seed: u64,
    rows: usize,
    format: impl Fn(&mut String, usize, &[u32]),
) -> io::Result<Vec<u32>> {
    let mut stream = SparseMultinomialStream::new(spec, seed)
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
    let mut line = String::with_capacity(2 * spec.features + 4);
    for _ in 0..rows {
        let (label, active) = stream.next_row();
        line.clear();
        format(&mut line, label, active);
        line.push('\n');
        out.write_all(line.as_bytes())?;
    }
    Ok(stream.relevant().to_vec())
}
