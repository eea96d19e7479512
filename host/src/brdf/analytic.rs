//! The analytic models: Lambert, isotropic Ward (eq. 1 of Cao et al.) and GGX with separable Smith
//! masking and Fresnel 1. All return 0 when either direction is at or below the horizon.

use super::microfacet::{ndf, projected_area};
use super::roughness::{floored, Roughness};
use super::Material;
use glam::DVec3;
use std::f64::consts::{FRAC_1_PI, PI};

/// f = albedo / pi.
#[derive(Clone, Debug, PartialEq)]
pub struct Lambert {
    pub albedo: DVec3,
}

impl Material for Lambert {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        self.albedo * FRAC_1_PI
    }
}

/// Isotropic Ward, eq. 1: f = rho_d / pi + rho_s exp(-tan^2(theta_h) / alpha^2) / (4 pi alpha^2 sqrt(cos_i cos_o)).
#[derive(Clone, Debug, PartialEq)]
pub struct Ward {
    pub rho_d: DVec3,
    pub rho_s: DVec3,
    pub alpha: f64,
}

/// The specular factor of eq. 1 without rho_s. tan^2(theta_h) is taken from the unnormalised sum
/// wi + wo (the ratio does not depend on its length). Guard: cos_i cos_o <= 0 returns 0, so the
/// 1/sqrt is only taken of a positive number; it grows without bound towards the horizon, as the
/// model does, but stays finite. An exp that underflows returns 0 before any 0 * inf can form.
pub fn ward_specular(wi: DVec3, wo: DVec3, alpha: f64) -> f64 {
    let cc = wi.z * wo.z;
    if wi.z <= 0.0 || wo.z <= 0.0 || !(cc > 0.0) {
        return 0.0;
    }
    let a2 = floored(alpha).powi(2);
    let s = wi + wo;
    let tan2 = (s.x * s.x + s.y * s.y) / (s.z * s.z);
    let e = (-tan2 / a2).exp();
    if e == 0.0 {
        return 0.0;
    }
    e / (4.0 * PI * a2 * cc.sqrt())
}

impl Material for Ward {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let diffuse = self.rho_d * FRAC_1_PI;
        match Roughness::new(self.alpha) {
            Roughness::Mirror => diffuse,
            Roughness::Rough(a) => diffuse + self.rho_s * ward_specular(wi, wo, a),
        }
    }
}

/// GGX microfacet reflection with separable Smith masking G1(wi) G1(wo) and Fresnel 1 (Mitsuba 3's
/// `roughconductor` with `material = "none"`), plus an optional Lambert term:
/// f = diffuse / pi + specular D(h) G1(wi) G1(wo) / (4 cos_i cos_o).
#[derive(Clone, Debug, PartialEq)]
pub struct Ggx {
    pub alpha: f64,
    pub diffuse: DVec3,
    pub specular: DVec3,
}

/// The specular factor of the GGX model without its colour. Since G1(w) = cos(w) / sigma(w), the
/// factor is D(h) / (4 sigma(wi) sigma(wo)): no division by a vanishing cosine, and sigma >= alpha/2 > 0
/// above the horizon, so the formula needs no further guard.
pub fn ggx_specular(wi: DVec3, wo: DVec3, alpha: f64) -> f64 {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return 0.0;
    }
    let Some(h) = super::frame::half_vector(wi, wo) else {
        return 0.0;
    };
    ndf(h, alpha) / (4.0 * projected_area(wi, alpha) * projected_area(wo, alpha))
}

impl Material for Ggx {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let diffuse = self.diffuse * FRAC_1_PI;
        match Roughness::new(self.alpha) {
            Roughness::Mirror => diffuse,
            Roughness::Rough(a) => diffuse + self.specular * ggx_specular(wi, wo, a),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::frame::from_spherical;
    use crate::brdf::microfacet::smith_g1;
    use crate::brdf::roughness::MIRROR_ALPHA;

    #[test]
    fn ward_matches_eq1_written_out() {
        let (ti, to, dphi) = (0.5_f64, 0.8_f64, 2.0_f64);
        let wi = from_spherical(ti, 0.0);
        let wo = from_spherical(to, dphi);
        let m = Ward {
            rho_d: DVec3::splat(0.3),
            rho_s: DVec3::splat(0.7),
            alpha: 0.25,
        };
        let h = (wi + wo).normalize();
        let th = h.z.acos();
        let want =
            0.3 / PI + 0.7 / (4.0 * PI * 0.0625 * (ti.cos() * to.cos()).sqrt()) * (-th.tan().powi(2) / 0.0625).exp();
        let got = m.eval(wi, wo);
        assert!((got.x - want).abs() < 1e-12 * want, "{got} vs {want}");
        assert_eq!(m.eval(wi, -wo), DVec3::ZERO);
    }

    #[test]
    fn ggx_matches_textbook_form() {
        let wi = from_spherical(0.9, 0.0);
        let wo = from_spherical(0.4, 2.5);
        let alpha = 0.3;
        let h = (wi + wo).normalize();
        let d = alpha * alpha / (PI * (h.z * h.z * (alpha * alpha - 1.0) + 1.0).powi(2));
        let want = d * smith_g1(wi, h, alpha) * smith_g1(wo, h, alpha) / (4.0 * wi.z * wo.z);
        let m = Ggx {
            alpha,
            diffuse: DVec3::ZERO,
            specular: DVec3::ONE,
        };
        let got = m.eval(wi, wo).x;
        assert!((got - want).abs() < 1e-12 * want, "{got} vs {want}");
    }

    /// Extremes: alpha in {0, 1e-6, 1e-4, just below/above the mirror threshold, 1}, theta in
    /// {0, 89.9, 90} deg: finite, non-negative, and below the threshold exactly the diffuse part.
    #[test]
    fn extremes_finite_and_mirror_switch() {
        let thetas = [0.0_f64, 89.9, 90.0].map(f64::to_radians);
        let alphas = [0.0, 1e-6, 1e-4, MIRROR_ALPHA * 0.999, MIRROR_ALPHA * 1.001, 1.0];
        for alpha in alphas {
            let w = Ward {
                rho_d: DVec3::splat(0.2),
                rho_s: DVec3::splat(0.8),
                alpha,
            };
            let g = Ggx {
                alpha,
                diffuse: DVec3::splat(0.2),
                specular: DVec3::ONE,
            };
            for &ti in &thetas {
                for &to in &thetas {
                    for phi in [0.0, 1.0, PI] {
                        let (wi, wo) = (from_spherical(ti, 0.0), from_spherical(to, phi));
                        for f in [w.eval(wi, wo), g.eval(wi, wo)] {
                            assert!(f.is_finite() && f.min_element() >= 0.0, "alpha {alpha} {ti} {to}: {f}");
                            if alpha < MIRROR_ALPHA && wi.z > 0.0 && wo.z > 0.0 {
                                assert_eq!(f, DVec3::splat(0.2 / PI));
                            }
                        }
                    }
                }
            }
        }
    }
}
