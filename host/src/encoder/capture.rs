//! The capture photo (`examples/capture.toml`: a sphere under a point light 30 deg off the view
//! axis) of a material, rendered as the network sees it; and the GGX alpha that labels it.

use super::{resample_square, CAPTURE_TOML, INPUT_SIZE};
use crate::brdf::fit::{fit, FitModel, FitResult};
use crate::brdf::spec::Analytic;
use crate::brdf::Material;
use crate::render::{render_with, Image, Scene};
use std::path::Path;

/// Render side before box-averaging to the network input (4 x 4 samples per input pixel).
pub const RENDER_SIZE: usize = 4 * INPUT_SIZE;

/// The capture scene with another material, at `size` x `size`.
pub fn capture_scene(spec: &str, size: usize) -> Result<Scene, String> {
    let mut scene = Scene::from_toml(CAPTURE_TOML, Path::new("examples/capture.toml")).map_err(|e| e.to_string())?;
    let other = Scene::orthographic_sphere(spec, size).map_err(|e| e.to_string())?;
    scene.material = other.material;
    scene.sampler = other.sampler;
    scene.material_spec = other.material_spec;
    scene.camera.width = size;
    scene.camera.height = size;
    Ok(scene)
}

/// The capture photo of `spec` at `size` x `size` pixels, full resolution (`gonio capture`).
pub fn capture_photo(spec: &str, size: usize) -> Result<Image, String> {
    let scene = capture_scene(spec, size)?;
    render_with(&scene, &scene.settings, &|| {}).map_err(|e| e.to_string())
}

/// The network-resolution linear photo of `spec` under the capture light times `intensity`.
pub fn render_capture(spec: &str, intensity: f64) -> Result<Image, String> {
    render_capture_scene(capture_scene(spec, RENDER_SIZE)?, intensity)
}

/// `render_capture` of a material that has no spec string (`TwoLobes`).
pub fn render_capture_material(material: Box<dyn Material>, intensity: f64) -> Result<Image, String> {
    let mut scene = capture_scene("lambert:albedo=0.5", RENDER_SIZE)?;
    // A point light evaluates only the material (the BRDF sampler serves environment lighting).
    scene.material = material;
    render_capture_scene(scene, intensity)
}

fn render_capture_scene(scene: Scene, intensity: f64) -> Result<Image, String> {
    let full = render_with(&scene, &scene.settings, &|| {}).map_err(|e| e.to_string())?;
    let mut small = resample_square(&full, INPUT_SIZE);
    for p in &mut small.pixels {
        *p *= intensity;
    }
    Ok(small)
}

/// The GGX alpha `brdf::fit` gives a material: the ground truth of MERL and two-lobe images.
pub fn ggx_fit_alpha(material: &dyn Material) -> Result<f64, String> {
    ggx_alpha(&fit(material, FitModel::Ggx))
}

/// The alpha of a GGX fit (`FitModel::Ggx` always gives a GGX model; anything else is an error).
pub fn ggx_alpha(fit: &FitResult) -> Result<f64, String> {
    match &fit.model {
        Analytic::Ggx(g) => Ok(g.alpha),
        other => Err(format!("the GGX fit gave {other:?}")),
    }
}
