//! Trial priors of `gonio-lab tradeoff --prior`: each lost to the product's prior (two-lobes until
//! issue 28, now two-lobes-or-pca-guarded; docs/tradeoff/README.md, docs/nielsen2015.md). One file,
//! one `reconstruct::Prior` each; not used by a scan.

use super::nielsen::selected::{self, SelectedPrior};
use super::photo_samples::{self, PhotoSamples};
use gonio::brdf::fit::{fit_samples, FitModel};
use gonio::brdf::fit_lobes::{fit_two_lobes_bounded, DiffuseBound, LobeFresnel};
use gonio::reconstruct::{FittedPrior, LevelSamples, NoPrior, OtherModel, Prior, TwoLobesPrior};
use std::sync::Arc;

/// The names `--prior` takes: the product's first.
pub const PRIOR_NAMES: [&str; 9] = [
    "two-lobes-or-pca-guarded",
    "two-lobes",
    "none",
    "fit",
    "two-lobes-plain",
    "two-lobes-capped",
    "two-lobes-photo",
    "pca",
    "two-lobes-or-pca",
];

/// The prior called `name`; `photo` supplies the capture photo's pixels, asked for by two-lobes-photo only.
pub fn prior_by_name(
    name: &str,
    photo: impl FnOnce() -> Result<PhotoSamples, String>,
) -> Result<Box<dyn Prior>, String> {
    Ok(match name {
        "two-lobes" => Box::new(TwoLobesPrior),
        "none" => Box::new(NoPrior),
        "fit" => Box::new(OneLobePrior),
        "two-lobes-plain" => Box::new(PlainTwoLobesPrior),
        "two-lobes-capped" => Box::new(CappedTwoLobesPrior),
        "two-lobes-photo" => Box::new(PhotoTwoLobesPrior { photo: photo()? }),
        "pca" => Box::new(selected::pca_prior()?),
        "two-lobes-or-pca" => Box::new(UnguardedSelectedPrior(SelectedPrior {
            max_unexplained: f64::INFINITY,
            ..selected::product_prior()?
        })),
        "two-lobes-or-pca-guarded" => Box::new(selected::product_prior()?),
        other => return Err(format!("unknown prior {other:?} (one of {})", PRIOR_NAMES.join(", "))),
    })
}

/// Whether the prior called `name` reads the nielsen2015 training basis (built or read from the cache).
pub fn needs_basis(name: &str) -> bool {
    matches!(name, "pca" | "two-lobes-or-pca" | "two-lobes-or-pca-guarded")
}

/// Whether the prior called `name` reads the capture photo.
pub fn needs_photo(name: &str) -> bool {
    name == "two-lobes-photo"
}

/// The product's choice without its span bound: the basis wherever it wins the cross-validation.
pub struct UnguardedSelectedPrior(SelectedPrior);

impl Prior for UnguardedSelectedPrior {
    fn name(&self) -> &'static str {
        "two-lobes-or-pca"
    }
    fn about(&self) -> &'static str {
        self.0.about()
    }
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        self.0.fit(s)
    }
}

/// One GGX lobe plus Lambert (`brdf::fit::fit_samples`).
pub struct OneLobePrior;

impl Prior for OneLobePrior {
    fn name(&self) -> &'static str {
        "fit"
    }
    fn about(&self) -> &'static str {
        " (each level's measurements are fitted with GGX + Lambert, the `gonio brdf fit` loss, each \
         sample weighted by the equal-angle measure it stands for; the grid interpolates the residuals \
         and the fitted lobe is evaluated at the query)"
    }
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        let lobe = fit_samples(s.pairs.clone(), s.values, &s.weights, FitModel::Ggx).model;
        Some(FittedPrior::Other(OtherModel {
            describe: lobe.to_spec(),
            model: Arc::new(lobe),
        }))
    }
}

/// Two lobes without the Fresnel rise: the ablation of the rise.
pub struct PlainTwoLobesPrior;

impl Prior for PlainTwoLobesPrior {
    fn name(&self) -> &'static str {
        "two-lobes-plain"
    }
    fn about(&self) -> &'static str {
        " (as two-lobes, without the Fresnel rise: an ablation)"
    }
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        let fit = fit_two_lobes_bounded(
            &s.pairs,
            s.values,
            &s.weights,
            s.sharp_floor(),
            LobeFresnel::None,
            DiffuseBound::Free,
        );
        Some(FittedPrior::TwoLobes(fit.model))
    }
}

/// Two lobes with Lambert no brighter than the darkest non-grazing measurement.
pub struct CappedTwoLobesPrior;

impl Prior for CappedTwoLobesPrior {
    fn name(&self) -> &'static str {
        "two-lobes-capped"
    }
    fn about(&self) -> &'static str {
        " (as two-lobes, with the Lambert term no brighter than the darkest measurement within 80 deg of \
         the normal: a trial)"
    }
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        let fit = fit_two_lobes_bounded(
            &s.pairs,
            s.values,
            &s.weights,
            s.sharp_floor(),
            LobeFresnel::Bounded,
            DiffuseBound::BelowDarkest,
        );
        Some(FittedPrior::TwoLobes(fit.model))
    }
}

/// The capture photo's samples together weigh this many times a level's measurements.
pub const PHOTO_WEIGHT: f64 = 3.0;

/// Two lobes fitted to the level's measurements and to the capture photo's pixels.
pub struct PhotoTwoLobesPrior {
    pub photo: PhotoSamples,
}

impl Prior for PhotoTwoLobesPrior {
    fn name(&self) -> &'static str {
        "two-lobes-photo"
    }
    fn about(&self) -> &'static str {
        " (as two-lobes, fitted to the capture photo's pixels too, weighed `plan::trials::PHOTO_WEIGHT` times the \
         measurements: a trial; the photo is taken under the point light that scores, so the point-light errors are not \
         independent of the fit's data)"
    }
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        // The floor reads the plan's own samples only.
        let floor = s.sharp_floor();
        let mut data = (s.pairs.clone(), s.values.to_vec(), s.weights.clone());
        photo_samples::append_weighted(&mut data, &self.photo, PHOTO_WEIGHT);
        let fit = fit_two_lobes_bounded(
            &data.0,
            &data.1,
            &data.2,
            floor,
            LobeFresnel::Bounded,
            DiffuseBound::Free,
        );
        Some(FittedPrior::TwoLobes(fit.model))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use gonio::brdf::analytic::Ggx;
    use gonio::brdf::frame::from_spherical;
    use gonio::brdf::Material;
    use gonio::instrument::default_instrument;
    use gonio::plan::predict::log_err_over;
    use gonio::plan::{ggx_estimate, Plan, PlanConfig, Planner, Strategy};
    use gonio::reconstruct::reconstruct_with;
    use rand::{Rng, SeedableRng};

    fn mixture_plan(alpha: f64, diffuse: f64, max_level: usize) -> Plan {
        Planner::new(default_instrument(), ggx_estimate(alpha, diffuse))
            .expect("planner")
            .plan(&PlanConfig {
                strategy: Strategy::Mixture,
                grids: gonio::plan::square_grids(max_level),
                ..PlanConfig::default()
            })
            .expect("plan")
    }

    /// 4000 random pairs over the hemisphere, theta_i mostly between the plan's slices.
    fn random_pairs() -> Vec<(DVec3, DVec3)> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        (0..4000)
            .map(|_| {
                let wi = from_spherical(rng.random::<f64>() * 1.4, rng.random::<f64>() * std::f64::consts::TAU);
                let wo = from_spherical(rng.random::<f64>() * 1.5, rng.random::<f64>() * std::f64::consts::TAU);
                (wi, wo)
            })
            .collect()
    }

    #[test]
    fn every_name_builds_its_prior_and_unknown_names_are_refused() {
        // The basis priors are built by `nielsen::selected`'s own tests (the training basis is slow in debug).
        for name in PRIOR_NAMES.into_iter().filter(|n| !needs_basis(n)) {
            let prior = prior_by_name(name, || Ok(PhotoSamples::default())).expect(name);
            assert_eq!(prior.name(), name);
        }
        assert!(prior_by_name("two-lobes-photo", || Err("no photo".into())).is_err());
        assert!(prior_by_name("cosine", || Ok(PhotoSamples::default())).is_err());
        assert!(needs_photo("two-lobes-photo") && !needs_photo("two-lobes"));
    }

    /// One lobe fitted to a GGX lobe's own measurements recovers it from the 2 x 2 level, even
    /// from a plan built on an estimate 3x too rough: every node's value is the truth's.
    #[test]
    fn one_lobe_recovers_an_analytic_lobe() {
        let truth = Ggx {
            alpha: 0.05,
            diffuse: DVec3::new(0.2, 0.1, 0.05),
            specular: DVec3::splat(0.7),
        };
        let plan = mixture_plan(0.15, 0.1, 2);
        let values = plan.measure(&truth);
        let none = reconstruct_with(&plan, 1, &values, &NoPrior).expect("rec");
        let fit = reconstruct_with(&plan, 1, &values, &OneLobePrior).expect("rec");
        let pairs = random_pairs();
        let (e_none, e_fit) = (log_err_over(&pairs, &truth, &none), log_err_over(&pairs, &truth, &fit));
        println!("2x2 log err: no prior {e_none:.5}, one lobe {e_fit:.5}");
        assert!(e_fit < 0.2 * e_none && e_fit < 2e-3, "{e_fit} vs {e_none}");
        let exact = reconstruct_with(&plan, 2, &values, &OneLobePrior).expect("rec");
        for k in 0..plan.thetas.len() {
            for (i, j) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                if let (Some(v), Some((wi, wo))) = (exact.node_value(k, i, j), exact.grid().node_directions(k, i, j)) {
                    let t = truth.eval(wi, wo);
                    assert!(
                        (v - t).abs().max_element() < 1e-6 * (1.0 + t.max_element()),
                        "{v} vs {t}"
                    );
                }
            }
        }
    }

    /// The capped prior's Lambert stays under the darkest non-grazing sample on the first level of
    /// a mirror-like metal's mixture plan, where the free fit's is under it too (docs/tradeoff/README.md).
    #[test]
    fn the_capped_prior_keeps_lambert_under_the_darkest_sample() {
        let truth = gonio::brdf::spec::parse_material("nbrdf:tungsten-carbide").expect("bundled material");
        let plan = mixture_plan(0.0076, 0.02, 4);
        let values = plan.measure(truth.as_ref());
        let level1 = plan.levels[0].cumulative_directions;
        let darkest = plan.directions[..level1]
            .iter()
            .zip(&values)
            .filter(|(d, _)| d.wi.z.min(d.wo.z) >= 80f64.to_radians().cos())
            .fold(DVec3::INFINITY, |m, (_, v)| m.min(*v));
        let diffuse = |prior: &dyn Prior| match reconstruct_with(&plan, 1, &values, prior).expect("rec").prior() {
            Some(FittedPrior::TwoLobes(t)) => t.diffuse,
            other => panic!("{}: {other:?}", prior.name()),
        };
        let cap = darkest * std::f64::consts::PI;
        let (free, capped) = (diffuse(&TwoLobesPrior), diffuse(&CappedTwoLobesPrior));
        println!("level 1: {level1} directions; Lambert albedo free {free:.4}, capped {capped:.4}, cap {cap:.4}");
        assert!(
            free.cmple(cap).all(),
            "the free fit's Lambert exceeds the darkest sample: {free} vs {cap}"
        );
        assert!(capped.cmple(cap * (1.0 + 1e-9)).all(), "{capped} vs cap {cap}");
        assert!(capped.is_finite() && capped.min_element() >= 0.0, "{capped}");
    }

    /// With the capture photo the 2 x 2 fit follows the photo's own slice better than the plan's
    /// measurements alone, and the hemisphere too; a photo read at the wrong pixels or scale would
    /// raise the slice's error (docs/tradeoff/README.md quotes the printed figures).
    #[test]
    fn the_photo_prior_fits_the_photos_slice() {
        let spec = "nbrdf:red-metallic-paint";
        let truth = gonio::brdf::spec::parse_material(spec).expect("bundled material");
        let plan = mixture_plan(0.013, 0.05, 4);
        let values = plan.measure(truth.as_ref());
        let scene = gonio::encoder::capture::capture_scene(spec, 128).expect("capture scene");
        let photo = gonio::render::render_with(&scene, &scene.settings, &|| {}).expect("render");
        let samples = photo_samples::photo_samples(&scene, &photo, None, 2).expect("photo samples");
        let plain = reconstruct_with(&plan, 1, &values, &TwoLobesPrior).expect("rec");
        let photo_prior = PhotoTwoLobesPrior { photo: samples.clone() };
        let with_photo = reconstruct_with(&plan, 1, &values, &photo_prior).expect("rec");
        let slice_err = |rec: &dyn Material| log_err_over(&samples.pairs, truth.as_ref(), rec);
        let (a, b) = (slice_err(&plain), slice_err(&with_photo));
        let pairs = random_pairs();
        let (ha, hb) = (
            log_err_over(&pairs, truth.as_ref(), &plain),
            log_err_over(&pairs, truth.as_ref(), &with_photo),
        );
        println!(
            "2x2 {spec}: {} photo samples; capture-slice log error {a:.5} -> {b:.5} with the photo; hemisphere {ha:.5} -> {hb:.5}",
            samples.len()
        );
        assert!(b < 0.9 * a, "the photo did not reach the fit: {a} -> {b}");
        assert!(hb < ha, "the photo cost the hemisphere: {ha} -> {hb}");
    }
}
