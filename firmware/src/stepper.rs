//! The step generator: one synchronised trapezoidal move at a time, each step's instant computed in
//! closed form when it is due (`docs/firmware.md`).

use crate::hal::Steppers;
use gonio_shared::instrument::{InstrumentConfig, AXES, AXIS_COUNT};
use gonio_shared::kinematics::Steps;
use gonio_shared::motion::SyncMove;
use gonio_shared::separation::SeparationGuard;
use gonio_shared::{Axis, Real};
use heapless::Vec;

/// Why a move could not start or continue.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepError {
    /// The profile is not finite (cannot happen with a validated configuration and finite targets).
    BadProfile,
    /// The next step of an arm would bring the arms inside the blocking angle.
    Blocked,
}

/// The profile of one axis within a move, in that axis's steps.
#[derive(Clone, Copy, Debug, Default)]
struct AxisRun {
    total: u32,
    done: u32,
    increasing: bool,
    /// steps/s^2 and steps/s.
    accel: f32,
    peak: f32,
    /// Steps covered by each ramp (half the move for a triangular profile).
    ramp_steps: f32,
    t_ramp_s: f32,
    due_us: u64,
}

impl AxisRun {
    /// The instant of step `k` (1-based) of this axis.
    fn due(&self, k: u32, start_us: u64, end_us: u64) -> u64 {
        let kf = k as f32;
        let n = self.total as f32;
        if kf <= self.ramp_steps {
            start_us.saturating_add(ceil_us(Real::sqrt(2.0 * kf / self.accel)))
        } else if kf >= n - self.ramp_steps {
            let left = Real::max(n - kf, 0.0);
            end_us.saturating_sub(floor_us(Real::sqrt(2.0 * left / self.accel)))
        } else {
            start_us.saturating_add(ceil_us(self.t_ramp_s + (kf - self.ramp_steps) / self.peak))
        }
    }
}

/// Seconds to whole microseconds, rounded up; NaN and negatives give 0, huge values saturate.
fn ceil_us(seconds: f32) -> u64 {
    let us = seconds * 1e6;
    (-Real::floor(-us)) as u64
}

fn floor_us(seconds: f32) -> u64 {
    Real::floor(seconds * 1e6) as u64
}

#[derive(Clone, Copy, Debug)]
struct ActiveMove {
    axes: [AxisRun; AXIS_COUNT],
    /// Arms whose steps widen the separation go first, so two arm steps due at the same instant
    /// never pass through a narrower pose than either end.
    order: [Axis; AXIS_COUNT],
    start_us: u64,
    end_us: u64,
}

/// The axis positions and the move in progress. The only code that changes a step position.
#[derive(Clone, Debug)]
pub struct Stepper {
    position: Steps,
    /// The move in progress, if any: a `Vec` of at most one rather than an `Option` so that an
    /// idle stepper is all zero bytes (see `Controller`).
    active: Vec<ActiveMove, 1>,
}

impl Default for Stepper {
    fn default() -> Self {
        Self::new()
    }
}

impl Stepper {
    pub const fn new() -> Self {
        Self {
            position: [0; AXIS_COUNT],
            active: Vec::new(),
        }
    }

    pub fn position(&self) -> Steps {
        self.position
    }

    /// Declare where an axis is (homing found its switch). Only while no move runs.
    pub fn set_position(&mut self, axis: Axis, steps: i32) {
        if let Some(p) = self.position.get_mut(axis.index()) {
            *p = steps;
        }
    }

    pub fn is_moving(&self) -> bool {
        !self.active.is_empty()
    }

    /// Stop every axis at once (limit switch, homing switch found, abort of homing).
    pub fn halt(&mut self) {
        self.active.clear();
    }

    /// The next instant a step is due, if a move runs.
    pub fn next_due_us(&self) -> Option<u64> {
        let m = self.active.first()?;
        m.axes.iter().filter(|r| r.done < r.total).map(|r| r.due_us).min()
    }

    /// Start the synchronised move to `target` at `now_us`, every axis limited to `speed_scale` of
    /// its configured maximum speed (1 for plan moves, less for homing).
    pub fn start<H: Steppers>(
        &mut self,
        hal: &mut H,
        now_us: u64,
        target: Steps,
        cfg: &InstrumentConfig<f32>,
        speed_scale: f32,
    ) -> Result<(), StepError> {
        let mut limits = *cfg;
        for a in limits.axes.iter_mut() {
            a.max_speed *= speed_scale;
        }
        let mut deltas = [0.0f32; AXIS_COUNT];
        let mut counts = [(0u32, true); AXIS_COUNT];
        for axis in AXES {
            let i = axis.index();
            let (Some(&to), Some(&from)) = (target.get(i), self.position.get(i)) else {
                return Err(StepError::BadProfile);
            };
            let d = i64::from(to) - i64::from(from);
            let n = u32::try_from(d.unsigned_abs()).map_err(|_| StepError::BadProfile)?;
            if let (Some(c), Some(r)) = (counts.get_mut(i), deltas.get_mut(i)) {
                *c = (n, d >= 0);
                *r = d as f32 / cfg.axis(axis).steps_per_radian();
            }
        }
        let unit = SyncMove::new(&limits, deltas).unit;
        self.active.clear();
        if counts.iter().all(|&(n, _)| n == 0) {
            return Ok(());
        }
        let ok = |x: f32| x > 0.0 && x.is_finite();
        if !(ok(unit.accel) && ok(unit.peak_speed) && unit.duration().is_finite()) {
            return Err(StepError::BadProfile);
        }
        let start_us = now_us;
        let end_us = now_us.saturating_add(ceil_us(unit.duration()));
        let mut axes = [AxisRun::default(); AXIS_COUNT];
        for (run, &(total, increasing)) in axes.iter_mut().zip(counts.iter()) {
            let n = total as f32;
            run.total = total;
            run.increasing = increasing;
            run.accel = unit.accel * n;
            run.peak = unit.peak_speed * n;
            run.t_ramp_s = unit.t_ramp;
            run.ramp_steps = 0.5 * run.accel * unit.t_ramp * unit.t_ramp;
            if total > 0 {
                run.due_us = run.due(1, start_us, end_us);
            }
        }
        for axis in AXES {
            if let Some(r) = axes.get(axis.index()).filter(|r| r.total > 0) {
                hal.set_direction(axis, r.increasing);
            }
        }
        let light_widens = axes.get(Axis::Light.index()).is_none_or(|r| r.increasing);
        let order = if light_widens {
            [Axis::Light, Axis::Detector, Axis::Tilt, Axis::Azimuth]
        } else {
            [Axis::Detector, Axis::Light, Axis::Tilt, Axis::Azimuth]
        };
        self.active
            .push(ActiveMove {
                axes,
                order,
                start_us,
                end_us,
            })
            .map_err(|_| StepError::BadProfile)
    }

    /// Emit every step due at `now_us` (at most one per axis: a late call catches up on the next
    /// ones instead of bursting). With a `guard`, an arm step that would break the separation
    /// invariant is not emitted and the move stops with [`StepError::Blocked`].
    pub fn poll<H: Steppers>(
        &mut self,
        hal: &mut H,
        now_us: u64,
        guard: Option<&SeparationGuard>,
    ) -> Result<(), StepError> {
        let Some(m) = self.active.first_mut() else {
            return Ok(());
        };
        for axis in m.order {
            let i = axis.index();
            let Some(run) = m.axes.get_mut(i) else { continue };
            if run.done >= run.total || now_us < run.due_us {
                continue;
            }
            let Some(&here) = self.position.get(i) else { continue };
            let next = if run.increasing {
                here.saturating_add(1)
            } else {
                here.saturating_sub(1)
            };
            if let Some(g) = guard {
                let mut after = self.position;
                if let Some(p) = after.get_mut(i) {
                    *p = next;
                }
                let (l, d) = (after[Axis::Light.index()], after[Axis::Detector.index()]);
                if matches!(axis, Axis::Light | Axis::Detector) && !g.allows(l, d) {
                    self.active.clear();
                    return Err(StepError::Blocked);
                }
            }
            hal.step(axis);
            if let Some(p) = self.position.get_mut(i) {
                *p = next;
            }
            run.done += 1;
            if run.done < run.total {
                run.due_us = run.due(run.done + 1, m.start_us, m.end_us).max(run.due_us);
            }
        }
        if m.axes.iter().all(|r| r.done >= r.total) {
            self.active.clear();
        }
        Ok(())
    }
}
