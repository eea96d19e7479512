//! The lab's planner studies on top of the library's planner (re-exported here, so `super::X`
//! names either): the accuracy-vs-time report (`report`, `gonio-lab plan-report`) and the
//! trade-off report (`tradeoff`, `gonio-lab tradeoff`). `tradeoff` uses `report`, never the reverse.

pub use gonio::plan::*;

pub mod nielsen;
pub mod photo_samples;
pub mod report;
pub mod tradeoff;
pub mod trials;
