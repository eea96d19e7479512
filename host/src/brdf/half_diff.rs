//! Rusinkiewicz half/difference coordinates, as the MERL reference reader computes them:
//! h = normalize(wi + wo); d = wi rotated about the normal (z) by -phi_h, then about the binormal
//! (y) by -theta_h. Isotropic tables drop phi_h.

use super::frame::{from_spherical, half_vector, phi_of, reflect, rotate_y, rotate_z, theta_of};
use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfDiff {
    pub theta_h: f64,
    pub phi_h: f64,
    pub theta_d: f64,
    pub phi_d: f64,
    /// The difference vector d itself (unit), which the neural fits take as input.
    pub d: DVec3,
}

/// Half/difference coordinates of a pair, `None` if the pair has no half vector (opposite directions).
pub fn to_half_diff(wi: DVec3, wo: DVec3) -> Option<HalfDiff> {
    let h = half_vector(wi, wo)?;
    let (theta_h, phi_h) = (theta_of(h), phi_of(h));
    let d = rotate_y(rotate_z(wi, -phi_h), -theta_h);
    Some(HalfDiff {
        theta_h,
        phi_h,
        theta_d: theta_of(d),
        phi_d: phi_of(d),
        d,
    })
}

/// The (wi, wo) pair with the given half/difference angles and phi_h = 0: the inverse of `to_half_diff`.
pub fn from_half_diff(theta_h: f64, theta_d: f64, phi_d: f64) -> (DVec3, DVec3) {
    let d = from_spherical(theta_d, phi_d);
    let wi = rotate_y(d, theta_h);
    let h = from_spherical(theta_h, 0.0);
    (wi, reflect(wi, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_diff_round_trip() {
        for (th, td, pd) in [(0.3, 0.7, 1.1), (0.0, 0.2, -2.0), (1.2, 0.05, 3.0)] {
            let (wi, wo) = from_half_diff(th, td, pd);
            let hd = to_half_diff(wi, wo).expect("pair has a half vector");
            assert!(
                (hd.theta_h - th).abs() < 1e-12 && (hd.theta_d - td).abs() < 1e-12,
                "{hd:?}"
            );
            assert!((hd.phi_d - pd).abs() < 1e-12, "{hd:?}");
            // wo is the mirror of wi about h, so d for wo is -d rotated by pi: theta_d is shared.
            assert!((wo.length() - 1.0).abs() < 1e-14);
        }
    }
}
