//! The environment light: an equirectangular map of incoming radiance, looked up per texel and
//! importance-sampled in proportion to (texel mean RGB) x sin(theta), so that every texel is drawn
//! with probability proportional to the power it sends.
//!
//! Orientation (the same as Mitsuba 3's `envmap` emitter with the identity transform, so a scene can
//! be cross-checked there): +y is up (row 0 of the file is the zenith, the last row the nadir);
//! for a world direction d toward the environment, u = atan2(d.x, -d.z) / 2 pi (wrapped into [0,1))
//! across the columns and v = acos(d.y) / pi down the rows. The centre column (u = 1/2) is the +z
//! direction, i.e. behind the default cameras, which look down -z; u = 1/4 is +x.

use super::distribution::Distribution2D;
use super::image::Image;
use super::RenderError;
use crate::brdf::frame::wrap_unit;
use glam::{DVec2, DVec3};
use std::f64::consts::PI;
use std::path::Path;

#[derive(Clone, Debug)]
pub struct EnvMap {
    texels: Image,
    scale: f64,
    dist: Distribution2D,
}

impl EnvMap {
    /// A map from texels (any size >= 1 x 1) and a radiance scale; texels must be finite and >= 0.
    pub fn new(texels: Image, scale: f64) -> Result<Self, String> {
        if texels.width == 0 || texels.height == 0 || texels.pixels.len() != texels.width * texels.height {
            return Err("environment map has no pixels".into());
        }
        if !(scale.is_finite() && scale >= 0.0) {
            return Err(format!("scale must be finite and >= 0, got {scale}"));
        }
        if let Some(i) = texels
            .pixels
            .iter()
            .position(|p| !(p.is_finite() && p.min_element() >= 0.0))
        {
            return Err(format!(
                "texel ({}, {}) is negative or not finite",
                i % texels.width,
                i / texels.width
            ));
        }
        Ok(Self::build(texels, scale))
    }

    /// The map and its sampling distribution, from texels already checked by the caller.
    fn build(texels: Image, scale: f64) -> Self {
        let (w, h) = (texels.width, texels.height);
        let weights: Vec<f64> = texels
            .pixels
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let theta = PI * ((i / w) as f64 + 0.5) / h as f64;
                p.element_sum() / 3.0 * theta.sin()
            })
            .collect();
        let dist = Distribution2D::new(&weights, w, h);
        Self { texels, scale, dist }
    }

    /// Read an EXR or PNG file (PNG is decoded from sRGB to linear).
    pub fn read(path: &Path, scale: f64) -> Result<Self, RenderError> {
        let texels = Image::read(path)?;
        Self::new(texels, scale).map_err(|reason| RenderError::image(path, reason))
    }

    /// A uniform environment of the given radiance (the furnace).
    pub fn constant(radiance: DVec3) -> Self {
        let mut texels = Image::new(16, 8);
        // Guard: a negative or non-finite radiance would poison every pixel; it becomes 0.
        let safe = |v: f64| if v.is_finite() && v > 0.0 { v } else { 0.0 };
        let radiance = DVec3::new(safe(radiance.x), safe(radiance.y), safe(radiance.z));
        texels.pixels.iter_mut().for_each(|p| *p = radiance);
        Self::build(texels, 1.0)
    }

    /// The map's texels, without the scale.
    pub fn texels(&self) -> &Image {
        &self.texels
    }

    /// The radiance scale applied to every texel.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// Incoming radiance from world direction `dir` (unit), scale applied.
    pub fn radiance(&self, dir: DVec3) -> DVec3 {
        let uv = direction_to_uv(dir);
        let (w, h) = (self.texels.width, self.texels.height);
        let x = ((uv.x * w as f64) as usize).min(w - 1);
        let y = ((uv.y * h as f64) as usize).min(h - 1);
        self.texels.get(x, y) * self.scale
    }

    /// A direction drawn in proportion to the map's power: (direction, radiance, pdf per solid angle).
    /// `None` for the (measure-zero) poles, where the equirectangular Jacobian vanishes.
    pub fn sample(&self, u: DVec2) -> Option<(DVec3, DVec3, f64)> {
        let (uv, pdf_uv) = self.dist.sample(u);
        let theta = PI * uv.y;
        let sin_theta = theta.sin();
        // Guard: pdf_omega = pdf_uv / (2 pi^2 sin theta) has no value at the poles.
        if !(sin_theta > 1e-12) || !(pdf_uv > 0.0) {
            return None;
        }
        let dir = uv_to_direction(uv);
        // The texel the sample came from (no round trip through atan2/acos).
        let (w, h) = (self.texels.width, self.texels.height);
        let x = ((uv.x * w as f64) as usize).min(w - 1);
        let y = ((uv.y * h as f64) as usize).min(h - 1);
        Some((
            dir,
            self.texels.get(x, y) * self.scale,
            pdf_uv / (2.0 * PI * PI * sin_theta),
        ))
    }

    /// `radiance(dir)` and `pdf(dir)` together, converting the direction to map coordinates once.
    pub fn radiance_and_pdf(&self, dir: DVec3) -> (DVec3, f64) {
        let uv = direction_to_uv(dir);
        let (w, h) = (self.texels.width, self.texels.height);
        let x = ((uv.x * w as f64) as usize).min(w - 1);
        let y = ((uv.y * h as f64) as usize).min(h - 1);
        let sin_theta = (PI * uv.y).sin();
        // Same guard as `pdf`: no density at the poles.
        let pdf = if sin_theta > 1e-12 {
            self.dist.pdf(uv) / (2.0 * PI * PI * sin_theta)
        } else {
            0.0
        };
        (self.texels.get(x, y) * self.scale, pdf)
    }

    /// Density of `sample` at world direction `dir`, per solid angle.
    pub fn pdf(&self, dir: DVec3) -> f64 {
        let uv = direction_to_uv(dir);
        let sin_theta = (PI * uv.y).sin();
        if !(sin_theta > 1e-12) {
            return 0.0;
        }
        self.dist.pdf(uv) / (2.0 * PI * PI * sin_theta)
    }
}

/// Equirectangular coordinates of a world direction (see the module doc).
pub fn direction_to_uv(d: DVec3) -> DVec2 {
    let u = wrap_unit(d.x.atan2(-d.z) / (2.0 * PI));
    let v = (d.y.clamp(-1.0, 1.0).acos() / PI).clamp(0.0, 1.0);
    DVec2::new(u, v)
}

/// The world direction at equirectangular coordinates (u, v).
pub fn uv_to_direction(uv: DVec2) -> DVec3 {
    let (sp, cp) = (2.0 * PI * uv.x).sin_cos();
    let (st, ct) = (PI * uv.y).sin_cos();
    DVec3::new(sp * st, ct, -cp * st)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn orientation_and_sampling_density() {
        assert!((uv_to_direction(DVec2::new(0.5, 0.5)) - DVec3::Z).length() < 1e-12);
        assert!((uv_to_direction(DVec2::new(0.25, 0.5)) - DVec3::X).length() < 1e-12);
        assert!((uv_to_direction(DVec2::new(0.0, 0.0)) - DVec3::Y).length() < 1e-12);
        let uv = direction_to_uv(DVec3::new(0.3, -0.4, 0.5).normalize());
        assert!((direction_to_uv(uv_to_direction(uv)) - uv).length() < 1e-12);
        // A map with one bright texel: every sample's pdf matches `pdf`, and the estimator
        // radiance / pdf integrates the map's irradiance over the sphere.
        let mut texels = Image::new(8, 4);
        texels.pixels.iter_mut().for_each(|p| *p = DVec3::splat(0.1));
        texels.pixels[9] = DVec3::new(5.0, 4.0, 3.0);
        let env = EnvMap::new(texels.clone(), 2.0).expect("valid map");
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut sum = DVec3::ZERO;
        let n = 20_000;
        for _ in 0..n {
            let (d, l, pdf) = env
                .sample(DVec2::new(rng.random(), rng.random()))
                .expect("away from poles");
            assert!((pdf - env.pdf(d)).abs() <= 1e-6 * pdf, "{pdf} vs {}", env.pdf(d));
            assert_eq!(l, env.radiance(d));
            assert_eq!((l, env.pdf(d)), env.radiance_and_pdf(d));
            sum += l / pdf;
        }
        // Exact: sum over texels of L * (solid angle of its row band / w).
        let mut want = DVec3::ZERO;
        for (i, p) in texels.pixels.iter().enumerate() {
            let (t0, t1) = (PI * (i / 8) as f64 / 4.0, PI * ((i / 8) + 1) as f64 / 4.0);
            want += *p * 2.0 * (2.0 * PI / 8.0) * (t0.cos() - t1.cos());
        }
        let got = sum / n as f64;
        assert!(((got - want) / want).abs().max_element() < 0.02, "{got} vs {want}");
        let mut bad = Image::new(2, 1);
        bad.pixels[1] = DVec3::new(0.0, f64::NAN, 0.0);
        assert_eq!(
            EnvMap::new(bad, 1.0).err().as_deref(),
            Some("texel (1, 0) is negative or not finite")
        );
    }
}
