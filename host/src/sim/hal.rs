//! The simulated board behind the real firmware: a clock the runner advances, motors whose outputs
//! go through the backlash dead band, home switches where the instrument has them, and a detector
//! that reads the scene's material at the pose the outputs actually reached.
//!
//! Kept in one file so that a change of the firmware's `Hal` trait is adapted here only.

use super::model::SimModel;
use gonio_firmware::{Hal, Readout};
use gonio_shared::instrument::{HomeSide, AXES, AXIS_COUNT};
use gonio_shared::Axis;
use std::cell::Cell;
use std::sync::Arc;

#[derive(Clone, Copy, Debug)]
enum Switch {
    /// Closed at or above this motor position.
    AtOrAbove(i64),
    AtOrBelow(i64),
    /// Index sensor of a continuous axis: closed at 0 mod `rev` and `window` steps below it.
    Index {
        rev: i64,
        window: i64,
    },
}

impl Switch {
    fn closed(self, pos: i64) -> bool {
        match self {
            Switch::AtOrAbove(p) => pos >= p,
            Switch::AtOrBelow(p) => pos <= p,
            Switch::Index { rev, window } => {
                let r = pos.rem_euclid(rev.max(1));
                r == 0 || r > rev - window
            }
        }
    }
}

pub struct SimHal {
    model: Arc<SimModel>,
    /// Instrument time, microseconds since power-on.
    pub now_us: u64,
    /// Motor positions, steps.
    motor: [i64; AXIS_COUNT],
    /// Axis output positions, steps (differs from `motor` by the backlash dead band).
    output: [f64; AXIS_COUNT],
    backlash: [f64; AXIS_COUNT],
    dir: [bool; AXIS_COUNT],
    switches: [Switch; AXIS_COUNT],
    exposure: Option<(u64, Readout)>,
    pub readings: u64,
    pub steps_taken: u64,
    /// The test hook's switch: armed after its reading count, closed from the next step until
    /// the firmware has seen it once (a `Cell` because looking at a switch is `&self`).
    fault_closed: Cell<Option<Axis>>,
    fault_fired: bool,
}

impl SimHal {
    pub fn new(model: Arc<SimModel>) -> Self {
        let cfg32 = model.instrument.cast::<f32>();
        let kin = model.kinematics();
        let switches = AXES.map(|axis| {
            let c = model.instrument.axis(axis);
            if c.continuous {
                let rev = (kin.steps_per_radian(axis) * std::f64::consts::TAU).round() as i64;
                Switch::Index {
                    rev,
                    window: (rev / 90).max(2),
                }
            } else {
                let home = i64::from(gonio_firmware::homing::home_position(&cfg32, axis));
                match c.home {
                    HomeSide::Max => Switch::AtOrAbove(home),
                    HomeSide::Min => Switch::AtOrBelow(home),
                }
            }
        });
        let backlash = model.backlash_steps();
        Self {
            model,
            now_us: 0,
            motor: [0; AXIS_COUNT],
            output: [0.0; AXIS_COUNT],
            backlash,
            dir: [true; AXIS_COUNT],
            switches,
            exposure: None,
            readings: 0,
            steps_taken: 0,
            fault_closed: Cell::new(None),
            fault_fired: false,
        }
    }

    pub fn motor_steps(&self) -> [i64; AXIS_COUNT] {
        self.motor
    }

    pub fn output_steps(&self) -> [f64; AXIS_COUNT] {
        self.output
    }

    /// The noise key of a reading: a hash of the motor positions (same pose, same noise).
    fn reading_key(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for p in self.motor {
            for b in p.to_le_bytes() {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
        h
    }
}

impl Hal for SimHal {
    fn now_us(&self) -> u64 {
        self.now_us
    }

    fn set_direction(&mut self, axis: Axis, increasing: bool) {
        if let Some(d) = self.dir.get_mut(axis.index()) {
            *d = increasing;
        }
    }

    fn step(&mut self, axis: Axis) {
        let i = axis.index();
        let (Some(m), Some(o), Some(&d)) = (self.motor.get_mut(i), self.output.get_mut(i), self.dir.get(i)) else {
            return;
        };
        *m += if d { 1 } else { -1 };
        // Dead band: the output follows only once the motor has taken up the play.
        let half = self.backlash.get(i).copied().unwrap_or(0.0) / 2.0;
        let mf = *m as f64;
        if mf - *o > half {
            *o = mf - half;
        } else if *o - mf > half {
            *o = mf + half;
        }
        self.steps_taken += 1;
        if let Some((fault_axis, after)) = self.model.limit_fault {
            if !self.fault_fired && self.readings >= after {
                self.fault_closed.set(Some(fault_axis));
                self.fault_fired = true;
            }
        }
    }

    fn limit_closed(&self, axis: Axis) -> bool {
        if self.fault_closed.get() == Some(axis) {
            self.fault_closed.set(None);
            return true;
        }
        let i = axis.index();
        match (self.switches.get(i), self.motor.get(i)) {
            (Some(s), Some(&p)) => s.closed(p),
            _ => false,
        }
    }

    fn start_exposure(&mut self, exposure_us: u32) {
        let pose = self.model.pose_at(&self.output);
        let counts = self
            .model
            .counts(&pose, exposure_us, self.now_us as f64 * 1e-6, self.reading_key());
        let mut r = Readout::new();
        for c in counts {
            // The model never makes more channels than the wire carries (checked at load).
            let _ = r.push(c);
        }
        self.exposure = Some((self.now_us.saturating_add(u64::from(exposure_us)), r));
    }

    fn poll_readout(&mut self) -> Option<Readout> {
        let (done, _) = self.exposure.as_ref()?;
        if self.now_us < *done {
            return None;
        }
        let (_, r) = self.exposure.take()?;
        self.readings += 1;
        Some(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn model(effects: &str) -> Arc<SimModel> {
        let text = format!(
            "[camera]\nkind = \"orthographic\"\nwidth = 8\nheight = 8\n[object]\nshape = \"sphere\"\nmaterial = \"lambert:albedo=0.5\"\n{effects}"
        );
        Arc::new(SimModel::from_toml(&text, Path::new("t.toml"), crate::instrument::default_instrument(), 0).unwrap())
    }

    fn steps(hal: &mut SimHal, axis: Axis, n: i64) {
        hal.set_direction(axis, n > 0);
        for _ in 0..n.abs() {
            hal.step(axis);
        }
    }

    #[test]
    fn backlash_makes_the_output_lag_after_a_reversal() {
        // 0.1 deg of play at 400 steps/deg = 40 steps of dead band.
        let mut hal = SimHal::new(model("[effects]\nbacklash = { light_deg = 0.1 }\n"));
        steps(&mut hal, Axis::Light, 200);
        assert_eq!(hal.output_steps()[0], 180.0, "output trails the motor by half the band");
        steps(&mut hal, Axis::Light, -30);
        assert_eq!(
            hal.output_steps()[0],
            180.0,
            "inside the dead band the output stands still"
        );
        steps(&mut hal, Axis::Light, -30);
        assert_eq!(hal.output_steps()[0], 160.0);
        // Without the effect the output is the motor.
        let mut ideal = SimHal::new(model(""));
        steps(&mut ideal, Axis::Light, 200);
        steps(&mut ideal, Axis::Light, -30);
        assert_eq!(ideal.output_steps()[0], 170.0);
    }

    #[test]
    fn the_limit_fault_hook_closes_the_switch_once_after_its_readings() {
        let mut hal = SimHal::new(model(
            "[effects]\nlimit_fault = { axis = \"tilt\", after_readings = 1 }\n",
        ));
        steps(&mut hal, Axis::Tilt, 1);
        assert!(!hal.limit_closed(Axis::Tilt));
        hal.start_exposure(10);
        hal.now_us = 10;
        assert!(hal.poll_readout().is_some());
        steps(&mut hal, Axis::Tilt, 1);
        assert!(hal.limit_closed(Axis::Tilt));
        assert!(!hal.limit_closed(Axis::Tilt), "one snag, not a stuck switch");
    }

    #[test]
    fn readouts_come_when_the_exposure_ends() {
        let mut hal = SimHal::new(model(""));
        hal.start_exposure(1000);
        assert!(hal.poll_readout().is_none());
        hal.now_us = 999;
        assert!(hal.poll_readout().is_none());
        hal.now_us = 1000;
        assert_eq!(hal.poll_readout().map(|r| r.len()), Some(3));
        assert!(hal.poll_readout().is_none());
    }
}
