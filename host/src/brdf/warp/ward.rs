//! Ward half-vector warp, eq. 7 and its inverse eq. 8 of Cao et al.:
//! theta_h = atan(alpha sqrt(-ln u1)), phi_h = 2 pi u2;  u1 = exp(-tan^2 theta_h / alpha^2), u2 = phi_h / 2 pi;
//! then wo = 2 (h.wi) h - wi. The half-vector density is p(h) = exp(-tan^2 / alpha^2) / (pi alpha^2 cos^3 theta_h).

use super::{normal_between, reflect_above, reflected_pdf, IncidentLobe, Warp};
use crate::brdf::frame::{clamp_u, phi_of, wrap_unit, ONE_MINUS_EPSILON};
use crate::brdf::roughness::floored;
use glam::{DVec2, DVec3};
use std::f64::consts::PI;

/// Density per solid angle of eq. 7's half vector. Guards: h at or below the horizon has density 0;
/// an exponential that underflows returns 0 before 1/cos^3 can overflow (the exponent reaches -745
/// long before cos^3 underflows).
pub fn ward_half_vector_pdf(h: DVec3, alpha: f64) -> f64 {
    if !(h.z > 0.0) {
        return 0.0;
    }
    let a2 = floored(alpha).powi(2);
    let tan2 = (h.x * h.x + h.y * h.y) / (h.z * h.z);
    let e = (-tan2 / a2).exp();
    if e == 0.0 {
        return 0.0;
    }
    let cos = h.z / h.length();
    e / (PI * a2 * cos * cos * cos)
}

#[derive(Clone, Debug)]
pub struct WardHalfVector {
    lobe: IncidentLobe,
}

impl WardHalfVector {
    pub fn new(wi: DVec3, alpha: f64) -> Self {
        Self {
            lobe: IncidentLobe::new(wi, alpha),
        }
    }
}

impl Warp for WardHalfVector {
    fn sample(&self, u: DVec2) -> Option<DVec3> {
        let alpha = match self.lobe.sampling_alpha() {
            Ok(a) => a,
            Err(answer) => return answer,
        };
        let u = clamp_u(u);
        // Eq. 7. u1 = 0 gives tan theta_h = inf, a normal on the horizon, whose reflection is never
        // above it: report that as invalid rather than build a direction from inf.
        let tan = alpha * (-u.x.ln()).sqrt();
        if !tan.is_finite() {
            return None;
        }
        let cos = 1.0 / (1.0 + tan * tan).sqrt();
        let sin = tan * cos;
        let (sp, cp) = (2.0 * PI * u.y).sin_cos();
        reflect_above(self.lobe.wi, DVec3::new(sin * cp, sin * sp, cos))
    }

    fn invert(&self, wo: DVec3) -> Option<DVec2> {
        let alpha = self.lobe.density_alpha()?;
        let h = normal_between(self.lobe.wi, wo)?;
        // Eq. 8, with tan^2 from x, y, z directly (no acos near the pole).
        let tan2 = (h.x * h.x + h.y * h.y) / (h.z * h.z);
        let u1 = (-tan2 / (alpha * alpha)).exp().min(ONE_MINUS_EPSILON);
        // Beyond tan^2 / alpha^2 ~ 708, u1 is subnormal or 0 in f64: sample can no longer reach this
        // direction (u1 = 0 is the horizon), so it is outside the warp's image. Its probability is
        // below 1e-308.
        if u1 < f64::MIN_POSITIVE {
            return None;
        }
        Some(DVec2::new(u1, wrap_unit(phi_of(h) / (2.0 * PI))))
    }

    fn pdf(&self, wo: DVec3) -> f64 {
        let Some(alpha) = self.lobe.density_alpha() else {
            return 0.0;
        };
        match normal_between(self.lobe.wi, wo) {
            Some(h) => reflected_pdf(ward_half_vector_pdf(h, alpha), wo, h),
            None => 0.0,
        }
    }

    fn is_delta(&self) -> bool {
        self.lobe.is_delta()
    }
}
