//! Writes the demo stream `tes fit` runs on in the README: `data/fit-demo.csv`.
//!
//! `cargo run -p tes-experiments --bin make-fit-demo -- [--seed 2017] [--rows 4000] [--out PATH]`

use std::fs::File;
use std::io::BufWriter;
use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use tes_experiments::write_labelled_csv;
use tes_learning::mdagl::synthetic::SyntheticSpec;

/// Generate the seeded labelled-CSV demo stream for `tes fit`.
#[derive(Debug, Parser)]
struct Args {
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
    // 5 effects; an always-on bias (column 0), 3 relevant features among 204 irrelevant ones.
    let spec = SyntheticSpec {
        classes: 5,
        features: 208,
        relevant: 3,
        density: 0.5,
        bias: true,
        weight_scale: 4.0,
    };
    let file =
        File::create(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let mut out = BufWriter::new(file);
    let relevant = write_labelled_csv(&mut out, spec, args.seed, args.rows)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    out.flush()
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!(
        "wrote {} rows to {} (seed {}; bias column 0; relevant feature columns {:?})",
        args.rows,
        args.out.display(),
        args.seed,
        relevant
    );
    Ok(())
}
