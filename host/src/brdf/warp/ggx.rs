//! GGX warps for a given wi: sampling the distribution of normals D(m) cos(m), and sampling the
//! visible normals D_wi(m) = D(m) max(0, wi.m) / sigma(wi) (Heitz 2018, "Sampling the GGX
//! Distribution of Visible Normals"), each followed by wo = 2 (wi.m) m - wi, with exact inverses.

use super::{normal_between, reflect_above, reflected_pdf, IncidentLobe, Warp};
use crate::brdf::frame::{clamp_u, phi_of, wrap_unit, ONE_MINUS_EPSILON};
use crate::brdf::microfacet::{ndf, projected_area};
use glam::{DVec2, DVec3};
use std::f64::consts::PI;

/// Normal sampling: tan^2 theta_m = alpha^2 u1 / (1 - u1), phi_m = 2 pi u2; pdf(m) = D(m) cos theta_m.
#[derive(Clone, Debug)]
pub struct GgxNdf {
    lobe: IncidentLobe,
}

impl GgxNdf {
    pub fn new(wi: DVec3, alpha: f64) -> Self {
        Self {
            lobe: IncidentLobe::new(wi, alpha),
        }
    }
}

impl Warp for GgxNdf {
    fn sample(&self, u: DVec2) -> Option<DVec3> {
        let alpha = match self.lobe.sampling_alpha() {
            Ok(a) => a,
            Err(answer) => return answer,
        };
        let u = clamp_u(u);
        // 1 - u1 >= eps after the clamp: tan^2 is finite.
        let tan2 = alpha * alpha * u.x / (1.0 - u.x);
        let cos = 1.0 / (1.0 + tan2).sqrt();
        let sin = (tan2 / (1.0 + tan2)).sqrt();
        let (sp, cp) = (2.0 * PI * u.y).sin_cos();
        reflect_above(self.lobe.wi, DVec3::new(sin * cp, sin * sp, cos))
    }

    fn invert(&self, wo: DVec3) -> Option<DVec2> {
        let alpha = self.lobe.density_alpha()?;
        let m = normal_between(self.lobe.wi, wo)?;
        // u1 = tan^2 / (alpha^2 + tan^2) = sin^2 / (alpha^2 cos^2 + sin^2): no tan, no division by 0.
        let s2 = m.x * m.x + m.y * m.y;
        let u1 = (s2 / (alpha * alpha * m.z * m.z + s2)).min(ONE_MINUS_EPSILON);
        Some(DVec2::new(u1, wrap_unit(phi_of(m) / (2.0 * PI))))
    }

    fn pdf(&self, wo: DVec3) -> f64 {
        let Some(alpha) = self.lobe.density_alpha() else {
            return 0.0;
        };
        match normal_between(self.lobe.wi, wo) {
            Some(m) => reflected_pdf(ndf(m, alpha) * m.z, wo, m),
            None => 0.0,
        }
    }

    fn is_delta(&self) -> bool {
        self.lobe.is_delta()
    }
}

/// Visible-normal sampling. In the hemisphere configuration (wi stretched by alpha), a disk point
/// (t1, t2) = sqrt(u1) (cos 2 pi u2, sin 2 pi u2) is squeezed onto the visible half-disk
/// t2 <- (1 - s) sqrt(1 - t1^2) + s t2 with s = (1 + v.z) / 2, lifted to the hemisphere and unstretched.
#[derive(Clone, Debug)]
pub struct GgxVndf {
    lobe: IncidentLobe,
    /// wi in the stretched (alpha = 1) configuration, and an orthonormal frame (t1, t2, v) around it.
    v: DVec3,
    t1: DVec3,
    t2: DVec3,
    /// The squeeze factor s = (1 + v.z) / 2, in [1/2, 1]: never 0, so its inverse needs no guard.
    s: f64,
}

impl GgxVndf {
    pub fn new(wi: DVec3, alpha: f64) -> Self {
        let lobe = IncidentLobe::new(wi, alpha);
        // The stretch needs some alpha even in the mirror limit, where it is never used.
        let a = lobe.density_alpha().unwrap_or(1.0);
        let usable = lobe.usable;
        let stretched = DVec3::new(a * wi.x, a * wi.y, wi.z);
        let v = if usable && stretched.length_squared() > 0.0 {
            stretched.normalize()
        } else {
            DVec3::Z
        };
        let lensq = v.x * v.x + v.y * v.y;
        // At normal incidence the tangent direction is arbitrary; Heitz picks +x.
        let t1 = if lensq > 0.0 {
            DVec3::new(-v.y, v.x, 0.0) / lensq.sqrt()
        } else {
            DVec3::X
        };
        let t2 = v.cross(t1);
        Self {
            lobe,
            v,
            t1,
            t2,
            s: 0.5 * (1.0 + v.z),
        }
    }
}

impl Warp for GgxVndf {
    fn sample(&self, u: DVec2) -> Option<DVec3> {
        let alpha = match self.lobe.sampling_alpha() {
            Ok(a) => a,
            Err(answer) => return answer,
        };
        let u = clamp_u(u);
        let r = u.x.sqrt();
        let (sp, cp) = (2.0 * PI * u.y).sin_cos();
        let p1 = r * cp;
        let p2 = (1.0 - self.s) * (1.0 - p1 * p1).max(0.0).sqrt() + self.s * (r * sp);
        let lift = (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
        let nh = p1 * self.t1 + p2 * self.t2 + lift * self.v;
        // Unstretch. nh.z >= 0 for a visible normal; max(0) only absorbs rounding.
        let m = DVec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0));
        let len = m.length();
        if !(len > 0.0) {
            return None;
        }
        reflect_above(self.lobe.wi, m / len)
    }

    fn invert(&self, wo: DVec3) -> Option<DVec2> {
        let alpha = self.lobe.density_alpha()?;
        let m = normal_between(self.lobe.wi, wo)?;
        let nh = DVec3::new(m.x / alpha, m.y / alpha, m.z).normalize();
        // Only normals that wi sees are in the image of the warp.
        if !(nh.dot(self.v) >= 0.0) {
            return None;
        }
        let p1 = nh.dot(self.t1);
        let q2 = nh.dot(self.t2);
        let p2 = (q2 - (1.0 - self.s) * (1.0 - p1 * p1).max(0.0).sqrt()) / self.s;
        let u1 = (p1 * p1 + p2 * p2).min(ONE_MINUS_EPSILON);
        Some(DVec2::new(u1, wrap_unit(p2.atan2(p1) / (2.0 * PI))))
    }

    fn pdf(&self, wo: DVec3) -> f64 {
        let Some(alpha) = self.lobe.density_alpha() else {
            return 0.0;
        };
        match normal_between(self.lobe.wi, wo) {
            // D_wi(m) = D(m) max(0, wi.m) / sigma(wi); sigma >= alpha/2 > 0, even at grazing wi.
            Some(m) => {
                let visible = ndf(m, alpha) * self.lobe.wi.dot(m).max(0.0) / projected_area(self.lobe.wi, alpha);
                reflected_pdf(visible, wo, m)
            }
            None => 0.0,
        }
    }

    fn is_delta(&self) -> bool {
        self.lobe.is_delta()
    }
}
