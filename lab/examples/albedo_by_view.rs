//! Where a reconstruction's environment-light loss sits: an environment integrates f over every
//! incoming direction, so a view elevation where the reconstruction's directional albedo is off
//! shows up as a dark or bright ring on the sphere. For the product's plan (`auto`, from the photo
//! estimate, as `gonio-lab closed-loop`'s `adaptive`) and the uniform grid at one level, it prints
//! (1) per view elevation theta_o, the directional albedo (cosine-weighted mean of f over the
//! incoming hemisphere, averaged over the view azimuth) of the truth and each reconstruction's
//! ratio to it per channel, the fitted prior's alone in brackets; (2) per incoming slice (the
//! plan's own theta_i) and theta_o, the ratio of f summed over phi_o; (3) along one slice at two
//! view elevations, f (channel sum) of the truth, each reconstruction and the product's prior per
//! azimuth step around the mirror direction (phi_o = 180 deg).
//!
//!     cargo run --release -p gonio-lab --example albedo_by_view -- LEVEL SPEC [SLICE]
//!
//! SLICE (default 5, theta_i 64 deg of the 8 incoming elevations) picks part (3)'s slice. Used in
//! docs/planner.md ("Guided residual lookup") to locate the real satin's environment-light loss.

use anyhow::Context;
use glam::DVec3;
use gonio::brdf::frame::from_spherical;
use gonio::brdf::Material;
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::{incoming_thetas, square_grids, PlanConfig, Planner, Strategy};
use gonio::reconstruct::{reconstruct, Reconstruction};
use gonio_lab::plan::tradeoff::{capture_photo, photo_estimate};
use std::f64::consts::TAU;

/// The directional albedo at view elevation `theta_o`: incoming directions stratified
/// cosine-weighted (sin^2 theta_i uniform), 8 view azimuths.
fn albedo(m: &dyn Material, theta_o: f64) -> DVec3 {
    let (rings, steps, views) = (24, 48, 8);
    let mut sum = DVec3::ZERO;
    for v in 0..views {
        let wo = from_spherical(theta_o, v as f64 / views as f64 * TAU);
        for a in 0..rings {
            let theta_i = ((a as f64 + 0.5) / rings as f64).sqrt().asin();
            for b in 0..steps {
                sum += m.eval(from_spherical(theta_i, b as f64 / steps as f64 * TAU), wo);
            }
        }
    }
    sum * std::f64::consts::PI / (rings * steps * views) as f64
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let level: usize = args.next().context("LEVEL SPEC [SLICE]")?.parse().context("LEVEL")?;
    let spec = args.next().context("LEVEL SPEC [SLICE]")?;
    let slice: usize = args.next().map_or(Ok(5), |s| s.parse()).context("SLICE")?;
    let encoder = Encoder::shipped(ModelKind::Ggx)?;
    let (_, photo) = capture_photo(&spec)?;
    let (estimate, _) = photo_estimate(&photo, &encoder)?;
    let truth = gonio::brdf::parse_material(&spec)?;
    let mut recs: Vec<(&str, Reconstruction)> = Vec::new();
    for (name, strategy) in [("auto", Strategy::Auto), ("uniform", Strategy::Uniform)] {
        let config = PlanConfig {
            strategy,
            grids: square_grids(level),
            ..PlanConfig::default()
        };
        let plan = Planner::new(gonio::instrument::default_instrument(), estimate.clone())?.plan(&config)?;
        let values = plan.measure(truth.as_ref());
        recs.push((name, reconstruct(&plan, level, &values)?));
    }
    let thetas = incoming_thetas(PlanConfig::default().k);
    anyhow::ensure!(
        slice < thetas.len(),
        "SLICE {slice}: the plan has {} slices",
        thetas.len()
    );

    println!("{spec}, level {level}");
    println!(
        "(1) theta_o, truth's albedo (channel mean), per plan: reconstruction / truth (RGB) (prior alone / truth)"
    );
    for t in (0..18).map(|i| (i as f64 * 5.0).to_radians()) {
        let want = albedo(truth.as_ref(), t);
        let mut line = format!("{:5.0}  {:.4}", t.to_degrees(), want.element_sum() / 3.0);
        for (name, rec) in &recs {
            let r = albedo(rec, t) / want;
            let p = rec
                .prior()
                .map_or(f64::NAN, |p| (albedo(p, t) / want).element_sum() / 3.0);
            line += &format!("  {name} {:.3} {:.3} {:.3} ({p:.3})", r.x, r.y, r.z);
        }
        println!("{line}");
    }
    for (name, rec) in &recs {
        println!(
            "(2) {name}: rows the plan's theta_i, columns theta_o 5..85 deg: sum over phi_o of reconstruction / truth"
        );
        for &ti in &thetas {
            let wi = from_spherical(ti, 0.0);
            let mut line = format!("{:3.0}", ti.to_degrees());
            for b in 0..9 {
                let to = (5.0 + 10.0 * b as f64).to_radians();
                let (mut got, mut want) = (0.0, 0.0);
                for p in 0..36 {
                    let wo = from_spherical(to, p as f64 / 36.0 * TAU);
                    got += rec.eval(wi, wo).element_sum();
                    want += truth.eval(wi, wo).element_sum();
                }
                line += &format!(" {:.3}", got / want);
            }
            println!("{line}");
        }
    }
    let wi = from_spherical(thetas[slice], 0.0);
    let auto = &recs[0].1;
    for to in [65.0f64, 75.0] {
        println!(
            "(3) theta_i {:.0}, theta_o {to:.0}: phi_o, f summed over channels: truth, auto, uniform, auto's prior",
            thetas[slice].to_degrees()
        );
        for p in 8..=12 {
            let phi = p as f64 * 15.0;
            let wo = from_spherical(to.to_radians(), phi.to_radians());
            let prior = auto.prior().map_or(f64::NAN, |m| m.eval(wi, wo).element_sum());
            println!(
                "{phi:4.0} {:.4} {:.4} {:.4} {prior:.4}",
                truth.eval(wi, wo).element_sum(),
                auto.eval(wi, wo).element_sum(),
                recs[1].1.eval(wi, wo).element_sum()
            );
        }
    }
    Ok(())
}
