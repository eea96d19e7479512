//! BRDF importance sampling for the environment light: a mixture of the BRDF core's warps chosen
//! from the material spec. Lambert -> cosine; Ward -> cosine + Ward half-vector; GGX -> cosine +
//! visible-normal sampling; each lobe weighted by the luminance of its colour. Tabulated and neural
//! materials (nbrdf, merl, rgl) have no analytic lobe to follow and are sampled by the cosine warp;
//! MIS with the environment samples keeps their estimate unbiased, only noisier.
//!
//! The warps sample wo for a given wi; the BRDFs are reciprocal, so building a warp around the
//! direction toward the detector samples directions toward the light with the same density.

use crate::brdf::frame::luminance;
use crate::brdf::roughness::Roughness;
use crate::brdf::spec::{parse_analytic, Analytic};
use crate::brdf::warp::{SliceWarp, Warp, WarpKind};
use glam::{DVec2, DVec3};

/// The lobes of a material, independent of direction.
#[derive(Clone, Debug, PartialEq)]
pub struct BrdfSampler {
    /// (selection probability, warp); probabilities sum to 1.
    lobes: Vec<(f64, WarpKind)>,
}

impl BrdfSampler {
    /// The sampler for a material spec string (any spec the BRDF core accepts).
    pub fn for_spec(spec: &str) -> Self {
        let mut lobes: Vec<(f64, WarpKind)> = Vec::new();
        let mut rough = |weight: f64, alpha: f64, kind: fn(f64) -> WarpKind| {
            // A mirror lobe is a delta the BRDF does not evaluate: nothing to sample.
            if let Roughness::Rough(a) = Roughness::new(alpha) {
                lobes.push((weight, kind(a)));
            }
        };
        let mut diffuse = 1.0;
        match parse_analytic(spec) {
            Ok(Analytic::Ward(m)) => {
                diffuse = luminance(m.rho_d);
                rough(luminance(m.rho_s), m.alpha, |alpha| WarpKind::Ward { alpha });
            }
            Ok(Analytic::Ggx(m)) => {
                diffuse = luminance(m.diffuse);
                rough(luminance(m.specular), m.alpha, |alpha| WarpKind::GgxVndf { alpha });
            }
            Ok(Analytic::Lambert(_)) | Err(_) => {}
        }
        lobes.push((diffuse, WarpKind::Cosine));
        lobes.retain(|(w, _)| *w > 0.0 && w.is_finite());
        let total: f64 = lobes.iter().map(|(w, _)| w).sum();
        if lobes.is_empty() || !(total > 0.0) {
            // A black material: any valid density will do.
            lobes = vec![(1.0, WarpKind::Cosine)];
        } else {
            lobes.iter_mut().for_each(|(w, _)| *w /= total);
        }
        Self { lobes }
    }

    /// The lobes bound to one direction toward the detector (local frame).
    pub fn at(&self, wo: DVec3) -> BoundSampler {
        BoundSampler {
            lobes: self.lobes.iter().map(|&(w, k)| (w, k.for_incident(wo))).collect(),
        }
    }
}

/// A `BrdfSampler` for one wo.
#[derive(Clone, Debug)]
pub struct BoundSampler {
    lobes: Vec<(f64, SliceWarp)>,
}

impl BoundSampler {
    /// A direction toward the light and the mixture density there; `None` below the horizon.
    /// `pick` in [0,1) selects the lobe, `u` drives its warp.
    pub fn sample(&self, pick: f64, u: DVec2) -> Option<(DVec3, f64)> {
        let mut acc = 0.0;
        let mut chosen = self.lobes.last()?;
        for lobe in &self.lobes {
            acc += lobe.0;
            if pick < acc {
                chosen = lobe;
                break;
            }
        }
        let wi = chosen.1.sample(u)?;
        let pdf = self.pdf(wi);
        (pdf > 0.0 && pdf.is_finite()).then_some((wi, pdf))
    }

    /// Mixture density per solid angle at wi (0 below the horizon).
    pub fn pdf(&self, wi: DVec3) -> f64 {
        self.lobes.iter().map(|(w, warp)| w * warp.pdf(wi)).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::frame::from_spherical;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn lobes_follow_the_spec_and_the_mixture_pdf_integrates_to_at_most_one() {
        assert_eq!(
            BrdfSampler::for_spec("lambert:albedo=0.5").lobes,
            vec![(1.0, WarpKind::Cosine)]
        );
        assert_eq!(
            BrdfSampler::for_spec("nbrdf:chrome").lobes,
            vec![(1.0, WarpKind::Cosine)]
        );
        assert_eq!(
            BrdfSampler::for_spec("ggx:alpha=1e-5").lobes,
            vec![(1.0, WarpKind::Cosine)]
        );
        let s = BrdfSampler::for_spec("ggx:alpha=0.3,diffuse=0.25");
        assert_eq!(s.lobes.len(), 2);
        assert!(
            (s.lobes[0].0 - 0.8).abs() < 1e-12,
            "specular 1 vs diffuse 0.25 -> 0.8 / 0.2"
        );
        // E[1/pdf] over samples = measure of the support (2 pi for the hemisphere when every sample is valid).
        let bound = s.at(from_spherical(0.6, 0.0));
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 40_000;
        let mut inv = 0.0;
        for _ in 0..n {
            if let Some((wi, pdf)) = bound.sample(rng.random(), DVec2::new(rng.random(), rng.random())) {
                assert!(wi.z > 0.0 && (pdf - bound.pdf(wi)).abs() < 1e-12 * pdf.max(1.0));
                inv += 1.0 / pdf;
            }
        }
        let measure = inv / n as f64;
        assert!((measure - 2.0 * std::f64::consts::PI).abs() < 0.1, "{measure}");
    }
}
