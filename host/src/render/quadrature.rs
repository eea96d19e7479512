//! A deterministic environment render for scoring: the environment map is downsampled to a fixed
//! set of light directions, each carrying the radiance its cell of the map sends times the cell's
//! solid angle, and every shading point sums f(wi, wo) cos(theta_i) over them. No random numbers:
//! two renders of one material are identical, and a truth and its reconstruction are lit by the
//! same directions, so their difference is the BRDF's alone (the Monte Carlo render's noise at
//! grazing angles swamped the difference on real materials, issue 25).
//!
//! Cells: `cols` x `rows` equal steps of the map's (u, v) square (default 64 x 32, 5.6 degrees).
//! A cell's direction is its power-weighted mean texel direction (a sun inside a cell stays where
//! it is), its weight the sum over its texels of radiance x texel solid angle; empty cells are
//! dropped. The render converges to the map's exact integral as the cells shrink; what it costs
//! against a 1,024 spp Monte Carlo render is what `lab/examples/env_quadrature.rs` prints
//! (figures in `docs/render.md`).

use super::envmap::{uv_to_direction, EnvMap};
use super::geometry::Hit;
use super::image::Image;
use super::renderer::{supersample, Frame};
use super::scene::Scene;
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// Cells across the map's width (azimuth) and height (elevation) by default.
pub const DEFAULT_COLS: usize = 64;
pub const DEFAULT_ROWS: usize = 32;

/// The fixed light directions of an environment map and their weights.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvQuadrature {
    /// Unit world directions toward the light.
    pub directions: Vec<DVec3>,
    /// Radiance x solid angle of each direction's cell (W/m^2 per unit cos, RGB), scale applied.
    pub weights: Vec<DVec3>,
}

impl EnvQuadrature {
    /// The map cut into at most `cols` x `rows` cells (no more than it has texels).
    pub fn new(env: &EnvMap, cols: usize, rows: usize) -> Self {
        let texels = env.texels();
        let (w, h) = (texels.width, texels.height);
        let (cols, rows) = (cols.clamp(1, w), rows.clamp(1, h));
        let mut power = vec![DVec3::ZERO; cols * rows];
        let mut centroid = vec![DVec3::ZERO; cols * rows];
        let mut geometric = vec![DVec3::ZERO; cols * rows];
        for y in 0..h {
            let (t0, t1) = (PI * y as f64 / h as f64, PI * (y + 1) as f64 / h as f64);
            let d_omega = 2.0 * PI / w as f64 * (t0.cos() - t1.cos());
            for x in 0..w {
                let cell = (y * rows / h) * cols + x * cols / w;
                let dir = uv_to_direction(DVec2::new((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64));
                let l = texels.get(x, y) * env.scale() * d_omega;
                power[cell] += l;
                centroid[cell] += dir * (l.element_sum() / 3.0);
                geometric[cell] += dir * d_omega;
            }
        }
        let mut q = Self {
            directions: Vec::new(),
            weights: Vec::new(),
        };
        for ((p, c), g) in power.into_iter().zip(centroid).zip(geometric) {
            // A dark cell lights nothing: drop it.
            if !(p.max_element() > 0.0) {
                continue;
            }
            // Guard: a cell whose power-weighted directions cancel (impossible for cells under a
            // hemisphere, kept for safety) falls back to its geometric centre.
            let dir = c.try_normalize().or_else(|| g.try_normalize()).unwrap_or(DVec3::Y);
            q.directions.push(dir);
            q.weights.push(p);
        }
        q
    }

    /// The default cells.
    pub fn of(env: &EnvMap) -> Self {
        Self::new(env, DEFAULT_COLS, DEFAULT_ROWS)
    }

    /// Reflected radiance toward local `wo` at a point with shading frame `frame`.
    fn reflect(&self, scene: &Scene, frame: &Frame, wo: DVec3) -> DVec3 {
        let mut sum = DVec3::ZERO;
        for (d, w) in self.directions.iter().zip(&self.weights) {
            let wi = frame.to_local(*d);
            // Below the local horizon the BRDF is 0: skip the evaluation.
            if wi.z > 0.0 {
                sum += scene.material.eval(wi, wo) * *w * wi.z;
            }
        }
        sum
    }
}

/// The scene rendered with its delta lights exact and its environment (if any) by `quad` instead of
/// Monte Carlo; pixels average the scene's sub-pixel grid as `render_plain` does, rows run in
/// parallel, and no random number is drawn. Effects are not applied.
pub fn render_quadrature(scene: &Scene, quad: &EnvQuadrature) -> Image {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mut image = Image::new(w, h);
    image.pixels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            *out = pixel(scene, quad, x, y);
        }
    });
    image
}

fn pixel(scene: &Scene, quad: &EnvQuadrature, x: usize, y: usize) -> DVec3 {
    supersample(scene, &scene.settings, x, y, |hit, wo| shade(scene, quad, hit, wo))
}

fn shade(scene: &Scene, quad: &EnvQuadrature, hit: &Hit, wo_world: DVec3) -> DVec3 {
    let frame = Frame::new(hit.normal);
    let wo = frame.to_local(wo_world);
    if !(wo.z > 0.0) {
        return DVec3::ZERO;
    }
    let mut radiance = quad.reflect(scene, &frame, wo);
    for light in &scene.lights {
        if let Some((wi_world, irradiance)) = light.incident(hit.point) {
            let wi = frame.to_local(wi_world);
            if wi.z > 0.0 {
                radiance += scene.material.eval(wi, wo) * irradiance * wi.z;
            }
        }
    }
    radiance
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::sky::{sky, SkyParams};

    fn sky_env() -> EnvMap {
        EnvMap::new(sky(&SkyParams::default()), 1.0).expect("valid sky")
    }

    /// The weights integrate the map exactly (sum of radiance x solid angle over its texels), and a
    /// uniform map sends 4 pi L.
    #[test]
    fn weights_integrate_the_map() {
        let q = EnvQuadrature::of(&EnvMap::constant(DVec3::new(1.0, 2.0, 0.5)));
        let total: DVec3 = q.weights.iter().sum();
        assert!(
            (total - DVec3::new(1.0, 2.0, 0.5) * 4.0 * PI).abs().max_element() < 1e-9,
            "{total}"
        );
        // The constant map is 16 x 8 texels: no more cells than texels.
        assert_eq!(q.directions.len(), 16 * 8);
        let env = sky_env();
        let q = EnvQuadrature::of(&env);
        assert!(q.directions.len() <= DEFAULT_COLS * DEFAULT_ROWS);
        assert!(q.directions.iter().all(|d| (d.length() - 1.0).abs() < 1e-12));
        // The brightest cell's direction is the power-weighted centre of the part of the sun disk
        // (3 degrees radius) it holds, so it lies on the disk, not at the cell's centre.
        let (e, a) = (35f64.to_radians(), 40f64.to_radians());
        let sun = DVec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos());
        let brightest = (0..q.weights.len())
            .max_by(|&i, &j| q.weights[i].x.total_cmp(&q.weights[j].x))
            .expect("cells");
        let off = q.directions[brightest].dot(sun).clamp(-1.0, 1.0).acos().to_degrees();
        assert!(off < 3.0, "{off} degrees from the sun");
    }

    /// A Lambert sphere in a uniform environment reflects albedo x L everywhere (the furnace): the
    /// quadrature's only error is the cosine's over a cell.
    #[test]
    fn furnace_lambert_sphere_reflects_its_albedo() {
        let mut s = Scene::orthographic_sphere("lambert:albedo=0.5", 16).expect("spec");
        s.environment = Some(EnvMap::constant(DVec3::ONE));
        let q = EnvQuadrature::new(s.environment.as_ref().expect("env"), 64, 32);
        let img = render_quadrature(&s, &q);
        let centre = img.get(8, 8);
        assert!((centre - DVec3::splat(0.5)).abs().max_element() < 0.02, "{centre}");
    }

    /// No random numbers: two renders are bit-identical, for an analytic material and a sharp one,
    /// and the sky lights the sphere (non-zero, finite).
    #[test]
    fn two_renders_are_identical() {
        for spec in ["ggx:alpha=0.2,diffuse=0.1", "ggx:alpha=0.01,diffuse=0.02"] {
            let mut s = Scene::orthographic_sphere(spec, 12).expect("spec");
            s.environment = Some(sky_env());
            let q = EnvQuadrature::of(s.environment.as_ref().expect("env"));
            let a = render_quadrature(&s, &q);
            let b = render_quadrature(&s, &q);
            assert_eq!(a, b, "{spec}");
            assert!(a.pixels.iter().all(|p| p.is_finite()));
            assert!(a.get(6, 6).max_element() > 0.0, "{spec}");
        }
    }
}
