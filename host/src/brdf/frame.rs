//! Directions in the local shading frame: +z is the surface normal, +x the tangent, theta measured
//! from +z, phi from +x counter-clockwise. Directions are unit vectors pointing away from the surface.

use glam::{DVec2, DVec3};

/// The largest f64 below 1 (pbrt's `OneMinusEpsilon`): every u in a warp is clamped to [0, this].
pub const ONE_MINUS_EPSILON: f64 = 1.0 - f64::EPSILON / 2.0;

/// Unit vector for polar angle `theta` and azimuth `phi` (radians).
pub fn from_spherical(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * cp, st * sp, ct)
}

/// Polar angle of `w` (need not be normalised). atan2 instead of acos keeps full precision near the
/// pole, where the round trips of the warps live.
pub fn theta_of(w: DVec3) -> f64 {
    w.x.hypot(w.y).atan2(w.z)
}

/// Azimuth of `w` in (-pi, pi]; 0 on the pole.
pub fn phi_of(w: DVec3) -> f64 {
    w.y.atan2(w.x)
}

/// Mirror `wi` about the unit normal `h`: 2 (wi.h) h - wi.
pub fn reflect(wi: DVec3, h: DVec3) -> DVec3 {
    2.0 * wi.dot(h) * h - wi
}

/// Below this length of wi + wo (unit vectors) the half vector is taken as undefined: the two
/// directions are opposite to within rounding and their sum carries no direction.
pub const MIN_HALF_LENGTH: f64 = 1e-12;

/// Normalised half vector of two unit directions; `None` when they are (nearly) opposite.
pub fn half_vector(wi: DVec3, wo: DVec3) -> Option<DVec3> {
    let s = wi + wo;
    let len = s.length();
    (len > MIN_HALF_LENGTH && len.is_finite()).then(|| s / len)
}

/// Clamp a warp input to [0, 1 - eps]^2 (NaN goes to 0), so u = 1 never reaches a formula.
pub fn clamp_u(u: DVec2) -> DVec2 {
    let c = |x: f64| {
        if x.is_nan() {
            0.0
        } else {
            x.clamp(0.0, ONE_MINUS_EPSILON)
        }
    };
    DVec2::new(c(u.x), c(u.y))
}

/// A periodic coordinate (azimuth / 2 pi) wrapped into [0, 1 - eps].
pub fn wrap_unit(x: f64) -> f64 {
    let r = x - x.floor();
    // x - floor(x) rounds up to exactly 1.0 for tiny negative x.
    if r.is_nan() {
        0.0
    } else {
        r.min(ONE_MINUS_EPSILON)
    }
}

/// Rotate `v` about +z by `angle` (right-handed).
pub fn rotate_z(v: DVec3, angle: f64) -> DVec3 {
    let (s, c) = angle.sin_cos();
    DVec3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z)
}

/// Rotate `v` about +y by `angle` (right-handed), the binormal rotation of the MERL reader.
pub fn rotate_y(v: DVec3, angle: f64) -> DVec3 {
    let (s, c) = angle.sin_cos();
    DVec3::new(c * v.x + s * v.z, v.y, -s * v.x + c * v.z)
}

/// Rec. 709 / linear sRGB luminance, used to reduce RGB to one number (fits, warps, reports).
pub fn luminance(rgb: DVec3) -> f64 {
    0.212671 * rgb.x + 0.715160 * rgb.y + 0.072169 * rgb.z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spherical_round_trip_and_rotations() {
        let w = from_spherical(0.7, -2.1);
        assert!((theta_of(w) - 0.7).abs() < 1e-14);
        assert!((phi_of(w) + 2.1).abs() < 1e-14);
        let r = rotate_y(rotate_z(w, 0.3), -0.4);
        let back = rotate_z(rotate_y(r, 0.4), -0.3);
        assert!((back - w).length() < 1e-14);
        // +x rotated a quarter turn about z is +y, +z a quarter turn about y is +x.
        assert!((rotate_z(DVec3::X, std::f64::consts::FRAC_PI_2) - DVec3::Y).length() < 1e-15);
        assert!((rotate_y(DVec3::Z, std::f64::consts::FRAC_PI_2) - DVec3::X).length() < 1e-15);
        assert_eq!(wrap_unit(-1e-300), ONE_MINUS_EPSILON);
        assert_eq!(clamp_u(DVec2::new(f64::NAN, 2.0)), DVec2::new(0.0, ONE_MINUS_EPSILON));
        assert!(half_vector(DVec3::X, -DVec3::X).is_none());
    }
}
