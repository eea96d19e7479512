//! Homing: find every axis's switch, one axis at a time, then park it; why the order is safe is in
//! `docs/firmware.md`.

use gonio_shared::instrument::{HomeSide, InstrumentConfig};
use gonio_shared::kinematics::Kinematics;
use gonio_shared::{Axis, Real};

/// The order axes are homed in.
pub const ORDER: [Axis; 4] = [Axis::Tilt, Axis::Azimuth, Axis::Light, Axis::Detector];
/// Seek and back-off speed, as a fraction of each axis's maximum speed.
pub const SPEED_SCALE: f32 = 0.25;
/// How far to back off a switch closed at the start, radians.
pub const BACKOFF_RAD: f32 = 0.1;

/// Where homing of the current axis stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// About to look at the switch of `ORDER[axis]`.
    Begin,
    BackOff,
    Seek,
    Park,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Homing {
    /// Index into [`ORDER`]; `ORDER.len()` when every axis is done.
    pub position_in_order: usize,
    pub stage: Stage,
    pub light_homed: bool,
    pub detector_homed: bool,
}

impl Homing {
    pub const fn new() -> Self {
        Self {
            position_in_order: 0,
            stage: Stage::Begin,
            light_homed: false,
            detector_homed: false,
        }
    }

    pub fn axis(&self) -> Option<Axis> {
        ORDER.get(self.position_in_order).copied()
    }

    pub fn arms_homed(&self) -> bool {
        self.light_homed && self.detector_homed
    }
}

impl Default for Homing {
    fn default() -> Self {
        Self::new()
    }
}

/// +1 if the switch is toward increasing steps, -1 otherwise.
pub fn toward_switch(cfg: &InstrumentConfig<f32>, axis: Axis) -> i32 {
    match cfg.axis(axis).home {
        HomeSide::Min => -1,
        HomeSide::Max => 1,
    }
}

/// The step position at which the switch closes: the soft limit on the home side, or 0 (the index
/// mark) for a continuous axis.
pub fn home_position(cfg: &InstrumentConfig<f32>, axis: Axis) -> i32 {
    let c = cfg.axis(axis);
    if c.continuous {
        return 0;
    }
    let limit = match c.home {
        HomeSide::Min => c.min,
        HomeSide::Max => c.max,
    };
    // Validated configs keep |limit| * steps_per_radian below 2^30.
    Real::round(limit * c.steps_per_radian()) as i32
}

pub fn backoff_steps(cfg: &InstrumentConfig<f32>, axis: Axis) -> i32 {
    Real::round(BACKOFF_RAD * cfg.axis(axis).steps_per_radian()) as i32
}

/// The longest seek that must meet the switch from anywhere in the travel.
pub fn seek_steps(cfg: &InstrumentConfig<f32>, axis: Axis) -> i32 {
    let c = cfg.axis(axis);
    let span = if c.continuous { f32::TAU } else { c.max - c.min };
    Real::round((span + 2.0 * BACKOFF_RAD) * c.steps_per_radian()) as i32
}

/// The rest step position of `axis` (where homing parks it).
pub fn rest_position(kin: &Kinematics<f32>, axis: Axis) -> i32 {
    let rest = kin.rest_pose().get(axis);
    Real::round(rest * kin.steps_per_radian(axis)) as i32
}
