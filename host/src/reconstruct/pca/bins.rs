//! The peer's BRDF space: 32 x 32 x 64 bins of (theta_h, theta_d, phi_d) in MERL's layout (theta_h
//! on a square-root scale, phi_d folded into [0, pi) by reciprocity), Nielsen et al.'s log mapping of
//! a bin's value, and a table of such bins as a `Material` (trilinear between bin centres).

use crate::brdf::half_diff::from_half_diff;
use crate::brdf::merl::{layout_coords, layout_trilinear};
use crate::brdf::Material;
use glam::DVec3;
use std::f64::consts::{FRAC_PI_2, PI};

pub const N_THETA_H: usize = 32;
pub const N_THETA_D: usize = 32;
pub const N_PHI_D: usize = 64;
pub const BINS: usize = N_THETA_H * N_THETA_D * N_PHI_D;
/// The grid's bins per axis (theta_h, theta_d, phi_d).
pub const DIMS: [usize; 3] = [N_THETA_H, N_THETA_D, N_PHI_D];

/// Nielsen et al.'s mapping: the cosine product is clipped below at this value ...
pub const COS_FLOOR: f64 = 0.01;
/// ... and the log mapping's offset (x + EPS) / (median + EPS).
pub const EPS: f64 = 1e-3;

/// Index of bin (theta_h, theta_d, phi_d).
pub fn index(th: usize, td: usize, pd: usize) -> usize {
    pd + N_PHI_D * (td + N_THETA_D * th)
}

/// The (wi, wo) pair at a bin's centre, rotated so that phi_i = 0 (the instrument's convention for
/// isotropic materials); `None` when either direction is at or below the horizon.
pub fn centre(bin: usize) -> Option<(DVec3, DVec3)> {
    let (pd, td, th) = (bin % N_PHI_D, (bin / N_PHI_D) % N_THETA_D, bin / (N_PHI_D * N_THETA_D));
    let u = (th as f64 + 0.5) / N_THETA_H as f64;
    let theta_h = u * u * FRAC_PI_2;
    let theta_d = (td as f64 + 0.5) / N_THETA_D as f64 * FRAC_PI_2;
    let phi_d = (pd as f64 + 0.5) / N_PHI_D as f64 * PI;
    let (wi, wo) = from_half_diff(theta_h, theta_d, phi_d);
    if !(wi.z > 1e-6 && wo.z > 1e-6) {
        return None;
    }
    let phi = wi.y.atan2(wi.x);
    let rot = |w: DVec3| {
        let (s, c) = (-phi).sin_cos();
        DVec3::new(c * w.x - s * w.y, s * w.x + c * w.y, w.z)
    };
    Some((rot(wi), rot(wo)))
}

/// Continuous bin coordinates of a pair (bin i spans [i, i + 1)), `None` without a half vector.
pub fn coords(wi: DVec3, wo: DVec3) -> Option<[f64; 3]> {
    layout_coords(wi, wo, DIMS)
}

/// The clipped cosine product of a pair.
pub fn cos_weight(wi: DVec3, wo: DVec3) -> f64 {
    (wi.z * wo.z).max(COS_FLOOR)
}

/// log((x + EPS) / (median + EPS)) of a cosine-weighted value x.
pub fn map(x: f64, median: f64) -> f64 {
    ((x.max(0.0) + EPS) / (median + EPS)).ln()
}

/// The inverse of `map`, never negative.
pub fn unmap(y: f64, median: f64) -> f64 {
    (y.exp() * (median + EPS) - EPS).max(0.0)
}

/// A reconstructed BRDF: f per bin and channel (1/sr), looked up trilinearly between bin centres
/// (phi_d periodic with period pi, the other two clamped at the first and last centre).
#[derive(Clone, Debug)]
pub struct BinnedBrdf {
    /// BINS x 3, bin-major.
    pub values: Vec<[f32; 3]>,
}

impl BinnedBrdf {
    fn bin(&self, th: usize, td: usize, pd: usize) -> DVec3 {
        let v = self.values[index(th, td, pd)];
        DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)
    }
}

impl Material for BinnedBrdf {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let Some(b) = coords(wi, wo) else {
            return DVec3::ZERO;
        };
        layout_trilinear(b, DIMS, |h, d, q| self.bin(h, d, q))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centres_fall_in_their_own_bin_with_phi_i_zero() {
        let mut valid = 0;
        for bin in (0..BINS).step_by(97) {
            let Some((wi, wo)) = centre(bin) else { continue };
            valid += 1;
            assert!(wi.y.abs() < 1e-9 && wi.x >= 0.0, "{wi}");
            let c = coords(wi, wo).expect("pair");
            let back = index(c[0] as usize, c[1] as usize, (c[2] as usize) % N_PHI_D);
            assert_eq!(back, bin);
        }
        assert!(valid > 300, "{valid}");
    }

    #[test]
    fn mapping_round_trips_and_a_table_reads_its_centres() {
        for (x, m) in [(0.0, 0.0), (0.3, 0.1), (12.0, 0.5)] {
            assert!((unmap(map(x, m), m) - x).abs() < 1e-9);
        }
        let values = (0..BINS).map(|b| [b as f32 * 1e-4, 1.0, 0.5]).collect();
        let t = BinnedBrdf { values };
        let bin = index(10, 12, 30);
        let (wi, wo) = centre(bin).expect("above the horizon");
        let got = t.eval(wi, wo);
        assert!(
            (got.x - bin as f64 * 1e-4).abs() < 1e-6 && (got.y - 1.0).abs() < 1e-6,
            "{got}"
        );
    }
}
