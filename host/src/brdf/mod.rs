//! BRDF models, data formats, warps and reconstruction (issue 4).
//!
//! Conventions (see DESIGN.md): local shading frame with +z the normal; `wi` points toward the light,
//! `wo` toward the detector, both away from the surface; radians; values in 1/sr, linear RGB.
//!
//! * `analytic`: Lambert, Ward (eq. 1 of Cao et al.), GGX; `microfacet` and `roughness` hold the
//!   GGX formulas and the alpha guards they share.
//! * `nbrdf`, `merl`, `rgl`: the neural MERL fits, the MERL `.binary` table, RGL `.bsdf` files.
//! * `spec`: the command-line material strings (`ward:rho_d=0.2,alpha=0.1`, ...).
//! * `warp`: the importance-sampling warps with their inverses; `grid`: the adaptive measurement
//!   grid and its reconstruction; `fit`: analytic fits to a measured material.

pub mod analytic;
mod error;
pub mod fit;
pub mod fit_lobes;
pub mod frame;
pub mod grid;
pub mod half_diff;
mod log_nnls;
pub mod merl;
pub mod microfacet;
pub mod nbrdf;
mod nbrdf_bundled;
pub mod rgl;
pub mod roughness;
pub mod spec;
pub mod warp;

#[cfg(test)]
mod chi2;

pub use error::BrdfError;
pub use spec::parse_material;

use glam::DVec3;

/// A reflectance function of the local frame.
pub trait Material: Send + Sync {
    /// BRDF value f(wi, wo) in 1/sr, linear RGB. 0 when either direction is at or below the horizon;
    /// never NaN for unit inputs.
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3;
}

impl<M: Material + ?Sized> Material for Box<M> {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        (**self).eval(wi, wo)
    }
}
