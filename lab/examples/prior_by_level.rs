//! Where a level's `brdf_log_err` comes from: per level of the product's plan (`auto`) and of the
//! uniform grid, the error of the reconstruction and of its fitted prior alone, and the prior.
//! When a level is worse than the one before (issue 25's monotonicity), this says whether the fit
//! moved (the prior alone got worse) or the residual grid did.
//!
//!     cargo run --release -p gonio-lab --example prior_by_level -- nbrdf:two-layer-silver [more specs]
//!
//! Planned as `gonio-lab closed-loop` plans (the shipped encoder on a capture photo, 4 levels, 8
//! incoming elevations), measured without noise.

use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::predict::Scorer;
use gonio::plan::{square_grids, PlanConfig, Planner, Strategy};
use gonio::reconstruct::reconstruct;
use gonio_lab::plan::tradeoff::closed_loop::ENV_SIZE;
use gonio_lab::plan::tradeoff::{capture_photo, photo_estimate};

fn main() -> anyhow::Result<()> {
    let specs: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(!specs.is_empty(), "usage: prior_by_level SPEC [SPEC...]");
    let encoder = Encoder::shipped(ModelKind::Ggx)?;
    let scorer = Scorer::new(ENV_SIZE)?;
    for spec in &specs {
        let (_, photo) = capture_photo(spec)?;
        let (estimate, _) = photo_estimate(&photo, &encoder)?;
        let truth = gonio::brdf::parse_material(spec)?;
        for strategy in [Strategy::Auto, Strategy::Uniform] {
            let config = PlanConfig {
                strategy,
                grids: square_grids(4),
                ..PlanConfig::default()
            };
            let plan = Planner::new(gonio::instrument::default_instrument(), estimate.clone())?.plan(&config)?;
            let values = plan.measure(truth.as_ref());
            for level in 1..=plan.levels.len() {
                let rec = reconstruct(&plan, level, &values)?;
                let (alone, fitted) = match rec.prior() {
                    Some(p) => (scorer.log_err(truth.as_ref(), p), p.describe()),
                    None => (f64::NAN, "none".into()),
                };
                println!(
                    "{spec} {strategy:?} level {level}: brdf_log_err reconstruction {:.5}, prior alone {alone:.5}; prior {fitted}",
                    scorer.log_err(truth.as_ref(), &rec)
                );
            }
        }
    }
    Ok(())
}
