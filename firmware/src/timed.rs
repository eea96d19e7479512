//! The controller ahead of real time, its step segments queued for the compare channels to play:
//! the board's HAL and loop (`docs/firmware.md`, "The board's step path").

use crate::hal::{Clock, Detector, Readout, Steppers, Switches};
pub use crate::segment::tick;
use crate::segment::Segment;
use crate::step_queue::StepQueue;
use crate::Device;
use gonio_shared::instrument::AXIS_COUNT;
use gonio_shared::Axis;

/// How far ahead of real time the controller runs during a move: segments are generated at least
/// this long before their first step is due, far longer than any pause of the loop (a full plan
/// chunk's reachability checks, the detector readout).
pub const LOOKAHEAD_US: u64 = 2_000;
/// Polls per `run`, so one turn of the loop is bounded; `run` asks to be called again at once if
/// it stopped on this budget.
pub const POLLS_PER_RUN: usize = 64;

/// The [`StepQueue`] shared with the interrupts: a critical-section mutex on the board (which
/// also arms and disarms the compare channels after every access), a `RefCell` in tests.
pub trait SharedQueue {
    fn with<R>(&self, f: impl FnOnce(&mut StepQueue) -> R) -> R;
}

impl SharedQueue for core::cell::RefCell<StepQueue> {
    fn with<R>(&self, f: impl FnOnce(&mut StepQueue) -> R) -> R {
        f(&mut self.borrow_mut())
    }
}

pub struct QueuedHal<B, Q> {
    pub board: B,
    pub queue: Q,
    /// The schedule clock the controller sees.
    now_us: u64,
}

impl<B, Q> QueuedHal<B, Q> {
    pub fn new(board: B, queue: Q) -> Self {
        Self {
            board,
            queue,
            now_us: 0,
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
                return Some(if moving { t.saturating_sub(LOOKAHEAD_US) } else { t });
            }
            self.now_us = self.now_us.max(t);
            device.poll(self);
            let mask = device.stop_mask();
            self.queue.with(|q| q.set_armed(mask));
        }
        Some(self.board.now_us())
    }

    /// Hand a latched trip to the controller, then resume playback. If the trip halts a move the
    /// controller had not stopped yet, the controller drops that move's queued segments
    /// (`Stepper::stop`); if it already reacted to the switch's level (e.g. queued the park move
    /// after finding a home switch), what is queued plays.
    fn take_trip(&mut self, device: &mut Device) {
        let tripped = self.queue.with(|q| q.tripped());
        if tripped == 0 {
            return;
        }
        if device.halts_on(tripped) {
            device.limit_tripped(self, tripped);
        }
        let mask = device.stop_mask();
        self.queue.with(|q| {
            q.take_trip();
            q.set_armed(mask);
        });
    }
}

impl<B, Q> Clock for QueuedHal<B, Q> {
    fn now_us(&self) -> u64 {
        self.now_us
    }
}

impl<B, Q: SharedQueue> Steppers for QueuedHal<B, Q> {
    const SEGMENTS: bool = true;

    fn segment_room(&self, axis: Axis) -> usize {
        self.queue.with(|q| q.room(axis))
    }

    /// A full ring is counted in the queue's stats (the stepper asks for room first).
    fn queue_segment(&mut self, axis: Axis, segment: Segment) {
        let _counted = self.queue.with(|q| q.push(axis, segment));
    }

    fn drop_queued(&mut self) -> [u32; AXIS_COUNT] {
        self.queue.with(|q| q.drop_all())
    }

    /// DIR travels with the segments.
    fn set_direction(&mut self, _axis: Axis, _increasing: bool) {}

    /// Never called: the stepper queues segments on a segment board.
    fn step(&mut self, _axis: Axis) {}
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
