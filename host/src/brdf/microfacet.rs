//! GGX / Trowbridge-Reitz microfacet formulas (isotropic), shared by the GGX model, the GGX warps
//! and the RGL files. Every function floors alpha itself (see `roughness`).

use super::roughness::floored;
use glam::DVec3;
use std::f64::consts::PI;

/// Normal distribution D(m) per unit solid angle, normalised so that the integral of D(m) m.z over
/// the hemisphere is 1. Written as alpha^2 / (pi (sin^2 + alpha^2 cos^2)^2), which equals the
/// textbook alpha^2 / (pi (cos^2 (alpha^2 - 1) + 1)^2) but takes sin^2 from x, y and so keeps its
/// precision near the pole. 0 for normals below the horizon.
pub fn ndf(m: DVec3, alpha: f64) -> f64 {
    if m.z <= 0.0 {
        return 0.0;
    }
    let a2 = floored(alpha).powi(2);
    let len2 = m.length_squared();
    let sin2 = (m.x * m.x + m.y * m.y) / len2;
    let cos2 = m.z * m.z / len2;
    // The denominator is >= alpha_floor^4 (times pi) > 0 for every unit m with m.z > 0.
    let t = sin2 + a2 * cos2;
    a2 / (PI * t * t)
}

/// Projected area of the microsurface seen from w, sigma(w) = integral of D(m) max(0, w.m) dm
/// = (cos + sqrt(cos^2 + alpha^2 sin^2)) / 2. Equals cos / G1(w) for separable Smith masking, but stays
/// positive (alpha/2) at grazing w, where G1 and cos both vanish. 0 below the horizon.
pub fn projected_area(w: DVec3, alpha: f64) -> f64 {
    if w.z < 0.0 {
        return 0.0;
    }
    let a = floored(alpha);
    let len = w.length();
    let c = w.z / len;
    let s2 = (w.x * w.x + w.y * w.y) / (len * len);
    0.5 * (c + (c * c + a * a * s2).sqrt())
}

/// Smith masking G1(w) for the microfacet normal m (the chi+ factor: 0 if w sees the back of m).
pub fn smith_g1(w: DVec3, m: DVec3, alpha: f64) -> f64 {
    if w.dot(m) <= 0.0 || w.z <= 0.0 {
        return 0.0;
    }
    w.z / w.length() / projected_area(w, alpha)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::frame::from_spherical;

    /// Integral of D cos over the hemisphere and of D max(0, w.m) against sigma(w), by midpoint
    /// quadrature in (cos theta, phi) with the lobe resolved (alpha >= 0.05 here).
    #[test]
    fn ndf_normalised_and_sigma_consistent() {
        for alpha in [0.05, 0.3, 1.0] {
            let w = from_spherical(1.1, 0.4);
            let (nz, np) = (4000, 64);
            let (mut norm, mut proj) = (0.0, 0.0);
            for i in 0..nz {
                // Cells uniform in sqrt(1 - z) crowd near the pole, where narrow lobes live.
                let (s0, s1) = (i as f64 / nz as f64, (i + 1) as f64 / nz as f64);
                let s = 0.5 * (s0 + s1);
                let z = 1.0 - s * s;
                let dz = 2.0 * s * (s1 - s0);
                for j in 0..np {
                    let phi = (j as f64 + 0.5) / np as f64 * 2.0 * PI;
                    let m = from_spherical(z.acos(), phi);
                    let da = dz * 2.0 * PI / np as f64;
                    norm += ndf(m, alpha) * m.z * da;
                    proj += ndf(m, alpha) * w.dot(m).max(0.0) * da;
                }
            }
            assert!((norm - 1.0).abs() < 2e-3, "alpha {alpha}: integral of D cos = {norm}");
            let sigma = projected_area(w, alpha);
            assert!(
                (proj / sigma - 1.0).abs() < 2e-3,
                "alpha {alpha}: {proj} vs sigma {sigma}"
            );
        }
        assert!((projected_area(DVec3::X, 0.3) - 0.15).abs() < 1e-15);
    }
}
