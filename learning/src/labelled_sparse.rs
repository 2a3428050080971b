//! Sparse labelled rows, libsvm or Vowpal Wabbit style: `label column:value …`.
//!
//! The format `tes fit` reads for wide data (thousands of columns, few of them non-zero per
//! row). A row is its class label (a whole number `0..K`, at most
//! [`MAX_LABEL`](crate::labelled_csv::MAX_LABEL)) and then, separated by spaces or tabs, its
//! non-zero features as `column:value`, where a column is a whole number `0..=`[`MAX_COLUMN`].
//! Columns are numbered as written: a file numbered from 1, as libsvm's tools write it, simply
//! never uses column 0. Two Vowpal Wabbit habits are read too: a `|` before the features (a
//! bare `|`, since a named namespace has no column number), and a column without a value,
//! which means the value 1. Text after `#` is a comment. Features may come in any order; a
//! column given twice is an error, as is anything else that is not a feature.
//!
//! ```
//! use tes_learning::labelled_sparse::parse_sparse_row;
//!
//! let mut features = Vec::new();
//! assert_eq!(parse_sparse_row("2 7:0.5 3:1", &mut features)?, 2);
//! assert_eq!(features, [(3, 1.0), (7, 0.5)]);
//! assert_eq!(parse_sparse_row("1 | 12 4:2  # a comment", &mut features)?, 1);
//! assert_eq!(features, [(4, 2.0), (12, 1.0)]);
//! assert!(parse_sparse_row("1 3:x", &mut features).is_err());
//! # Ok::<(), tes_learning::labelled_csv::RowError>(())
//! ```

use crate::labelled_csv::{RowError, parse_label, quote};

// Defined beside the row error that names it, so that the two row formats share one module
// below them rather than naming each other.
pub use crate::labelled_csv::MAX_COLUMN;

/// Parses one sparse row into its label and `features`, the non-zero `(column, value)` pairs
/// in increasing column order (`features` is cleared first; its capacity is reused).
///
/// Zero values are dropped, so `features` holds exactly the row's non-zero entries.
pub fn parse_sparse_row(line: &str, features: &mut Vec<(u32, f64)>) -> Result<usize, RowError> {
    features.clear();
    let content = line
        .as_bytes()
        .iter()
        .position(|&b| b == b'#')
        .map_or(line, |at| &line[..at]);
    let mut fields = content.split_ascii_whitespace();
    let label = parse_label(fields.next().unwrap_or(""))?;
    for field in fields {
        if field.as_bytes()[0] == b'|' {
            if field.len() == 1 {
                continue;
            }
            return Err(RowError::NamedNamespace { text: quote(field) });
        }
        let (column, value) = parse_feature(field)?;
        if value != 0.0 {
            features.push((column, value));
        }
    }
    // Rows written by a program come sorted: check before sorting.
    if !features.is_sorted_by_key(|&(column, _)| column) {
        features.sort_unstable_by_key(|&(column, _)| column);
    }
    if let Some(pair) = features.windows(2).find(|pair| pair[0].0 == pair[1].0) {
        return Err(RowError::RepeatedColumn { column: pair[0].0 });
    }
    Ok(label)
}

/// One `column:value` (or bare `column`, value 1) field.
fn parse_feature(field: &str) -> Result<(u32, f64), RowError> {
    let (column_text, value_text) = match field.as_bytes().iter().position(|&b| b == b':') {
        Some(at) => (&field[..at], &field[at + 1..]),
        None => (field, "1"),
    };
    let column = match column_text.parse::<u64>() {
        Ok(column) if column <= u64::from(MAX_COLUMN) => column as u32,
        Ok(_) => return Err(RowError::ColumnTooLarge { text: quote(field) }),
        Err(_) if !column_text.is_empty() && column_text.bytes().all(|b| b.is_ascii_digit()) => {
            return Err(RowError::ColumnTooLarge { text: quote(field) });
        }
        Err(_) => return Err(RowError::BadFeature { text: quote(field) }),
    };
    // Binary data writes `1` in nearly every field: skip the float parser for it.
    let value = if value_text == "1" {
        1.0
    } else {
        value_text
            .parse::<f64>()
            .map_err(|_| RowError::BadFeature { text: quote(field) })?
    };
    if !value.is_finite() {
        return Err(RowError::NonFiniteFeature { text: quote(field) });
    }
    Ok((column, value))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::labelled_csv::MAX_LABEL;
    use proptest::prelude::*;

    #[test]
    fn reads_libsvm_and_vw_rows() {
        let mut f = Vec::new();
        assert_eq!(parse_sparse_row("0", &mut f), Ok(0));
        assert!(f.is_empty());
        assert_eq!(parse_sparse_row("3 1:0.5 10:-2e1 4:0\r\n", &mut f), Ok(3));
        assert_eq!(f, [(1, 0.5), (10, -20.0)]);
        assert_eq!(
            parse_sparse_row("1 |  9 2:3\t0:1 # trailing", &mut f),
            Ok(1)
        );
        assert_eq!(f, [(0, 1.0), (2, 3.0), (9, 1.0)]);
        assert_eq!(parse_sparse_row(" 2 | ", &mut f), Ok(2));
        assert!(f.is_empty());
    }

    #[test]
    fn names_what_is_wrong() {
        let mut f = Vec::new();
        let cases = [
            ("x 1:1", r#"the label "x" is not a whole number >= 0"#),
            ("", r#"the label "" is not a whole number >= 0"#),
            (
                "70000 1:1",
                r#"the label "70000" is larger than 65535, the largest class label supported"#,
            ),
            (
                "1 a:1",
                r#"feature "a:1" is not `column:value` or `column` (a whole number column)"#,
            ),
            (
                "1 3:x",
                r#"feature "3:x" is not `column:value` or `column` (a whole number column)"#,
            ),
            (
                "1 3:nan",
                r#"feature "3:nan" has a value that is not finite"#,
            ),
            (
                "1 2147483647:1",
                r#"feature "2147483647:1" has a column above 16777216, the largest supported"#,
            ),
            (
                "1 99999999999999999999999:1",
                r#"feature "99999999999999999999999:…" has a column above 16777216, the largest supported"#,
            ),
            ("1 2:1 5 2:0.5", "column 2 is given twice"),
            (
                "1 |words 2:1",
                r#""|words" names a namespace; only a bare `|` is read (columns are numbers)"#,
            ),
        ];
        for (line, expected) in cases {
            let err = parse_sparse_row(line, &mut f).unwrap_err();
            assert_eq!(err.to_string(), expected, "{line:?}");
        }
    }

    proptest! {
        /// Any text: a row or a typed error, never a panic.
        #[test]
        fn never_panics(line in "\\PC{0,80}") {
            let mut f = Vec::new();
            let _ = parse_sparse_row(&line, &mut f);
        }

        /// Written rows, in any order, read back sorted, with their zeros dropped.
        #[test]
        fn round_trips(
            label in 0..=MAX_LABEL,
            entries in proptest::collection::btree_map(0..=MAX_COLUMN, -1e6..1e6f64, 0..40),
            bare_ones in any::<bool>(),
        ) {
            let mut fields: Vec<String> = entries
                .iter()
                .rev()
                .map(|(c, v)| if bare_ones && *v == 1.0 { c.to_string() } else { format!("{c}:{v:?}") })
                .collect();
            fields.insert(0, label.to_string());
            let mut f = Vec::new();
            prop_assert_eq!(parse_sparse_row(&fields.join(" "), &mut f), Ok(label));
            let expected: Vec<(u32, f64)> =
                entries.into_iter().filter(|(_, v)| *v != 0.0).collect();
            prop_assert_eq!(f, expected);
        }
    }
}
