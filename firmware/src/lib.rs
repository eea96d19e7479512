//! `gonio-firmware`: the controller logic of the gonio instrument, `no_std` and heap-free.
//!
//! All behaviour lives here, generic over [`Hal`], so it runs unchanged on the STM32 (the embassy
//! binary in `firmware/stm32` only implements `Hal` and moves bytes) and on the host under a mock
//! HAL and inside the virtual gonio.
//!
//! - [`hal`]: what the board does (step/dir, switches, detector, clock);
//! - [`link`]: frames in and out, NAKs, host sequence numbers, the bounded outbox;
//! - [`controller`]: the state machine, homing, the per-direction scan sequence;
//! - [`plan`]: the bounded plan ring and the reachability check of each direction;
//! - [`stepper`]: synchronised trapezoidal moves with step instants computed in real time;
//! - [`step_queue`]: timed STEP/DIR events played back by a timer interrupt (the board's steps);
//! - [`timed`]: the `Hal` adapter and loop that run the controller ahead of real time into it;
//! - [`separation`]: the arms' blocking-angle invariant;
//! - [`measurements`]: readings kept until acknowledged;
//! - [`homing`]: switch positions and homing moves;
//! - [`capacity`]: every buffer size, in one place;
//! - [`device`]: link + controller behind one value.
#![no_std]
#![forbid(unsafe_code)]

pub mod capacity;
pub mod controller;
pub mod device;
pub mod hal;
pub mod homing;
pub mod link;
pub mod measurements;
pub mod plan;
pub mod separation;
pub mod step_queue;
pub mod stepper;
pub mod timed;

pub use device::Device;
pub use hal::{Hal, Readout};
