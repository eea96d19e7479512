//! Warps from the unit square to outgoing directions, for one given incoming direction wi.
//!
//! Each warp is a triad: `sample(u) -> Option<wo>`, `invert(wo) -> Option<u>` and `pdf(wo)`, the
//! density of `sample`'s outputs per unit solid angle. u is clamped to [0, 1 - eps]^2. A u whose
//! direction lands at or below the horizon is reported as `None`, never clamped into a wrong
//! direction; `pdf` integrates over the upper hemisphere to the probability that `sample` is valid
//! (1 for the cosine warp, less for the reflected microfacet warps at grazing wi).
//! In every warp u.y is the azimuth: phi = 2 pi u.y, so the square is periodic in u.y.
//! wi must be a unit vector at or above the horizon; a warp built for any other wi samples nothing.

mod cosine;
mod ggx;
mod tabulated;
mod ward;

pub use cosine::CosineHemisphere;
pub use ggx::{GgxNdf, GgxVndf};
pub use tabulated::{
    Marginal2D, MixtureWarp, MixtureWeights, UniformAngles, MIXTURE_BASE_ALPHA_MIN, MIXTURE_SPECULAR_WEIGHT,
    MIXTURE_UNIFORM_WEIGHT,
};
pub use ward::{ward_half_vector_pdf, WardHalfVector};

use super::frame::{half_vector, reflect, MIN_HALF_LENGTH};
use super::roughness::Roughness;
use super::BrdfError;
use glam::{DVec2, DVec3};
use std::fmt;
use std::sync::Arc;

/// A warp for one fixed incoming direction.
pub trait Warp {
    /// The outgoing direction for u, or `None` if it lies at or below the horizon.
    fn sample(&self, u: DVec2) -> Option<DVec3>;
    /// The u that `sample` maps to wo, or `None` if no u does (wo below the horizon, a delta warp,
    /// or a direction outside the warp's image).
    fn invert(&self, wo: DVec3) -> Option<DVec2>;
    /// Density of `sample`'s outputs per unit solid angle at wo; 0 below the horizon and for a delta warp.
    fn pdf(&self, wo: DVec3) -> f64;
    /// True for the mirror limit, where all of `sample` goes to one direction and `pdf` is 0.
    fn is_delta(&self) -> bool {
        false
    }
}

/// What every half-vector warp starts from: the incident direction and the lobe's roughness, with
/// the two guards they all share, written once. A wi the warp cannot use (`incident_ok`) samples
/// nothing; a lobe in the mirror limit samples the mirror direction and has no density or inverse.
#[derive(Clone, Copy, Debug)]
pub(super) struct IncidentLobe {
    pub wi: DVec3,
    pub roughness: Roughness,
    pub usable: bool,
}

impl IncidentLobe {
    pub fn new(wi: DVec3, alpha: f64) -> Self {
        Self {
            wi,
            roughness: Roughness::new(alpha),
            usable: incident_ok(wi),
        }
    }

    /// For `sample`: the rough alpha, or else the whole answer (`None` for an unusable wi, the
    /// mirror direction in the mirror limit).
    pub fn sampling_alpha(&self) -> Result<f64, Option<DVec3>> {
        if !self.usable {
            return Err(None);
        }
        match self.roughness {
            Roughness::Mirror => Err(mirror_direction(self.wi)),
            Roughness::Rough(a) => Ok(a),
        }
    }

    /// For `invert` and `pdf`: the rough alpha, `None` where there is no density (an unusable wi
    /// or the mirror limit).
    pub fn density_alpha(&self) -> Option<f64> {
        match self.roughness {
            Roughness::Rough(a) if self.usable => Some(a),
            _ => None,
        }
    }

    pub fn is_delta(&self) -> bool {
        self.roughness == Roughness::Mirror
    }
}

/// Which warp, with its parameters, independent of wi: what a measurement plan records.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum WarpKind {
    Cosine,
    /// Ward half-vector warp (eq. 7/8 of Cao et al.).
    Ward {
        alpha: f64,
    },
    /// GGX distribution-of-normals sampling.
    GgxNdf {
        alpha: f64,
    },
    /// GGX visible-normal sampling (Heitz 2018).
    GgxVndf {
        alpha: f64,
    },
    /// Equal steps in (theta_o, phi_o), independent of wi: the planner's uniform baseline.
    Uniform,
}

impl WarpKind {
    /// The warp for the incoming direction `wi`.
    pub fn for_incident(&self, wi: DVec3) -> SliceWarp {
        match *self {
            WarpKind::Cosine => SliceWarp::Cosine(CosineHemisphere),
            WarpKind::Ward { alpha } => SliceWarp::Ward(WardHalfVector::new(wi, alpha)),
            WarpKind::GgxNdf { alpha } => SliceWarp::GgxNdf(GgxNdf::new(wi, alpha)),
            WarpKind::GgxVndf { alpha } => SliceWarp::GgxVndf(GgxVndf::new(wi, alpha)),
            WarpKind::Uniform => SliceWarp::Uniform(UniformAngles),
        }
    }

    /// Parse `cosine`, `ward:alpha=A`, `ggx-ndf:alpha=A` or `ggx-vndf:alpha=A`.
    pub fn parse(spec: &str) -> Result<Self, BrdfError> {
        let (kind, rest) = spec.split_once(':').unwrap_or((spec, ""));
        let alpha = || -> Result<f64, BrdfError> {
            let v = rest
                .strip_prefix("alpha=")
                .ok_or_else(|| BrdfError::spec(spec, "expected alpha=A"))?
                .trim()
                .parse::<f64>()
                .map_err(|_| BrdfError::spec(spec, "alpha is not a number"))?;
            if !(v.is_finite() && v >= 0.0) {
                return Err(BrdfError::spec(spec, "alpha must be finite and >= 0"));
            }
            Ok(v)
        };
        match kind.trim() {
            "cosine" if rest.is_empty() => Ok(WarpKind::Cosine),
            "uniform" if rest.is_empty() => Ok(WarpKind::Uniform),
            "ward" => Ok(WarpKind::Ward { alpha: alpha()? }),
            "ggx-ndf" => Ok(WarpKind::GgxNdf { alpha: alpha()? }),
            "ggx-vndf" => Ok(WarpKind::GgxVndf { alpha: alpha()? }),
            _ => Err(BrdfError::spec(
                spec,
                "unknown warp (cosine, uniform, ward:alpha=A, ggx-ndf:alpha=A, ggx-vndf:alpha=A)",
            )),
        }
    }
}

impl fmt::Display for WarpKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WarpKind::Cosine => write!(f, "cosine"),
            WarpKind::Ward { alpha } => write!(f, "ward:alpha={alpha}"),
            WarpKind::GgxNdf { alpha } => write!(f, "ggx-ndf:alpha={alpha}"),
            WarpKind::GgxVndf { alpha } => write!(f, "ggx-vndf:alpha={alpha}"),
            WarpKind::Uniform => write!(f, "uniform"),
        }
    }
}

/// A `WarpKind` bound to one wi (static dispatch for the reconstruction's inner loop).
#[derive(Clone, Debug)]
pub enum SliceWarp {
    Cosine(CosineHemisphere),
    Ward(WardHalfVector),
    GgxNdf(GgxNdf),
    GgxVndf(GgxVndf),
    Uniform(UniformAngles),
    /// Shared: a mixture's table is built once per slice and cloned with the grid.
    Mixture(Arc<MixtureWarp>),
}

impl Warp for SliceWarp {
    fn sample(&self, u: DVec2) -> Option<DVec3> {
        match self {
            SliceWarp::Cosine(w) => w.sample(u),
            SliceWarp::Ward(w) => w.sample(u),
            SliceWarp::GgxNdf(w) => w.sample(u),
            SliceWarp::GgxVndf(w) => w.sample(u),
            SliceWarp::Uniform(w) => w.sample(u),
            SliceWarp::Mixture(w) => w.sample(u),
        }
    }
    fn invert(&self, wo: DVec3) -> Option<DVec2> {
        match self {
            SliceWarp::Cosine(w) => w.invert(wo),
            SliceWarp::Ward(w) => w.invert(wo),
            SliceWarp::GgxNdf(w) => w.invert(wo),
            SliceWarp::GgxVndf(w) => w.invert(wo),
            SliceWarp::Uniform(w) => w.invert(wo),
            SliceWarp::Mixture(w) => w.invert(wo),
        }
    }
    fn pdf(&self, wo: DVec3) -> f64 {
        match self {
            SliceWarp::Cosine(w) => w.pdf(wo),
            SliceWarp::Ward(w) => w.pdf(wo),
            SliceWarp::GgxNdf(w) => w.pdf(wo),
            SliceWarp::GgxVndf(w) => w.pdf(wo),
            SliceWarp::Uniform(w) => w.pdf(wo),
            SliceWarp::Mixture(w) => w.pdf(wo),
        }
    }
    fn is_delta(&self) -> bool {
        match self {
            SliceWarp::Cosine(w) => w.is_delta(),
            SliceWarp::Ward(w) => w.is_delta(),
            SliceWarp::GgxNdf(w) => w.is_delta(),
            SliceWarp::GgxVndf(w) => w.is_delta(),
            SliceWarp::Uniform(w) => w.is_delta(),
            SliceWarp::Mixture(w) => w.is_delta(),
        }
    }
}

/// True if wi can carry a reflection warp: finite and at or above the horizon.
fn incident_ok(wi: DVec3) -> bool {
    wi.is_finite() && wi.z >= 0.0
}

/// wo = 2 (wi.h) h - wi for a sampled microfacet normal h, or `None` at or below the horizon.
/// A normal facing away from wi (wi.h <= 0) always reflects to wo.z <= 0, so it is caught here too.
/// So is a normal nearly perpendicular to wi: |wi + wo| = 2 wi.h, and below MIN_HALF_LENGTH the pair
/// has no half vector, so `invert` could not map wo back (wo = -wi, on the horizon, to rounding).
fn reflect_above(wi: DVec3, h: DVec3) -> Option<DVec3> {
    if !(2.0 * wi.dot(h) > MIN_HALF_LENGTH) {
        return None;
    }
    let wo = reflect(wi, h);
    (wo.z > 0.0 && wo.is_finite()).then(|| wo.normalize())
}

/// The microfacet normal that reflects wi into wo, if wo is above the horizon and the pair has one.
fn normal_between(wi: DVec3, wo: DVec3) -> Option<DVec3> {
    if !(wo.z > 0.0) {
        return None;
    }
    half_vector(wi, wo.normalize()).filter(|h| h.z > 0.0)
}

/// Density of wo from the density of its half vector h (per solid angle): p(wo) = p(h) / (4 |wo.h|),
/// the Jacobian of the reflection map. Guard: wo.h -> 0 only for wo and wi nearly opposite at the
/// horizon, where every density here has already fallen to 0; a non-positive dot returns 0.
fn reflected_pdf(pdf_h: f64, wo: DVec3, h: DVec3) -> f64 {
    let c = wo.normalize().dot(h);
    if !(c > 0.0) || pdf_h == 0.0 {
        return 0.0;
    }
    pdf_h / (4.0 * c)
}

/// The mirror limit shared by the microfacet warps below MIRROR_ALPHA.
fn mirror_direction(wi: DVec3) -> Option<DVec3> {
    let wo = DVec3::new(-wi.x, -wi.y, wi.z);
    (wo.z > 0.0).then_some(wo)
}

#[cfg(test)]
mod tests;
