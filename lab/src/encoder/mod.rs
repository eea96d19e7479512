//! The lab's encoder work on top of the library's encoder (re-exported here, so `super::X` names
//! either): datasets of capture renders, training (feature `train`), the ONNX writer and the
//! accuracy report.
//!
//! * `dataset`: `gonio-lab dataset`, synthetic renders of `examples/capture.toml` and the MERL fits;
//! * `onnx`: the ONNX graph writer (opset 13), from plain weight arrays;
//! * `report`: accuracy tables, the intensity sweep and the predicted-vs-true plot;
//! * `train` (cargo feature `train`): the candle network, training loop and export.

pub use gonio::encoder::*;

pub mod dataset;
pub mod onnx;
pub mod report;
#[cfg(feature = "train")]
pub mod train;

#[cfg(test)]
mod tests;
