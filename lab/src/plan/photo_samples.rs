//! The capture photo's pixels as BRDF samples, for the reconstruction's fitted prior.
//!
//! Why: a coarse plan (2 x 2 per slice) measures the peak and the far field of a sharp lobe but
//! not its shoulder between them, and the two-lobe fit extrapolates the shoulder from its shape
//! alone. The capture photo of the same sample has already seen that shoulder: under one light and
//! an orthographic view every sphere pixel is one direction pair, at one fixed half-angle between
//! the light and the view (15 degrees in `examples/capture.toml`) and half-vector angles from the
//! highlight's centre out to the rim. Each pixel is P = s f(wi, wo) cos(theta_i) E(p), with E the
//! light's irradiance at the point (known from the scene) and s the light x exposure scale;
//! `PhotoSamples` holds (wi, wo) and P / (cos(theta_i) E) = s f. `append_weighted` takes s = 1, a
//! calibrated capture (as `gonio-lab tradeoff`'s rendered one is); `trials::PhotoTwoLobesPrior` is a trial
//! (docs/tradeoff/README.md), and an uncalibrated photo would need s fitted too.
//!
//! The geometry is the renderer's own (camera ray through the pixel centre, the shape's hit, the
//! shading frame), so a photo rendered from the scene with one sample per pixel maps exactly.

use glam::DVec3;
use gonio::render::renderer::Frame;
use gonio::render::{Image, Scene};

/// Pixels with either direction closer to the horizon than this (cos theta) are left out: there
/// the value divides by a small cosine, and a real photo's rim mixes in the background.
pub const MIN_COS: f64 = 0.17364817766693041; // cos 80 deg

/// The photo's usable pixels as (wi, wo) pairs in the sample's local frame and their values s f.
#[derive(Clone, Debug, Default)]
pub struct PhotoSamples {
    pub pairs: Vec<(DVec3, DVec3)>,
    pub values: Vec<DVec3>,
}

impl PhotoSamples {
    pub fn len(&self) -> usize {
        self.pairs.len()
    }
    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }
}

/// Append `photo`'s samples to a fit's (pairs, values, weights), each photo sample weighing the
/// same and all of them together `share` times the weights already there. The photo's values are
/// s f with the scale s taken as 1: the capture is calibrated (as `gonio tradeoff`'s rendered one
/// is, whose light delivers exactly the irradiance divided out); an uncalibrated photo would need
/// s fitted too. Nothing is appended for an empty photo or a fit without weight.
pub fn append_weighted(fit: &mut (Vec<(DVec3, DVec3)>, Vec<DVec3>, Vec<f64>), photo: &PhotoSamples, share: f64) {
    let total: f64 = fit.2.iter().filter(|w| w.is_finite() && **w > 0.0).sum();
    if photo.is_empty() || !(total > 0.0) {
        return;
    }
    // Guard: photo.len() >= 1 here.
    let w = share * total / photo.len() as f64;
    fit.0.extend_from_slice(&photo.pairs);
    fit.1.extend_from_slice(&photo.values);
    fit.2.extend(std::iter::repeat_n(w, photo.len()));
}

/// Read `photo` (linear, taken of `scene`'s object under its one point or directional light, at
/// the scene camera's size) every `stride` pixels in x and y. Pixels at or above `saturation` in
/// any channel are left out (clipped), as are misses, pixels beyond `MIN_COS` and pixels the light
/// does not reach. Errors: the scene must have exactly one light and no environment, the photo the
/// camera's size.
pub fn photo_samples(
    scene: &Scene,
    photo: &Image,
    saturation: Option<f64>,
    stride: usize,
) -> Result<PhotoSamples, String> {
    if scene.lights.len() != 1 || scene.environment.is_some() {
        return Err("photo samples need a capture scene with exactly one light and no environment".into());
    }
    if photo.width != scene.camera.width || photo.height != scene.camera.height {
        return Err(format!(
            "photo is {} x {}, the capture scene's camera {} x {}",
            photo.width, photo.height, scene.camera.width, scene.camera.height
        ));
    }
    let light = &scene.lights[0];
    let stride = stride.max(1);
    let mut out = PhotoSamples::default();
    for y in (stride / 2..photo.height).step_by(stride) {
        for x in (stride / 2..photo.width).step_by(stride) {
            let p = photo.pixels[y * photo.width + x];
            if !p.is_finite() || saturation.is_some_and(|s| p.max_element() >= s) {
                continue;
            }
            let ray = scene.camera.ray(x as f64 + 0.5, y as f64 + 0.5);
            let Some(hit) = scene.shape.intersect(&ray) else {
                continue;
            };
            let Some((wi_world, irradiance)) = light.incident(hit.point) else {
                continue;
            };
            let frame = Frame::new(hit.normal);
            let (wi, wo) = (frame.to_local(wi_world), frame.to_local(-ray.dir));
            if wi.z < MIN_COS || wo.z < MIN_COS || !(irradiance > 0.0) {
                continue;
            }
            // Guard: wi.z >= MIN_COS and irradiance > 0, so the division is finite.
            out.pairs.push((wi, wo));
            out.values.push(p.max(DVec3::ZERO) / (wi.z * irradiance));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio::encoder::capture::capture_scene;
    use gonio::render::render_with;

    #[test]
    fn appended_photo_samples_weigh_their_share_of_the_fit() {
        let photo = PhotoSamples {
            pairs: vec![(DVec3::Z, DVec3::Z); 4],
            values: vec![DVec3::ONE; 4],
        };
        let mut fit = (vec![(DVec3::Z, DVec3::Z); 2], vec![DVec3::ONE; 2], vec![1.0, f64::NAN]);
        append_weighted(&mut fit, &photo, 3.0);
        assert_eq!((fit.0.len(), fit.1.len()), (6, 6));
        // The NaN weight counts as none: the photo's four samples share 3 x 1.
        assert_eq!(&fit.2[2..], &[0.75; 4]);
        // An empty photo, or a fit without weight, appends nothing.
        let mut none = (vec![], vec![], vec![]);
        append_weighted(&mut none, &photo, 3.0);
        assert!(none.0.is_empty());
        append_weighted(&mut fit, &PhotoSamples::default(), 3.0);
        assert_eq!(fit.2.len(), 6);
    }

    #[test]
    fn a_photo_of_another_size_or_scene_is_refused() {
        let scene = capture_scene("lambert:albedo=0.5", 16).unwrap();
        let e = photo_samples(&scene, &Image::new(8, 8), None, 1).unwrap_err();
        assert!(e.contains("8 x 8"), "{e}");
        let mut no_light = capture_scene("lambert:albedo=0.5", 16).unwrap();
        no_light.lights.clear();
        assert!(photo_samples(&no_light, &Image::new(16, 16), None, 1).is_err());
    }

    #[test]
    fn saturated_and_grazing_pixels_are_left_out() {
        let scene = capture_scene("ggx:alpha=0.05,diffuse=0.2,specular=1", 64).unwrap();
        let photo = render_with(&scene, &scene.settings, &|| {}).unwrap();
        let all = photo_samples(&scene, &photo, None, 1).unwrap();
        let clipped = photo_samples(&scene, &photo, Some(0.5), 1).unwrap();
        assert!(
            !clipped.is_empty() && clipped.len() < all.len(),
            "{} of {}",
            clipped.len(),
            all.len()
        );
        for (wi, wo) in &all.pairs {
            assert!(wi.z >= MIN_COS && wo.z >= MIN_COS);
        }
        // Every 2nd pixel in x and y: about a quarter of the samples.
        let half = photo_samples(&scene, &photo, None, 2).unwrap();
        assert!(
            (half.len() as f64 / all.len() as f64 - 0.25).abs() < 0.03,
            "{} of {}",
            half.len(),
            all.len()
        );
    }

    #[test]
    fn a_rendered_capture_photo_reads_back_as_the_brdf_at_every_pixel() {
        for spec in [
            "ggx:alpha=0.05,diffuse=0.2/0.1/0.05,specular=0.8",
            "nbrdf:gold-metallic-paint3",
        ] {
            let scene = capture_scene(spec, 64).unwrap();
            let photo = render_with(&scene, &scene.settings, &|| {}).unwrap();
            let samples = photo_samples(&scene, &photo, None, 1).unwrap();
            assert!(samples.len() > 1000, "{}", samples.len());
            let mut worst = 0.0f64;
            for (&(wi, wo), v) in samples.pairs.iter().zip(&samples.values) {
                let f = scene.material.eval(wi, wo);
                worst = worst.max(((*v - f).abs() / (f + DVec3::splat(1e-9))).max_element());
            }
            assert!(worst < 1e-9, "{spec}: worst relative error {worst}");
        }
    }
}
