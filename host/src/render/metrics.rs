//! Image metrics: RMSE and PSNR of the linear values, and mean LDR FLIP of the tone-mapped images
//! (NVIDIA's reference implementation through the `nv-flip` binding), as the paper reports them.

use super::image::{write_rgb8_png, Image};
use super::RenderError;
use serde::Serialize;
use std::path::Path;

/// PSNR's peak signal: 1, the white of the tone-mapped (LDR) image.
pub const PSNR_PEAK: f64 = 1.0;

/// Viewing condition of the FLIP error: 67 pixels per degree, FLIP's default (a 0.7 m distance from
/// a 3840-pixel-wide 0.7 m monitor).
pub const FLIP_PIXELS_PER_DEGREE: f32 = nv_flip::DEFAULT_PIXELS_PER_DEGREE;

#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Comparison {
    pub rmse: f64,
    /// In dB; infinite for identical images (serialised as null in JSON).
    pub psnr: f64,
    /// Mean LDR FLIP in [0, 1].
    pub flip: f64,
}

/// A per-pixel FLIP error map, values in [0, 1], row 0 first.
#[derive(Clone, Debug, PartialEq)]
pub struct FlipMap {
    pub width: usize,
    pub height: usize,
    pub errors: Vec<f32>,
}

fn same_size(reference: &Image, test: &Image) -> Result<(), RenderError> {
    if (reference.width, reference.height) != (test.width, test.height) {
        return Err(RenderError::Invalid(format!(
            "images differ in size: reference {}x{}, test {}x{}",
            reference.width, reference.height, test.width, test.height
        )));
    }
    if reference.pixels.is_empty() {
        return Err(RenderError::Invalid("images have no pixels".into()));
    }
    Ok(())
}

/// Root-mean-square difference over every pixel and channel of the linear values.
pub fn rmse(reference: &Image, test: &Image) -> Result<f64, RenderError> {
    same_size(reference, test)?;
    let sum: f64 = reference
        .pixels
        .iter()
        .zip(&test.pixels)
        .map(|(a, b)| (*a - *b).length_squared())
        .sum();
    Ok((sum / (3 * reference.pixels.len()) as f64).sqrt())
}

/// PSNR in dB for an RMSE against PSNR_PEAK; +infinity for rmse = 0.
pub fn psnr(rmse: f64) -> f64 {
    if rmse > 0.0 {
        20.0 * (PSNR_PEAK / rmse).log10()
    } else {
        f64::INFINITY
    }
}

/// LDR FLIP of the tone-mapped images (see `image::tone_map`): the mean error and its map.
pub fn flip(reference: &Image, test: &Image) -> Result<(f64, FlipMap), RenderError> {
    same_size(reference, test)?;
    let too_big = || RenderError::Invalid("image too large for FLIP".into());
    let w = u32::try_from(reference.width).map_err(|_| too_big())?;
    let h = u32::try_from(reference.height).map_err(|_| too_big())?;
    let a = nv_flip::FlipImageRgb8::with_data(w, h, &reference.to_srgb8());
    let b = nv_flip::FlipImageRgb8::with_data(w, h, &test.to_srgb8());
    let errors = nv_flip::flip(a, b, FLIP_PIXELS_PER_DEGREE).to_vec();
    let mean = errors.iter().map(|&e| e as f64).sum::<f64>() / errors.len() as f64;
    Ok((
        mean,
        FlipMap {
            width: reference.width,
            height: reference.height,
            errors,
        },
    ))
}

/// RMSE, PSNR and mean FLIP in one call (the report's scoring).
pub fn compare(reference: &Image, test: &Image) -> Result<(Comparison, FlipMap), RenderError> {
    let rmse = rmse(reference, test)?;
    let (flip, map) = flip(reference, test)?;
    Ok((
        Comparison {
            rmse,
            psnr: psnr(rmse),
            flip,
        },
        map,
    ))
}

impl FlipMap {
    /// Write the map as a PNG through FLIP's magma colour map (black = no error, yellow = 1).
    pub fn write_png(&self, path: &Path) -> Result<(), RenderError> {
        // Both sizes came from an Image that FLIP accepted, so they fit in u32.
        let (w, h) = (self.width as u32, self.height as u32);
        let map = nv_flip::FlipImageFloat::with_data(w, h, &self.errors);
        let bytes = map.apply_color_lut(&nv_flip::magma_lut()).to_vec();
        write_rgb8_png(path, self.width, self.height, bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn metrics_of_known_differences() {
        let mut a = Image::new(16, 16);
        a.pixels.iter_mut().for_each(|p| *p = DVec3::splat(0.5));
        let (same, map) = compare(&a, &a).expect("same size");
        assert_eq!((same.rmse, same.flip), (0.0, 0.0));
        assert!(same.psnr.is_infinite());
        assert_eq!(map.errors.len(), 256);
        let mut b = a.clone();
        b.pixels.iter_mut().for_each(|p| *p += DVec3::splat(0.1));
        let (c, _) = compare(&a, &b).expect("same size");
        assert!((c.rmse - 0.1).abs() < 1e-12);
        assert!((c.psnr - 20.0).abs() < 1e-9, "{}", c.psnr);
        assert!(c.flip > 0.0 && c.flip < 1.0, "{}", c.flip);
        // A sharper difference scores worse.
        let mut d = a.clone();
        d.pixels.iter_mut().step_by(2).for_each(|p| *p = DVec3::ONE);
        assert!(compare(&a, &d).expect("same size").0.flip > c.flip);
        let small = Image::new(8, 16);
        assert_eq!(
            compare(&a, &small).err().map(|e| e.to_string()).unwrap_or_default(),
            "images differ in size: reference 16x16, test 8x16"
        );
        let json = serde_json::to_string(&same).expect("json");
        assert_eq!(json, r#"{"rmse":0.0,"psnr":null,"flip":0.0}"#);
        let dir = tempfile::tempdir().expect("temp dir");
        map.write_png(&dir.path().join("flip.png")).expect("write map");
    }
}
