//! The step generator: one synchronised trapezoidal move at a time, each axis's steps as segments
//! fitted to the analytic profile (`segment`), queued to a segment board or played here step by
//! step (`docs/firmware.md`).

use crate::hal::Steppers;
use crate::segment::{tick, AxisProfile, Playback, SegmentGen, ONE_TICK};
use gonio_shared::instrument::{InstrumentConfig, AXES, AXIS_COUNT};
use gonio_shared::kinematics::Steps;
use gonio_shared::motion::SyncMove;
use gonio_shared::separation::SeparationGuard;
use gonio_shared::Axis;
use heapless::Vec;

/// A segment board's ring was full: look again this much later.
const REFILL_RETRY_US: u64 = 500;

/// Why a move could not start or continue.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepError {
    /// The profile is not finite (cannot happen with a validated configuration and finite targets).
    BadProfile,
    /// A step of an arm would bring the arms inside the blocking angle.
    Blocked,
}

#[derive(Clone, Copy, Debug)]
struct ActiveMove {
    gens: [SegmentGen; AXIS_COUNT],
    /// The per-step path: the segment each axis plays, and whether its scheduled step is still
    /// to come.
    play: [Playback; AXIS_COUNT],
    due: [bool; AXIS_COUNT],
    /// Arms whose steps widen the separation go first, so two arm steps due at the same instant
    /// never pass through a narrower pose than either end.
    order: [Axis; AXIS_COUNT],
    start_us: u64,
    /// The last step's instant (rounded up).
    end_us: u64,
    target: Steps,
    /// Segment boards: when the loop must come back to refill a ring.
    refill_us: u64,
    /// Segment boards: when the first ring of an axis with steps still to make runs out of queued
    /// steps (`u64::MAX` once every segment is queued). A loop that comes back later was late.
    dry_us: u64,
    /// `Stepper::next_due_us`, kept up to date (the loop asks for it on every turn).
    next_us: u64,
}

impl ActiveMove {
    fn update_next(&mut self) {
        let steps = (0..AXIS_COUNT)
            .filter(|&i| self.due.get(i).copied().unwrap_or(false))
            .filter_map(|i| self.play.get(i).map(|p| self.us(p.tick())))
            .min();
        self.next_us = steps.map_or(self.refill_us, |s| s).min(self.end_us);
    }
}

impl ActiveMove {
    /// The microsecond of a tick of this move (ticks are the low 32 bits of microseconds).
    fn us(&self, t: u32) -> u64 {
        self.start_us
            .saturating_add(u64::from(t.wrapping_sub(tick(self.start_us))))
    }
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

    /// Stop every axis at once (any fault, homing switch found, abort of homing); on a segment
    /// board the queued steps are dropped and the position is what was really made.
    pub fn stop<H: Steppers>(&mut self, hal: &mut H) {
        let Some(m) = self.active.first() else { return };
        if H::SEGMENTS {
            // The position stays at the move's start until its end: add what was made.
            let left = hal.drop_queued();
            for ((p, g), l) in self.position.iter_mut().zip(m.gens.iter()).zip(left) {
                let made = g.generated().saturating_sub(l) as i32;
                *p = p.wrapping_add(if g.profile.increasing { made } else { -made });
            }
        }
        self.active.clear();
    }

    /// Segment boards: the instant a ring of an axis with steps still to make runs dry, if a move
    /// runs and is not fully queued: the step generator's own deadline.
    pub fn dry_us(&self) -> Option<u64> {
        self.active.first().map(|m| m.dry_us).filter(|&t| t != u64::MAX)
    }

    /// The next instant the stepper has work, if a move runs: a step (per-step path), or a ring
    /// to refill, a look at the switches and the move's end (segment boards).
    pub fn next_due_us(&self) -> Option<u64> {
        self.active.first().map(|m| m.next_us)
    }

    /// Start the synchronised move to `target` at `now_us`, every axis limited to `speed_scale` of
    /// its configured maximum speed (1 for plan moves, less for homing). With a `guard`, both
    /// ends must keep the arms apart: the move is a straight line in joint space, so the
    /// separation changes monotonically in between (`gonio_shared::motion`).
    pub fn start<H: Steppers>(
        &mut self,
        hal: &mut H,
        now_us: u64,
        target: Steps,
        cfg: &InstrumentConfig<f32>,
        speed_scale: f32,
        guard: Option<&SeparationGuard>,
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
        if let Some(g) = guard {
            let arms = |s: &Steps| (s[Axis::Light.index()], s[Axis::Detector.index()]);
            let ((l0, d0), (l1, d1)) = (arms(&self.position), arms(&target));
            if !(g.allows(l0, d0) && g.allows(l1, d1)) {
                return Err(StepError::Blocked);
            }
        }
        let start = u64::from(tick(now_us)) << 32;
        let mut end = 0u64;
        let mut gens = [SegmentGen::default(); AXIS_COUNT];
        for (g, &(total, increasing)) in gens.iter_mut().zip(counts.iter()) {
            let profile = AxisProfile::new(&unit, total, increasing);
            if total > 0 {
                end = end.max(profile.duration());
            }
            *g = SegmentGen::new(profile, start);
        }
        for axis in AXES {
            if let Some(&(_, increasing)) = counts.get(axis.index()).filter(|c| c.0 > 0) {
                hal.set_direction(axis, increasing);
            }
        }
        let light_widens = counts.get(Axis::Light.index()).is_none_or(|c| c.1);
        let order = if light_widens {
            [Axis::Light, Axis::Detector, Axis::Tilt, Axis::Azimuth]
        } else {
            [Axis::Detector, Axis::Light, Axis::Tilt, Axis::Azimuth]
        };
        let mut m = ActiveMove {
            gens,
            play: [Playback::new(); AXIS_COUNT],
            due: [false; AXIS_COUNT],
            order,
            start_us: now_us,
            end_us: now_us.saturating_add(end.div_ceil(ONE_TICK)),
            target,
            refill_us: now_us,
            dry_us: u64::MAX,
            next_us: now_us,
        };
        if H::SEGMENTS {
            fill(&mut m, hal, now_us);
            m.next_us = m.refill_us.min(m.end_us);
        } else {
            for i in 0..AXIS_COUNT {
                load_next(&mut m, i);
            }
            m.update_next();
        }
        self.active.push(m).map_err(|_| StepError::BadProfile)
    }

    /// Segment boards: refill the rings and end the move at its last step. Per-step path: emit
    /// every step due at `now_us` (at most one per axis: a late call catches up on the next ones
    /// instead of bursting); with a `guard`, an arm step that would break the separation invariant
    /// is not emitted and the move stops with [`StepError::Blocked`].
    pub fn poll<H: Steppers>(
        &mut self,
        hal: &mut H,
        now_us: u64,
        guard: Option<&SeparationGuard>,
    ) -> Result<(), StepError> {
        let Some(m) = self.active.first_mut() else {
            return Ok(());
        };
        if H::SEGMENTS {
            fill(m, hal, now_us);
            m.next_us = m.refill_us.min(m.end_us);
            if now_us >= m.end_us && m.gens.iter().all(SegmentGen::is_done) {
                self.position = m.target;
                self.active.clear();
            }
            return Ok(());
        }
        for axis in m.order {
            let i = axis.index();
            let (Some(&due), Some(p)) = (m.due.get(i), m.play.get(i)) else {
                continue;
            };
            if !due || now_us < m.us(p.tick()) {
                continue;
            }
            let Some(&here) = self.position.get(i) else { continue };
            let increasing = m.gens.get(i).is_some_and(|g| g.profile.increasing);
            let next = if increasing {
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
            let scheduled = m.play.get_mut(i).is_some_and(Playback::schedule);
            if !scheduled {
                load_next(m, i);
            }
        }
        m.update_next();
        if !m.due.iter().any(|&d| d) {
            self.active.clear();
        }
        Ok(())
    }
}

/// Per-step path: play axis `i`'s next segment (or mark it done).
fn load_next(m: &mut ActiveMove, i: usize) {
    let seg = m.gens.get_mut(i).and_then(SegmentGen::next_segment);
    if let (Some(p), Some(d)) = (m.play.get_mut(i), m.due.get_mut(i)) {
        *d = seg.is_some();
        if let Some(s) = seg {
            p.load(&s);
        }
    }
}

/// Segment boards: queue segments while the rings have room; note when to come back.
fn fill<H: Steppers>(m: &mut ActiveMove, hal: &mut H, now_us: u64) {
    let mut refill = u64::MAX;
    let mut dry = u64::MAX;
    let rooms = hal.segment_room();
    for (axis, mut room) in AXES.into_iter().zip(rooms) {
        let Some(g) = m.gens.get_mut(axis.index()) else {
            continue;
        };
        while room > 0 {
            let Some(seg) = g.next_segment() else { break };
            hal.queue_segment(axis, seg);
            room -= 1;
        }
        if !g.is_done() {
            let until = (g.generated_until() >> 32) as u32;
            let at = m
                .start_us
                .saturating_add(u64::from(until.wrapping_sub(tick(m.start_us))));
            dry = dry.min(at);
            // A full ring that ends this soon: come back a little later, not at once.
            refill = refill.min(at.max(now_us.saturating_add(REFILL_RETRY_US)));
        }
    }
    m.refill_us = refill;
    m.dry_us = dry;
}
