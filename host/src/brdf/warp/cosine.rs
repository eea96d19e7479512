//! Cosine-weighted hemisphere warp (independent of wi): sin^2 theta = u.x, phi = 2 pi u.y,
//! pdf = cos theta / pi.

use super::Warp;
use crate::brdf::frame::{clamp_u, phi_of, wrap_unit};
use glam::{DVec2, DVec3};
use std::f64::consts::{FRAC_1_PI, PI};

#[derive(Clone, Copy, Debug, Default)]
pub struct CosineHemisphere;

impl Warp for CosineHemisphere {
    fn sample(&self, u: DVec2) -> Option<DVec3> {
        let u = clamp_u(u);
        // u.x <= 1 - eps keeps z >= sqrt(eps) > 0: every clamped u is valid.
        let z = (1.0 - u.x).sqrt();
        let r = u.x.sqrt();
        let (s, c) = (2.0 * PI * u.y).sin_cos();
        Some(DVec3::new(r * c, r * s, z))
    }

    fn invert(&self, wo: DVec3) -> Option<DVec2> {
        if !(wo.z > 0.0) {
            return None;
        }
        let w = wo.normalize();
        let u1 = (w.x * w.x + w.y * w.y).min(crate::brdf::frame::ONE_MINUS_EPSILON);
        Some(DVec2::new(u1, wrap_unit(phi_of(w) / (2.0 * PI))))
    }

    fn pdf(&self, wo: DVec3) -> f64 {
        if !(wo.z > 0.0) {
            return 0.0;
        }
        wo.normalize().z * FRAC_1_PI
    }
}
