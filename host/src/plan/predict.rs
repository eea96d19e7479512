//! The predictive level rule (`gonio plan` and `gonio scan` choose their level with it) and the
//! scores it and the accuracy report use: the capture scene (`examples/sphere-point.toml`: a
//! sphere under a point light) of a reconstruction against that of a reference, with
//! `render::metrics` (RMSE and PSNR of the 8-bit sRGB images as the paper computed them, mean LDR
//! FLIP), and `brdf_log_err` over the fit's direction set (`fit::fit_directions`).

use super::{Estimate, Plan, PlanError};
use crate::brdf::fit::fit_directions;
use crate::brdf::Material;
use crate::reconstruct::{reconstruct_with, NoPrior};
use crate::render::brdf_sampling::BrdfSampler;
use crate::render::metrics::{compare, Comparison};
use crate::render::quadrature::{render_quadrature, EnvQuadrature};
use crate::render::{render_plain, Image, Scene};
use glam::DVec3;
use std::path::Path;

/// The capture scene the renders use.
const CAPTURE_SCENE: &str = include_str!("../../../examples/sphere-point.toml");

/// Renders a material in the capture scene (point light) and, if given, in an environment-lit
/// scene; scores BRDF-space error over the fit's direction set.
pub struct Scorer {
    scene: Scene,
    /// The environment-lit scene and its fixed light directions.
    env: Option<(Scene, EnvQuadrature)>,
    pairs: Vec<(DVec3, DVec3)>,
}

impl Scorer {
    pub fn new(size: usize) -> Result<Self, PlanError> {
        let mut scene = Scene::from_toml(CAPTURE_SCENE, Path::new("examples/sphere-point.toml"))
            .map_err(|e| PlanError::Invalid(e.to_string()))?;
        scene.camera.width = size;
        scene.camera.height = size;
        Ok(Self {
            scene,
            env: None,
            pairs: fit_directions(),
        })
    }

    /// Also render under `env` (e.g. `examples/sphere-sky.toml`), with its own camera and sub-pixel
    /// grid; its environment is lit by `EnvQuadrature::of` (a scene without one renders its delta
    /// lights only).
    pub fn with_env(mut self, env: Scene) -> Self {
        let quad = env.environment.as_ref().map_or(
            EnvQuadrature {
                directions: Vec::new(),
                weights: Vec::new(),
            },
            EnvQuadrature::of,
        );
        self.env = Some((env, quad));
        self
    }

    pub fn render(&mut self, material: Box<dyn Material>) -> Image {
        self.scene.material = material;
        render_plain(&self.scene, &self.scene.settings, &|| {})
    }

    /// The environment render: deterministic quadrature over the map's fixed light directions
    /// (`render::quadrature`), so the truth and its reconstructions are lit by the same directions
    /// and two runs agree exactly. `sampler_spec` no longer changes the image (nothing is sampled);
    /// it is kept so that callers name the truth's spec as before, and sets the scene's sampler for
    /// anyone who renders the scene by Monte Carlo afterwards.
    pub fn render_env(&mut self, material: Box<dyn Material>, sampler_spec: &str) -> Option<Image> {
        let (env, quad) = self.env.as_mut()?;
        env.material = material;
        env.sampler = BrdfSampler::for_spec(sampler_spec);
        Some(render_quadrature(env, quad))
    }

    /// `brdf_log_err`: `log_err_over` the documented direction set.
    pub fn log_err(&self, truth: &dyn Material, test: &dyn Material) -> f64 {
        log_err_over(&self.pairs, truth, test)
    }
}

/// Mean over `pairs` of |log(1 + f cos) - log(1 + f_test cos)|, averaged over RGB (Liu et al. 2023);
/// 0 for no pairs.
pub fn log_err_over(pairs: &[(DVec3, DVec3)], truth: &dyn Material, test: &dyn Material) -> f64 {
    let mut sum = 0.0;
    for &(wi, wo) in pairs {
        let a = truth.eval(wi, wo) * wo.z;
        let b = test.eval(wi, wo) * wo.z;
        for c in 0..3 {
            sum += (a[c].max(0.0).ln_1p() - b[c].max(0.0).ln_1p()).abs() / 3.0;
        }
    }
    sum / pairs.len().max(1) as f64
}

/// Render side of the predictive rule's simulated captures.
pub const PREDICTIVE_SIZE: usize = 128;

/// The predictive stopping rule (no ground truth needed): simulate the scan on the estimate itself
/// (measure it at the plan's directions, reconstruct each level) and return the first level whose
/// capture render meets `meets` against the estimate's own render; None if no level does.
/// `gonio plan` and `gonio scan` both choose their level with it.
///
/// The simulation reconstructs without the fitted prior (`NoPrior`), whatever the scan's: an
/// analytic estimate is exactly what the prior fits, so with it every level would predict a perfect
/// render and the rule would always stop at the first. Without it the rule predicts the grid's own
/// error, an upper estimate of the real scan's (which has the prior to help).
pub fn predictive_level(
    plan: &Plan,
    estimate: &Estimate,
    meets: impl Fn(&Comparison) -> bool,
) -> Result<Option<usize>, PlanError> {
    let mut scorer = Scorer::new(PREDICTIVE_SIZE)?;
    let reference = scorer.render(estimate.material());
    let values = plan.measure(estimate.material().as_ref());
    for l in &plan.levels {
        let image = scorer.render(Box::new(reconstruct_with(plan, l.level, &values, &NoPrior)?));
        if meets(&score(&reference, &image)?) {
            return Ok(Some(l.level));
        }
    }
    Ok(None)
}

/// RMSE and PSNR of the 8-bit sRGB images (exposure 1, clipped, values / 255, peak 1, whole image),
/// as the paper computed them, and the renderer's mean LDR FLIP.
pub fn score(reference: &Image, test: &Image) -> Result<Comparison, PlanError> {
    let (c, _) = compare(reference, test).map_err(|e| PlanError::Invalid(e.to_string()))?;
    let (a, b) = (reference.to_srgb8(), test.to_srgb8());
    let sq: f64 = a
        .iter()
        .zip(&b)
        .map(|(&x, &y)| ((x as f64 - y as f64) / 255.0).powi(2))
        .sum();
    let rmse = (sq / a.len().max(1) as f64).sqrt();
    Ok(Comparison {
        rmse,
        psnr: crate::render::metrics::psnr(rmse),
        flip: c.flip,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::instrument::default_instrument;
    use crate::plan::{ggx_estimate, square_grids, PlanConfig, Planner};

    fn small_plan(estimate: &Estimate) -> Plan {
        let config = PlanConfig {
            k: 3,
            grids: square_grids(2),
            ..PlanConfig::default()
        };
        Planner::new(default_instrument(), estimate.clone())
            .expect("planner")
            .plan(&config)
            .expect("plan")
    }

    #[test]
    fn the_predictive_rule_takes_the_first_level_that_meets_the_target() {
        let estimate = ggx_estimate(0.3, 0.2);
        let plan = small_plan(&estimate);
        assert_eq!(predictive_level(&plan, &estimate, |_| true).expect("rule"), Some(1));
        assert_eq!(predictive_level(&plan, &estimate, |_| false).expect("rule"), None);
        // A target only the finer level reaches: its FLIP, simulated on the estimate.
        let mut scorer = Scorer::new(PREDICTIVE_SIZE).expect("scorer");
        let reference = scorer.render(estimate.material());
        let values = plan.measure(estimate.material().as_ref());
        let mut flip = |level: usize| {
            let rec = reconstruct_with(&plan, level, &values, &NoPrior).expect("reconstruct");
            score(&reference, &scorer.render(Box::new(rec))).expect("score").flip
        };
        let (coarse, fine) = (flip(1), flip(2));
        assert!(fine < coarse, "level 2 FLIP {fine} should be below level 1's {coarse}");
        let target = (coarse + fine) / 2.0;
        assert_eq!(
            predictive_level(&plan, &estimate, |c| c.flip <= target).expect("rule"),
            Some(2)
        );
    }

    #[test]
    fn identical_renders_score_infinite_psnr_and_zero_flip() {
        let mut scorer = Scorer::new(32).expect("scorer");
        let a = scorer.render(ggx_estimate(0.2, 0.1).material());
        let c = score(&a, &a).expect("score");
        assert_eq!((c.rmse, c.flip), (0.0, 0.0));
        assert!(c.psnr.is_infinite());
        let b = scorer.render(ggx_estimate(0.05, 0.1).material());
        assert!(score(&a, &b).expect("score").flip > 0.0);
    }
}
