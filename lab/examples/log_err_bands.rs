//! Where a reconstruction's `brdf_log_err` comes from, level by level: the fit's direction set
//! split into bands of the half-vector angle theta_h (each band's share of the mean), for the `auto`
//! plan (from the photo estimate, as `gonio-lab closed-loop`'s `adaptive`), with the fitted prior
//! alone beside it. With `--peak`, the luminance of the truth, the reconstruction and the prior at
//! each pair of the first two bands (the mirror pairs: 13 of the 21 below 1 deg are the one pair
//! wi = wo = n, repeated over phi_i). With `--uniform`, the uniform grid's plan instead of `auto`
//! (the closed loop's `uniform` rows).
//!
//!     cargo run --release -p gonio-lab --example log_err_bands [--peak] [--uniform] [MATERIAL ...]
//!
//! Used in docs/tradeoff/README.md ("The normal-incidence peak") to find the closed loop's level-4
//! brdf_log_err jumps on sharp materials at wi = wo = n.

use anyhow::Context;
use glam::DVec3;
use gonio::brdf::fit::fit_directions;
use gonio::brdf::frame::{half_vector, theta_of};
use gonio::brdf::{parse_material, Material};
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::predict::log_err_over;
use gonio::plan::{PlanConfig, Planner, Strategy};
use gonio_lab::plan::tradeoff::{capture_photo, photo_estimate};

/// Band edges in theta_h (degrees).
const EDGES: [f64; 9] = [0.0, 1.0, 2.0, 4.0, 7.0, 15.0, 30.0, 60.0, 91.0];

fn main() -> anyhow::Result<()> {
    let (flags, mut materials): (Vec<String>, Vec<String>) =
        std::env::args().skip(1).partition(|a| a.starts_with("--"));
    let peak = flags.iter().any(|f| f == "--peak");
    let strategy = if flags.iter().any(|f| f == "--uniform") {
        Strategy::Uniform
    } else {
        Strategy::Auto
    };
    if let Some(bad) = flags.iter().find(|f| *f != "--peak" && *f != "--uniform") {
        anyhow::bail!("unknown flag {bad} (--peak, --uniform)");
    }
    if materials.is_empty() {
        materials = vec!["nbrdf:tungsten-carbide".into()];
    }
    let encoder = Encoder::shipped(ModelKind::Ggx)?;
    let instrument = gonio::instrument::default_instrument();
    let pairs = fit_directions();
    // Opposite directions have no half vector: counted in the last band (facing away).
    let theta_h = |wi: DVec3, wo: DVec3| half_vector(wi, wo).map_or(180.0, |h| theta_of(h).to_degrees());
    let band_of = |&(wi, wo): &(DVec3, DVec3)| {
        let t = theta_h(wi, wo);
        EDGES[1..].iter().position(|&e| t < e).unwrap_or(EDGES.len() - 2)
    };
    let mut banded: Vec<Vec<(DVec3, DVec3)>> = vec![Vec::new(); EDGES.len() - 1];
    for p in &pairs {
        banded[band_of(p)].push(*p);
    }
    for spec in &materials {
        let truth = parse_material(spec)?;
        let (estimate, _) = photo_estimate(&capture_photo(spec)?.1, &encoder)?;
        let config = PlanConfig {
            strategy,
            ..PlanConfig::default()
        };
        let plan = Planner::new(instrument, estimate.clone())?.plan(&config)?;
        println!(
            "== {spec} ({} plan); brdf_log_err share by theta_h band (upper edges {:?})",
            plan.warp,
            &EDGES[1..]
        );
        println!("  band pairs: {:?}", banded.iter().map(Vec::len).collect::<Vec<_>>());
        let values = plan.measure(truth.as_ref());
        for l in 1..=plan.levels.len() {
            let rec = gonio::reconstruct::reconstruct(&plan, l, &values)?;
            let total = log_err_over(&pairs, truth.as_ref(), &rec);
            let shares = |m: &dyn Material| -> Vec<String> {
                banded
                    .iter()
                    .map(|b| {
                        format!(
                            "{:.5}",
                            log_err_over(b, truth.as_ref(), m) * b.len() as f64 / pairs.len() as f64
                        )
                    })
                    .collect()
            };
            println!(
                "  level {l} ({} dirs) brdf_log_err {total:.5}: {}",
                plan.level(l).context("level")?.cumulative_directions,
                shares(&rec).join(" ")
            );
            if let Some(p) = rec.prior() {
                println!(
                    "    prior {} alone {:.5}: {}",
                    p.kind(),
                    log_err_over(&pairs, truth.as_ref(), p),
                    shares(p).join(" ")
                );
                if peak {
                    for (wi, wo) in banded[0].iter().chain(&banded[1]) {
                        let lum = |v: DVec3| gonio::brdf::frame::luminance(v);
                        println!(
                            "      ti {:5.1} to {:5.1} th {:.3} truth {:10.3} rec {:10.3} prior {:10.3}",
                            theta_of(*wi).to_degrees(),
                            theta_of(*wo).to_degrees(),
                            theta_h(*wi, *wo),
                            lum(truth.eval(*wi, *wo)),
                            lum(rec.eval(*wi, *wo)),
                            lum(p.eval(*wi, *wo))
                        );
                    }
                }
            }
        }
    }
    Ok(())
}
