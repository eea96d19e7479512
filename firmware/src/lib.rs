//! `gonio-firmware`: the controller logic of the gonio instrument, `no_std` and heap-free.
//!
//! All behaviour lives here, generic over the small traits of [`hal`], so it runs unchanged on the
//! STM32 (the embassy binary in `firmware/stm32` only implements them and moves bytes), on the host
//! under a mock HAL, and inside the virtual gonio (through the board's [`timed`] step path).
//!
//! - [`hal`]: what the board does: clock, steppers, switches, detector;
//! - [`link`]: frames in, NAKs, host sequence numbers; yields host commands;
//! - [`outbox`]: encoded frames out, bounded, with room reserved for replies;
//! - [`controller`]: the state machine, homing, the per-direction scan sequence;
//! - [`plan`]: the bounded plan ring, each direction checked on arrival (`gonio_shared::acceptance`);
//! - [`stepper`]: synchronised trapezoidal moves, queued as segments or played step by step;
//! - [`segment`]: `(interval, count, add)` step segments fitted to the trapezoid, and their playback;
//! - [`step_queue`]: per-axis segment rings played by one timer compare channel per axis;
//! - [`timed`]: the `Hal` adapter and loop that run the controller ahead of real time into it;
//! - [`measurements`]: readings kept until acknowledged;
//! - [`homing`]: switch positions and homing moves;
//! - [`capacity`]: every buffer size, in one place;
//! - [`pin_map`]: the board's stepper-driver pins and the GPIO words the step and fault paths write;
//! - [`watchdog`]: when the loop feeds the independent watchdog;
//! - [`device`]: link + controller + outbox behind one value; dispatches what the link yields.
#![no_std]
#![forbid(unsafe_code)]

pub mod capacity;
pub mod controller;
pub mod device;
pub mod hal;
pub mod homing;
pub mod link;
pub mod measurements;
pub mod outbox;
pub mod pin_map;
pub mod plan;
pub mod segment;
pub mod step_queue;
pub mod stepper;
pub mod timed;
pub mod watchdog;

pub use device::Device;
pub use hal::{Clock, Detector, Hal, Readout, Steppers, Switches};
