//! Feeds arbitrary bytes to the sparse-row reader of `tes fit` (libsvm and Vowpal Wabbit
//! style, learning/src/labelled_sparse.rs) line by line, then, as `tes fit` does, has an
//! mDAGL model of `largest label + 1` classes and `largest column + 1` features learn the rows
//! through its sparse input.
//!
//! A row must parse or give a typed error, never panic; a parsed row must hold only finite,
//! non-zero values in strictly increasing columns, and read back exactly from its own
//! rendering.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tes_learning::labelled_csv::MAX_LABEL;
use tes_learning::labelled_sparse::{MAX_COLUMN, parse_sparse_row};
use tes_learning::mdagl::{Features, Mdagl, MdaglParams};

/// Models bigger than this (classes × features) are not built: fuzzing is about the reader.
const MAX_WEIGHTS: usize = 1 << 20;

fuzz_target!(|data: &[u8]| {
    let mut rows: Vec<(usize, Vec<(u32, f64)>)> = Vec::new();
    let mut features = Vec::new();
    let mut echo = Vec::new();
    for raw in data.split_inclusive(|&b| b == b'\n') {
        let Ok(line) = std::str::from_utf8(raw) else {
            return;
        };
        if line.trim().is_empty() {
            continue;
        }
        let label = match parse_sparse_row(line, &mut features) {
            Ok(label) => label,
            Err(e) => {
                assert!(!e.to_string().is_empty());
                return;
            }
        };
        assert!(label <= MAX_LABEL);
        assert!(features.windows(2).all(|w| w[0].0 < w[1].0), "{features:?}");
        assert!(
            features
                .iter()
                .all(|&(c, v)| c <= MAX_COLUMN && v.is_finite() && v != 0.0),
            "{features:?}"
        );
        let text = std::iter::once(label.to_string())
            .chain(features.iter().map(|(c, v)| format!("{c}:{v:?}")))
            .collect::<Vec<_>>()
            .join(" ");
        assert_eq!(parse_sparse_row(&text, &mut echo), Ok(label), "{text}");
        assert_eq!(echo, features, "{text}");
        rows.push((label, features.clone()));
    }
    let Some(max_label) = rows.iter().map(|(label, _)| *label).max() else {
        return;
    };
    let classes = max_label + 1;
    let d = rows
        .iter()
        .filter_map(|(_, x)| x.last().map(|&(c, _)| c as usize + 1))
        .max()
        .unwrap_or(0);
    if classes < 2 || d == 0 || classes.saturating_mul(d + 1) > MAX_WEIGHTS {
        return;
    }
    let Ok(mut model) = Mdagl::new(classes, d, MdaglParams::default()) else {
        return;
    };
    let (mut indices, mut values) = (Vec::new(), Vec::new());
    for (label, x) in &rows {
        indices.clear();
        values.clear();
        indices.extend(x.iter().map(|&(c, _)| c));
        values.extend(x.iter().map(|&(_, v)| v));
        let input = Features::Sparse {
            indices: &indices,
            values: &values,
        };
        match model.update(input, *label) {
            Ok(pre) => assert!(pre.log_prob <= 0.0 && pre.predicted < classes, "{pre:?}"),
            Err(e) => assert!(!e.to_string().is_empty()),
        }
    }
});
