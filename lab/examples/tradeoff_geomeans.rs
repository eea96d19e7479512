//! Geometric means over materials of `tradeoff.csv` files side by side, per strategy and direction
//! level, for docs/nielsen2015.md (runs made with different `--prior`s are told apart by the label):
//!
//!     cargo run --release -p gonio-lab --example tradeoff_geomeans -- LABEL=FILE.csv [LABEL=FILE.csv ...]
//!
//! Printed: one row per (label, strategy, level) with the mean directions and the geometric means
//! of brdf_log_err, liu_log_err, point FLIP and environment FLIP (each floored at 1e-6).

use anyhow::{bail, Context};
use std::collections::BTreeMap;

#[derive(serde::Deserialize)]
struct Row {
    material: String,
    strategy: String,
    level: usize,
    directions: usize,
    flip: f64,
    flip_env: f64,
    brdf_log_err: f64,
    liu_log_err: f64,
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.is_empty() {
        bail!("usage: tradeoff_geomeans LABEL=FILE.csv [LABEL=FILE.csv ...]");
    }
    println!("| run | strategy | level | directions | materials | brdf_log_err | liu_log_err | FLIP | FLIP env |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for arg in &args {
        let (label, path) = arg.split_once('=').context("each argument is LABEL=FILE.csv")?;
        let mut reader = csv::Reader::from_path(path).with_context(|| path.to_string())?;
        // (strategy, level, directions for level 0) -> rows.
        let mut groups: BTreeMap<(String, usize, usize), Vec<Row>> = BTreeMap::new();
        for row in reader.deserialize::<Row>() {
            let row = row.with_context(|| path.to_string())?;
            let small = if row.level == 0 { row.directions } else { 0 };
            groups
                .entry((row.strategy.clone(), row.level, small))
                .or_default()
                .push(row);
        }
        for ((strategy, level, _), rows) in &groups {
            let n = rows.len() as f64;
            let gm = |f: fn(&Row) -> f64| (rows.iter().map(|r| f(r).max(1e-6).ln()).sum::<f64>() / n).exp();
            let dirs = rows.iter().map(|r| r.directions).sum::<usize>() as f64 / n;
            let materials = rows
                .iter()
                .map(|r| r.material.as_str())
                .collect::<std::collections::BTreeSet<_>>();
            println!(
                "| {label} | {strategy} | {level} | {dirs:.0} | {} | {:.5} | {:.5} | {:.4} | {:.4} |",
                materials.len(),
                gm(|r| r.brdf_log_err),
                gm(|r| r.liu_log_err),
                gm(|r| r.flip),
                gm(|r| r.flip_env)
            );
        }
    }
    Ok(())
}
