//! Instrument kinematics of the reference gonioreflectometer.
//!
//! ```text
//!  world: Z vertical, arms in the horizontal XY plane through the sample
//!
//!                 light arm (angle a)
//!                  \
//!                   \        sample normal n = (cos t, 0, sin t)
//!       detector --- (o) ---> X (arm angle 0)      tilt t about world Y,
//!       (angle b)                                   then azimuth psi about n
//! ```
//!
//! Light direction `L = (cos a, sin a, 0)`, detector `D = (cos b, sin b, 0)`. Since both arms lie in
//! one plane, that plane (world Z = its normal) must contain wi and wo: so world Z seen from the
//! sample is `m = ±normalize(wo x wi)`, the tilt is `asin(m.z)` and the arm angles follow from the
//! projections of wi and wo on the plane. The two signs of `m` are the two solution branches (light
//! counter-clockwise of the detector by `gamma` or by `2 pi - gamma`); we take the one nearest the
//! current pose. The arms keep the light counter-clockwise of the detector by a separation in
//! `[blocking, 2 pi - blocking]`: they never pass each other, so retro-reflection is unreachable.
//!
//! Singularities, each guarded where it arises:
//! - `wi` parallel to `wo` (retro-reflection): inside the blocked cone, refused before the cross product;
//! - `wi` antiparallel to `wo`: needs both on the horizon, which the horizon margin refuses;
//! - `|tilt| = 90 deg` (both directions on the horizon, out of plane): outside the tilt limits, which
//!   `InstrumentConfig::validate` keeps strictly inside (-90, 90) degrees.

use crate::instrument::{Axis, InstrumentConfig, AXES, AXIS_COUNT};
use crate::real::{wrap_pi, Real};
use crate::vec3::Vec3;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// A direction whose `cos theta` is at or below this is "below the horizon" (theta > 89.99994 deg):
/// no detector sees anything there, and it keeps the antiparallel singularity out of reach.
pub const HORIZON_MIN_COS: f64 = 1e-6;

/// Why a direction pair cannot be measured on this instrument.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum Unreachable {
    /// The incoming (`incoming = true`) or outgoing direction is at or below the horizon.
    BelowHorizon { incoming: bool },
    /// wi and wo are closer than the blocking angle: the arms would collide / shadow the sample.
    Blocked,
    /// The pose needs this axis beyond its soft limits.
    Limit(Axis),
    /// NaN or infinite input.
    NotFinite,
}

/// Axis angles in radians, one per axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose<R> {
    pub light: R,
    pub detector: R,
    pub tilt: R,
    pub azimuth: R,
}

impl<R: Real> Pose<R> {
    pub fn to_array(self) -> [R; AXIS_COUNT] {
        [self.light, self.detector, self.tilt, self.azimuth]
    }
    pub fn from_array(a: [R; AXIS_COUNT]) -> Self {
        Self {
            light: a[0],
            detector: a[1],
            tilt: a[2],
            azimuth: a[3],
        }
    }
    pub fn get(&self, axis: Axis) -> R {
        self.to_array()[axis.index()]
    }
}

/// Integer microstep positions, one per axis (`Axis::index` order). Step 0 is angle 0.
pub type Steps = [i32; AXIS_COUNT];

/// Kinematics of one validated instrument, in precision `R`.
#[derive(Clone, Debug)]
pub struct Kinematics<R> {
    cfg: InstrumentConfig<R>,
    steps_per_radian: [R; AXIS_COUNT],
}

impl<R: Real> Kinematics<R> {
    pub fn new(cfg: InstrumentConfig<R>) -> Result<Self, crate::instrument::ConfigError> {
        cfg.validate()?;
        let steps_per_radian = AXES.map(|a| cfg.axis(a).steps_per_radian());
        Ok(Self { cfg, steps_per_radian })
    }

    pub fn config(&self) -> &InstrumentConfig<R> {
        &self.cfg
    }

    /// The pose of the reference position (all axes at 0 except the arms, which must keep their
    /// order): light at +90 deg, detector at -90 deg.
    pub fn rest_pose(&self) -> Pose<R> {
        Pose {
            light: R::FRAC_PI_2,
            detector: -R::FRAC_PI_2,
            tilt: R::ZERO,
            azimuth: R::ZERO,
        }
    }

    /// Local directions of light and detector for a pose: `(wi, wo)`.
    pub fn forward(&self, p: &Pose<R>) -> (Vec3<R>, Vec3<R>) {
        let (st, ct) = (p.tilt.sin(), p.tilt.cos());
        let n = Vec3::new(ct, R::ZERO, st);
        // Stage frame at azimuth 0: x up the tilted sample, y = n x x = -Y.
        let x0 = Vec3::new(-st, R::ZERO, ct);
        let y0 = Vec3::new(R::ZERO, -R::ONE, R::ZERO);
        let x = x0.scale(p.azimuth.cos()) + y0.scale(p.azimuth.sin());
        let y = n.cross(x);
        let local = |v: Vec3<R>| Vec3::new(v.dot(x), v.dot(y), v.dot(n));
        let l = Vec3::new(p.light.cos(), p.light.sin(), R::ZERO);
        let d = Vec3::new(p.detector.cos(), p.detector.sin(), R::ZERO);
        (local(l), local(d))
    }

    /// Inverse kinematics from spherical angles (theta from +z, phi from +x), radians.
    pub fn inverse_angles(
        &self,
        theta_i: R,
        phi_i: R,
        theta_o: R,
        phi_o: R,
        current: &Pose<R>,
    ) -> Result<Pose<R>, Unreachable> {
        if !(theta_i.is_finite() && phi_i.is_finite() && theta_o.is_finite() && phi_o.is_finite()) {
            return Err(Unreachable::NotFinite);
        }
        self.inverse(
            Vec3::from_spherical(theta_i, phi_i),
            Vec3::from_spherical(theta_o, phi_o),
            current,
        )
    }

    /// Inverse kinematics: the pose that puts the light at `wi` and the detector at `wo` (local,
    /// unit vectors), on the solution branch nearest `current`. Isotropic instruments keep the
    /// azimuth where it is (the pair is then reproduced up to a rotation about the normal).
    pub fn inverse(&self, wi: Vec3<R>, wo: Vec3<R>, current: &Pose<R>) -> Result<Pose<R>, Unreachable> {
        let finite = |v: Vec3<R>| v.x.is_finite() && v.y.is_finite() && v.z.is_finite();
        if !finite(wi) || !finite(wo) {
            return Err(Unreachable::NotFinite);
        }
        let tiny = R::from_f64(1e-30);
        let (wi, wo) = match (wi.normalize(tiny), wo.normalize(tiny)) {
            (Some(i), Some(o)) => (i, o),
            _ => return Err(Unreachable::NotFinite),
        };
        let horizon = R::from_f64(HORIZON_MIN_COS);
        if wi.z <= horizon {
            return Err(Unreachable::BelowHorizon { incoming: true });
        }
        if wo.z <= horizon {
            return Err(Unreachable::BelowHorizon { incoming: false });
        }
        // Retro-reflection guard: refuse before the cross product degenerates.
        let gamma = wi.angle_to(wo);
        if gamma < self.cfg.blocking_angle || gamma <= R::ZERO {
            return Err(Unreachable::Blocked);
        }
        let z = Vec3::new(R::ZERO, R::ZERO, R::ONE);
        // Antiparallel guard: unreachable above the horizon margin, but never divide by ~0.
        let m = match wo.cross(wi).normalize(tiny) {
            Some(m) => m,
            None => z
                .cross(wi)
                .normalize(tiny)
                .ok_or(Unreachable::BelowHorizon { incoming: true })?,
        };

        let mut best: Option<(R, Pose<R>)> = None;
        let mut reason = Unreachable::Limit(Axis::Tilt);
        for sign in [R::ONE, -R::ONE] {
            let ms = m.scale(sign);
            let cos_t = (ms.x * ms.x + ms.y * ms.y).sqrt();
            let tilt = ms.z.atan2(cos_t);
            if !self.within(Axis::Tilt, tilt) {
                continue;
            }
            // cos_t >= cos(tilt limit) > 0 here (validated config), so e1 is well defined.
            let e1 = (z - ms.scale(ms.z)).scale(R::ONE / cos_t);
            let e2 = ms.cross(e1);
            let a = wi.dot(e2).atan2(wi.dot(e1));
            let b = wo.dot(e2).atan2(wo.dot(e1));
            // Light counter-clockwise of the detector: separation in (0, 2 pi).
            let mut sep = a - b;
            if sep < R::ZERO {
                sep = sep + R::TAU;
            }
            let azimuth = if self.cfg.isotropic {
                current.azimuth
            } else {
                // The material's tangent (local +x) in world coordinates, against the stage's x0/y0.
                let (xw_x, xw_y, xw_z) = (e1.x, e2.x, ms.x);
                let psi = (-xw_y).atan2(-tilt.sin() * xw_x + tilt.cos() * xw_z);
                current.azimuth + wrap_pi(psi - current.azimuth)
            };
            // Unwind the arms: try the detector one turn either way.
            for k in [-1i64, 0, 1] {
                let detector = b + R::from_i64(k) * R::TAU;
                let light = detector + sep;
                if !self.within(Axis::Detector, detector) {
                    reason = Unreachable::Limit(Axis::Detector);
                    continue;
                }
                if !self.within(Axis::Light, light) {
                    reason = Unreachable::Limit(Axis::Light);
                    continue;
                }
                let pose = Pose {
                    light,
                    detector,
                    tilt,
                    azimuth,
                };
                let cost = self.travel_cost(current, &pose);
                if best.as_ref().is_none_or(|(c, _)| cost < *c) {
                    best = Some((cost, pose));
                }
            }
        }
        best.map(|(_, p)| p).ok_or(reason)
    }

    /// A proxy for move time used to pick a branch: the slowest axis at full speed.
    fn travel_cost(&self, from: &Pose<R>, to: &Pose<R>) -> R {
        let mut cost = R::ZERO;
        for axis in AXES {
            let c = (to.get(axis) - from.get(axis)).abs() / self.cfg.axis(axis).max_speed;
            cost = cost.max(c);
        }
        cost
    }

    fn within(&self, axis: Axis, angle: R) -> bool {
        let c = self.cfg.axis(axis);
        c.continuous || (angle >= c.min && angle <= c.max)
    }

    /// Is this pose allowed: every axis within its limits and the arms at least the blocking angle
    /// apart with the light counter-clockwise of the detector.
    pub fn check_pose(&self, p: &Pose<R>) -> Result<(), Unreachable> {
        for axis in AXES {
            let v = p.get(axis);
            if !v.is_finite() {
                return Err(Unreachable::NotFinite);
            }
            if !self.within(axis, v) {
                return Err(Unreachable::Limit(axis));
            }
        }
        let sep = p.light - p.detector;
        if sep < self.cfg.blocking_angle || sep > R::TAU - self.cfg.blocking_angle {
            return Err(Unreachable::Blocked);
        }
        Ok(())
    }

    /// Integer step targets (round half away from zero), `Limit` if a count would overflow i32.
    pub fn to_steps(&self, p: &Pose<R>) -> Result<Steps, Unreachable> {
        let mut out = [0i32; AXIS_COUNT];
        for axis in AXES {
            let s = (p.get(axis) * self.steps_per_radian[axis.index()]).round();
            if !s.is_finite() {
                return Err(Unreachable::NotFinite);
            }
            let s = s.to_f64();
            if !(s >= i32::MIN as f64 && s <= i32::MAX as f64) {
                return Err(Unreachable::Limit(axis));
            }
            out[axis.index()] = s as i32;
        }
        Ok(out)
    }

    /// The pose at integer step positions.
    pub fn from_steps(&self, s: &Steps) -> Pose<R> {
        Pose::from_array(AXES.map(|a| R::from_i64(s[a.index()] as i64) / self.steps_per_radian[a.index()]))
    }

    pub fn steps_per_radian(&self, axis: Axis) -> R {
        self.steps_per_radian[axis.index()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn kin64(isotropic: bool) -> Kinematics<f64> {
        Kinematics::new(InstrumentConfig {
            isotropic,
            ..InstrumentConfig::<f64>::reference()
        })
        .unwrap()
    }

    fn angle(a: Vec3<f64>, b: Vec3<f64>) -> f64 {
        a.angle_to(b)
    }

    /// Invariants of an isotropic pair: theta_i, theta_o and the angle between them.
    fn iso_error(wi: Vec3<f64>, wo: Vec3<f64>, fi: Vec3<f64>, fo: Vec3<f64>) -> f64 {
        let (ti, to) = (wi.to_spherical().0, wo.to_spherical().0);
        let (fti, fto) = (fi.to_spherical().0, fo.to_spherical().0);
        (ti - fti)
            .abs()
            .max((to - fto).abs())
            .max((angle(wi, wo) - angle(fi, fo)).abs())
    }

    fn deg(x: f64) -> f64 {
        x.to_radians()
    }

    #[test]
    fn normal_incidence_and_in_plane_pairs_need_no_tilt() {
        let k = kin64(false);
        let rest = k.rest_pose();
        let wi = Vec3::from_spherical(0.0, 0.0);
        for theta_o in [deg(10.0), deg(45.0), deg(89.9)] {
            let wo = Vec3::from_spherical(theta_o, deg(30.0));
            let p = k.inverse(wi, wo, &rest).unwrap();
            let (fi, fo) = k.forward(&p);
            assert!(angle(fi, wi) < 1e-12 && angle(fo, wo) < 1e-12, "{p:?}");
            assert!(p.tilt.abs() < 1e-12, "in-plane pair needs no tilt: {p:?}");
            assert!((p.light - p.detector - theta_o).abs() < 1e-12);
        }
    }

    #[test]
    fn grazing_pairs_stay_finite_and_exact() {
        let k = kin64(false);
        for (ti, pi, to, po) in [
            (89.9, 0.0, 89.9, 180.0),
            (89.9, 0.0, 60.0, 170.0),
            (0.0, 0.0, 89.9, 0.0),
            (89.9, 10.0, 89.9, 100.0),
        ] {
            let (wi, wo) = (
                Vec3::from_spherical(deg(ti), deg(pi)),
                Vec3::from_spherical(deg(to), deg(po)),
            );
            match k.inverse(wi, wo, &k.rest_pose()) {
                Ok(p) => {
                    let (fi, fo) = k.forward(&p);
                    assert!(
                        angle(fi, wi) < 1e-9 && angle(fo, wo) < 1e-9,
                        "{ti} {pi} {to} {po}: {p:?}"
                    );
                }
                // Both grazing and 90 deg apart in azimuth needs |tilt| ~ 90: out of the tilt limits.
                Err(e) => assert_eq!(e, Unreachable::Limit(Axis::Tilt), "{ti} {pi} {to} {po}"),
            }
        }
        // Both grazing, 90 deg apart in phi: the plane through them is the surface: tilt 90 deg.
        let e = k.inverse(
            Vec3::from_spherical(deg(89.9), 0.0),
            Vec3::from_spherical(deg(89.9), deg(90.0)),
            &k.rest_pose(),
        );
        assert_eq!(e, Err(Unreachable::Limit(Axis::Tilt)));
    }

    #[test]
    fn horizon_nan_and_retro_reflection_fail_with_their_reason() {
        let k = kin64(false);
        let r = k.rest_pose();
        let up = Vec3::from_spherical(deg(30.0), 0.0);
        assert_eq!(
            k.inverse_angles(deg(90.0), 0.0, deg(30.0), 1.0, &r),
            Err(Unreachable::BelowHorizon { incoming: true })
        );
        assert_eq!(
            k.inverse_angles(deg(30.0), 0.0, deg(95.0), 1.0, &r),
            Err(Unreachable::BelowHorizon { incoming: false })
        );
        assert_eq!(
            k.inverse_angles(f64::NAN, 0.0, deg(30.0), 1.0, &r),
            Err(Unreachable::NotFinite)
        );
        assert_eq!(k.inverse(up, Vec3::new(0.0, 0.0, 0.0), &r), Err(Unreachable::NotFinite));
        assert_eq!(k.inverse(up, up, &r), Err(Unreachable::Blocked));
        // At the edge of the blocked cone (5 deg): just outside is reachable, just inside is not.
        let beta = deg(5.0);
        let out = Vec3::from_spherical(deg(30.0) + beta + 1e-9, 0.0);
        let inside = Vec3::from_spherical(deg(30.0) + beta - 1e-9, 0.0);
        let p = k.inverse(up, out, &r).unwrap();
        assert!(
            (p.light - p.detector - (beta + 1e-9)).abs() < 1e-12
                || (p.light - p.detector - (2.0 * core::f64::consts::PI - beta - 1e-9)).abs() < 1e-12
        );
        k.check_pose(&p).unwrap();
        assert_eq!(k.inverse(up, inside, &r), Err(Unreachable::Blocked));
    }

    #[test]
    fn tilt_near_its_limit() {
        // wi and wo chosen so that m.z = sin(tilt): tilt just inside and just outside 85 deg.
        let k = kin64(false);
        for (t, ok) in [(84.999, true), (85.001, false)] {
            let p = Pose {
                light: deg(40.0),
                detector: deg(-40.0),
                tilt: deg(t),
                azimuth: 0.3,
            };
            let (wi, wo) = k.forward(&p);
            let r = k.inverse(wi, wo, &p);
            if ok {
                let q = r.unwrap();
                let (fi, fo) = k.forward(&q);
                assert!(angle(fi, wi) < 1e-9 && angle(fo, wo) < 1e-9);
            } else {
                assert_eq!(r, Err(Unreachable::Limit(Axis::Tilt)));
            }
        }
    }

    #[test]
    fn steps_round_trip_and_overflow_is_a_limit() {
        let k = kin64(false);
        let p = Pose {
            light: 1.0,
            detector: -1.0,
            tilt: 0.2,
            azimuth: 3.0,
        };
        let s = k.to_steps(&p).unwrap();
        let q = k.from_steps(&s);
        for a in AXES {
            assert!((p.get(a) - q.get(a)).abs() <= 0.5 / k.steps_per_radian(a) + 1e-15);
        }
        let far = Pose { azimuth: 1e9, ..p };
        assert_eq!(k.to_steps(&far), Err(Unreachable::Limit(Axis::Azimuth)));
    }

    /// The hard poses in the firmware's precision: the same outcome as f64, and where reachable,
    /// FK(IK(w)) within a few f32 ulps of w.
    #[test]
    fn hard_poses_in_f32_match_f64() {
        let k64 = kin64(false);
        let k32 = Kinematics::new(InstrumentConfig {
            isotropic: false,
            ..InstrumentConfig::<f32>::reference()
        })
        .unwrap();
        let hard = [
            (0.0, 0.0, 45.0, 30.0),    // normal incidence
            (0.0, 0.0, 89.9, 0.0),     // normal in, grazing out
            (89.9, 0.0, 89.9, 180.0),  // both grazing, in plane
            (89.9, 0.0, 60.0, 170.0),  // grazing, near in plane
            (89.9, 10.0, 89.9, 100.0), // both grazing, 90 deg apart: tilt limit
            (30.0, 0.0, 35.5, 0.0),    // 5.5 deg apart: just outside the blocked cone
            (30.0, 0.0, 34.5, 0.0),    // 4.5 deg apart: blocked
            (30.0, 0.0, 30.0, 0.0),    // retro-reflection
            (90.0, 0.0, 30.0, 0.0),    // on the horizon
            (60.0, 0.0, 60.0, 120.0),  // far out of plane
        ];
        for (ti, pi, to, po) in hard {
            let r64 = k64.inverse_angles(deg(ti), deg(pi), deg(to), deg(po), &k64.rest_pose());
            let (ti32, pi32, to32, po32) = (deg(ti) as f32, deg(pi) as f32, deg(to) as f32, deg(po) as f32);
            let r32 = k32.inverse_angles(ti32, pi32, to32, po32, &k32.rest_pose());
            match (r64, r32) {
                (Ok(_), Ok(p)) => {
                    let (fi, fo) = k32.forward(&p);
                    let (wi, wo) = (Vec3::from_spherical(ti32, pi32), Vec3::from_spherical(to32, po32));
                    assert!(p.to_array().iter().all(|x| x.is_finite()));
                    assert!(
                        fi.angle_to(wi) < 2e-6 && fo.angle_to(wo) < 2e-6,
                        "{ti} {pi} {to} {po}: {p:?}"
                    );
                }
                (Err(a), Err(b)) => assert_eq!(a, b, "{ti} {pi} {to} {po}"),
                (a, b) => panic!("{ti} {pi} {to} {po}: f64 {a:?} but f32 {b:?}"),
            }
        }
    }

    fn dir() -> impl Strategy<Value = (f64, f64)> {
        (0.0..deg(89.9), -core::f64::consts::PI..core::f64::consts::PI)
    }

    fn pose_strategy() -> impl Strategy<Value = Pose<f64>> {
        (-1.0..1.0f64, deg(10.0)..deg(300.0), -1.4..1.4f64, -3.0..3.0f64).prop_map(|(d, sep, t, az)| Pose {
            light: d + sep,
            detector: d,
            tilt: t,
            azimuth: az,
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]

        /// FK(IK(w)) = w within 1e-9 rad, and the pose is legal, for every reachable pair.
        #[test]
        fn fk_of_ik_is_identity_anisotropic((ti, pi) in dir(), (to, po) in dir(), current in pose_strategy()) {
            let k = kin64(false);
            let (wi, wo) = (Vec3::from_spherical(ti, pi), Vec3::from_spherical(to, po));
            if let Ok(p) = k.inverse(wi, wo, &current) {
                k.check_pose(&p).unwrap();
                let (fi, fo) = k.forward(&p);
                prop_assert!(angle(fi, wi) < 1e-9 && angle(fo, wo) < 1e-9, "{:?}", p);
                prop_assert!((p.azimuth - current.azimuth).abs() <= core::f64::consts::PI + 1e-12, "unwound the short way");
            }
        }

        #[test]
        fn fk_of_ik_keeps_the_isotropic_invariants((ti, pi) in dir(), (to, po) in dir(), current in pose_strategy()) {
            let k = kin64(true);
            let (wi, wo) = (Vec3::from_spherical(ti, pi), Vec3::from_spherical(to, po));
            if let Ok(p) = k.inverse(wi, wo, &current) {
                prop_assert_eq!(p.azimuth, current.azimuth, "isotropic: azimuth never moves");
                let (fi, fo) = k.forward(&p);
                prop_assert!(iso_error(wi, wo, fi, fo) < 1e-9);
            }
        }

        /// FK is total: any legal pose gives unit directions, and IK from that pose returns to it.
        #[test]
        fn ik_of_fk_returns_the_pose_when_above_horizon(p in pose_strategy()) {
            let k = kin64(false);
            let p = Pose { tilt: p.tilt.clamp(deg(-84.0), deg(84.0)), ..p };
            let (wi, wo) = k.forward(&p);
            prop_assert!((wi.length() - 1.0).abs() < 1e-12 && (wo.length() - 1.0).abs() < 1e-12);
            if let Ok(q) = k.inverse(wi, wo, &p) {
                let (fi, fo) = k.forward(&q);
                prop_assert!(angle(fi, wi) < 1e-9 && angle(fo, wo) < 1e-9);
            }
        }
    }
}
