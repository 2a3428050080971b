//! Benchmarks, data generators and experiment drivers for TES.
//!
//! * `benches/mdagl.rs` — criterion benchmarks of the view learner.
//! * [`experiment`] — agents on episodic tasks: the machinery of the paper's experiments.
//! * [`stats`], [`svg`] — confidence intervals and dependency-free SVG charts for reports.
//! * [`write_labelled_csv`] and the `make-fit-demo` binary — the seeded demo stream that
//!   `tes fit` runs on in the README (`data/fit-demo.csv`).

pub mod experiment;
pub mod fixtures;
pub mod relay;
pub mod scaling;
pub mod stats;
pub mod svg;

use std::io::{self, Write};

use tes_controller::mdagl::synthetic::{SparseMultinomialStream, SyntheticSpec};

/// Writes `rows` rows of a synthetic sparse multinomial stream as labelled CSV
/// (`label,x_0,…,x_{d-1}`, no header) and returns the stream's relevant features.
///
/// ```
/// use tes_bench::write_labelled_csv;
/// use tes_controller::mdagl::synthetic::SyntheticSpec;
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
    let mut stream = SparseMultinomialStream::new(spec, seed)
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
    let mut line = String::with_capacity(2 * spec.features + 4);
    for _ in 0..rows {
        let (label, active) = stream.next_row();
        line.clear();
        line.push_str(&label.to_string());
        let mut next = active.iter().peekable();
        for i in 0..spec.features as u32 {
            let on = next.next_if_eq(&&i).is_some();
            line.push_str(if on { ",1" } else { ",0" });
        }
        line.push('\n');
        out.write_all(line.as_bytes())?;
    }
    Ok(stream.relevant().to_vec())
}
