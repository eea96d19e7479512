//! A minimal 3-vector generic over [`Real`], enough for the kinematics (glam has no generic scalar).

use crate::real::Real;
use core::ops::{Add, Sub};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vec3<R> {
    pub x: R,
    pub y: R,
    pub z: R,
}

impl<R: Real> Vec3<R> {
    pub const fn new(x: R, y: R, z: R) -> Self {
        Self { x, y, z }
    }
    /// Unit vector from spherical angles (theta from +z, phi from +x counter-clockwise).
    pub fn from_spherical(theta: R, phi: R) -> Self {
        let s = theta.sin();
        Self::new(s * phi.cos(), s * phi.sin(), theta.cos())
    }
    /// (theta, phi) of a unit vector; theta via atan2, which stays accurate at 0 and 90 degrees.
    pub fn to_spherical(self) -> (R, R) {
        let rho = (self.x * self.x + self.y * self.y).sqrt();
        (rho.atan2(self.z), self.y.atan2(self.x))
    }
    pub fn dot(self, o: Self) -> R {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    pub fn cross(self, o: Self) -> Self {
        Self::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    pub fn length(self) -> R {
        self.dot(self).sqrt()
    }
    pub fn scale(self, s: R) -> Self {
        Self::new(self.x * s, self.y * s, self.z * s)
    }
    /// Unit vector, or `None` when the length is too small to define a direction.
    pub fn normalize(self, min_length: R) -> Option<Self> {
        let l = self.length();
        if l > min_length {
            Some(self.scale(R::ONE / l))
        } else {
            None
        }
    }
    /// Angle between two unit vectors, accurate at 0 and pi (atan2 of |cross| and dot, not acos).
    pub fn angle_to(self, o: Self) -> R {
        self.cross(o).length().atan2(self.dot(o))
    }
}

impl<R: Real> Add for Vec3<R> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}

impl<R: Real> Sub for Vec3<R> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Self::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
