//! Writes the demo stream `tes fit` runs on in the README (`data/fit-demo.csv`), or the
//! robot-shaped and wide streams `bench/peers/run` compares mDAGL and Vowpal Wabbit on.
//!
//! `cargo run -p tes-experiments --bin make-fit-demo -- [--shape demo|robot|wide|wider] [--format csv|sparse] [--seed 2017] [--rows 4000] [--out PATH]`

use std::fs::File;
use std::io::BufWriter;
use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, ValueEnum};
use tes_experiments::{write_labelled_csv, write_labelled_sparse};
use tes_learning::mdagl::synthetic::SyntheticSpec;

/// The streams this writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum StreamShape {
    /// 5 effects; an always-on bias (column 0) and 3 relevant features among 204 irrelevant
    /// ones, each on half the time: `data/fit-demo.csv`.
    Demo,
    /// The arena's shape: 312 binary features each on with probability 15/312, 20 effects
    /// drawn from a multinomial logistic model over 12 of them (weights in ±4), no bias
    /// column.
    Robot,
    /// A wide stream: 1 000 binary features with 40 on per row on average, 5 effects drawn
    /// from a multinomial logistic model over 20 of them (weights in ±4), no bias column.
    Wide,
    /// A wider one: 5 000 binary features with 80 on per row on average, 20 effects over 40
    /// relevant ones (weights in ±4), no bias column.
    Wider,
}

impl StreamShape {
    fn spec(self) -> SyntheticSpec {
        match self {
            StreamShape::Demo => SyntheticSpec {
                classes: 5,
                features: 208,
                relevant: 3,
                density: 0.5,
                bias: true,
                weight_scale: 4.0,
            },
            StreamShape::Robot => SyntheticSpec {
                classes: 20,
                features: 312,
                relevant: 12,
                density: 15.0 / 312.0,
                bias: false,
                weight_scale: 4.0,
            },
            StreamShape::Wide => SyntheticSpec {
                classes: 5,
                features: 1000,
                relevant: 20,
                density: 40.0 / 1000.0,
                bias: false,
                weight_scale: 4.0,
            },
            StreamShape::Wider => SyntheticSpec {
                classes: 20,
                features: 5000,
                relevant: 40,
                density: 80.0 / 5000.0,
                bias: false,
                weight_scale: 4.0,
            },
        }
    }
}

/// How the rows are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum RowFormat {
    /// `label,f0,f1,…` with every column written (0 or 1).
    Csv,
    /// `label column:1 …` with the row's on columns only (the form for wide streams).
    Sparse,
}

/// Generate a seeded labelled stream for `tes fit`.
#[derive(Debug, Parser)]
struct Args {
    /// Which stream.
    #[arg(long, value_enum, default_value = "demo")]
    shape: StreamShape,
    /// How the rows are written.
    #[arg(long, value_enum, default_value = "csv")]
    format: RowFormat,
    /// Seed of the ground-truth model and of every row.
    #[arg(long, default_value_t = 2017)]
    seed: u64,
    /// Number of rows.
    #[arg(long, default_value_t = 4000)]
    rows: usize,
    /// Where to write the CSV.
    #[arg(long, default_value = "data/fit-demo.csv")]
    out: PathBuf,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let spec = args.shape.spec();
    let file =
        File::create(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let mut out = BufWriter::new(file);
    type Writer = fn(&mut BufWriter<File>, SyntheticSpec, u64, usize) -> std::io::Result<Vec<u32>>;
    let write: Writer = match args.format {
        RowFormat::Csv => write_labelled_csv,
        RowFormat::Sparse => write_labelled_sparse,
    };
    let relevant = write(&mut out, spec, args.seed, args.rows)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    out.flush()
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!(
        "wrote {} rows to {} (seed {}; {}relevant feature columns {:?})",
        args.rows,
        args.out.display(),
        args.seed,
        if spec.bias { "bias column 0; " } else { "" },
        relevant
    );
    Ok(())
}
