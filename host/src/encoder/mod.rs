//! The encoder (issue 6): one photo of the sample in, analytic BRDF parameters out (Cao, Fig. 3).
//!
//! * this module: the two models, their parameters and output ranges, and the input convention
//!   (photo loading and preprocessing) that training and inference share;
//! * `infer`: the only place that touches tract (ONNX inference);
//! * `capture`: the capture photo of a material (`examples/capture.toml`) as the network sees it;
//! * `observable`: what a capture photo shows of a BRDF, and the GGX alpha that alone supports.
//!
//! Datasets, training, the ONNX writer and accuracy reports are the lab's (`gonio-lab`).

pub mod capture;
pub mod infer;
pub mod observable;
pub mod photo;

use crate::render::image::srgb_to_linear;
use crate::render::Image;
use glam::DVec3;
use std::path::{Path, PathBuf};

/// Side of the network's square input.
pub const INPUT_SIZE: usize = 64;
/// Input channels (linear RGB after preprocessing).
pub const CHANNELS: usize = 3;
/// Floats in one preprocessed image (CHW).
pub const INPUT_LEN: usize = CHANNELS * INPUT_SIZE * INPUT_SIZE;
/// The input convention in one line (the ONNX files' `gonio.input` metadata).
pub const INPUT_DOC: &str = "1x3x64x64 linear RGB, divided by max(p90 luminance, 1e-4 max), then ln(1 + x)";

/// The scene every training image is rendered from, and the photo convention users follow.
pub const CAPTURE_TOML: &str = include_str!("../../../examples/capture.toml");

#[derive(Debug, thiserror::Error)]
pub enum EncoderError {
    #[error("{path}: {reason}")]
    Image { path: PathBuf, reason: String },
    #[error("model: {0}")]
    Model(String),
    #[error("dataset {path}: {reason}")]
    Dataset { path: PathBuf, reason: String },
}

impl EncoderError {
    fn image(path: &Path, reason: impl ToString) -> Self {
        Self::Image {
            path: path.to_path_buf(),
            reason: reason.to_string(),
        }
    }
    pub fn dataset(path: &Path, reason: impl ToString) -> Self {
        Self::Dataset {
            path: path.to_path_buf(),
            reason: reason.to_string(),
        }
    }
}

/// Which analytic model a network predicts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::EnumString, strum::VariantNames)]
#[strum(serialize_all = "kebab-case")]
pub enum ModelKind {
    Ward,
    Ggx,
}

/// How a sigmoid output s in (0, 1) maps to a parameter: `lo + (hi - lo) s`, or `lo (hi / lo)^s`
/// for roughness, whose useful values span decades.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamRange {
    pub name: &'static str,
    pub lo: f64,
    pub hi: f64,
    pub log: bool,
}

impl ParamRange {
    pub fn from_unit(&self, s: f64) -> f64 {
        if self.log {
            self.lo * (self.hi / self.lo).powf(s)
        } else {
            self.lo + (self.hi - self.lo) * s
        }
    }
    pub fn to_unit(&self, v: f64) -> f64 {
        if self.log {
            (v / self.lo).ln() / (self.hi / self.lo).ln()
        } else {
            (v - self.lo) / (self.hi - self.lo)
        }
    }
}

impl std::fmt::Display for ModelKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl ModelKind {
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::Ward => "ward",
            ModelKind::Ggx => "ggx",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        name.parse().ok()
    }

    /// The network's outputs, in order. The ranges are slightly wider than the training data's
    /// (the lab's `dataset::sample_params`), because a sigmoid never reaches its ends.
    pub fn outputs(self) -> &'static [ParamRange] {
        match self {
            ModelKind::Ward => &[
                ParamRange {
                    name: "rho_d",
                    lo: 0.0,
                    hi: 1.0,
                    log: false,
                },
                ParamRange {
                    name: "alpha",
                    lo: 0.01,
                    hi: 1.0,
                    log: true,
                },
            ],
            ModelKind::Ggx => &[ParamRange {
                name: "alpha",
                lo: 0.001,
                hi: 1.5,
                log: true,
            }],
        }
    }

    /// The material spec of predicted parameters (Ward keeps rho_s = 1 - rho_d, as trained).
    pub fn spec(self, values: &[f64]) -> String {
        let names = self.outputs().iter().map(|p| p.name);
        let body: Vec<String> = names.zip(values).map(|(n, v)| format!("{n}={v:.4}")).collect();
        format!("{}:{}", self.name(), body.join(","))
    }
}

/// Read a photo for the encoder: PNG (8 or 16 bit, RGB or RGBA; sRGB-decoded to linear) or EXR
/// (linear). Grayscale, unreadable, empty or non-finite images are errors.
pub fn load_photo(path: &Path) -> Result<Image, EncoderError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let image = match ext.as_str() {
        "png" => load_png(path)?,
        "exr" => Image::read(path).map_err(|e| EncoderError::image(path, e))?,
        _ => return Err(EncoderError::image(path, "expected a .png or .exr photo")),
    };
    if image.width == 0 || image.height == 0 {
        return Err(EncoderError::image(path, "the image is empty"));
    }
    if image.pixels.iter().any(|p| !p.is_finite()) {
        return Err(EncoderError::image(path, "the image has NaN or infinite pixels"));
    }
    Ok(image)
}

fn load_png(path: &Path) -> Result<Image, EncoderError> {
    use image::ColorType;
    let decoded = image::ImageReader::open(path)
        .map_err(|e| EncoderError::image(path, e))?
        .with_guessed_format()
        .map_err(|e| EncoderError::image(path, e))?
        .decode()
        .map_err(|e| EncoderError::image(path, e))?;
    match decoded.color() {
        ColorType::Rgb8 | ColorType::Rgba8 | ColorType::Rgb16 | ColorType::Rgba16 => {}
        ColorType::L8 | ColorType::La8 | ColorType::L16 | ColorType::La16 => {
            return Err(EncoderError::image(
                path,
                "grayscale image: the encoder needs an RGB or RGBA photo",
            ))
        }
        other => {
            return Err(EncoderError::image(
                path,
                format!("unsupported PNG colour type {other:?}"),
            ))
        }
    }
    // 32-bit float keeps 16-bit PNGs at full precision; alpha is dropped (the sphere is opaque).
    let rgb = decoded.to_rgb32f();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let pixels = rgb
        .pixels()
        .map(|p| {
            DVec3::new(
                srgb_to_linear(p[0] as f64),
                srgb_to_linear(p[1] as f64),
                srgb_to_linear(p[2] as f64),
            )
        })
        .collect();
    Ok(Image {
        width: w,
        height: h,
        pixels,
    })
}

/// Centre-crop to a square and area-resample to `size` x `size`: each output pixel averages a k x k
/// grid of points over its footprint (k = ceil(source / size)), which is the exact box average when
/// the source side is a multiple of `size` (the dataset's 256 -> 64).
pub fn resample_square(image: &Image, size: usize) -> Image {
    let side = image.width.min(image.height);
    let (x0, y0) = ((image.width - side) / 2, (image.height - side) / 2);
    let f = side as f64 / size as f64;
    let k = side.div_ceil(size).max(1);
    let mut out = Image::new(size, size);
    for oy in 0..size {
        for ox in 0..size {
            let mut sum = DVec3::ZERO;
            for sy in 0..k {
                for sx in 0..k {
                    let px = ((ox as f64 + (sx as f64 + 0.5) / k as f64) * f) as usize;
                    let py = ((oy as f64 + (sy as f64 + 0.5) / k as f64) * f) as usize;
                    sum += image.get(x0 + px.min(side - 1), y0 + py.min(side - 1));
                }
            }
            out.pixels[oy * size + ox] = sum / (k * k) as f64;
        }
    }
    out
}

/// Quantile of luminance (over all pixels of the resampled image) that sets an image's brightness.
const SCALE_QUANTILE: f64 = 0.9;
/// The scale never drops below this fraction of the brightest pixel (a black-diffuse mirror sphere).
const SCALE_FLOOR: f64 = 1e-4;

/// The network input of a linear photo: resample to 64 x 64, divide by the image's own brightness
/// s = max(90th percentile of luminance, 1e-4 x max luminance), then ln(1 + x / s) per channel, CHW.
/// s is positively homogeneous (s(kI) = k s(I)), so multiplying the photo by any light intensity or
/// exposure leaves the input unchanged: intensity robustness is structural, not learned.
pub fn preprocess(image: &Image) -> Result<Vec<f32>, String> {
    if image.width == 0 || image.height == 0 {
        return Err("the image is empty".into());
    }
    // Checked on the whole photo, before cropping, and before any `max` (which would turn NaN into 0).
    if image.pixels.iter().any(|p| !p.is_finite()) {
        return Err("the image has NaN or infinite pixels".into());
    }
    let small = resample_square(image, INPUT_SIZE);
    let lum = |p: DVec3| 0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z;
    let mut l: Vec<f64> = small.pixels.iter().map(|&p| lum(p).max(0.0)).collect();
    l.sort_by(f64::total_cmp);
    let max = l[l.len() - 1];
    if !(max > 0.0) {
        return Err("the image is black".into());
    }
    let q = l[((l.len() - 1) as f64 * SCALE_QUANTILE).round() as usize];
    let s = q.max(SCALE_FLOOR * max);
    let mut out = vec![0f32; INPUT_LEN];
    let plane = INPUT_SIZE * INPUT_SIZE;
    for (i, p) in small.pixels.iter().enumerate() {
        for c in 0..CHANNELS {
            out[c * plane + i] = (p[c].max(0.0) / s).ln_1p() as f32;
        }
    }
    Ok(out)
}

/// A preprocessed input flipped top to bottom: the capture's light lies in the plane y = 0, so this
/// is the photo of the same isotropic material (training augmentation).
pub fn flip_vertical(input: &[f32]) -> Vec<f32> {
    let mut out = vec![0f32; input.len()];
    let n = INPUT_SIZE;
    for c in 0..input.len() / (n * n) {
        for y in 0..n {
            let src = &input[c * n * n + y * n..c * n * n + (y + 1) * n];
            out[c * n * n + (n - 1 - y) * n..c * n * n + (n - y) * n].copy_from_slice(src);
        }
    }
    out
}

#[cfg(test)]
mod tests;
