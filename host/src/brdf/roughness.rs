//! The two guards on microfacet roughness, documented once here and used by every model and warp.
//!
//! * `ALPHA_FLOOR = 1e-4`: the smallest alpha any rough-lobe formula (GGX D, sigma, Ward's exponent)
//!   is evaluated with. The formulas clamp to it themselves, so a direct caller can never divide by
//!   alpha^2 = 0.
//! * `MIRROR_ALPHA = 1e-3`: below it a lobe is "effectively smooth" (pbrt-v4's
//!   `TrowbridgeReitzDistribution::EffectivelySmooth`, max(alpha_x, alpha_y) < 1e-3) and models and
//!   warps switch, deterministically, to the mirror limit: the specular lobe becomes a delta, so
//!   `eval` returns only the diffuse part (a delta has no finite value), a warp's `sample` returns
//!   the mirror direction for every u, its `pdf` is 0 (no density) and `invert` is `None`.
//!
//! Since MIRROR_ALPHA > ALPHA_FLOOR, models never reach the floor; it protects the bare formulas.

/// Smallest alpha a rough-lobe formula is evaluated with.
pub const ALPHA_FLOOR: f64 = 1e-4;
/// Below this alpha a lobe is a perfect mirror.
pub const MIRROR_ALPHA: f64 = 1e-3;

/// A lobe's roughness after the mirror switch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Roughness {
    /// alpha < MIRROR_ALPHA (or not a number): a delta lobe.
    Mirror,
    /// alpha >= MIRROR_ALPHA.
    Rough(f64),
}

impl Roughness {
    pub fn new(alpha: f64) -> Self {
        // `!(a >= t)` also sends NaN to the mirror, the one deterministic choice that stays finite.
        if !(alpha >= MIRROR_ALPHA) {
            Roughness::Mirror
        } else {
            Roughness::Rough(alpha)
        }
    }
}

/// alpha clamped to the floor: the guard every rough-lobe formula applies to its own alpha.
pub fn floored(alpha: f64) -> f64 {
    if alpha.is_nan() {
        ALPHA_FLOOR
    } else {
        alpha.max(ALPHA_FLOOR)
    }
}
