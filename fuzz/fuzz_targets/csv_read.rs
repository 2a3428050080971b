//! Feeds arbitrary bytes to the labelled-CSV reader as `tes fit` uses it
//! (learning/src/prequential.rs): line by line (a line that is not UTF-8 stops `tes fit` with
//! `RowError::NotText` naming it), blank lines skipped, every row parsed, every row as wide as
//! the first; then, as `tes fit` does, an mDAGL model of `largest label + 1` classes learns the
//! rows in order.
//!
//! A row must parse or give a typed error, never panic; a parsed row must hold only finite
//! values, one per field after the label, and read back exactly from its own rendering.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tes_learning::labelled_csv::{MAX_LABEL, is_blank, parse_row};
use tes_learning::mdagl::{Features, Mdagl, MdaglParams};

/// Models bigger than this (classes × features) are not built: fuzzing is about the reader,
/// and `tes fit` would simply need the memory.
const MAX_WEIGHTS: usize = 1 << 20;

fuzz_target!(|data: &[u8]| {
    let mut rows: Vec<(usize, Vec<f64>)> = Vec::new();
    let mut features = Vec::new();
    let mut echo = Vec::new();
    for raw in data.split_inclusive(|&b| b == b'\n') {
        let Ok(line) = std::str::from_utf8(raw) else {
            return;
        };
        if is_blank(line) {
            continue;
        }
        let label = match parse_row(line, &mut features) {
            Ok(label) => label,
            Err(e) => {
                assert!(!e.to_string().is_empty());
                return;
            }
        };
        assert!(label <= MAX_LABEL);
        assert_eq!(features.len(), line.split(',').count() - 1);
        assert!(features.iter().all(|v| v.is_finite()), "{features:?}");
        let text = std::iter::once(label.to_string())
            .chain(features.iter().map(|v| format!("{v:?}")))
            .collect::<Vec<_>>()
            .join(",");
        assert_eq!(parse_row(&text, &mut echo), Ok(label), "{text}");
        assert_eq!(echo, features, "{text}");
        if rows
            .first()
            .is_some_and(|(_, first)| first.len() != features.len())
        {
            return; // `tes fit`: "expected N columns like the first row".
        }
        rows.push((label, features.clone()));
    }
    let Some(max_label) = rows.iter().map(|(label, _)| *label).max() else {
        return; // `tes fit`: "no rows to learn from".
    };
    let classes = max_label + 1;
    let d = rows[0].1.len();
    if classes < 2 || classes.saturating_mul(d + 1) > MAX_WEIGHTS {
        return;
    }
    let Ok(mut model) = Mdagl::new(classes, d, MdaglParams::default()) else {
        return;
    };
    for (label, x) in &rows {
        match model.update(Features::Dense(x), *label) {
            Ok(pre) => assert!(pre.log_prob <= 0.0 && pre.predicted < classes, "{pre:?}"),
            Err(e) => assert!(!e.to_string().is_empty()),
        }
    }
});
