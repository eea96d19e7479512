//! The renderer: one object, delta lights evaluated exactly, an environment light by Monte Carlo
//! with multiple importance sampling (power heuristic) of one environment sample and one BRDF sample
//! per `spp`. Pixels average a pixel_samples x pixel_samples grid of stratum centres (antialiasing
//! that adds no noise); the `spp` environment samples of a pixel are spread over those centres,
//! ceil(spp / pixel_samples^2) each. Rows run in parallel (rayon); every pixel has its own random
//! stream seeded from (seed, pixel index), so the image does not depend on the thread count.

use super::effects::{stream_seed, EffectPipeline};
use super::geometry::Hit;
use super::image::Image;
use super::scene::{Background, RenderSettings, Scene};
use super::RenderError;
use glam::{DVec2, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// The stream id of the renderer's own random numbers (the effects use small ids, see `Effect::random_stream`).
const RENDER_STREAM: u64 = 0x72656e646572;

/// Render with the scene's own settings, then apply the effects the scene lists.
pub fn render(scene: &Scene) -> Result<Image, RenderError> {
    render_with(scene, &scene.settings, &|| {})
}

/// Render with explicit settings; `on_row` is called once per finished row (progress bars).
pub fn render_with(scene: &Scene, settings: &RenderSettings, on_row: &(dyn Fn() + Sync)) -> Result<Image, RenderError> {
    super::scene::check_settings(settings).map_err(RenderError::Invalid)?;
    let mut image = render_plain(scene, settings, on_row);
    if let Some(cfg) = &scene.effects {
        let pipeline = EffectPipeline::from_config(cfg, settings.seed).map_err(RenderError::Invalid)?;
        pipeline.apply_image(&mut image);
    }
    Ok(image)
}

/// The noise-free (except for Monte Carlo) radiance image, without effects.
pub fn render_plain(scene: &Scene, settings: &RenderSettings, on_row: &(dyn Fn() + Sync)) -> Image {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mut image = Image::new(w, h);
    image.pixels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            *out = pixel(scene, settings, x, y);
        }
        on_row();
    });
    image
}

fn pixel(scene: &Scene, settings: &RenderSettings, x: usize, y: usize) -> DVec3 {
    let n = settings.pixel_samples.max(1) as usize;
    let env_samples = match scene.environment {
        Some(_) => (settings.spp as usize).div_ceil(n * n).max(1),
        None => 0,
    };
    // Only a scene with an environment draws random numbers.
    let mut rng = (env_samples > 0).then(|| {
        let index = (y * scene.camera.width + x) as u64;
        ChaCha8Rng::seed_from_u64(stream_seed(settings.seed, RENDER_STREAM, index))
    });
    supersample(scene, settings, x, y, |hit, wo| {
        shade(scene, hit, wo, env_samples, rng.as_mut())
    })
}

/// A pixel's value: the mean over its pixel_samples x pixel_samples stratum centres of
/// `shade_hit(hit, wo)` where the ray meets the object, else the background (as `settings` say).
pub(super) fn supersample(
    scene: &Scene,
    settings: &RenderSettings,
    x: usize,
    y: usize,
    mut shade_hit: impl FnMut(&Hit, DVec3) -> DVec3,
) -> DVec3 {
    let n = settings.pixel_samples.max(1) as usize;
    let mut sum = DVec3::ZERO;
    for sy in 0..n {
        for sx in 0..n {
            let px = x as f64 + (sx as f64 + 0.5) / n as f64;
            let py = y as f64 + (sy as f64 + 0.5) / n as f64;
            let ray = scene.camera.ray(px, py);
            sum += match scene.shape.intersect(&ray) {
                Some(hit) => shade_hit(&hit, -ray.dir),
                None => match (&scene.environment, settings.background) {
                    (Some(env), Background::Environment) => env.radiance(ray.dir),
                    _ => DVec3::ZERO,
                },
            };
        }
    }
    let value = sum / (n * n) as f64;
    // Last line of defence: the formulas are guarded, but a NaN must never reach a file.
    if value.is_finite() {
        value
    } else {
        DVec3::ZERO
    }
}

/// The shading frame at a hit: tangent, bitangent, normal. The tangent is glam's
/// `any_orthonormal_pair` (Duff et al. 2017), which is fine for the isotropic materials this renderer
/// is used with; an anisotropic material would need a tangent field of the shape instead.
pub struct Frame {
    t: DVec3,
    b: DVec3,
    n: DVec3,
}

impl Frame {
    pub fn new(n: DVec3) -> Self {
        let (t, b) = n.any_orthonormal_pair();
        Self { t, b, n }
    }
    pub fn to_local(&self, v: DVec3) -> DVec3 {
        DVec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }
    fn to_world(&self, v: DVec3) -> DVec3 {
        v.x * self.t + v.y * self.b + v.z * self.n
    }
}

/// Outgoing radiance toward `wo_world` (unit, pointing at the camera).
fn shade(scene: &Scene, hit: &Hit, wo_world: DVec3, env_samples: usize, rng: Option<&mut ChaCha8Rng>) -> DVec3 {
    let frame = Frame::new(hit.normal);
    let wo = frame.to_local(wo_world);
    if !(wo.z > 0.0) {
        return DVec3::ZERO;
    }
    let mut radiance = DVec3::ZERO;
    for light in &scene.lights {
        if let Some((wi_world, irradiance)) = light.incident(hit.point) {
            let wi = frame.to_local(wi_world);
            // Below the horizon the BRDF is 0 anyway; skipping saves the evaluation.
            if wi.z > 0.0 {
                radiance += scene.material.eval(wi, wo) * irradiance * wi.z;
            }
        }
    }
    if let (Some(env), Some(rng)) = (&scene.environment, rng) {
        let sampler = scene.sampler.at(wo);
        let mut acc = DVec3::ZERO;
        for _ in 0..env_samples {
            // Environment sample, weighted against the BRDF sampler's density there.
            if let Some((wi_world, l, p_env)) = env.sample(DVec2::new(rng.random(), rng.random())) {
                let wi = frame.to_local(wi_world);
                if wi.z > 0.0 {
                    let f = scene.material.eval(wi, wo);
                    let p_brdf = sampler.pdf(wi);
                    acc += f * l * (wi.z * power_heuristic(p_env, p_brdf) / p_env);
                }
            }
            // BRDF sample, weighted against the environment's density there.
            let pick: f64 = rng.random();
            if let Some((wi, p_brdf)) = sampler.sample(pick, DVec2::new(rng.random(), rng.random())) {
                let wi_world = frame.to_world(wi);
                let (l, p_env) = env.radiance_and_pdf(wi_world);
                let f = scene.material.eval(wi, wo);
                acc += f * l * (wi.z * power_heuristic(p_brdf, p_env) / p_brdf);
            }
        }
        radiance += acc / env_samples as f64;
    }
    radiance
}

/// Veach's power heuristic (beta = 2) for the strategy with density `a` against one with `b`:
/// a^2 / (a^2 + b^2), written as 1 / (1 + (b/a)^2) so that it stays finite where a^2 would overflow.
/// Guards: a strategy that could not have drawn the sample (a <= 0) gets weight 0; a NaN density of
/// the other strategy counts as 0.
fn power_heuristic(a: f64, b: f64) -> f64 {
    if !(a > 0.0) {
        return 0.0;
    }
    let r = b / a;
    if r.is_nan() {
        return 1.0;
    }
    1.0 / (1.0 + r * r)
}
