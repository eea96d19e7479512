//! The controller ahead of real time, its steps queued for a timer to play: the board's HAL and loop
//! (`docs/firmware.md`, "The board's step path").

use crate::controller::TRANSITIONS_PER_POLL;
use crate::hal::{Clock, Detector, Readout, Steppers, Switches};
use crate::step_queue::StepQueue;
use crate::Device;
use gonio_shared::instrument::AXIS_COUNT;
use gonio_shared::Axis;

/// How far ahead of real time the controller schedules steps during a move. 2 ms is 160 steps at
/// 4 x 20 kHz (see [`crate::capacity::STEP_QUEUE_EVENTS`]) and far longer than any pause of the
/// loop (a full plan chunk's reachability checks, the detector readout).
pub const LOOKAHEAD_US: u64 = 2_000;
/// While moving, the loop refills the queue this often: the queue never holds less than
/// `LOOKAHEAD_US - REFILL_US` of steps, and the loop wakes ~2000 times a second, not per step.
pub const REFILL_US: u64 = 500;
/// Events one `Device::poll` can queue: a step per axis, and a direction per axis for each move
/// the poll's transitions can start.
pub const EVENTS_PER_POLL: usize = AXIS_COUNT * (1 + TRANSITIONS_PER_POLL);
/// Polls per `run`, so one turn of the loop is bounded; `run` asks to be called again at once if
/// it stopped on this budget.
pub const POLLS_PER_RUN: usize = 64;

/// The [`StepQueue`] shared with the interrupts: a critical-section mutex on the board (which
/// also re-arms the step timer after every access), a `RefCell` in tests.
pub trait SharedQueue {
    fn with<R>(&self, f: impl FnOnce(&mut StepQueue) -> R) -> R;
}

impl SharedQueue for core::cell::RefCell<StepQueue> {
    fn with<R>(&self, f: impl FnOnce(&mut StepQueue) -> R) -> R {
        f(&mut self.borrow_mut())
    }
}

/// Microseconds to step-timer ticks: the timer counts the same microseconds, modulo 2^32.
pub fn tick(us: u64) -> u32 {
    us as u32
}

pub struct QueuedHal<B, Q> {
    pub board: B,
    pub queue: Q,
    /// The schedule clock the controller sees.
    now_us: u64,
    /// The last direction queued per axis, so only changes are queued; forgotten when a trip
    /// drops queued events.
    dir: [Option<bool>; AXIS_COUNT],
}

impl<B, Q> QueuedHal<B, Q> {
    pub fn new(board: B, queue: Q) -> Self {
        Self {
            board,
            queue,
            now_us: 0,
            dir: [None; AXIS_COUNT],
        }
    }
}

impl<B: Clock + Switches + Detector, Q: SharedQueue> QueuedHal<B, Q> {
    /// Run the controller up to the horizon. Returns the real instant to call again (`None`:
    /// only the host can make progress). Call it also after every `Device::receive`.
    pub fn run(&mut self, device: &mut Device) -> Option<u64> {
        for _ in 0..POLLS_PER_RUN {
            let real = self.board.now_us();
            self.now_us = self.now_us.max(real);
            self.take_trip(device);
            let t = device.next_deadline_us()?;
            let moving = device.controller().is_moving();
            let horizon = if moving {
                real.saturating_add(LOOKAHEAD_US)
            } else {
                real
            };
            if t > horizon {
                return Some(if moving {
                    t.saturating_sub(LOOKAHEAD_US).max(real.saturating_add(REFILL_US))
                } else {
                    t
                });
            }
            if self.queue.with(|q| q.free()) < EVENTS_PER_POLL {
                return Some(real.saturating_add(REFILL_US));
            }
            self.now_us = self.now_us.max(t);
            device.poll(self);
            let mask = device.stop_mask();
            self.queue.with(|q| q.set_armed(mask));
        }
        Some(self.board.now_us())
    }

    /// Hand a latched trip to the controller. If it halts a move the controller had not stopped
    /// yet, the events queued since the trip are that move's and are dropped first; if the
    /// controller already reacted to the switch's level (e.g. queued the park move after finding a
    /// home switch), they are kept.
    fn take_trip(&mut self, device: &mut Device) {
        let tripped = self.queue.with(|q| q.take_trip());
        if tripped == 0 {
            return;
        }
        if device.halts_on(tripped) {
            self.queue.with(|q| q.flush());
            // DIR events may have been dropped: queue the next direction of each axis again.
            self.dir = [None; AXIS_COUNT];
            device.limit_tripped(self, tripped);
        }
        let mask = device.stop_mask();
        self.queue.with(|q| q.set_armed(mask));
    }
}

impl<B, Q> Clock for QueuedHal<B, Q> {
    fn now_us(&self) -> u64 {
        self.now_us
    }
}

impl<B, Q: SharedQueue> Steppers for QueuedHal<B, Q> {
    fn set_direction(&mut self, axis: Axis, increasing: bool) {
        let Some(last) = self.dir.get_mut(axis.index()) else {
            return;
        };
        if *last == Some(increasing) {
            return;
        }
        let t = tick(self.now_us);
        if self.queue.with(|q| q.push_dir(axis, increasing, t)).is_ok() {
            *last = Some(increasing);
        }
    }

    /// Queued for the timer; a full queue is counted in the queue's stats (the loop keeps
    /// `EVENTS_PER_POLL` free before each poll, so it does not happen).
    fn step(&mut self, axis: Axis) {
        let t = tick(self.now_us);
        let _counted = self.queue.with(|q| q.push_step(axis, t));
    }
}

impl<B: Switches, Q> Switches for QueuedHal<B, Q> {
    fn limit_closed(&self, axis: Axis) -> bool {
        self.board.limit_closed(axis)
    }
}

impl<B: Detector, Q> Detector for QueuedHal<B, Q> {
    fn start_exposure(&mut self, exposure_us: u32) {
        self.board.start_exposure(exposure_us);
    }

    fn poll_readout(&mut self) -> Option<Readout> {
        self.board.poll_readout()
    }
}
