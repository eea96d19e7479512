//! The scalar type of the shared numerics: `f64` on the host, `f32` on the Cortex-M4F.
//!
//! Every transcendental goes through the `libm` crate on both sides (not `std`), so the host can
//! reproduce the firmware's `f32` results exactly in its tests.

use core::fmt::Debug;
use core::ops::{Add, Div, Mul, Neg, Sub};

/// A float the shared code computes in. Implemented for `f32` and `f64` only.
pub trait Real:
    Copy
    + Debug
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    const ZERO: Self;
    const ONE: Self;
    const TWO: Self;
    const HALF: Self;
    const PI: Self;
    const TAU: Self;
    const FRAC_PI_2: Self;
    /// Machine epsilon of the type.
    const EPSILON: Self;

    fn from_f64(x: f64) -> Self;
    fn to_f64(self) -> f64;
    fn from_i64(x: i64) -> Self;
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    fn atan2(self, x: Self) -> Self;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    /// Round half away from zero.
    fn round(self) -> Self;
    fn floor(self) -> Self;
    fn is_finite(self) -> bool;

    fn max(self, o: Self) -> Self {
        if self > o {
            self
        } else {
            o
        }
    }
    fn min(self, o: Self) -> Self {
        if self < o {
            self
        } else {
            o
        }
    }
    fn clamp(self, lo: Self, hi: Self) -> Self {
        self.max(lo).min(hi)
    }
    fn to_degrees(self) -> Self {
        self * Self::from_f64(180.0) / Self::PI
    }
    fn to_radians(self) -> Self {
        self * Self::PI / Self::from_f64(180.0)
    }
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const TWO: Self = 2.0;
    const HALF: Self = 0.5;
    const PI: Self = core::f64::consts::PI;
    const TAU: Self = core::f64::consts::TAU;
    const FRAC_PI_2: Self = core::f64::consts::FRAC_PI_2;
    const EPSILON: Self = f64::EPSILON;
    fn from_f64(x: f64) -> Self {
        x
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn from_i64(x: i64) -> Self {
        x as f64
    }
    fn sin(self) -> Self {
        libm::sin(self)
    }
    fn cos(self) -> Self {
        libm::cos(self)
    }
    fn atan2(self, x: Self) -> Self {
        libm::atan2(self, x)
    }
    fn sqrt(self) -> Self {
        libm::sqrt(self)
    }
    fn abs(self) -> Self {
        libm::fabs(self)
    }
    fn round(self) -> Self {
        libm::round(self)
    }
    fn floor(self) -> Self {
        libm::floor(self)
    }
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const TWO: Self = 2.0;
    const HALF: Self = 0.5;
    const PI: Self = core::f32::consts::PI;
    const TAU: Self = core::f32::consts::TAU;
    const FRAC_PI_2: Self = core::f32::consts::FRAC_PI_2;
    const EPSILON: Self = f32::EPSILON;
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn from_i64(x: i64) -> Self {
        x as f32
    }
    fn sin(self) -> Self {
        trig32::sin(self)
    }
    fn cos(self) -> Self {
        trig32::cos(self)
    }
    fn atan2(self, x: Self) -> Self {
        libm::atan2f(self, x)
    }
    fn sqrt(self) -> Self {
        libm::sqrtf(self)
    }
    fn abs(self) -> Self {
        libm::fabsf(self)
    }
    fn round(self) -> Self {
        libm::roundf(self)
    }
    fn floor(self) -> Self {
        libm::floorf(self)
    }
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
}

/// `sin` and `cos` computed in f32 alone (Cephes' `sinf`/`cosf`: a three-part Cody-Waite
/// reduction by pi/4 and degree-7/8 polynomials on [-pi/4, pi/4]), within 2 ulp of the true
/// value (tested). libm's `sinf`/`cosf` reduce and evaluate in f64, soft-float on a Cortex-M4F
/// (its flash cost: `docs/firmware.md`).
///
/// The reduction is exact for `|x| <= LIMIT` (8192 rad, about 1300 turns); beyond it, and for
/// NaN and infinities, the result is NaN, which the kinematics reject as `NotFinite`.
pub mod trig32 {
    /// Largest `|x|` served.
    pub const LIMIT: f32 = 8192.0;
    const FOPI: f32 = 1.273_239_5; // 4 / pi
                                   // pi/4 = DP1 + DP2 + DP3, DP1 and DP2 with few enough bits that y * DP1, y * DP2 are exact.
    const DP1: f32 = 0.785_156_25;
    const DP2: f32 = 2.418_756_5e-4;
    const DP3: f32 = 3.774_895e-8;

    /// For `0 <= x <= LIMIT`: the octant (0..8) and `x` reduced into [-pi/4, pi/4] around it.
    fn reduce(x: f32) -> (u32, f32) {
        // In range, so the conversion is exact truncation (and saturating in any case).
        let mut j = (x * FOPI) as u32;
        let mut y = j as f32;
        if j & 1 == 1 {
            j += 1;
            y += 1.0;
        }
        (j & 7, ((x - y * DP1) - y * DP2) - y * DP3)
    }

    fn sin_poly(x: f32) -> f32 {
        let z = x * x;
        ((-1.951_529_6e-4 * z + 8.332_161e-3) * z - 1.666_665_5e-1) * z * x + x
    }

    fn cos_poly(x: f32) -> f32 {
        let z = x * x;
        ((2.443_315_7e-5 * z - 1.388_731_6e-3) * z + 4.166_664_6e-2) * z * z - 0.5 * z + 1.0
    }

    pub fn sin(x: f32) -> f32 {
        let a = libm::fabsf(x);
        // Also false for NaN.
        if !(a <= LIMIT) {
            return f32::NAN;
        }
        let (mut j, r) = reduce(a);
        let mut negative = x < 0.0;
        if j > 3 {
            negative = !negative;
            j -= 4;
        }
        let v = if j == 1 || j == 2 { cos_poly(r) } else { sin_poly(r) };
        if negative {
            -v
        } else {
            v
        }
    }

    pub fn cos(x: f32) -> f32 {
        let a = libm::fabsf(x);
        if !(a <= LIMIT) {
            return f32::NAN;
        }
        let (mut j, r) = reduce(a);
        let mut negative = false;
        if j > 3 {
            negative = true;
            j -= 4;
        }
        if j > 1 {
            negative = !negative;
        }
        let v = if j == 1 || j == 2 { sin_poly(r) } else { cos_poly(r) };
        if negative {
            -v
        } else {
            v
        }
    }
}

/// Wrap an angle into `(-pi, pi]`.
pub fn wrap_pi<R: Real>(a: R) -> R {
    let w = a - R::TAU * ((a + R::PI) / R::TAU).floor();
    // floor() puts w in [-pi, pi); move the lower end to the upper one.
    if w <= -R::PI {
        w + R::TAU
    } else {
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units of the last place of the correctly rounded f32 result (f64 reference),
    /// with an absolute floor of one ulp of 2^-24 near zero crossings.
    fn ulps(got: f32, exact: f64) -> f64 {
        let ulp = (libm::fabs(exact) as f32).max(1.0 / 16_777_216.0);
        let ulp = f64::from(f32::from_bits(ulp.to_bits() + 1) - ulp);
        libm::fabs(f64::from(got) - exact) / ulp
    }

    /// The arms' range (|x| <= 2 pi, beyond any axis' travel) on a fine grid plus special
    /// points: within 2 ulp of f64 sin/cos of the same f32 (libm's f64-based sinf/cosf are within
    /// 1). A coarser sweep to the limit: absolute error within 2^-23 (the reduction's error grows
    /// with |x|, which only matters near zero crossings).
    #[test]
    fn f32_sin_cos_are_within_two_ulp_over_the_arm_range_and_nan_beyond() {
        let mut worst = (0.0f64, 0.0f32);
        let mut check = |x: f32| {
            let xd = f64::from(x);
            for (got, exact) in [(trig32::sin(x), libm::sin(xd)), (trig32::cos(x), libm::cos(xd))] {
                let u = ulps(got, exact);
                assert!(u <= 2.0, "x = {x:e}: {got:e} vs {exact:e} ({u} ulp)");
                if u > worst.0 {
                    worst = (u, x);
                }
            }
        };
        let tau = core::f32::consts::TAU;
        let n = 2_000_000;
        for k in -n..=n {
            check(tau * k as f32 / n as f32);
        }
        for x in [
            0.0,
            -0.0,
            f32::MIN_POSITIVE,
            1e-30,
            1e-8,
            core::f32::consts::FRAC_PI_4,
            core::f32::consts::FRAC_PI_2,
            core::f32::consts::PI,
            3.0 * core::f32::consts::FRAC_PI_2,
            core::f32::consts::TAU,
        ] {
            check(x);
            check(-x);
        }
        assert!(worst.0 > 0.0);
        for k in 0..=400_000 {
            let x = trig32::LIMIT * k as f32 / 400_000.0;
            for x in [x, -x] {
                let xd = f64::from(x);
                let err = libm::fabs(f64::from(trig32::sin(x)) - libm::sin(xd))
                    .max(libm::fabs(f64::from(trig32::cos(x)) - libm::cos(xd)));
                assert!(err <= 1.0 / 8_388_608.0, "x = {x:e}: error {err:e}");
            }
        }
        for x in [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            trig32::LIMIT * 1.001,
            -1e30,
            f32::MAX,
        ] {
            assert!(trig32::sin(x).is_nan() && trig32::cos(x).is_nan(), "{x}");
        }
    }

    #[test]
    fn wrap_pi_range_and_identity() {
        for &a in &[0.0, 1.0, -1.0, 3.2, -3.2, 7.0, -7.0, 100.0, core::f64::consts::PI] {
            let w = wrap_pi(a);
            assert!(w > -core::f64::consts::PI && w <= core::f64::consts::PI, "{a} -> {w}");
            assert!((libm::sin(w) - libm::sin(a)).abs() < 1e-12);
            assert!((libm::cos(w) - libm::cos(a)).abs() < 1e-12);
        }
        assert_eq!(wrap_pi(-core::f64::consts::PI), core::f64::consts::PI);
    }
}
