//! The gonio host: instrument description, BRDF mathematics, and (in later issues) planning,
//! streaming, reconstruction, rendering and reports. The `gonio` binary is a thin clap layer on top.

pub mod brdf;
pub mod encoder;
pub mod fsio;
pub mod instrument;
pub mod journal;
pub mod link;
pub mod plan;
pub mod plot;
pub mod progress_bar;
pub mod render;
pub mod scan;
pub mod sim;
