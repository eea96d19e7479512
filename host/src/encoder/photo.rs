//! From one capture photo to the estimate a plan is built from (steps 1 -> 2 of the pipeline).
//!
//! The encoder predicts the lobe's shape (GGX alpha, or Ward rho_d and alpha). The planner's mixture
//! warp also needs the *ratio* of diffuse to specular reflectance, which the GGX network does not
//! predict (with an unknown light intensity only ratios are observable). That ratio is read off the
//! photo by analysis by synthesis: the capture scene is linear in the BRDF, so with the encoder's
//! alpha the photo P is, pixel by pixel, P = a D + b S, where D and S are renders of the capture
//! scene with a unit diffuse term and a unit GGX specular term. A non-negative weighted least-squares
//! fit per channel gives a and b; the estimate is `ggx:alpha, diffuse = a / s, specular = b / s` with
//! s the summed luminance of a and b (the absolute scale, light times exposure, stays unknown and does
//! not matter to the warp).
//!
//! Weights are relative (1 / (P + eps)^2) so the few highlight pixels do not outvote the diffuse base,
//! and saturated pixels of 8-bit or 16-bit PNGs are left out of the fit (a clipped highlight would
//! bias b low).

use super::capture::render_capture;
use super::infer::Encoder;
use super::{load_photo, preprocess, resample_square, EncoderError, ModelKind, INPUT_SIZE};
use crate::brdf::analytic::{Ggx, Ward};
use crate::brdf::spec::Analytic;
use crate::plan::{Estimate, PlanError};
use crate::render::Image;
use glam::DVec3;
use std::path::Path;

/// A PNG channel at or above this linear value is taken as saturated (sRGB 253/255 = 0.982).
pub const PNG_SATURATION: f64 = 0.98;
/// Relative weight floor: eps = EPS_FRACTION x the channel's mean over the lit sphere.
const EPS_FRACTION: f64 = 0.05;

#[derive(Debug, thiserror::Error)]
pub enum PhotoError {
    #[error(transparent)]
    Encoder(#[from] EncoderError),
    #[error("{0}")]
    Fit(String),
}

impl From<PhotoError> for PlanError {
    fn from(e: PhotoError) -> Self {
        PlanError::Invalid(e.to_string())
    }
}

/// The diffuse/specular split read off the photo (GGX only).
#[derive(Clone, Debug)]
pub struct RatioFit {
    /// Fitted coefficients of the unit-diffuse and unit-specular renders, per channel (scale: the
    /// photo's light x exposure).
    pub diffuse_coeff: DVec3,
    pub specular_coeff: DVec3,
    /// Sphere pixels used, and those left out as saturated.
    pub pixels: usize,
    pub saturated: usize,
    /// RMS relative residual of the fit over the used pixels (how well one GGX lobe + diffuse
    /// explains the photo).
    pub rel_residual: f64,
}

/// What the photo says about the material.
#[derive(Clone, Debug)]
pub struct PhotoEstimate {
    pub estimate: Estimate,
    pub kind: ModelKind,
    /// The encoder's raw outputs, in `kind.outputs()` order.
    pub outputs: Vec<f64>,
    pub ratio: Option<RatioFit>,
}

impl PhotoEstimate {
    /// The estimate as a material spec (`ggx:alpha=...,diffuse=R/G/B,specular=R/G/B`).
    pub fn spec(&self) -> String {
        self.estimate.model.to_spec()
    }
}

/// Estimate from a photo file with a shipped model. PNG channels at or above `PNG_SATURATION` are
/// treated as clipped; EXR photos are linear and never clipped.
pub fn estimate_from_photo(path: &Path, model: ModelKind) -> Result<PhotoEstimate, PhotoError> {
    let photo = load_photo(path)?;
    let encoder = Encoder::shipped(model)?;
    let is_png = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    estimate_from_image(&photo, &encoder, is_png.then_some(PNG_SATURATION))
        .map_err(|e| prefix(e, &path.display().to_string()))
}

fn prefix(e: PhotoError, what: &str) -> PhotoError {
    match e {
        PhotoError::Fit(m) => PhotoError::Fit(format!("{what}: {m}")),
        other => other,
    }
}

/// Estimate from a linear photo in memory. `saturation`: channel values at or above it are clipped
/// (None for linear photos).
pub fn estimate_from_image(
    photo: &Image,
    encoder: &Encoder,
    saturation: Option<f64>,
) -> Result<PhotoEstimate, PhotoError> {
    let input = preprocess(photo).map_err(PhotoError::Fit)?;
    let outputs = encoder.estimate(&input)?;
    let (model, ratio) = match encoder.kind {
        ModelKind::Ward => {
            // rho_s = 1 - rho_d is the trained convention (encoder/dataset.rs).
            let (rho_d, alpha) = (outputs[0], outputs[1]);
            let model = Analytic::Ward(Ward {
                rho_d: DVec3::splat(rho_d),
                rho_s: DVec3::splat((1.0 - rho_d).max(0.0)),
                alpha,
            });
            (model, None)
        }
        ModelKind::Ggx => {
            let alpha = outputs[0];
            let fit = fit_ratio(photo, alpha, saturation)?;
            let lum = |v: DVec3| 0.2126 * v.x + 0.7152 * v.y + 0.0722 * v.z;
            // Only the ratio is known: scale so the two terms' luminances sum to 1. Guard beside
            // the division: fit_ratio never returns both terms zero for a lit photo, but a zero
            // sum must not make NaNs.
            let s = (lum(fit.specular_coeff) + lum(fit.diffuse_coeff)).max(f64::MIN_POSITIVE);
            let model = Analytic::Ggx(Ggx {
                alpha,
                diffuse: fit.diffuse_coeff / s,
                specular: fit.specular_coeff / s,
            });
            (model, Some(fit))
        }
    };
    Ok(PhotoEstimate {
        estimate: Estimate { model },
        kind: encoder.kind,
        outputs,
        ratio,
    })
}

/// Fit photo = a D + b S per channel (a, b >= 0) at the network's resolution.
pub fn fit_ratio(photo: &Image, alpha: f64, saturation: Option<f64>) -> Result<RatioFit, PhotoError> {
    let render = |spec: String| render_capture(&spec, 1.0).map_err(PhotoError::Fit);
    let d = render(format!("ggx:alpha={alpha},diffuse=1,specular=0"))?;
    let s = render(format!("ggx:alpha={alpha},diffuse=0,specular=1"))?;
    let p = resample_square(photo, INPUT_SIZE);
    // A block is saturated if any source pixel in it is: resample a 0/1 mask the same way.
    let clipped = saturation.map(|level| {
        let mut mask = photo.clone();
        for px in &mut mask.pixels {
            let hit = px.max_element() >= level;
            *px = DVec3::splat(if hit { 1.0 } else { 0.0 });
        }
        resample_square(&mask, INPUT_SIZE)
    });
    let lit: Vec<usize> = (0..p.pixels.len())
        .filter(|&i| d.pixels[i].max_element() > 0.0 || s.pixels[i].max_element() > 0.0)
        .collect();
    let used: Vec<usize> = lit
        .iter()
        .copied()
        .filter(|&i| clipped.as_ref().is_none_or(|m| m.pixels[i].x == 0.0))
        .collect();
    if used.len() < 16 {
        return Err(PhotoError::Fit(format!(
            "only {} unsaturated pixels on the lit sphere: not a capture photo, or overexposed",
            used.len()
        )));
    }
    let mut a = DVec3::ZERO;
    let mut b = DVec3::ZERO;
    let mut res2 = 0.0;
    for c in 0..3 {
        let mean = used.iter().map(|&i| p.pixels[i][c].max(0.0)).sum::<f64>() / used.len() as f64;
        let eps = (EPS_FRACTION * mean).max(1e-12);
        let w = |i: usize| (p.pixels[i][c].max(0.0) + eps).powi(-2);
        let (mut dd, mut ds, mut ss, mut dp, mut sp) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &i in &used {
            let (dv, sv, pv, wi) = (d.pixels[i][c], s.pixels[i][c], p.pixels[i][c], w(i));
            dd += wi * dv * dv;
            ds += wi * dv * sv;
            ss += wi * sv * sv;
            dp += wi * dv * pv;
            sp += wi * sv * pv;
        }
        let (ac, bc) = nnls2(dd, ds, ss, dp, sp);
        a[c] = ac;
        b[c] = bc;
        for &i in &used {
            let r = (ac * d.pixels[i][c] + bc * s.pixels[i][c] - p.pixels[i][c]) / (p.pixels[i][c].max(0.0) + eps);
            res2 += r * r;
        }
    }
    Ok(RatioFit {
        diffuse_coeff: a,
        specular_coeff: b,
        pixels: used.len(),
        saturated: lit.len() - used.len(),
        rel_residual: (res2 / (3 * used.len()) as f64).sqrt(),
    })
}

/// Non-negative least squares in two unknowns from the normal equations
/// [dd ds; ds ss] (a, b) = (dp, sp). The unconstrained solution is used when it is non-negative;
/// otherwise the better of the two one-variable fits. Guard: a singular system (D and S parallel,
/// or empty) falls through to the one-variable fits, whose denominators are checked.
fn nnls2(dd: f64, ds: f64, ss: f64, dp: f64, sp: f64) -> (f64, f64) {
    let det = dd * ss - ds * ds;
    if det > 1e-12 * dd * ss {
        let a = (dp * ss - sp * ds) / det;
        let b = (sp * dd - dp * ds) / det;
        if a >= 0.0 && b >= 0.0 {
            return (a, b);
        }
    }
    // Objective up to a constant: x^2 xx - 2 x xp for a single variable x.
    let only_a = if dd > 0.0 { (dp / dd).max(0.0) } else { 0.0 };
    let only_b = if ss > 0.0 { (sp / ss).max(0.0) } else { 0.0 };
    let cost_a = only_a * only_a * dd - 2.0 * only_a * dp;
    let cost_b = only_b * only_b * ss - 2.0 * only_b * sp;
    if cost_a <= cost_b {
        (only_a, 0.0)
    } else {
        (0.0, only_b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lum(v: DVec3) -> f64 {
        0.2126 * v.x + 0.7152 * v.y + 0.0722 * v.z
    }

    #[test]
    fn nnls2_solves_the_unconstrained_case_and_clamps_negative_ones() {
        // a = 2, b = 3 exactly: dd = 1, ds = 0.5, ss = 1 -> dp = 2 + 1.5, sp = 1 + 3.
        let (a, b) = nnls2(1.0, 0.5, 1.0, 3.5, 4.0);
        assert!((a - 2.0).abs() < 1e-12 && (b - 3.0).abs() < 1e-12, "{a} {b}");
        // The unconstrained solution has b < 0: the constrained optimum is b = 0, a = dp / dd.
        let (a, b) = nnls2(1.0, 0.5, 1.0, 1.0, -1.0);
        assert_eq!(b, 0.0);
        assert!((a - 1.0).abs() < 1e-12);
        // Empty system: zero, not NaN.
        assert_eq!(nnls2(0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.0));
    }

    #[test]
    fn the_ratio_of_a_rendered_ggx_photo_is_recovered_at_its_alpha() {
        // A photo of a known GGX material (under 3x light, which must cancel): with the true alpha,
        // the fit recovers diffuse / specular per channel.
        let diffuse = DVec3::new(0.2, 0.1, 0.05);
        let specular = DVec3::new(0.9, 0.8, 0.7);
        for alpha in [0.05, 0.3] {
            let spec = format!(
                "ggx:alpha={alpha},diffuse={}/{}/{},specular={}/{}/{}",
                diffuse.x, diffuse.y, diffuse.z, specular.x, specular.y, specular.z
            );
            let photo = render_capture(&spec, 3.0).unwrap();
            let fit = fit_ratio(&photo, alpha, None).unwrap();
            let got = fit.diffuse_coeff / fit.specular_coeff;
            let want = diffuse / specular;
            for c in 0..3 {
                assert!(
                    (got[c] / want[c] - 1.0).abs() < 0.02,
                    "alpha {alpha} channel {c}: ratio {} vs {}",
                    got[c],
                    want[c]
                );
            }
            assert!(fit.rel_residual < 0.02, "residual {}", fit.rel_residual);
            assert_eq!(fit.saturated, 0);
        }
    }

    #[test]
    fn saturated_pixels_are_left_out_and_a_clipped_highlight_does_not_bias_the_ratio() {
        let spec = "ggx:alpha=0.1,diffuse=0.1,specular=1";
        let mut photo = render_capture(spec, 1.0).unwrap();
        // Expose so the diffuse base sits near mid-grey and the highlight clips at 1.0 (an 8-bit PNG).
        let base = photo.pixels.iter().map(|p| lum(*p)).fold(0.0, f64::max);
        let scale = 8.0 / base;
        for p in &mut photo.pixels {
            *p = (*p * scale).min(DVec3::ONE);
        }
        let fit = fit_ratio(&photo, 0.1, Some(PNG_SATURATION)).unwrap();
        assert!(fit.saturated > 0, "the clipped highlight was not detected");
        let ratio = lum(fit.diffuse_coeff) / lum(fit.specular_coeff);
        assert!((ratio / 0.1 - 1.0).abs() < 0.15, "ratio {ratio} vs 0.1");
        // Without the saturation rule the clipped highlight drags the specular term down.
        let naive = fit_ratio(&photo, 0.1, None).unwrap();
        let naive_ratio = lum(naive.diffuse_coeff) / lum(naive.specular_coeff);
        assert!(
            (naive_ratio / 0.1 - 1.0).abs() > (ratio / 0.1 - 1.0).abs(),
            "saturation rule did not help: {naive_ratio} vs {ratio}"
        );
    }

    #[test]
    fn a_diffuse_only_photo_gives_a_finite_estimate_with_a_negligible_specular_term() {
        let photo = render_capture("lambert:albedo=0.5/0.4/0.3", 1.0).unwrap();
        let encoder = Encoder::shipped(ModelKind::Ggx).unwrap();
        let est = estimate_from_image(&photo, &encoder, None).unwrap();
        let Analytic::Ggx(g) = &est.estimate.model else {
            panic!("GGX encoder gave {:?}", est.estimate.model)
        };
        assert!(g.alpha.is_finite() && g.diffuse.is_finite() && g.specular.is_finite());
        assert!(lum(g.diffuse) > 10.0 * lum(g.specular), "{g:?}");
    }

    #[test]
    fn a_black_or_tiny_photo_is_a_clear_error() {
        let encoder = Encoder::shipped(ModelKind::Ggx).unwrap();
        let black = Image::new(64, 64);
        let e = estimate_from_image(&black, &encoder, None).unwrap_err().to_string();
        assert!(e.contains("black"), "{e}");
    }
}
