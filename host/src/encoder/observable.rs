//! What a capture photo can show of a BRDF, and the GGX alpha that this alone supports.
//!
//! The capture (`examples/capture.toml`) looks at the sphere orthographically with a distant point
//! light 30 deg off the view axis. The view and light directions are (nearly) the same at every pixel,
//! so every pixel sees the BRDF at one angle between wi and wo: theta_d is about 15 deg everywhere,
//! and the photo is the slice f(theta_h, theta_d ~ 15 deg, phi_d) of the four-dimensional BRDF.
//! The encoder's MERL label is `brdf::fit` over the whole hemisphere (theta_i up to 80 deg), which
//! also weighs what happens at grazing angles, where the photo has no pixel.
//!
//! `observable_fit` fits GGX to the photo's own direction pairs, one pair per lit pixel, with the loss
//! of `brdf::fit`. Where its alpha and the label part, two materials that give the same photo can carry
//! labels that far apart, and no encoder can read the label off the photo: a bound on what an encoder
//! can reach, not a property of one network.

use super::capture::{capture_scene, ggx_alpha};
use super::INPUT_SIZE;
use crate::brdf::fit::{fit_samples, FitModel, FitResult};
use crate::brdf::Material;
use crate::render::renderer::Frame;
use glam::DVec3;

/// The local (wi, wo) of every lit, visible pixel of the capture photo at `size` x `size` (pixel
/// centres), in the renderer's own shading frame (`render::renderer::Frame`), so the pairs are the
/// ones the rendered photo evaluated.
pub fn capture_pairs(size: usize) -> Result<Vec<(DVec3, DVec3)>, String> {
    let scene = capture_scene("lambert:albedo=0.5", size)?;
    let mut pairs = Vec::new();
    for y in 0..size {
        for x in 0..size {
            let ray = scene.camera.ray(x as f64 + 0.5, y as f64 + 0.5);
            let Some(hit) = scene.shape.intersect(&ray) else {
                continue;
            };
            let frame = Frame::new(hit.normal);
            let wo = frame.to_local(-ray.dir);
            for light in &scene.lights {
                if let Some((wi_world, _)) = light.incident(hit.point) {
                    let wi = frame.to_local(wi_world);
                    // Guard: a pixel the light does not reach, or seen edge-on, shows nothing.
                    if wi.z > 0.0 && wo.z > 0.0 {
                        pairs.push((wi, wo));
                    }
                }
            }
        }
    }
    if pairs.is_empty() {
        return Err("the capture scene lights no visible pixel".into());
    }
    Ok(pairs)
}

/// `model` fitted to `material` over the capture photo's direction pairs at the network's resolution
/// (every lit pixel weighs the same, as in the photo).
pub fn observable_fit(material: &dyn Material, model: FitModel) -> Result<FitResult, String> {
    let pairs = capture_pairs(INPUT_SIZE)?;
    let values: Vec<DVec3> = pairs.iter().map(|&(wi, wo)| material.eval(wi, wo)).collect();
    let weights = vec![1.0; pairs.len()];
    Ok(fit_samples(pairs, &values, &weights, model))
}

/// The alpha of `observable_fit` (GGX): the GGX roughness the capture photo of `material` supports.
pub fn observable_alpha(material: &dyn Material) -> Result<f64, String> {
    ggx_alpha(&observable_fit(material, FitModel::Ggx)?)
}

/// The half angle theta_d (radians) of a pair: half the angle between wi and wo.
pub fn theta_d(wi: DVec3, wo: DVec3) -> f64 {
    0.5 * wi.dot(wo).clamp(-1.0, 1.0).acos()
}

#[cfg(test)]
mod tests {
    use super::super::capture::ggx_fit_alpha;
    use super::*;
    use crate::brdf::spec::parse_material;

    #[test]
    fn the_photo_sees_one_theta_d() {
        let pairs = capture_pairs(INPUT_SIZE).unwrap();
        // About pi/4 of the 64 x 64 frame is sphere, and most of it is lit (light 30 deg off axis).
        assert!(pairs.len() > 2500 && pairs.len() < 3300, "{} pairs", pairs.len());
        let (lo, hi) = pairs.iter().fold((f64::MAX, f64::MIN), |(lo, hi), &(wi, wo)| {
            let d = theta_d(wi, wo).to_degrees();
            (lo.min(d), hi.max(d))
        });
        // The light is 10 units away from a unit sphere, so the angle varies a little around 15 deg.
        assert!(lo > 12.0 && hi < 18.0, "theta_d in [{lo}, {hi}] deg");
        // ... while theta_h spans the highlight (to the pixel pitch, ~1 deg at 64 px) to the terminator.
        let th = |&(wi, wo): &(DVec3, DVec3)| (wi + wo).normalize().z.acos().to_degrees();
        let max_h = pairs.iter().map(th).fold(0.0, f64::max);
        let min_h = pairs.iter().map(th).fold(90.0, f64::min);
        assert!(min_h < 1.5 && max_h > 70.0, "theta_h in [{min_h}, {max_h}] deg");
        // The figures the model card quotes (`-- --nocapture` shows them).
        println!(
            "{} pairs; theta_d in [{lo:.1}, {hi:.1}] deg, theta_h in [{min_h:.1}, {max_h:.1}] deg",
            pairs.len()
        );
    }

    #[test]
    fn a_ggx_material_is_observed_as_itself() {
        // One GGX lobe on a Lambert base is inside the fit's family: the slice gives its alpha,
        // as the hemisphere fit does, from a mirror-like lobe to a rough one.
        for alpha in [0.01, 0.1, 0.5] {
            let m = parse_material(&format!("ggx:alpha={alpha},diffuse=0.1,specular=0.8")).unwrap();
            let seen = observable_alpha(m.as_ref()).unwrap();
            let whole = ggx_fit_alpha(m.as_ref()).unwrap();
            assert!((seen / alpha - 1.0).abs() < 0.05, "alpha {alpha}: slice fit {seen}");
            assert!(
                (whole / alpha - 1.0).abs() < 0.05,
                "alpha {alpha}: hemisphere fit {whole}"
            );
        }
    }
}
