//! `gonio-firmware`: the controller logic of the gonio instrument, `no_std` and heap-free.
//!
//! All behaviour lives here, generic over [`Hal`], so it runs unchanged on the STM32 (the embassy
//! binary in `firmware/stm32` only implements `Hal` and moves bytes) and on the host under a mock
//! HAL and inside the virtual gonio. The controller itself (state machine, plan intake, motion,
//! measurements) comes with the firmware issue; today this crate fixes the board interface.
#![no_std]
#![forbid(unsafe_code)]

pub mod hal;

pub use hal::{Hal, Readout};
