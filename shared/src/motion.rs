//! Motion-profile math: trapezoidal moves and synchronised multi-axis moves.
//!
//! This is the time model the planner uses and the profile the firmware's step generator follows,
//! so both compute it from this one module.
//!
//! A synchronised move drives every axis along the same normalised profile `p(t)` in `[0, 1]`:
//! axis `i` is at `start_i + delta_i * p(t)`. All axes start and stop together and the move is a
//! straight line in joint space, so the arms' separation `light - detector` changes monotonically
//! and, since both end poses keep the blocking angle, so does every pose in between.
//! `p` is the fastest unit-distance trapezoid with peak speed `min_i vmax_i / |delta_i|` and
//! acceleration `min_i amax_i / |delta_i|`, so no axis exceeds its limits. Its duration is at least
//! the slowest single-axis time, and equal to it when one axis binds both speed and acceleration
//! (always so when the axes share the ratio vmax/amax, as the two arms do); otherwise a straight
//! joint-space line costs a little more than each axis alone (see `sync_move_time_bounds`).

use crate::instrument::{InstrumentConfig, AXES, AXIS_COUNT};
use crate::real::Real;

/// A symmetric trapezoidal (or, for short moves, triangular) velocity profile from rest to rest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trapezoid<R> {
    /// Distance covered, >= 0.
    pub distance: R,
    /// Speed reached (max speed, or less for a triangular profile).
    pub peak_speed: R,
    pub accel: R,
    /// Duration of each ramp.
    pub t_ramp: R,
    /// Duration at peak speed.
    pub t_cruise: R,
}

impl<R: Real> Trapezoid<R> {
    /// Fastest rest-to-rest move over `|distance|` under `vmax` and `amax`. `None` if a limit is
    /// not positive and finite, or the distance is not finite.
    pub fn new(distance: R, vmax: R, amax: R) -> Option<Self> {
        let ok = |x: R| x > R::ZERO && x.is_finite();
        if !ok(vmax) || !ok(amax) || !distance.is_finite() {
            return None;
        }
        let d = distance.abs();
        // Distance needed to reach vmax and stop again: vmax^2 / amax.
        let (peak, t_ramp, t_cruise) = if d * amax >= vmax * vmax {
            (vmax, vmax / amax, (d - vmax * vmax / amax) / vmax)
        } else {
            // Triangular: peak = sqrt(d * amax); sqrt(0) = 0 gives the zero-length move.
            let peak = (d * amax).sqrt();
            (peak, peak / amax, R::ZERO)
        };
        Some(Self {
            distance: d,
            peak_speed: peak,
            accel: amax,
            t_ramp,
            t_cruise,
        })
    }

    pub fn duration(&self) -> R {
        R::TWO * self.t_ramp + self.t_cruise
    }

    /// Distance covered at time `t` (clamped to [0, duration]).
    pub fn position(&self, t: R) -> R {
        let total = self.duration();
        let t = t.clamp(R::ZERO, total);
        let ramp_d = R::HALF * self.accel * self.t_ramp * self.t_ramp;
        if t <= self.t_ramp {
            R::HALF * self.accel * t * t
        } else if t <= self.t_ramp + self.t_cruise {
            ramp_d + self.peak_speed * (t - self.t_ramp)
        } else {
            let r = total - t;
            self.distance - R::HALF * self.accel * r * r
        }
    }

    /// Speed at time `t` (0 outside the move).
    pub fn speed(&self, t: R) -> R {
        let total = self.duration();
        if t <= R::ZERO || t >= total {
            R::ZERO
        } else if t < self.t_ramp {
            self.accel * t
        } else if t <= self.t_ramp + self.t_cruise {
            self.peak_speed
        } else {
            self.accel * (total - t)
        }
    }
}

/// Time of the fastest single-axis move (0 for a zero distance; infinite for invalid limits).
pub fn move_time<R: Real>(distance: R, vmax: R, amax: R) -> R {
    match Trapezoid::new(distance, vmax, amax) {
        Some(t) => t.duration(),
        None => R::from_f64(f64::INFINITY),
    }
}

/// All axes moving together along one normalised profile.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SyncMove<R> {
    /// Signed displacement per axis, radians.
    pub deltas: [R; AXIS_COUNT],
    /// Unit-distance profile shared by all axes.
    pub unit: Trapezoid<R>,
}

impl<R: Real> SyncMove<R> {
    /// The synchronised move by `deltas` under the limits of `cfg` (a validated config).
    pub fn new(cfg: &InstrumentConfig<R>, deltas: [R; AXIS_COUNT]) -> Self {
        let big = R::from_f64(f64::MAX);
        let (mut v, mut a) = (big, big);
        for axis in AXES {
            let d = deltas[axis.index()].abs();
            // A still axis sets no limit (guard against dividing by zero).
            if d > R::ZERO {
                let c = cfg.axis(axis);
                v = v.min(c.max_speed / d);
                a = a.min(c.max_accel / d);
            }
        }
        let zero = Trapezoid {
            distance: R::ZERO,
            peak_speed: R::ZERO,
            accel: R::ONE,
            t_ramp: R::ZERO,
            t_cruise: R::ZERO,
        };
        let unit = if v == big {
            zero
        } else {
            Trapezoid::new(R::ONE, v, a).unwrap_or(zero)
        };
        Self { deltas, unit }
    }

    pub fn duration(&self) -> R {
        self.unit.duration()
    }

    /// Displacement of every axis at time `t` since the start.
    pub fn offsets(&self, t: R) -> [R; AXIS_COUNT] {
        let p = self.unit.position(t);
        self.deltas.map(|d| d * p)
    }
}

/// Duration of the synchronised move between two poses (the planner's time model).
pub fn sync_move_time<R: Real>(cfg: &InstrumentConfig<R>, from: &[R; AXIS_COUNT], to: &[R; AXIS_COUNT]) -> R {
    let mut deltas = [R::ZERO; AXIS_COUNT];
    for i in 0..AXIS_COUNT {
        deltas[i] = to[i] - from[i];
    }
    SyncMove::new(cfg, deltas).duration()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn trapezoid_and_triangle_closed_forms() {
        // Long move: d/v + v/a.
        let t = Trapezoid::new(10.0, 2.0, 1.0).unwrap();
        assert!((t.duration() - (10.0 / 2.0 + 2.0)).abs() < 1e-12);
        assert!((t.position(t.duration()) - 10.0).abs() < 1e-12);
        // Short move: 2 sqrt(d/a).
        let t = Trapezoid::new(1.0, 2.0, 1.0).unwrap();
        assert!((t.duration() - 2.0).abs() < 1e-12);
        assert!((t.peak_speed - 1.0).abs() < 1e-12);
        // Boundary d = v^2/a: both formulas agree.
        let t = Trapezoid::new(4.0, 2.0, 1.0).unwrap();
        assert!((t.duration() - 4.0).abs() < 1e-12);
        // Zero, negative and invalid.
        assert_eq!(Trapezoid::new(0.0, 2.0, 1.0).unwrap().duration(), 0.0);
        assert_eq!(
            Trapezoid::new(-10.0, 2.0, 1.0).unwrap().duration(),
            Trapezoid::new(10.0, 2.0, 1.0).unwrap().duration()
        );
        assert!(Trapezoid::new(1.0, 0.0, 1.0).is_none());
        assert!(Trapezoid::new(1.0, 1.0, f64::NAN).is_none());
        assert!(Trapezoid::new(f64::INFINITY, 1.0, 1.0).is_none());
        assert!(move_time(1.0f64, -1.0, 1.0).is_infinite());
    }

    #[test]
    fn zero_move_takes_no_time() {
        let cfg = InstrumentConfig::<f64>::reference();
        let m = SyncMove::new(&cfg, [0.0; 4]);
        assert_eq!(m.duration(), 0.0);
        assert_eq!(m.offsets(1.0), [0.0; 4]);
    }

    fn deltas() -> impl Strategy<Value = [f64; 4]> {
        [-4.0..4.0f64, -4.0..4.0f64, -2.0..2.0f64, -6.0..6.0f64]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn trapezoid_respects_limits_and_ends_at_distance(d in -10.0..10.0f64, v in 0.01..10.0f64, a in 0.01..10.0f64) {
            let t = Trapezoid::new(d, v, a).unwrap();
            let total = t.duration();
            prop_assert!((t.position(total) - d.abs()).abs() < 1e-9 * (1.0 + d.abs()));
            prop_assert!(t.peak_speed <= v * (1.0 + 1e-12));
            // Monotone position, speed within limits at sample times.
            let mut last = 0.0;
            for i in 0..=64 {
                let s = total * i as f64 / 64.0;
                let p = t.position(s);
                prop_assert!(p >= last - 1e-12);
                prop_assert!(t.speed(s) <= v * (1.0 + 1e-12));
                last = p;
            }
        }

        /// The synchronised move: every axis within its own speed and acceleration, all finish
        /// together at their deltas, and the duration is bounded below by the slowest axis alone.
        #[test]
        fn sync_move_time_bounds(deltas in deltas()) {
            let cfg = InstrumentConfig::<f64>::reference();
            let m = SyncMove::new(&cfg, deltas);
            let total = m.duration();
            let slowest = AXES.iter().map(|&ax| {
                let c = cfg.axis(ax);
                move_time(deltas[ax.index()], c.max_speed, c.max_accel)
            }).fold(0.0f64, f64::max);
            prop_assert!(total >= slowest * (1.0 - 1e-12), "{total} < {slowest}");
            let end = m.offsets(total);
            for ax in AXES {
                let i = ax.index();
                let c = cfg.axis(ax);
                prop_assert!((end[i] - deltas[i]).abs() < 1e-9);
                prop_assert!(deltas[i].abs() * m.unit.peak_speed <= c.max_speed * (1.0 + 1e-9));
                prop_assert!(deltas[i].abs() * m.unit.accel <= c.max_accel * (1.0 + 1e-9));
            }
        }

        /// Two arms only (same vmax/amax ratio): the synchronised move takes exactly the slowest
        /// arm's single-axis time.
        #[test]
        fn sync_move_of_the_arms_equals_the_slowest_arm(dl in -4.0..4.0f64, dd in -4.0..4.0f64) {
            let cfg = InstrumentConfig::<f64>::reference();
            let m = SyncMove::new(&cfg, [dl, dd, 0.0, 0.0]);
            let c = cfg.axes[0];
            let slowest = move_time(dl, c.max_speed, c.max_accel).max(move_time(dd, c.max_speed, c.max_accel));
            prop_assert!((m.duration() - slowest).abs() <= 1e-12 * (1.0 + slowest));
        }

        /// Any two axes, whatever their limits: when the same axis binds speed and acceleration,
        /// the synchronised time equals that axis's single-axis time.
        #[test]
        fn sync_move_equals_slowest_when_one_axis_binds(deltas in deltas()) {
            let cfg = InstrumentConfig::<f64>::reference();
            let m = SyncMove::new(&cfg, deltas);
            let moving: std::vec::Vec<_> = AXES.iter().filter(|a| deltas[a.index()] != 0.0).collect();
            let vbind = moving.iter().min_by(|a, b| (cfg.axis(***a).max_speed / deltas[a.index()].abs()).total_cmp(&(cfg.axis(***b).max_speed / deltas[b.index()].abs()))).unwrap();
            let abind = moving.iter().min_by(|a, b| (cfg.axis(***a).max_accel / deltas[a.index()].abs()).total_cmp(&(cfg.axis(***b).max_accel / deltas[b.index()].abs()))).unwrap();
            if vbind == abind {
                let c = cfg.axis(**vbind);
                let own = move_time(deltas[vbind.index()], c.max_speed, c.max_accel);
                prop_assert!((m.duration() - own).abs() <= 1e-12 * (1.0 + own));
            }
        }

        /// Separation light - detector is monotone along a synchronised move.
        #[test]
        fn arm_separation_is_monotone(deltas in deltas()) {
            let cfg = InstrumentConfig::<f64>::reference();
            let m = SyncMove::new(&cfg, deltas);
            let total = m.duration();
            let sep = |t: f64| { let o = m.offsets(t); o[0] - o[1] };
            let dir = (deltas[0] - deltas[1]).signum();
            let mut last = sep(0.0);
            for i in 1..=128 {
                let s = sep(total * i as f64 / 128.0);
                prop_assert!((s - last) * dir >= -1e-12);
                last = s;
            }
        }
    }
}
