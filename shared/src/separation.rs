//! The arm-separation invariant (light counter-clockwise of the detector by `[blocking, 2 pi -
//! blocking]`), checked per arm step and, with a guard band, per plan target (`docs/firmware.md`).

use crate::instrument::Axis;
use crate::kinematics::{Kinematics, Steps};
use crate::real::Real;

/// Guard band of plan targets, in steps of each arm: one step of quantisation lag plus half a step
/// of margin for f32 rounding in the step timing.
pub const QUANTISATION_STEPS: f32 = 1.5;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeparationGuard {
    min: f32,
    max: f32,
    light_rad_per_step: f32,
    detector_rad_per_step: f32,
}

impl SeparationGuard {
    pub fn new(kin: &Kinematics<f32>) -> Self {
        let blocking = kin.config().blocking_angle;
        Self {
            min: blocking,
            max: f32::TAU - blocking,
            light_rad_per_step: 1.0 / kin.steps_per_radian(Axis::Light),
            detector_rad_per_step: 1.0 / kin.steps_per_radian(Axis::Detector),
        }
    }

    /// Separation `light - detector` in radians at these step positions.
    pub fn separation(&self, light: i32, detector: i32) -> f32 {
        light as f32 * self.light_rad_per_step - detector as f32 * self.detector_rad_per_step
    }

    /// May the arms be at these step positions?
    pub fn allows(&self, light: i32, detector: i32) -> bool {
        let s = self.separation(light, detector);
        s >= self.min && s <= self.max
    }

    /// May a move end at these step positions (the invariant plus the quantisation guard band)?
    pub fn allows_target(&self, steps: &Steps) -> bool {
        let band = QUANTISATION_STEPS * (self.light_rad_per_step + self.detector_rad_per_step);
        let s = self.separation(steps[Axis::Light.index()], steps[Axis::Detector.index()]);
        s >= self.min + band && s <= self.max - band
    }
}
