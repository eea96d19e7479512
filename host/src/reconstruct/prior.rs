//! What a reconstruction interpolates on top of: a model fitted to a level's own measurements.
//!
//! The product fits `pca::SelectedPrior` (per level, `TwoLobesPrior` or the PCA basis); a trial is
//! another `Prior` (docs/planner.md, "Adding a prior").

use crate::brdf::fit_lobes::{self, DiffuseBound, LobeFresnel};
use crate::brdf::Material;
use crate::reconstruct::pca::bins::BinnedBrdf;
use glam::DVec3;
use std::sync::Arc;

/// A level's measurements as a prior fits them.
#[derive(Clone, Debug)]
pub struct LevelSamples<'a> {
    /// (wi, wo) of each measurement.
    pub pairs: Vec<(DVec3, DVec3)>,
    pub values: &'a [DVec3],
    /// The equal-angle measure each measurement stands for (0 where its warp density is undefined).
    pub weights: Vec<f64>,
    /// Roughness of the estimate the plan was built from.
    pub estimate_alpha: f64,
}

impl LevelSamples<'_> {
    /// `sharp_lobe_floor` of these samples.
    pub fn sharp_floor(&self) -> f64 {
        sharp_lobe_floor(self.estimate_alpha, &self.pairs)
    }
}

/// A way to fit the model a reconstruction's residuals are taken against.
pub trait Prior: Send + Sync {
    /// The name reports and `--prior` use.
    fn name(&self) -> &'static str;
    /// How it fits, in a phrase for report headers.
    fn about(&self) -> &'static str {
        ""
    }
    /// The model fitted to `samples`; None to interpolate the measurements themselves.
    fn fit(&self, samples: &LevelSamples<'_>) -> Option<FittedPrior>;
}

/// Lambert, a coated diffuse and two GGX lobes with a bounded Fresnel rise: the product's prior
/// wherever the PCA basis is not chosen (`pca::SelectedPrior`).
#[derive(Clone, Copy, Debug, Default)]
pub struct TwoLobesPrior;

impl Prior for TwoLobesPrior {
    fn name(&self) -> &'static str {
        "two-lobes"
    }
    fn about(&self) -> &'static str {
        " (each level's measurements are fitted with a diffuse base (Lambert plus a coated diffuse \
         that darkens toward grazing) + two GGX lobes with a bounded Schlick Fresnel rise each, \
         `brdf::fit_lobes`, the `gonio brdf fit` loss, each sample weighted by the \
         equal-angle measure it stands for; the grid interpolates the residuals and the fitted lobes \
         are evaluated at the query)"
    }
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        let fit = fit_lobes::fit_two_lobes_bounded(
            &s.pairs,
            s.values,
            &s.weights,
            s.sharp_floor(),
            LobeFresnel::Bounded,
            DiffuseBound::Free,
        );
        Some(FittedPrior::TwoLobes(fit.model))
    }
}

/// No prior: the grid interpolates the measurements themselves (the predictive rule's simulation).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoPrior;

impl Prior for NoPrior {
    fn name(&self) -> &'static str {
        "none"
    }
    fn about(&self) -> &'static str {
        " (the grid interpolates the measurements themselves)"
    }
    fn fit(&self, _: &LevelSamples<'_>) -> Option<FittedPrior> {
        None
    }
}

/// The model a prior fitted to a level's measurements.
#[derive(Clone, Debug)]
pub enum FittedPrior {
    /// The two-lobe model.
    TwoLobes(fit_lobes::TwoLobes),
    /// The PCA basis' fit, tabulated (`pca::PcaPrior`).
    Basis(Arc<BinnedBrdf>),
    /// A lab trial's model, with its one-line description (the product fits two lobes or the basis).
    Other(OtherModel),
}

/// A fitted model other than two lobes, e.g. one analytic lobe or a basis fit's table.
#[derive(Clone)]
pub struct OtherModel {
    pub model: Arc<dyn Material>,
    pub describe: String,
}

impl std::fmt::Debug for OtherModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.describe)
    }
}

/// The fitted model alone, without the grid's residual (BRDF, 1/sr).
impl Material for FittedPrior {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        match self {
            FittedPrior::TwoLobes(m) => m.eval(wi, wo),
            FittedPrior::Basis(m) => m.eval(wi, wo),
            FittedPrior::Other(m) => m.model.eval(wi, wo),
        }
    }
}

impl FittedPrior {
    /// One line for reports.
    pub fn describe(&self) -> String {
        match self {
            FittedPrior::TwoLobes(m) => m.describe(),
            FittedPrior::Basis(_) => "pca basis fit (32 x 32 x 64 bins)".to_string(),
            FittedPrior::Other(m) => m.describe.clone(),
        }
    }

    /// Which model it is, in a word for the scan's level lines.
    pub fn kind(&self) -> &'static str {
        match self {
            FittedPrior::TwoLobes(_) => "two-lobes",
            FittedPrior::Basis(_) => "pca",
            FittedPrior::Other(_) => "other",
        }
    }
}

/// Share of the estimate's and of the samples' resolvable roughness the sharp lobe may not go below.
pub const SHARP_FLOOR_SHARE: f64 = 0.5;

/// The sharpest lobe a two-lobe prior may fit to `pairs` of a plan built on `estimate_alpha`: the
/// smaller share of the estimate and of what the samples resolve (docs/planner.md).
pub fn sharp_lobe_floor(estimate_alpha: f64, pairs: &[(DVec3, DVec3)]) -> f64 {
    (SHARP_FLOOR_SHARE * estimate_alpha).min(SHARP_FLOOR_SHARE * fit_lobes::resolvable_alpha(pairs))
}
