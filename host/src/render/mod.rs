//! Renderer, scene files with opt-in effects, and image metrics (issue 5).
//!
//! * `scene`: the TOML scene file (camera, object, lights, render settings, effects), validated on load.
//! * `geometry`: cameras and the object; `envmap` + `distribution`: the environment light and its
//!   importance sampling; `brdf_sampling`: BRDF sampling built from the BRDF core's warps.
//! * `renderer`: exact delta lights, MIS for the environment, stratified antialiasing, rayon rows.
//! * `effects`: sensor/instrument effects on single readings and on images (built only when listed).
//! * `image`: the image type and its EXR/PNG files; `metrics`: RMSE, PSNR, FLIP.
//! * `quadrature`: the deterministic environment render the lab scores with (fixed light directions).
//! * `sky`: the procedural sky shipped as `examples/sky.exr`.

pub mod brdf_sampling;
pub mod distribution;
pub mod effects;
pub mod envmap;
mod error;
pub mod geometry;
pub mod image;
pub mod metrics;
pub mod quadrature;
pub mod renderer;
pub mod scene;
pub mod sky;

#[cfg(test)]
mod tests;

pub use error::RenderError;
pub use image::Image;
pub use renderer::{render, render_plain, render_with};
pub use scene::{RenderSettings, Scene};
