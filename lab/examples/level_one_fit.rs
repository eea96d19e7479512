//! Issue 28's smallest regime (env FLIP <= 0.03 at <= 24 directions, held-out): which level-1 fit
//! closes the gap to the peer? At level 1 the product's reconstruction is the fitted prior alone,
//! so the fit is all there is. Per material of a closed-loop preset (planned as `gonio-lab
//! closed-loop` plans: the shipped encoder on a capture photo), three level-1 direction sets:
//! - `photo`: the photo plan's level 1 (the product's);
//! - `designed`: the peer's 24-direction design (as trial `designed`);
//! - `mixed`: the photo plan's level 1 over `MIXED_ELEVATIONS` incoming elevations with the
//!   design of the remaining count beside it (`Designed::mixed`).
//!
//! Each set is reconstructed by `product` (the product's prior, basis ridge `PCA_RIDGE`) and by
//! `guarded r=R` (the same choice at basis ridge R: cross-validation, bound and fit), and the
//! design also by `peer` (the basis alone at the peer's `RIDGE`: the peer's own reconstruction).
//!
//! Printed: per material and variant point FLIP / env FLIP / brdf_log_err, then per variant the
//! geometric means and how many level-1 fits picked the basis (docs/nielsen2015.md; the committed
//! outputs: docs/tradeoff/closed-loop/level-one-fit/<preset>.txt).
//!
//!     cargo run --release -p gonio-lab --example level_one_fit -- [training|heldout|real]

use gonio::brdf::Material;
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::predict::{score, Scorer};
use gonio::plan::{Planner, Strategy};
use gonio::reconstruct::pca::selected::{self, PcaPrior};
use gonio::reconstruct::{reconstruct_with, Levels, Prior};
use gonio_lab::plan::tradeoff::closed_loop::{photo_plan, LoopPreset, ENV_SIZE};
use gonio_lab::plan::tradeoff::designed::Designed;
use gonio_lab::plan::tradeoff::{choose, peer};

const RIDGES: [f64; 2] = [1e-3, 1e-2];
/// Incoming elevations of the photo plan's level 1 in the `mixed` rows (the design fills the rest).
const MIXED_ELEVATIONS: usize = 4;

fn main() -> anyhow::Result<()> {
    let name = std::env::args().nth(1).unwrap_or_else(|| "heldout".into());
    let preset = LoopPreset::named(&name).map_err(anyhow::Error::msg)?;
    let encoder = Encoder::shipped(ModelKind::Ggx)?;
    let instrument = gonio::instrument::default_instrument();
    let mut env = gonio::render::Scene::load(std::path::Path::new("examples/sphere-sky.toml"))?;
    env.camera.width = ENV_SIZE;
    env.camera.height = ENV_SIZE;
    let mut scorer = Scorer::new(ENV_SIZE)?.with_env(env);
    let product = selected::product_prior().map_err(anyhow::Error::msg)?;
    let mut variants: Vec<(String, Box<dyn Prior>)> = vec![(
        "product".into(),
        Box::new(selected::product_prior().map_err(anyhow::Error::msg)?),
    )];
    for r in RIDGES {
        let mut guarded = selected::product_prior().map_err(anyhow::Error::msg)?;
        guarded.pca.ridge = r;
        variants.push((format!("guarded r={r}"), Box::new(guarded)));
    }
    let peer_fit = PcaPrior {
        model: product.pca.model.clone(),
        ridge: gonio_lab::plan::nielsen::RIDGE,
    };
    let (design, seconds) = peer::design(&instrument, 24)?;
    // Per (plan, variant): point, env, brdf per material, and basis picks.
    let mut table: Vec<(String, Vec<[f64; 3]>, usize)> = Vec::new();
    for spec in preset.materials() {
        let (estimate, plan) = photo_plan(&spec, &encoder, &instrument, 4)?;
        let truth = gonio::brdf::parse_material(&spec)?;
        let truth_point = scorer.render(gonio::brdf::parse_material(&spec)?);
        let truth_env = scorer
            .render_env(gonio::brdf::parse_material(&spec)?, &spec)
            .ok_or_else(|| anyhow::anyhow!("no env"))?;
        let designed = Designed::new(&plan, &design, seconds).ok_or_else(|| anyhow::anyhow!("design"))?;
        let photo_values = plan.measure(truth.as_ref());
        let design_values: Vec<_> = designed.pairs().iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        let small = Planner::new(instrument, estimate.clone())?.plan(&choose::config(
            Strategy::Auto,
            &[(MIXED_ELEVATIONS, 2)],
            0,
        ))?;
        let rest = plan.levels[0]
            .cumulative_directions
            .saturating_sub(small.levels[0].cumulative_directions);
        let (part, part_seconds) = peer::design(&instrument, rest)?;
        let mixed = Designed::mixed(&small, &part, part_seconds).ok_or_else(|| anyhow::anyhow!("mixed"))?;
        let mixed_values: Vec<_> = mixed.pairs().iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        let sets: [(&str, &dyn Levels, &[glam::DVec3]); 3] = [
            ("photo", &plan, &photo_values),
            ("designed", &designed, &design_values),
            ("mixed", &mixed, &mixed_values),
        ];
        let mut line = Vec::new();
        let mut row = 0;
        for (set, levels, values) in sets {
            let mut all: Vec<(String, &dyn Prior)> = variants.iter().map(|(n, p)| (n.clone(), p.as_ref())).collect();
            if set == "designed" {
                all.push(("peer".into(), &peer_fit));
            }
            for (variant, prior) in all {
                let rec = reconstruct_with(levels, 1, values, prior)?;
                let pca = rec.prior().is_some_and(|p| p.kind() == "pca");
                let point = score(&truth_point, &scorer.render(Box::new(rec.clone())))?.flip;
                let env = score(
                    &truth_env,
                    &scorer
                        .render_env(Box::new(rec.clone()), &spec)
                        .ok_or_else(|| anyhow::anyhow!("no env"))?,
                )?
                .flip;
                let brdf = scorer.log_err(truth.as_ref(), &rec);
                let label = format!("{set} {variant}");
                if table.len() <= row {
                    table.push((label.clone(), Vec::new(), 0));
                }
                table[row].1.push([point, env, brdf]);
                table[row].2 += pca as usize;
                row += 1;
                line.push(format!(
                    "{label} {point:.4}/{env:.4}/{brdf:.5}{}",
                    if pca { " pca" } else { "" }
                ));
            }
        }
        println!(
            "{spec}: level 1 photo {} / mixed {} + {} designed; {}",
            plan.levels[0].cumulative_directions,
            small.levels[0].cumulative_directions,
            part.len(),
            line.join("; ")
        );
    }
    println!(
        "\ngeometric means over {} materials (point FLIP / env FLIP / brdf_log_err), basis picks:",
        preset.materials().len()
    );
    for (label, v, picks) in &table {
        let g = |i: usize| (v.iter().map(|x| x[i].max(1e-9).ln()).sum::<f64>() / v.len().max(1) as f64).exp();
        println!("| {label} | {:.4} | {:.4} | {:.5} | {picks} |", g(0), g(1), g(2));
    }
    Ok(())
}
