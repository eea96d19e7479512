//! A linear RGB image (row 0 at the top) and its files: OpenEXR (linear, f32) and PNG (tone-mapped
//! sRGB, 8 bit). Files are written to a temporary name beside the target and then renamed, so a
//! failed or interrupted write never leaves a half-written image under the requested name.

use super::RenderError;
use glam::DVec3;
use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// Row-major, row 0 is the top of the picture.
    pub pixels: Vec<DVec3>,
}

/// The file formats, chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    Exr,
    Png,
}

impl ImageFormat {
    pub fn from_path(path: &Path) -> Result<Self, RenderError> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("exr") => Ok(ImageFormat::Exr),
            Some("png") => Ok(ImageFormat::Png),
            _ => Err(RenderError::image(path, "unknown image format (use .exr or .png)")),
        }
    }
}

impl Image {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![DVec3::ZERO; width * height],
        }
    }

    pub fn get(&self, x: usize, y: usize) -> DVec3 {
        self.pixels[y * self.width + x]
    }

    /// Read an EXR (linear) or PNG (sRGB-encoded, decoded to linear) file.
    pub fn read(path: &Path) -> Result<Self, RenderError> {
        match ImageFormat::from_path(path)? {
            ImageFormat::Exr => read_exr(path),
            ImageFormat::Png => read_png(path),
        }
    }

    /// Write by extension: EXR keeps the linear values, PNG is tone-mapped (see `tone_map`).
    pub fn write(&self, path: &Path) -> Result<(), RenderError> {
        let format = ImageFormat::from_path(path)?;
        crate::fsio::write_atomically(path, |tmp| match format {
            ImageFormat::Exr => self.write_exr(tmp),
            ImageFormat::Png => self.write_png(tmp),
        })
        .map_err(|e| RenderError::image(path, e))
    }

    fn write_exr(&self, tmp: &Path) -> Result<(), String> {
        use exr::prelude::{Blocks, Encoding, Layer, LayerAttributes, SpecificChannels, Vec2, WritableImage};
        let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
            let p = self.get(x, y);
            (p.x as f32, p.y as f32, p.z as f32)
        });
        let mut layer = Layer::new(
            (self.width, self.height),
            LayerAttributes::named("rgb"),
            Encoding::SMALL_LOSSLESS,
            channels,
        );
        // Scanline blocks keep the file readable by every EXR reader.
        layer.encoding.blocks = Blocks::ScanLines;
        exr::prelude::Image::from_layer(layer)
            .write()
            .to_file(tmp)
            .map_err(|e| e.to_string())
    }

    fn write_png(&self, tmp: &Path) -> Result<(), String> {
        save_rgb8_png(tmp, self.width, self.height, self.to_srgb8())
    }

    /// The 8-bit sRGB bytes of the tone-mapped image (RGBRGB..., row 0 first): what PNG and FLIP see.
    pub fn to_srgb8(&self) -> Vec<u8> {
        self.pixels
            .iter()
            .flat_map(|p| [p.x, p.y, p.z])
            .map(|v| (tone_map(v) * 255.0).round() as u8)
            .collect()
    }
}

/// Linear value -> display value in [0, 1]: clamp to [0, 1], then the sRGB transfer curve. The clamp
/// is the whole tone map: renders are meant to be exposed (scene intensities, `exposure`) so that the
/// sample stays below 1. NaN maps to 0.
pub fn tone_map(linear: f64) -> f64 {
    let v = if linear.is_nan() { 0.0 } else { linear.clamp(0.0, 1.0) };
    if v <= 0.0031308 {
        12.92 * v
    } else {
        // The formula gives 1 - 1e-16 at v = 1; clamp so that white stays exactly white.
        if v >= 1.0 {
            1.0
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        }
    }
}

/// The inverse of the sRGB transfer curve, for reading PNG files back to linear values.
pub fn srgb_to_linear(v: f64) -> f64 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Write display-ready 8-bit RGB bytes (RGBRGB..., row 0 first) as a PNG, through a temporary name.
pub fn write_rgb8_png(path: &Path, width: usize, height: usize, bytes: Vec<u8>) -> Result<(), RenderError> {
    crate::fsio::write_atomically(path, |tmp| save_rgb8_png(tmp, width, height, bytes))
        .map_err(|e| RenderError::image(path, e))
}

fn save_rgb8_png(path: &Path, width: usize, height: usize, bytes: Vec<u8>) -> Result<(), String> {
    let w = u32::try_from(width).map_err(|_| "image too wide")?;
    let h = u32::try_from(height).map_err(|_| "image too tall")?;
    let buf = image::RgbImage::from_raw(w, h, bytes).ok_or("pixel buffer size mismatch")?;
    buf.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| e.to_string())
}

/// `out.exr` -> `.out.exr.tmp-PID` in the same directory, so the final rename stays on one filesystem.
fn read_exr(path: &Path) -> Result<Image, RenderError> {
    use exr::prelude::{read_first_rgba_layer_from_file, Vec2};
    let read = read_first_rgba_layer_from_file(
        path,
        |res: Vec2<usize>, _| Image::new(res.width(), res.height()),
        |img: &mut Image, pos: Vec2<usize>, (r, g, b, _a): (f32, f32, f32, f32)| {
            let w = img.width;
            img.pixels[pos.y() * w + pos.x()] = DVec3::new(r as f64, g as f64, b as f64);
        },
    )
    .map_err(|e| RenderError::image(path, e))?;
    let img = read.layer_data.channel_data.pixels;
    if img.width == 0 || img.height == 0 {
        return Err(RenderError::image(path, "image has no pixels"));
    }
    Ok(img)
}

fn read_png(path: &Path) -> Result<Image, RenderError> {
    let decoded = image::ImageReader::open(path)
        .map_err(|e| RenderError::image(path, e))?
        .with_guessed_format()
        .map_err(|e| RenderError::image(path, e))?
        .decode()
        .map_err(|e| RenderError::image(path, e))?
        .to_rgb8();
    let (w, h) = (decoded.width() as usize, decoded.height() as usize);
    let pixels = decoded
        .pixels()
        .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) / 255.0)
        .map(|c| DVec3::new(srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z)))
        .collect();
    Ok(Image {
        width: w,
        height: h,
        pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_round_trips_and_png_is_tone_mapped() {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut img = Image::new(3, 2);
        img.pixels[1] = DVec3::new(0.25, 2.5, 0.125);
        img.pixels[5] = DVec3::new(0.5, 0.0, 7.0);
        let exr = dir.path().join("a.exr");
        img.write(&exr).expect("write exr");
        let back = Image::read(&exr).expect("read exr");
        assert_eq!(back, img, "values representable in f32 survive exactly");
        let png = dir.path().join("a.png");
        img.write(&png).expect("write png");
        let back = Image::read(&png).expect("read png");
        assert_eq!((back.width, back.height), (3, 2));
        // 0.25 -> sRGB 137/255 -> ~0.2502; saturated values clamp to 1.
        assert!((back.pixels[1].x - 0.25).abs() < 3e-3, "{}", back.pixels[1].x);
        assert_eq!(back.pixels[1].y, 1.0);
        let names: Vec<_> = std::fs::read_dir(dir.path()).expect("ls").flatten().collect();
        assert_eq!(names.len(), 2, "no temporary files left behind");
        let err = img
            .write(&dir.path().join("a.jpg"))
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.ends_with("unknown image format (use .exr or .png)"), "{err}");
        assert!(tone_map(f64::NAN) == 0.0 && tone_map(-1.0) == 0.0 && tone_map(5.0) == 1.0);
    }
}
