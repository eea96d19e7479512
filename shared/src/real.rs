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
        libm::sinf(self)
    }
    fn cos(self) -> Self {
        libm::cosf(self)
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
