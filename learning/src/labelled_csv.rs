//! Labelled CSV rows: `label,feature_1,…,feature_d`, no header.
//!
//! The format `tes fit` reads: each line is one example, its first field the class label (a
//! whole number `0..K`, at most [`MAX_LABEL`]), the rest the feature values. Parsing never
//! panics and names what is wrong; the caller adds the line number.
//!
//! ```
//! use tes_learning::labelled_csv::{parse_row, RowError};
//!
//! let mut features = Vec::new();
//! let label = parse_row("2, 0, 1, 0.5", &mut features)?;
//! assert_eq!((label, features.as_slice()), (2, &[0.0, 1.0, 0.5][..]));
//! assert!(matches!(parse_row("x,1", &mut features), Err(RowError::BadLabel { .. })));
//! # Ok::<(), RowError>(())
//! ```

use std::num::IntErrorKind;

use thiserror::Error;

/// Longest field text quoted back in an error message.
const QUOTE_LIMIT: usize = 24;

/// The largest class label a row may have. A model has one weight per class and feature, so
/// a label is a promise of memory: a first column that is really an id or a time stamp
/// (`1700000000,…`) must be refused, not turned into a billion-class model.
pub const MAX_LABEL: usize = 65_535;

/// The largest column number a [sparse row](crate::labelled_sparse) may use. A model has a weight per class and column
/// up to the largest one used, so a column is a promise of memory, as a label is: a hashed
/// feature id (`2147483647:1`) must be refused, not turned into a model of billions of
/// weights.
pub const MAX_COLUMN: u32 = 1 << 24;

/// Why a row could not be read.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RowError {
    /// The first field is not a whole number ≥ 0.
    #[error("the label {text:?} is not a whole number >= 0")]
    BadLabel {
        /// The field's text (shortened).
        text: String,
    },
    /// The label is a whole number but above [`MAX_LABEL`].
    #[error("the label {text:?} is larger than {MAX_LABEL}, the largest class label supported")]
    LabelTooLarge {
        /// The field's text (shortened).
        text: String,
    },
    /// A feature field is not a number.
    #[error("column {column}: {text:?} is not a number")]
    BadNumber {
        /// 1-based column of the field in the line (the label is column 1).
        column: usize,
        /// The field's text (shortened).
        text: String,
    },
    /// A feature is NaN or infinite.
    #[error("column {column}: {text:?} is not a finite number")]
    NonFinite {
        /// 1-based column of the field in the line.
        column: usize,
        /// The field's text (shortened).
        text: String,
    },
    /// A sparse row's feature is not `column:value` or `column`
    /// ([`labelled_sparse`](crate::labelled_sparse)).
    #[error("feature {text:?} is not `column:value` or `column` (a whole number column)")]
    BadFeature {
        /// The field's text (shortened).
        text: String,
    },
    /// A sparse row's feature value is NaN or infinite.
    #[error("feature {text:?} has a value that is not finite")]
    NonFiniteFeature {
        /// The field's text (shortened).
        text: String,
    },
    /// A sparse row's column is above
    /// [`MAX_COLUMN`].
    #[error(
        "feature {text:?} has a column above {}, the largest supported",
        MAX_COLUMN
    )]
    ColumnTooLarge {
        /// The field's text (shortened).
        text: String,
    },
    /// A sparse row gives a column twice.
    #[error("column {column} is given twice")]
    RepeatedColumn {
        /// The column.
        column: u32,
    },
    /// A Vowpal Wabbit namespace with a name (`|words`): its features are names, not columns.
    #[error("{text:?} names a namespace; only a bare `|` is read (columns are numbers)")]
    NamedNamespace {
        /// The field's text (shortened).
        text: String,
    },
    /// The line is not UTF-8 text (a binary file, or text in another encoding).
    #[error("byte 0x{byte:02X} at position {position} is not UTF-8 text (is this a CSV file?)")]
    NotText {
        /// The first byte that is not part of valid UTF-8.
        byte: u8,
        /// Its 1-based position in the line, in bytes.
        position: usize,
    },
}

/// `text` as quoted back in an error: at most [`QUOTE_LIMIT`] characters.
pub(crate) fn quote(text: &str) -> String {
    match text.char_indices().nth(QUOTE_LIMIT) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text.to_owned(),
    }
}

/// A line's bytes as text, or [`RowError::NotText`] naming the first byte that is not UTF-8.
/// Read lines as bytes and pass them through this, rather than reading text, to get a typed
/// error for a file that is not text.
pub fn row_text(line: &[u8]) -> Result<&str, RowError> {
    std::str::from_utf8(line).map_err(|e| {
        let at = e.valid_up_to();
        RowError::NotText {
            byte: line.get(at).copied().unwrap_or(0),
            position: at + 1,
        }
    })
}

/// Whether a line holds no row (blank or only white space).
pub fn is_blank(line: &str) -> bool {
    line.trim().is_empty()
}

/// Parses one row into its label and `features` (cleared first; its capacity is reused).
///
/// Fields are separated by commas; white space around a field is ignored.
pub fn parse_row(line: &str, features: &mut Vec<f64>) -> Result<usize, RowError> {
    features.clear();
    let mut fields = line.split(',');
    let label = parse_label(fields.next().unwrap_or("").trim())?;
    for (i, field) in fields.enumerate() {
        let text = field.trim();
        let column = i + 2;
        let value = text.parse::<f64>().map_err(|_| RowError::BadNumber {
            column,
            text: quote(text),
        })?;
        if !value.is_finite() {
            return Err(RowError::NonFinite {
                column,
                text: quote(text),
            });
        }
        features.push(value);
    }
    Ok(label)
}

/// A row's first field as a class label: a whole number `0..=`[`MAX_LABEL`].
pub(crate) fn parse_label(text: &str) -> Result<usize, RowError> {
    match text.parse::<usize>() {
        Ok(label) if label <= MAX_LABEL => Ok(label),
        Err(e) if *e.kind() != IntErrorKind::PosOverflow => {
            Err(RowError::BadLabel { text: quote(text) })
        }
        // All digits, but above the limit (or even beyond `usize`).
        _ => Err(RowError::LabelTooLarge { text: quote(text) }),
    }
}

/// The column names, when `line` is a header: a line in which no field is a number (`label,
/// speed, colour`). A line with a number in it is a row, and is parsed (and refused, if it is
/// not one) as such.
///
/// ```
/// use tes_learning::labelled_csv::header_names;
///
/// assert_eq!(header_names("effect, x, y").unwrap(), ["effect", "x", "y"]);
/// assert_eq!(header_names("1,0,1"), None);
/// ```
pub fn header_names(line: &str) -> Option<Vec<String>> {
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    let is_header = fields.iter().all(|f| f.parse::<f64>().is_err());
    is_header.then(|| fields.into_iter().map(str::to_owned).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn reads_rows_and_names_bad_fields() {
        let mut f = Vec::new();
        assert_eq!(parse_row("0", &mut f), Ok(0));
        assert!(f.is_empty());
        assert_eq!(parse_row(" 3 ,1,0 ,-2.5e-1\r", &mut f), Ok(3));
        assert_eq!(f, vec![1.0, 0.0, -0.25]);
        assert_eq!(
            parse_row("-1,0", &mut f),
            Err(RowError::BadLabel { text: "-1".into() })
        );
        assert_eq!(
            parse_row("1.5,0", &mut f),
            Err(RowError::BadLabel { text: "1.5".into() })
        );
        assert_eq!(
            parse_row("1,0,,1", &mut f),
            Err(RowError::BadNumber {
                column: 3,
                text: String::new()
            })
        );
        assert_eq!(
            parse_row("1,0,NaN", &mut f),
            Err(RowError::NonFinite {
                column: 3,
                text: "NaN".into()
            })
        );
        assert_eq!(
            parse_row("1,inf", &mut f),
            Err(RowError::NonFinite {
                column: 2,
                text: "inf".into()
            })
        );
        assert_eq!(parse_row("65535,1", &mut f), Ok(MAX_LABEL));
        assert_eq!(
            parse_row("65536,1", &mut f),
            Err(RowError::LabelTooLarge {
                text: "65536".into()
            })
        );
        // Found writing the csv_read fuzz target: `tes fit` builds a model of `largest
        // label + 1` classes, so a first column that is a time stamp asked for 1.7 × 10^9
        // classes (an allocation abort), and one beyond usize overflowed the `+ 1`.
        assert_eq!(
            parse_row("1700000000,0.5,1", &mut f),
            Err(RowError::LabelTooLarge {
                text: "1700000000".into()
            })
        );
        assert_eq!(
            parse_row("99999999999999999999999,1", &mut f),
            Err(RowError::LabelTooLarge {
                text: "99999999999999999999999".into()
            })
        );
        let long = format!("1,{}", "z".repeat(100));
        let err = parse_row(&long, &mut f).unwrap_err().to_string();
        assert!(err.len() < 80, "{err}");
        assert!(is_blank("  \r") && !is_blank("0"));
    }

    #[test]
    fn lines_that_are_not_utf8_are_refused_naming_the_byte() {
        assert_eq!(row_text(b"1,0.5\n"), Ok("1,0.5\n"));
        assert_eq!(row_text("1,\u{e9}\n".as_bytes()), Ok("1,\u{e9}\n"));
        assert_eq!(
            row_text(b"1,\xff\xfe,0\n"),
            Err(RowError::NotText {
                byte: 0xFF,
                position: 3
            })
        );
        // A multi-byte sequence cut short is named by its first byte.
        let err = row_text(b"\xc3").unwrap_err();
        assert_eq!(
            err,
            RowError::NotText {
                byte: 0xC3,
                position: 1
            }
        );
        assert!(err.to_string().contains("0xC3"), "{err}");
    }

    proptest! {
        /// Any text: a row or a typed error, never a panic.
        #[test]
        fn never_panics(line in "\\PC{0,80}") {
            let mut f = Vec::new();
            let _ = parse_row(&line, &mut f);
        }

        /// Any bytes: text exactly when they are UTF-8, else the first bad byte named.
        #[test]
        fn any_bytes_are_text_or_name_their_first_bad_byte(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            match (row_text(&bytes), std::str::from_utf8(&bytes)) {
                (Ok(text), Ok(expected)) => prop_assert_eq!(text, expected),
                (Err(RowError::NotText { byte, position }), Err(e)) => {
                    prop_assert_eq!(position, e.valid_up_to() + 1);
                    prop_assert_eq!(byte, bytes[e.valid_up_to()]);
                }
                (got, _) => prop_assert!(false, "{:?}", got),
            }
        }

        /// Written rows read back exactly.
        #[test]
        fn round_trips(label in 0usize..1000, values in proptest::collection::vec(-1e6..1e6f64, 0..50)) {
            let line = std::iter::once(label.to_string())
                .chain(values.iter().map(|v| format!("{v:?}")))
                .collect::<Vec<_>>()
                .join(",");
            let mut f = Vec::new();
            prop_assert_eq!(parse_row(&line, &mut f), Ok(label));
            prop_assert_eq!(f, values);
        }
    }
}
