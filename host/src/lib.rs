//! The gonio library: BRDF models, rendering, the encoder's inference, the planner, the link to
//! the instrument, the virtual gonio and the scan pipeline. The `gonio` binary (cli/) and the
//! research lab (`gonio-lab`, lab/) are built on it; it depends on neither.

pub mod brdf;
pub mod encoder;
pub mod fsio;
pub mod instrument;
pub mod journal;
pub mod link;
pub mod plan;
pub mod reconstruct;
pub mod render;
pub mod scan;
pub mod sim;

/// This build's version: the package version, plus `git describe` when built from a git checkout
/// (see build.rs). A scan records it, and a resume by another build is refused.
pub const VERSION: &str = env!("GONIO_VERSION");
