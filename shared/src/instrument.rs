//! The instrument description: four axes and the arms' blocking angle.
//!
//! Angles are radians, speeds rad/s, accelerations rad/s^2 (degrees only in the host's TOML file).
//! The host reads `gonio.toml` into an `InstrumentConfig<f64>`, validates it, and sends
//! `InstrumentConfig<f32>` to the firmware, which validates it again: nothing from the wire is trusted.

use crate::real::Real;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// The four motorised axes of the reference instrument.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Schema)]
pub enum Axis {
    /// Arm carrying the light source, rotating about the vertical axis Z.
    Light,
    /// Arm carrying the detector, rotating about Z.
    Detector,
    /// Sample tilt: normal `n = (cos t, 0, sin t)`.
    Tilt,
    /// Sample rotation about its own normal.
    Azimuth,
}

/// The axes in wire/array order: `steps[i]` always belongs to `AXES[i]`.
pub const AXES: [Axis; 4] = [Axis::Light, Axis::Detector, Axis::Tilt, Axis::Azimuth];
/// Number of axes (the length of every per-axis array).
pub const AXIS_COUNT: usize = 4;
/// The fastest step rate an axis may be configured for, steps/s: what the firmware's step path
/// plays on every axis at once without starving the link (`docs/firmware.md`, "Step rate cap").
pub const MAX_AXIS_STEP_RATE: u32 = 50_000;

impl Axis {
    pub const fn index(self) -> usize {
        match self {
            Axis::Light => 0,
            Axis::Detector => 1,
            Axis::Tilt => 2,
            Axis::Azimuth => 3,
        }
    }
    pub const fn name(self) -> &'static str {
        match self {
            Axis::Light => "light",
            Axis::Detector => "detector",
            Axis::Tilt => "tilt",
            Axis::Azimuth => "azimuth",
        }
    }
}

/// Which end of its travel an axis homes to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum HomeSide {
    Min,
    Max,
}

/// One stepper axis.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct AxisConfig<R> {
    /// Full steps per motor revolution (200 for a 1.8 degree motor).
    pub steps_per_rev: u16,
    /// Driver microstepping factor.
    pub microsteps: u16,
    /// Motor revolutions per axis revolution.
    pub gear_ratio: R,
    /// rad/s at the axis.
    pub max_speed: R,
    /// rad/s^2 at the axis.
    pub max_accel: R,
    /// Soft limits, radians. A continuous axis (azimuth) has `continuous = true` and ignores them.
    pub min: R,
    pub max: R,
    pub continuous: bool,
    pub home: HomeSide,
}

/// The whole instrument.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct InstrumentConfig<R> {
    /// Indexed by [`Axis::index`].
    pub axes: [AxisConfig<R>; AXIS_COUNT],
    /// The arms keep at least this angle apart (light shadow / collision), radians.
    pub blocking_angle: R,
    /// Pause after a move before the exposure, milliseconds.
    pub settle_ms: u32,
    /// Detector exposure per reading, microseconds.
    pub exposure_us: u32,
    /// Isotropic materials: the azimuth stage never moves.
    pub isotropic: bool,
}

/// Why a configuration is refused (host file or wire).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, thiserror::Error)]
pub enum ConfigError {
    #[error("axis {0:?}: steps_per_rev, microsteps and gear_ratio must be positive")]
    BadResolution(Axis),
    #[error("axis {0:?}: max_speed and max_accel must be positive and finite")]
    BadDynamics(Axis),
    #[error("axis {0:?}: soft limits must be finite with min < max")]
    BadLimits(Axis),
    #[error("axis {0:?}: more than 2^30 steps across the travel")]
    TooManySteps(Axis),
    #[error("tilt limits must lie strictly inside (-90, 90) degrees")]
    TiltRange,
    #[error("blocking angle must lie in [0, 180) degrees")]
    BlockingAngle,
    #[error("the arms' home positions must keep the light counter-clockwise of the detector by [blocking, 360 - blocking] degrees")]
    ArmHomes,
    #[error("axis {0:?}: max_speed is more than 50,000 steps/s (the step path's cap)")]
    TooFast(Axis),
}

impl<R: Real> AxisConfig<R> {
    /// Microsteps per radian at the axis.
    pub fn steps_per_radian(&self) -> R {
        R::from_i64(self.steps_per_rev as i64) * R::from_i64(self.microsteps as i64) * self.gear_ratio / R::TAU
    }

    fn validate(&self, axis: Axis) -> Result<(), ConfigError> {
        if self.steps_per_rev == 0
            || self.microsteps == 0
            || !(self.gear_ratio > R::ZERO)
            || !self.gear_ratio.is_finite()
        {
            return Err(ConfigError::BadResolution(axis));
        }
        let dyn_ok = |v: R| v > R::ZERO && v.is_finite();
        if !dyn_ok(self.max_speed) || !dyn_ok(self.max_accel) {
            return Err(ConfigError::BadDynamics(axis));
        }
        let rate = self.max_speed * self.steps_per_radian();
        if !(rate <= R::from_f64(f64::from(MAX_AXIS_STEP_RATE))) {
            return Err(ConfigError::TooFast(axis));
        }
        if !self.continuous {
            if !(self.min.is_finite() && self.max.is_finite() && self.min < self.max) {
                return Err(ConfigError::BadLimits(axis));
            }
            let span = self.min.abs().max(self.max.abs()) * self.steps_per_radian();
            if !(span < R::from_f64((1u64 << 30) as f64)) {
                return Err(ConfigError::TooManySteps(axis));
            }
        }
        Ok(())
    }

    pub fn cast<S: Real>(&self) -> AxisConfig<S> {
        let c = |x: R| S::from_f64(x.to_f64());
        AxisConfig {
            steps_per_rev: self.steps_per_rev,
            microsteps: self.microsteps,
            gear_ratio: c(self.gear_ratio),
            max_speed: c(self.max_speed),
            max_accel: c(self.max_accel),
            min: c(self.min),
            max: c(self.max),
            continuous: self.continuous,
            home: self.home,
        }
    }
}

impl<R: Real> InstrumentConfig<R> {
    pub fn axis(&self, axis: Axis) -> &AxisConfig<R> {
        &self.axes[axis.index()]
    }

    /// Check every invariant the kinematics relies on. Both sides call this on every config.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for axis in AXES {
            self.axis(axis).validate(axis)?;
        }
        for arm in [Axis::Light, Axis::Detector, Axis::Tilt] {
            if self.axis(arm).continuous {
                return Err(ConfigError::BadLimits(arm));
            }
        }
        // The kinematics divides by cos(tilt); |tilt| = 90 degrees is the stage's singularity.
        let tilt = self.axis(Axis::Tilt);
        if !(tilt.min > -R::FRAC_PI_2 && tilt.max < R::FRAC_PI_2) {
            return Err(ConfigError::TiltRange);
        }
        if !(self.blocking_angle >= R::ZERO && self.blocking_angle < R::PI) {
            return Err(ConfigError::BlockingAngle);
        }
        // Homing parks each arm at its switch; both parked arms must form a legal pose.
        let home = |c: &AxisConfig<R>| match c.home {
            HomeSide::Min => c.min,
            HomeSide::Max => c.max,
        };
        let sep = home(self.axis(Axis::Light)) - home(self.axis(Axis::Detector));
        if !(sep >= self.blocking_angle && sep <= R::TAU - self.blocking_angle) {
            return Err(ConfigError::ArmHomes);
        }
        Ok(())
    }

    /// The same instrument in another precision (host f64 -> wire f32 and back).
    pub fn cast<S: Real>(&self) -> InstrumentConfig<S> {
        InstrumentConfig {
            axes: [
                self.axes[0].cast(),
                self.axes[1].cast(),
                self.axes[2].cast(),
                self.axes[3].cast(),
            ],
            blocking_angle: S::from_f64(self.blocking_angle.to_f64()),
            settle_ms: self.settle_ms,
            exposure_us: self.exposure_us,
            isotropic: self.isotropic,
        }
    }

    /// The reference instrument of the README (the same numbers as `examples/gonio.toml`).
    pub fn reference() -> Self {
        let d = |deg: f64| R::from_f64(deg.to_radians());
        let arm = |min: f64, max: f64, home| AxisConfig {
            steps_per_rev: 200,
            microsteps: 16,
            gear_ratio: R::from_f64(45.0),
            max_speed: d(45.0),
            max_accel: d(90.0),
            min: d(min),
            max: d(max),
            continuous: false,
            home,
        };
        InstrumentConfig {
            axes: [
                arm(-175.0, 175.0, HomeSide::Max),
                arm(-175.0, 175.0, HomeSide::Min),
                AxisConfig {
                    steps_per_rev: 200,
                    microsteps: 16,
                    gear_ratio: R::from_f64(30.0),
                    max_speed: d(30.0),
                    max_accel: d(60.0),
                    min: d(-85.0),
                    max: d(85.0),
                    continuous: false,
                    home: HomeSide::Min,
                },
                AxisConfig {
                    steps_per_rev: 200,
                    microsteps: 16,
                    gear_ratio: R::from_f64(10.0),
                    max_speed: d(90.0),
                    max_accel: d(180.0),
                    // Ignored for a continuous axis (the file may leave them out, as 0).
                    min: R::ZERO,
                    max: R::ZERO,
                    continuous: true,
                    home: HomeSide::Min,
                },
            ],
            blocking_angle: d(5.0),
            settle_ms: 50,
            exposure_us: 10_000,
            isotropic: true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_instrument_is_valid_in_both_precisions() {
        InstrumentConfig::<f64>::reference().validate().unwrap();
        InstrumentConfig::<f32>::reference().validate().unwrap();
        assert_eq!(
            InstrumentConfig::<f64>::reference().cast::<f32>(),
            InstrumentConfig::<f32>::reference()
        );
    }

    #[test]
    fn the_step_rate_cap_allows_exactly_its_rate() {
        let mut c = InstrumentConfig::<f64>::reference();
        let spr = c.axes[0].steps_per_radian();
        c.axes[0].max_speed = f64::from(MAX_AXIS_STEP_RATE) / spr;
        assert_eq!(c.validate(), Ok(()));
        c.axes[0].max_speed *= 1.0 + 1e-9;
        assert_eq!(c.validate(), Err(ConfigError::TooFast(Axis::Light)));
    }

    #[test]
    fn invalid_configs_are_refused_with_their_reason() {
        let good = InstrumentConfig::<f32>::reference();
        let mut c = good;
        c.axes[0].microsteps = 0;
        assert_eq!(c.validate(), Err(ConfigError::BadResolution(Axis::Light)));
        let mut c = good;
        c.axes[1].max_accel = f32::NAN;
        assert_eq!(c.validate(), Err(ConfigError::BadDynamics(Axis::Detector)));
        let mut c = good;
        c.axes[2].max = 1.6;
        assert_eq!(c.validate(), Err(ConfigError::TiltRange));
        let mut c = good;
        c.axes[0].min = 1.0;
        c.axes[0].max = 0.5;
        assert_eq!(c.validate(), Err(ConfigError::BadLimits(Axis::Light)));
        let mut c = good;
        c.blocking_angle = -0.1;
        assert_eq!(c.validate(), Err(ConfigError::BlockingAngle));
        let mut c = good;
        c.axes[0].max = 3.2; // light homes at +183 deg, detector at -175: 358 > 355 deg apart
        assert_eq!(c.validate(), Err(ConfigError::ArmHomes));
        let mut c = good;
        c.axes[0].home = HomeSide::Min; // light parked at -175, detector at -175: blocked
        assert_eq!(c.validate(), Err(ConfigError::ArmHomes));
        let mut c = good;
        c.axes[0].gear_ratio = 1e6;
        c.axes[0].max_speed = 1e-5;
        assert_eq!(c.validate(), Err(ConfigError::TooManySteps(Axis::Light)));
        let mut c = good;
        c.axes[3].max_speed = 1e3; // 2.3e7 steps/s (the fuzz run's config)
        assert_eq!(c.validate(), Err(ConfigError::TooFast(Axis::Azimuth)));
        let mut c = good;
        c.axes[2].max_speed = f32::MAX;
        assert_eq!(c.validate(), Err(ConfigError::TooFast(Axis::Tilt)));
    }
}
