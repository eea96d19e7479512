//! The controller ahead of real time, its step segments queued for the compare channels to play:
//! the board's HAL and loop (`docs/firmware.md`, "The board's step path").

use crate::hal::{Clock, Detector, Readout, Steppers, Switches};
pub use crate::segment::tick;
use crate::segment::Segment;
use crate::step_queue::StepQueue;
use crate::Device;
use gonio_shared::instrument::{AXES, AXIS_COUNT};
use gonio_shared::Axis;

/// How far ahead of real time the controller runs during a move: segments are generated at least
/// this long before their first step is due, far longer than any pause of the loop (a full plan
/// chunk's reachability checks, the detector readout).
pub const LOOKAHEAD_US: u64 = 2_000;
/// During a move the loop reads the armed switches' levels at least this often, besides their
/// EXTI interrupts (a switch already closed, or an edge the interrupt missed), and stops the
/// channels as a trip would. Reading four pins costs ~50 instructions; running the whole
/// controller this often would cost ~1,000 (about 25 instructions per step at full speed).
pub const SWITCH_POLL_US: u64 = 4_000;
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
    /// The switches that stop playback (as last armed), and when to read their levels next.
    armed: u8,
    switch_poll_us: u64,
}

impl<B, Q> QueuedHal<B, Q> {
    pub fn new(board: B, queue: Q) -> Self {
        Self {
            board,
            queue,
            now_us: 0,
            armed: 0,
            switch_poll_us: 0,
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
            let moving = device.controller().is_moving();
            if moving && real >= self.switch_poll_us {
                self.poll_switches();
                self.switch_poll_us = real.saturating_add(SWITCH_POLL_US);
            }
            self.take_trip(device);
            let t = device.next_deadline_us()?;
            let horizon = if moving {
                real.saturating_add(LOOKAHEAD_US)
            } else {
                real
            };
            if t > horizon {
                return Some(if moving {
                    t.saturating_sub(LOOKAHEAD_US).min(self.switch_poll_us)
                } else {
                    t
                });
            }
            self.now_us = self.now_us.max(t);
            self.poll_device(device, real);
        }
        Some(self.board.now_us())
    }

    /// The controller's poll, out of line: most turns of the loop during a move only read the
    /// switches and find nothing due, and should not pay for the poll's stack frame.
    #[inline(never)]
    fn poll_device(&mut self, device: &mut Device, real: u64) {
        // Before the poll refills the rings: a loop that came back (real time `real`) after one
        // ran dry was late. Here, not on every turn: only a poll refills, so none can hide it.
        device.check_steps_on_time(self, real);
        device.poll(self);
        self.arm(device.stop_mask());
    }

    /// An armed switch found closed stops the channels as its interrupt would have.
    fn poll_switches(&mut self) {
        let closed = AXES
            .iter()
            .filter(|a| self.armed & (1 << a.index()) != 0 && self.board.limit_closed(**a))
            .fold(0u8, |m, a| m | 1 << a.index());
        if closed != 0 {
            self.queue.with(|q| q.trip(closed));
        }
    }

    fn arm(&mut self, mask: u8) {
        if mask != self.armed {
            self.armed = mask;
            self.queue.with(|q| q.set_armed(mask));
        }
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
        self.queue.with(|q| q.take_trip());
        self.arm(device.stop_mask());
    }
}

impl<B, Q> Clock for QueuedHal<B, Q> {
    fn now_us(&self) -> u64 {
        self.now_us
    }
}

impl<B, Q: SharedQueue> Steppers for QueuedHal<B, Q> {
    const SEGMENTS: bool = true;

    fn segment_room(&self) -> [usize; AXIS_COUNT] {
        self.queue.with(|q| q.rooms())
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
