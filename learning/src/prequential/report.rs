//! A fit as `tes fit` says it: a table for people ([`text`]), or one JSON object
//! ([`summary`], serialised).

use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;

use super::{FitResult, RowFormat};

/// A hyper-parameter as it was asked for: a value, or `auto` (raced).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Hyper {
    /// Race the grid's values.
    Auto,
    /// This value.
    Value(f64),
}

impl Hyper {
    /// The value asked for; `None` for `auto`.
    pub fn value(self) -> Option<f64> {
        match self {
            Hyper::Auto => None,
            Hyper::Value(v) => Some(v),
        }
    }

    /// `auto (chose 0.005)`, or the value given.
    fn chosen(self, used: f64) -> String {
        match self {
            Hyper::Auto => format!("auto (chose {used})"),
            Hyper::Value(v) => v.to_string(),
        }
    }
}

impl std::fmt::Display for Hyper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Hyper::Auto => f.write_str("auto"),
            Hyper::Value(v) => write!(f, "{v}"),
        }
    }
}

impl std::str::FromStr for Hyper {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        if text == "auto" {
            return Ok(Hyper::Auto);
        }
        text.parse()
            .map(Hyper::Value)
            .map_err(|_| format!("expected a number or `auto`, got {text:?}"))
    }
}

/// What a fit was asked: λ and α (a value or `auto`) and whether with an intercept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Asked {
    /// `--lambda`.
    pub lambda: Hyper,
    /// `--alpha`.
    pub alpha: Hyper,
    /// `--intercept`.
    pub intercept: bool,
}

/// The fit as one JSON object (`tes fit --json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// Rows learned.
    pub n: u64,
    /// Prequential mean log-loss, nats.
    pub mean_logloss: f64,
    /// Prequential accuracy.
    pub accuracy: f64,
    /// The selected features' columns.
    pub selected: Vec<usize>,
    /// Rows learned per second of the model's work.
    pub updates_per_sec: f64,
    /// Classes of the model.
    pub classes: usize,
    /// Feature columns.
    pub features: usize,
    /// Whether every feature is 0 or 1.
    pub binary: bool,
    /// `csv` or `sparse`.
    pub format: &'static str,
    /// The selected features' header names; `None` without a header.
    pub selected_names: Option<Vec<String>>,
    /// The λ of the model reported.
    pub lambda: f64,
    /// The α of the model reported.
    pub alpha: f64,
    /// Whether with an intercept.
    pub intercept: bool,
    /// With `auto`: what was raced and how each setting stood; `None` for a fixed setting.
    pub auto: Option<AutoSummary>,
}

/// What `auto` raced.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AutoSummary {
    /// `--lambda` as given.
    pub lambda: String,
    /// `--alpha` as given.
    pub alpha: String,
    /// Every raced setting, best first.
    pub standings: Vec<StandingSummary>,
}

/// One raced setting's standing.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StandingSummary {
    /// Its λ.
    pub lambda: f64,
    /// Its α.
    pub alpha: f64,
    /// Its mean log-loss over the rows it learned, nats.
    pub mean_logloss: f64,
    /// Rows it learned.
    pub rows: u64,
    /// Whether it was still racing.
    pub racing: bool,
}

/// `fit`, asked as `asked`, as one JSON-ready object.
pub fn summary(fit: &FitResult, asked: Asked) -> Summary {
    let auto = (!fit.standings.is_empty()).then(|| AutoSummary {
        lambda: asked.lambda.to_string(),
        alpha: asked.alpha.to_string(),
        standings: fit
            .standings
            .iter()
            .map(|s| StandingSummary {
                lambda: s.params.lambda,
                alpha: s.params.alpha,
                mean_logloss: s.mean_log_loss,
                rows: s.rows,
                racing: s.racing,
            })
            .collect(),
    });
    Summary {
        n: fit.shape.rows,
        mean_logloss: fit.mean_log_loss,
        accuracy: fit.accuracy,
        selected: fit.selected.clone(),
        updates_per_sec: fit.updates_per_sec,
        classes: fit.classes,
        features: fit.shape.features,
        binary: fit.shape.binary,
        format: match fit.shape.format {
            RowFormat::Csv => "csv",
            RowFormat::Sparse => "sparse",
        },
        selected_names: (!fit.shape.names.is_empty()).then(|| {
            fit.selected
                .iter()
                .map(|&column| fit.shape.feature_name(column))
                .collect()
        }),
        lambda: fit.params.lambda,
        alpha: fit.params.alpha,
        intercept: asked.intercept,
        auto,
    }
}

/// `fit` of the rows of `input`, asked as `asked`, as a table for people.
pub fn text(fit: &FitResult, input: &Path, asked: Asked) -> String {
    let mut out = String::new();
    let kind = match (fit.shape.binary, fit.shape.format) {
        (true, RowFormat::Csv) => "binary CSV features, sparse path",
        (true, RowFormat::Sparse) => "binary sparse-row features, sparse path",
        (false, RowFormat::Csv) => "real-valued CSV features, dense path",
        (false, RowFormat::Sparse) => "real-valued sparse-row features, sparse path",
    };
    let _ = writeln!(
        out,
        "{}: {} rows, {} {kind}, {} classes",
        input.display(),
        fit.shape.rows,
        fit.shape.features,
        fit.classes
    );
    let _ = writeln!(
        out,
        "mDAGL  lambda = {}  alpha = {}  {}",
        asked.lambda.chosen(fit.params.lambda),
        asked.alpha.chosen(fit.params.alpha),
        if asked.intercept {
            "with intercept"
        } else {
            "no intercept"
        }
    );
    if let [_, runner_up, ..] = fit.standings.as_slice() {
        let _ = writeln!(
            out,
            "  raced {} settings in one pass; the runner-up, lambda = {} alpha = {}, scored {:.4} \
             nats ({} rows)",
            fit.standings.len(),
            runner_up.params.lambda,
            runner_up.params.alpha,
            runner_up.mean_log_loss,
            runner_up.rows
        );
    }
    let _ = writeln!(
        out,
        "  prequential mean log-loss  {:.4} nats   (uniform guess: {:.4})",
        fit.mean_log_loss,
        (fit.classes as f64).ln()
    );
    let _ = writeln!(
        out,
        "  prequential accuracy       {:.2} %",
        100.0 * fit.accuracy
    );
    selected_lines(&mut out, fit);
    let _ = writeln!(
        out,
        "  update throughput          {:.0} updates/s ({:.1} ms learning)",
        fit.updates_per_sec,
        fit.seconds * 1e3
    );
    out
}

/// The selected features: how many, then their names or columns.
fn selected_lines(out: &mut String, fit: &FitResult) {
    let columns = match (fit.shape.names.is_empty(), fit.shape.format) {
        (false, _) => "named by the header",
        (true, RowFormat::Csv) => "0-based feature columns",
        (true, RowFormat::Sparse) => "columns as numbered in the rows",
    };
    let _ = writeln!(
        out,
        "  selected features          {} of {} ({columns})",
        fit.selected.len(),
        fit.shape.features
    );
    if fit.selected.is_empty() && fit.standings.is_empty() {
        let _ = writeln!(
            out,
            "    none: no column's average gradient reached lambda x sqrt(K); \
             `--lambda auto --alpha auto` races smaller settings"
        );
    }
    let per_line = if fit.shape.names.is_empty() { 16 } else { 6 };
    for line in fit.selected.chunks(per_line) {
        let cols: Vec<String> = line.iter().map(|&c| fit.shape.feature_name(c)).collect();
        let _ = writeln!(out, "    {}", cols.join(" "));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hyper_parameter_is_a_number_or_auto() {
        assert_eq!("auto".parse(), Ok(Hyper::Auto));
        assert_eq!("0.05".parse(), Ok(Hyper::Value(0.05)));
        assert!("fast".parse::<Hyper>().unwrap_err().contains("\"fast\""));
        assert_eq!(Hyper::Auto.chosen(0.005), "auto (chose 0.005)");
        assert_eq!(Hyper::Value(1.5).to_string(), "1.5");
    }
}
