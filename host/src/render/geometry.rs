//! Cameras and the one object of a scene (unit sphere or flat square sample), in world space.
//! A single convex object lit from outside needs no shadow rays: a direction above a point's tangent
//! plane never meets the object again, and below it the BRDF is 0.

use glam::DVec3;

#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub origin: DVec3,
    /// Unit direction.
    pub dir: DVec3,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Projection {
    /// Looks down -z at the origin; the image spans x, y in [-1, 1], row 0 at y = +1.
    Orthographic,
    /// A pinhole at `position` looking at `look_at`, vertical field of view `2 atan(tan_half)`.
    Perspective {
        position: DVec3,
        forward: DVec3,
        right: DVec3,
        up: DVec3,
        tan_half: f64,
    },
}

#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub width: usize,
    pub height: usize,
    pub projection: Projection,
}

/// Where orthographic rays start: above the unit sphere and the sample.
const ORTHO_HEIGHT: f64 = 10.0;

impl Camera {
    /// A perspective camera; `None` when position and look_at coincide, `up` is parallel to the view,
    /// or the field of view is outside (0, 180) degrees.
    pub fn perspective(
        width: usize,
        height: usize,
        position: DVec3,
        look_at: DVec3,
        up: DVec3,
        fov_deg: f64,
    ) -> Option<Self> {
        if !(fov_deg > 0.0 && fov_deg < 180.0) {
            return None;
        }
        let forward = (look_at - position).try_normalize()?;
        let right = forward.cross(up).try_normalize()?;
        let up = right.cross(forward);
        Some(Self {
            width,
            height,
            projection: Projection::Perspective {
                position,
                forward,
                right,
                up,
                tan_half: (0.5 * fov_deg.to_radians()).tan(),
            },
        })
    }

    /// The ray through the continuous pixel position (px, py), px in [0, width), py in [0, height)
    /// from the top.
    pub fn ray(&self, px: f64, py: f64) -> Ray {
        let sx = 2.0 * px / self.width as f64 - 1.0;
        let sy = 1.0 - 2.0 * py / self.height as f64;
        match &self.projection {
            Projection::Orthographic => Ray {
                origin: DVec3::new(sx, sy, ORTHO_HEIGHT),
                dir: -DVec3::Z,
            },
            Projection::Perspective {
                position,
                forward,
                right,
                up,
                tan_half,
            } => {
                let aspect = self.width as f64 / self.height as f64;
                let d = *forward + (sx * tan_half * aspect) * *right + (sy * tan_half) * *up;
                Ray {
                    origin: *position,
                    // forward is a unit vector, so |d| >= 1: the normalisation never divides by 0.
                    dir: d.normalize(),
                }
            }
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// Unit sphere at the origin.
    Sphere,
    /// The square |x|, |y| <= 1 in the plane z = 0, facing +z.
    Plane,
}

/// A surface point: position and unit outward normal.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub point: DVec3,
    pub normal: DVec3,
}

impl Shape {
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        match self {
            Shape::Sphere => {
                // |o + t d|^2 = 1 with |d| = 1: t^2 + 2 b t + c = 0.
                let b = ray.origin.dot(ray.dir);
                let c = ray.origin.length_squared() - 1.0;
                let disc = b * b - c;
                if !(disc >= 0.0) {
                    return None;
                }
                // The nearer root, written to avoid cancellation: t0 = c / (-b + sqrt(disc)).
                let q = -b + disc.sqrt();
                let t = if q > 0.0 { c / q } else { -b - disc.sqrt() };
                if !(t > 0.0) {
                    return None;
                }
                let point = ray.origin + t * ray.dir;
                // Re-project onto the sphere: the normal is exactly unit even after rounding.
                let normal = point.try_normalize()?;
                Some(Hit { point: normal, normal })
            }
            Shape::Plane => {
                // Guard: a ray parallel to the plane never meets it.
                if ray.dir.z.abs() < 1e-15 {
                    return None;
                }
                let t = -ray.origin.z / ray.dir.z;
                if !(t > 0.0) {
                    return None;
                }
                let mut point = ray.origin + t * ray.dir;
                point.z = 0.0;
                (point.x.abs() <= 1.0 && point.y.abs() <= 1.0).then_some(Hit {
                    point,
                    normal: DVec3::Z,
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orthographic_rays_hit_the_sphere_where_expected() {
        let cam = Camera {
            width: 4,
            height: 2,
            projection: Projection::Orthographic,
        };
        let r = cam.ray(0.0, 0.0);
        assert_eq!((r.origin.x, r.origin.y), (-1.0, 1.0), "row 0 is the top (+y)");
        let hit = Shape::Sphere.intersect(&cam.ray(2.0, 1.0)).expect("centre hits");
        assert!((hit.point - DVec3::Z).length() < 1e-12);
        assert!(Shape::Sphere.intersect(&cam.ray(0.1, 0.1)).is_none(), "corner misses");
        let p = Shape::Plane
            .intersect(&cam.ray(3.0, 0.5))
            .expect("plane fills the frame");
        assert_eq!(p.point, DVec3::new(0.5, 0.5, 0.0));
        let persp =
            Camera::perspective(8, 8, DVec3::new(0.0, 0.0, 5.0), DVec3::ZERO, DVec3::Y, 30.0).expect("valid camera");
        let centre = persp.ray(4.0, 4.0);
        assert!((centre.dir + DVec3::Z).length() < 1e-12);
        let hit = Shape::Sphere.intersect(&centre).expect("hits");
        assert!((hit.point - DVec3::Z).length() < 1e-12);
        assert!(Camera::perspective(8, 8, DVec3::Y, DVec3::ZERO, DVec3::Y, 30.0).is_none());
        assert!(Camera::perspective(8, 8, DVec3::Z, DVec3::ZERO, DVec3::Y, 180.0).is_none());
    }
}
