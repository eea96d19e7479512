//! What the board does, as four small traits: a clock, step/dir outputs, limit switches, a detector.
//!
//! Synchronous and small (embedded-hal style): the step generator decides *when* to step from
//! [`Clock::now_us`], the board only carries it out. [`Hal`] is all four, what the controller needs.
//! On the board `timed::QueuedHal` provides [`Clock`] and [`Steppers`] itself (a schedule
//! clock and queued step segments) over a board that only has the clock, switches and detector;
//! host tests implement all four with a mock that records every call with its timestamp.

use crate::segment::Segment;
use gonio_shared::instrument::AXIS_COUNT;
use gonio_shared::msg::caps::MAX_CHANNELS;
use gonio_shared::Axis;
use heapless::Vec;

/// Counts per detector channel from one exposure.
pub type Readout = Vec<u32, MAX_CHANNELS>;

pub trait Clock {
    /// Monotonic time since boot, microseconds. Never goes backwards.
    fn now_us(&self) -> u64;
}

pub trait Steppers {
    /// Does this board play step segments itself (one compare channel per axis)? Then the step
    /// generator queues segments ([`Steppers::queue_segment`]) and never calls `step`; otherwise it
    /// plays the same segments in software and calls `step` at each step's instant (the mock HAL).
    const SEGMENTS: bool = false;

    /// Free segment slots per axis (segment boards only).
    fn segment_room(&self) -> [usize; AXIS_COUNT] {
        [0; AXIS_COUNT]
    }

    /// Queue a segment of `axis` behind the ones already queued (segment boards only).
    fn queue_segment(&mut self, _axis: Axis, _segment: Segment) {}

    /// Stop every axis at once and drop what is queued; returns the steps per axis that were
    /// queued and never made (segment boards only).
    fn drop_queued(&mut self) -> [u32; AXIS_COUNT] {
        [0; AXIS_COUNT]
    }

    /// Set the direction pin of `axis` (`true` = increasing step count). Takes effect before the
    /// next [`Steppers::step`] of that axis (the driver's direction setup time is honoured).
    fn set_direction(&mut self, axis: Axis, increasing: bool);

    /// Emit one step pulse on `axis`.
    fn step(&mut self, axis: Axis);
}

pub trait Switches {
    /// Is the limit / home switch of `axis` closed? For a continuous axis this is its index sensor,
    /// which only homing looks at.
    fn limit_closed(&self, axis: Axis) -> bool;
}

pub trait Detector {
    /// Start an exposure of `exposure_us` microseconds (restarts one already running).
    fn start_exposure(&mut self, exposure_us: u32);

    /// The readout of the last exposure once it is complete, `None` while it is still running.
    fn poll_readout(&mut self) -> Option<Readout>;
}

/// Everything the controller drives; implemented for any type that has all four parts.
pub trait Hal: Clock + Steppers + Switches + Detector {}

impl<T: Clock + Steppers + Switches + Detector> Hal for T {}
