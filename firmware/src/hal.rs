//! What the board does, and nothing else: step/dir outputs, limit inputs, the detector, a clock.
//!
//! Deliberately small and synchronous (embedded-hal style): the step generator decides *when* to
//! step from [`Hal::now_us`], the HAL only carries it out. The controller tells its caller when it
//! next needs to run ([`crate::Device::next_deadline_us`]), so host tests jump a mock clock straight
//! to it. On the board, [`crate::timed::QueuedHal`] implements this trait with a clock that runs
//! ahead of real time during moves and turns `step` / `set_direction` into timed events that a
//! timer interrupt plays ([`crate::step_queue`]). A mock HAL records every call with its timestamp,
//! so host tests can check step rates, accelerations and the arm-separation invariant.

use gonio_shared::msg::caps::MAX_CHANNELS;
use gonio_shared::Axis;
use heapless::Vec;

/// Counts per detector channel from one exposure.
pub type Readout = Vec<u32, MAX_CHANNELS>;

pub trait Hal {
    /// Monotonic time since boot, microseconds. Never goes backwards.
    fn now_us(&self) -> u64;

    /// Set the direction pin of `axis` (`true` = increasing step count). Takes effect before the
    /// next [`Hal::step`] of that axis (the HAL honours the driver's direction setup time).
    fn set_direction(&mut self, axis: Axis, increasing: bool);

    /// Emit one step pulse on `axis`.
    fn step(&mut self, axis: Axis);

    /// Is the limit / home switch of `axis` closed? For a continuous axis this is its index sensor,
    /// which only homing looks at.
    fn limit_closed(&self, axis: Axis) -> bool;

    /// Start an exposure of `exposure_us` microseconds (restarts one already running).
    fn start_exposure(&mut self, exposure_us: u32);

    /// The readout of the last exposure once it is complete, `None` while it is still running.
    fn poll_readout(&mut self) -> Option<Readout>;
}
