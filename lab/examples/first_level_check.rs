//! Can level 1 of the closed loop estimate its own error? Level 1 has no previous level, so the
//! product's loop has no estimate there and no rule stops there, which costs the stop rule its time
//! goal wherever level 1 already meets the target. This measures measurement-only candidates on a preset's materials, planned as
//! `gonio-lab closed-loop` plans them (the shipped encoder on a capture photo, the product's plan):
//! - `change`: point FLIP between level 1's reconstruction and level 1 without every other incoming
//!   elevation (`choose::LeaveOut`), the analogue of the loop's change between levels;
//! - `fit_rms` / `fit_q90`: the fitted prior's log residuals at the measurements;
//! - `cv_rms` / `cv_q90`: the left-out elevations' log residuals against the subset's reconstruction.
//!
//!     cargo run --release -p gonio-lab --example first_level_check -- [training|heldout|real]
//!
//! Printed: per material the true point FLIP and each candidate; per candidate its Spearman rank
//! correlation with the true FLIP; the quantiles of true / change (what a ratio estimate would use);
//! and from the preset's recorded `docs/tradeoff/closed-loop/<preset>/closed-loop.csv`, on how many
//! materials level 1 already meets each stop target.

use glam::DVec3;
use gonio::brdf::Material;
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::closed_loop::ESTIMATE_SIZE;
use gonio::plan::predict::{score, Scorer};
use gonio::reconstruct::{reconstruct, Levels, RATIO_FLOOR};
use gonio_lab::plan::tradeoff::choose::{alternate_slices, LeaveOut};
use gonio_lab::plan::tradeoff::closed_loop::{photo_plan, quantile, read_rows, LoopPreset, LoopRow};

const CANDIDATES: [&str; 5] = ["change", "fit_rms", "fit_q90", "cv_rms", "cv_q90"];

fn log_space(v: DVec3) -> DVec3 {
    v.max(DVec3::ZERO).map(|x| (x + RATIO_FLOOR).ln())
}

/// |log residual| per channel of `values[d]` against `model`, for the measurements `ds`.
fn residuals(ds: &[usize], measured: &[(usize, DVec3, DVec3)], values: &[DVec3], model: &dyn Material) -> Vec<f64> {
    ds.iter()
        .flat_map(|&d| {
            let (_, wi, wo) = measured[d];
            let r = log_space(values[d]) - log_space(model.eval(wi, wo));
            [r.x.abs(), r.y.abs(), r.z.abs()]
        })
        .collect()
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

fn ranks(v: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..v.len()).collect();
    order.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    let mut r = vec![0.0; v.len()];
    for (rank, &i) in order.iter().enumerate() {
        r[i] = rank as f64;
    }
    r
}

fn spearman(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let d2: f64 = ranks(a).iter().zip(ranks(b)).map(|(x, y)| (x - y).powi(2)).sum();
    1.0 - 6.0 * d2 / (n * (n * n - 1.0))
}

fn main() -> anyhow::Result<()> {
    let name = std::env::args().nth(1).unwrap_or_else(|| "training".into());
    let preset = LoopPreset::named(&name).map_err(anyhow::Error::msg)?;
    let encoder = Encoder::shipped(ModelKind::Ggx)?;
    let instrument = gonio::instrument::default_instrument();
    let mut scorer = Scorer::new(ESTIMATE_SIZE)?;
    let (mut truths, mut candidates) = (Vec::new(), vec![Vec::new(); CANDIDATES.len()]);
    for spec in preset.materials() {
        let (_, plan) = photo_plan(&spec, &encoder, &instrument, 4)?;
        let truth = gonio::brdf::parse_material(&spec)?;
        let values = plan.measure(truth.as_ref());
        let nodes = plan.level_nodes(1).ok_or_else(|| anyhow::anyhow!("no level 1"))?;
        let values = &values[..nodes.measured.len()];
        let rec = reconstruct(&plan, 1, values)?;
        let keep = alternate_slices(nodes.thetas.len()).ok_or_else(|| anyhow::anyhow!("too few elevations"))?;
        let subset = LeaveOut::new(&plan, 1, values, &keep, false).ok_or_else(|| anyhow::anyhow!("no subset"))?;
        let coarse = reconstruct(&subset, 1, &subset.values)?;
        let left_out: Vec<usize> = (0..nodes.measured.len())
            .filter(|&d| !keep.contains(&nodes.measured[d].0))
            .collect();
        let image = scorer.render(Box::new(rec.clone()));
        let true_flip = score(&scorer.render(gonio::brdf::parse_material(&spec)?), &image)?.flip;
        let change = score(&scorer.render(Box::new(coarse.clone())), &image)?.flip;
        let all: Vec<usize> = (0..nodes.measured.len()).collect();
        let mut fit = match rec.prior() {
            Some(p) => residuals(&all, &nodes.measured, values, p),
            None => Vec::new(),
        };
        let mut cv = residuals(&left_out, &nodes.measured, values, &coarse);
        fit.sort_by(f64::total_cmp);
        cv.sort_by(f64::total_cmp);
        let row = [change, rms(&fit), quantile(fit, 0.9), rms(&cv), quantile(cv, 0.9)];
        println!(
            "{spec}: true point FLIP {true_flip:.4}; {}",
            CANDIDATES
                .iter()
                .zip(row)
                .map(|(n, v)| format!("{n} {v:.4}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
        truths.push(true_flip);
        for (c, v) in candidates.iter_mut().zip(row) {
            c.push(v);
        }
    }
    for (n, c) in CANDIDATES.iter().zip(&candidates) {
        println!(
            "Spearman rank correlation with the true FLIP, {n}: {:.2}",
            spearman(c, &truths)
        );
    }
    let ratios: Vec<f64> = truths
        .iter()
        .zip(&candidates[0])
        .map(|(t, c)| t / c.max(1e-9))
        .collect();
    println!(
        "true / change over {} materials: median {:.3}, 5% {:.3}, 95% {:.3}",
        ratios.len(),
        quantile(ratios.clone(), 0.5),
        quantile(ratios.clone(), 0.05),
        quantile(ratios, 0.95)
    );
    let csv = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join(format!("../docs/tradeoff/closed-loop/{name}/closed-loop.csv"));
    let rows = read_rows(&csv)?;
    let first: Vec<&LoopRow> = rows
        .iter()
        .filter(|r| r.strategy == "adaptive" && r.level == 1)
        .collect();
    for target in [0.02, 0.01] {
        println!(
            "{}: level 1 already meets point FLIP {target} on {} of {} materials (where the loop cannot stop)",
            csv.display(),
            first
                .iter()
                .filter(|r| r.true_flip.is_some_and(|t| t <= target))
                .count(),
            first.len()
        );
    }
    Ok(())
}
