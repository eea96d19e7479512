//! The simulated board behind the real firmware, driven through the board's own step path: the
//! controller runs ahead of real time in [`QueuedHal`] and its step segments are played back from
//! the [`StepQueue`] as the STM32's compare channels play them. The board has a clock the runner
//! advances, motors whose outputs go through the backlash dead band, home switches (a closing one
//! raises the EXTI trip) and a detector that reads the scene's material at the pose the outputs reached.
//!
//! Kept in one file so that a change of the firmware's HAL traits is adapted here only.

use super::model::SimModel;
use gonio_firmware::step_queue::{Pins, StepQueue};
use gonio_firmware::timed::{tick, QueuedHal, SharedQueue};
use gonio_firmware::{Clock, Detector, Readout, Switches};
use gonio_shared::instrument::{HomeSide, AXES, AXIS_COUNT};
use gonio_shared::Axis;
use std::cell::{Cell, RefCell};
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

/// The virtual gonio's HAL: the board's step path over the simulated board.
pub type SimHal = QueuedHal<SimBoard, RefCell<StepQueue>>;

/// A fresh board (every motor at step 0) behind an empty step queue.
pub fn sim_hal(model: Arc<SimModel>) -> SimHal {
    QueuedHal::new(SimBoard::new(model), RefCell::new(StepQueue::new()))
}

/// When a compare channel next fires, as board time; `None` while every channel is idle.
pub fn timer_wake(hal: &SimHal) -> Option<u64> {
    let now = hal.board.now_us;
    let wake = hal.queue.with(|q| q.next_wake(tick(now)))?;
    let ahead = wake.wrapping_sub(tick(now));
    // A wake-up "behind" the counter is one already due.
    Some(if ahead >= 1 << 31 {
        now
    } else {
        now.saturating_add(u64::from(ahead))
    })
}

/// The compare interrupts at the board's time: play what is due, and raise the EXTI trip for
/// every switch that the played steps closed.
pub fn service_timer(hal: &mut SimHal) {
    let now = tick(hal.board.now_us);
    let (pins, _) = hal.queue.with(|q| q.service(now));
    let closed = hal.board.apply(pins);
    if closed != 0 {
        let latched = hal.queue.with(|q| {
            q.trip(closed);
            q.tripped()
        });
        hal.board.fault_seen(latched);
    }
}

pub struct SimBoard {
    model: Arc<SimModel>,
    /// Instrument time, microseconds since power-on.
    pub now_us: u64,
    /// Motor positions, steps.
    motor: [i64; AXIS_COUNT],
    /// Axis output positions, steps (differs from `motor` by the backlash dead band).
    output: [f64; AXIS_COUNT],
    backlash: [f64; AXIS_COUNT],
    /// DIR levels as last played.
    dir: [bool; AXIS_COUNT],
    switches: [Switch; AXIS_COUNT],
    exposure: Option<(u64, Readout)>,
    pub readings: u64,
    /// STEP edges played (steps dropped by a limit trip never happened).
    pub steps_taken: u64,
    /// The test hook's switch: armed after its reading count, closed from the next step until
    /// the firmware has seen it once, by the trip or by reading its level (a `Cell` because
    /// reading a switch is `&self`).
    fault_closed: Cell<Option<Axis>>,
    fault_fired: bool,
}

impl SimBoard {
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

    /// Apply the pin changes of one timer interrupt (DIR first: the queue never changes DIR and
    /// raises STEP of one axis at the same instant). Returns the switches the steps closed (bit per axis).
    fn apply(&mut self, pins: Pins) -> u8 {
        let mut closed = 0u8;
        for axis in AXES {
            let bit = 1u8 << axis.index();
            if let Some(d) = self.dir.get_mut(axis.index()) {
                if pins.dir_increasing & bit != 0 {
                    *d = true;
                } else if pins.dir_decreasing & bit != 0 {
                    *d = false;
                }
            }
        }
        for axis in AXES {
            let bit = 1u8 << axis.index();
            if pins.step_high & bit != 0 {
                let was = self.limit_closed_now(axis);
                self.step(axis);
                if !was && self.limit_closed_now(axis) {
                    closed |= bit;
                }
                if let Some(fault) = self.fault_closed.get() {
                    closed |= 1 << fault.index();
                }
            }
        }
        closed
    }

    /// The trip latched these switches: the firmware has seen the test hook's closing.
    fn fault_seen(&self, latched: u8) {
        if self.fault_closed.get().is_some_and(|a| latched & (1 << a.index()) != 0) {
            self.fault_closed.set(None);
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

    /// The switch's level from the motor position alone (not the test hook).
    fn limit_closed_now(&self, axis: Axis) -> bool {
        let i = axis.index();
        match (self.switches.get(i), self.motor.get(i)) {
            (Some(s), Some(&p)) => s.closed(p),
            _ => false,
        }
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

impl Clock for SimBoard {
    fn now_us(&self) -> u64 {
        self.now_us
    }
}

impl Switches for SimBoard {
    fn limit_closed(&self, axis: Axis) -> bool {
        if self.fault_closed.get() == Some(axis) {
            self.fault_closed.set(None);
            return true;
        }
        self.limit_closed_now(axis)
    }
}

impl Detector for SimBoard {
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

    /// `n` steps of `axis` as the timer interrupt would play them.
    fn steps(board: &mut SimBoard, axis: Axis, n: i64) -> u8 {
        let bit = 1u8 << axis.index();
        let dir = if n > 0 {
            Pins {
                dir_increasing: bit,
                ..Pins::default()
            }
        } else {
            Pins {
                dir_decreasing: bit,
                ..Pins::default()
            }
        };
        let mut closed = board.apply(dir);
        for _ in 0..n.abs() {
            closed |= board.apply(Pins {
                step_high: bit,
                ..Pins::default()
            });
        }
        closed
    }

    #[test]
    fn backlash_makes_the_output_lag_after_a_reversal() {
        // 0.1 deg of play at 400 steps/deg = 40 steps of dead band.
        let mut hal = SimBoard::new(model("[effects]\nbacklash = { light_deg = 0.1 }\n"));
        steps(&mut hal, Axis::Light, 200);
        assert_eq!(hal.output[0], 180.0, "output trails the motor by half the band");
        steps(&mut hal, Axis::Light, -30);
        assert_eq!(hal.output[0], 180.0, "inside the dead band the output stands still");
        steps(&mut hal, Axis::Light, -30);
        assert_eq!(hal.output[0], 160.0);
        // Without the effect the output is the motor.
        let mut ideal = SimBoard::new(model(""));
        steps(&mut ideal, Axis::Light, 200);
        steps(&mut ideal, Axis::Light, -30);
        assert_eq!(ideal.output[0], 170.0);
    }

    #[test]
    fn the_limit_fault_hook_closes_the_switch_once_after_its_readings() {
        let mut hal = SimBoard::new(model(
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
        let mut hal = SimBoard::new(model(""));
        hal.start_exposure(1000);
        assert!(hal.poll_readout().is_none());
        hal.now_us = 999;
        assert!(hal.poll_readout().is_none());
        hal.now_us = 1000;
        assert_eq!(hal.poll_readout().map(|r| r.len()), Some(3));
        assert!(hal.poll_readout().is_none());
    }
}

#[cfg(test)]
mod step_path_tests {
    use super::*;
    use gonio_firmware::segment::Segment;
    use gonio_firmware::Steppers;
    use std::path::Path;

    fn hal() -> SimHal {
        let text = "[camera]\nkind = \"orthographic\"\nwidth = 8\nheight = 8\n[object]\nshape = \"sphere\"\nmaterial = \"lambert:albedo=0.5\"\n";
        let model = SimModel::from_toml(text, Path::new("t.toml"), crate::instrument::default_instrument(), 0).unwrap();
        sim_hal(Arc::new(model))
    }

    /// `count` steps 100 us apart from t = 10 us.
    fn segment(count: u32, increasing: bool) -> Segment {
        Segment {
            t0: 10 << 32,
            interval: 100 << 32,
            add: 0,
            count,
            increasing,
        }
    }

    /// Play the channels until they are idle.
    fn play(hal: &mut SimHal) {
        while let Some(w) = timer_wake(hal) {
            hal.board.now_us = hal.board.now_us.max(w);
            service_timer(hal);
        }
    }

    #[test]
    fn queued_steps_move_the_motors_only_when_the_channel_plays_them() {
        let mut hal = hal();
        hal.queue_segment(Axis::Tilt, segment(5, false));
        assert_eq!(hal.board.steps_taken, 0, "queued, not played");
        play(&mut hal);
        assert_eq!(hal.board.steps_taken, 5);
        assert_eq!(hal.board.output[Axis::Tilt.index()], -5.0);
    }

    #[test]
    fn an_armed_switch_that_a_played_step_closes_trips_the_channels() {
        let mut hal = hal();
        let home = match hal.board.switches[Axis::Light.index()] {
            Switch::AtOrAbove(p) => p,
            s => panic!("light switch {s:?}"),
        };
        hal.board.motor[Axis::Light.index()] = home - 2;
        hal.queue.with(|q| q.set_armed(1 << Axis::Light.index()));
        hal.queue_segment(Axis::Light, segment(5, true));
        play(&mut hal);
        assert_eq!(
            hal.board.motor[Axis::Light.index()],
            home,
            "playback stops on the closing step"
        );
        assert_eq!(hal.queue.with(|q| q.tripped()), 1 << Axis::Light.index());
        assert_eq!(hal.drop_queued()[Axis::Light.index()], 3, "the steps never made");
    }
}
