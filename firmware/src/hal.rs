//! What the board does, as four small traits: a clock, step/dir outputs, limit switches, a detector.
//!
//! Synchronous and small (embedded-hal style): the step generator decides *when* to step from
//! [`Clock::now_us`], the board only carries it out. [`Hal`] is all four, what the controller needs.
//! On the board `timed::QueuedHal` provides [`Clock`] and [`Steppers`] itself (a schedule
//! clock and queued step events) over a board that only has the clock, switches and detector;
//! host tests implement all four with a mock that records every call with its timestamp.

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
