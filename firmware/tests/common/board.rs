//! The board's step path simulated around `QueuedHal`: real time, the motors' true positions from
//! played STEP edges and DIR levels only, switches that close on those positions, a detector; the
//! compare interrupt as `StepQueue::service` runs it, and the EXTI trip of a closing switch.

use super::{MockHal, SwitchModel};
use gonio_firmware::step_queue::StepQueue;
use gonio_firmware::timed::{tick, QueuedHal};
use gonio_firmware::{Clock, Detector, Readout, Switches};
use gonio_shared::instrument::{InstrumentConfig, AXES};
use gonio_shared::Axis;
use std::cell::RefCell;

pub type SimHal = QueuedHal<SimBoard, RefCell<StepQueue>>;

pub struct SimBoard {
    pub real: u64,
    /// True positions and DIR levels, from played events only.
    pub pos: [i64; 4],
    pub dir: [bool; 4],
    pub switches: [SwitchModel; 4],
    /// Switches held closed whatever the position (bit per axis).
    pub forced: u8,
    pub exposure_done: Option<u64>,
    pub exposures: u32,
    /// A detector that never reads out.
    pub detector_dead: bool,
}

impl Clock for SimBoard {
    fn now_us(&self) -> u64 {
        self.real
    }
}

impl Switches for SimBoard {
    fn limit_closed(&self, axis: Axis) -> bool {
        let i = axis.index();
        self.forced & (1 << i) != 0 || self.switches[i].closed(self.pos[i])
    }
}

impl Detector for SimBoard {
    fn start_exposure(&mut self, exposure_us: u32) {
        self.exposures += 1;
        self.exposure_done = Some(self.real + u64::from(exposure_us));
    }
    fn poll_readout(&mut self) -> Option<Readout> {
        self.exposure_done.filter(|&d| !self.detector_dead && self.real >= d)?;
        self.exposure_done = None;
        let mut r = Readout::new();
        r.push(self.exposures).unwrap();
        Some(r)
    }
}

/// The board at real time 0 with the motors at `start` and `cfg`'s switches.
pub fn sim_hal(cfg: &InstrumentConfig<f32>, start: [i64; 4]) -> SimHal {
    let board = SimBoard {
        real: 0,
        pos: start,
        dir: [true; 4],
        switches: MockHal::new(cfg).switches,
        forced: 0,
        exposure_done: None,
        exposures: 0,
        detector_dead: false,
    };
    QueuedHal::new(board, RefCell::new(StepQueue::new()))
}

/// The compare interrupt's next wake-up, as real time (a compare already passed is due now).
pub fn isr_at(hal: &SimHal) -> Option<u64> {
    let now = hal.board.real;
    let w = hal.queue.borrow().next_wake(tick(now))?;
    let ahead = w.wrapping_sub(tick(now));
    Some(if ahead >= 1 << 31 { now } else { now + u64::from(ahead) })
}

/// The compare interrupt at the board's real time: play every edge due and move the motors on
/// the rising ones; a switch that closes raises its EXTI trip. Returns the axes that stepped and
/// the switches that closed (bits per axis).
pub fn isr(hal: &mut SimHal) -> (u8, u8) {
    let now = hal.board.real;
    let (pins, _) = hal.queue.borrow_mut().service(tick(now));
    let b = &mut hal.board;
    let mut closed_now = 0u8;
    for axis in AXES {
        let (i, bit) = (axis.index(), 1u8 << axis.index());
        if pins.dir_increasing & bit != 0 {
            b.dir[i] = true;
        }
        if pins.dir_decreasing & bit != 0 {
            b.dir[i] = false;
        }
        if pins.step_high & bit != 0 {
            let was = b.limit_closed(axis);
            b.pos[i] += if b.dir[i] { 1 } else { -1 };
            if !was && b.limit_closed(axis) {
                closed_now |= bit;
            }
        }
    }
    if closed_now != 0 {
        hal.queue.borrow_mut().trip(closed_now);
    }
    (pins.step_high, closed_now)
}
