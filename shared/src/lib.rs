//! What the gonio host and firmware share bit for bit.
//!
//! - [`msg`]: the messages on the wire (postcard + serde, heapless, no alloc) and the version handshake;
//! - [`frame`]: COBS framing with a sequence number and CRC-32 per frame, and the streaming decoder;
//! - [`instrument`]: the description of the instrument (axes, limits, blocking angle);
//! - [`kinematics`]: local directions <-> axis angles <-> integer step targets, and reachability;
//! - [`motion`]: trapezoidal move times and synchronised multi-axis moves (the planner's time model);
//! - [`separation`]: the arms' blocking-angle invariant;
//! - [`acceptance`]: the firmware's acceptance test of one plan direction, re-run by the planner;
//! - [`schema_hash`]: the wire schema's hash for the version handshake.
//!
//! Everything numeric is generic over [`real::Real`] so the host runs it in `f64` and the firmware in
//! `f32` through the *same* code, with the same `libm` functions on both sides.
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![forbid(unsafe_code)]

pub mod acceptance;
pub mod frame;
pub mod instrument;
pub mod kinematics;
pub mod motion;
pub mod msg;
pub mod real;
pub mod schema_hash;
pub mod separation;
pub mod vec3;

pub use instrument::{Axis, AxisConfig, HomeSide, InstrumentConfig, AXES};
pub use real::Real;
