//! Fit an analytic model (GGX or Ward) to any material: least squares on log(1 + f cos theta_o),
//! the log-mapped cosine-weighted values the paper (and the neural fits) train on, which keeps a
//! bright specular peak from drowning the diffuse part.
//!
//! Direction set (isotropic materials, so phi_i = 0 and phi_o in [0, 180] deg by symmetry):
//! theta_i = 0, 10, ..., 80 deg (9 values) x theta_o = 0, 5, ..., 85 deg (18) x phi_o = 0, 15, ..., 180 deg
//! (13): 2106 pairs.
//!
//! Model: f = kd / pi + ks b(alpha; wi, wo), with b the GGX or Ward specular factor and kd, ks >= 0
//! per RGB channel. For each alpha the two colours are linear, so they are solved per channel by
//! projected Gauss-Newton from a linear least-squares start; alpha is searched on a log grid in
//! [2e-3, 1] (just above the mirror threshold) and refined by golden section.

use super::analytic::{ggx_specular, ward_specular, Ggx, Ward};
use super::frame::from_spherical;
use super::spec::Analytic;
use super::Material;
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitModel {
    Ggx,
    Ward,
}

#[derive(Clone, Debug)]
pub struct FitResult {
    pub model: Analytic,
    /// RMS of the residuals of log(1 + f cos theta_o) over the direction set and channels.
    pub rms_log_error: f64,
    pub pairs: usize,
}

const ALPHA_MIN: f64 = 2e-3;
const ALPHA_MAX: f64 = 1.0;

/// The documented direction set.
pub fn fit_directions() -> Vec<(DVec3, DVec3)> {
    let mut pairs = Vec::new();
    for ti in (0..=80).step_by(10) {
        let wi = from_spherical((ti as f64).to_radians(), 0.0);
        for to in (0..=85).step_by(5) {
            for po in (0..=180).step_by(15) {
                pairs.push((wi, from_spherical((to as f64).to_radians(), (po as f64).to_radians())));
            }
        }
    }
    pairs
}

struct Problem {
    pairs: Vec<(DVec3, DVec3)>,
    cos_o: Vec<f64>,
    /// Each pair's weight in the loss (1 for the documented direction set).
    weight: Vec<f64>,
    /// log(1 + f cos) of the target, per channel.
    target: [Vec<f64>; 3],
    model: FitModel,
}

impl Problem {
    fn basis(&self, alpha: f64) -> Vec<f64> {
        let b = match self.model {
            FitModel::Ggx => ggx_specular,
            FitModel::Ward => ward_specular,
        };
        self.pairs.iter().map(|&(wi, wo)| b(wi, wo, alpha)).collect()
    }

    /// Best (kd, ks) for one channel and the sum of squared residuals.
    fn solve_channel(&self, c: usize, spec: &[f64]) -> (f64, f64, f64) {
        let t = &self.target[c];
        let residuals = |kd: f64, ks: f64| -> f64 {
            let mut s = 0.0;
            for i in 0..spec.len() {
                let f = kd * FRAC_1_PI + ks * spec[i];
                s += self.weight[i] * ((f * self.cos_o[i]).ln_1p() - t[i]).powi(2);
            }
            s
        };
        // Start: linear least squares on f cos = exp(t) - 1, projected to >= 0.
        let (mut a11, mut a12, mut a22, mut r1, mut r2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..spec.len() {
            let (x1, x2) = (FRAC_1_PI * self.cos_o[i], spec[i] * self.cos_o[i]);
            let (y, w) = (t[i].exp_m1(), self.weight[i]);
            a11 += w * x1 * x1;
            a12 += w * x1 * x2;
            a22 += w * x2 * x2;
            r1 += w * x1 * y;
            r2 += w * x2 * y;
        }
        let (mut kd, mut ks) = solve2(a11, a12, a22, r1, r2);
        let mut best = residuals(kd, ks);
        for _ in 0..30 {
            let (mut a11, mut a12, mut a22, mut g1, mut g2) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for i in 0..spec.len() {
                let f = kd * FRAC_1_PI + ks * spec[i];
                let denom = 1.0 + f * self.cos_o[i];
                let r = denom.ln() - t[i];
                let (j1, j2) = (FRAC_1_PI * self.cos_o[i] / denom, spec[i] * self.cos_o[i] / denom);
                let w = self.weight[i];
                a11 += w * j1 * j1;
                a12 += w * j1 * j2;
                a22 += w * j2 * j2;
                g1 += w * j1 * r;
                g2 += w * j2 * r;
            }
            let (d1, d2) = solve2(a11, a12, a22, g1, g2);
            // Step halving keeps the loss monotone; the projection keeps the colours physical.
            let mut step = 1.0;
            let mut improved = false;
            while step > 1e-6 {
                let (nk, ns) = ((kd - step * d1).max(0.0), (ks - step * d2).max(0.0));
                let r = residuals(nk, ns);
                if r < best {
                    (kd, ks, best) = (nk, ns, r);
                    improved = true;
                    break;
                }
                step *= 0.5;
            }
            if !improved {
                break;
            }
        }
        (kd, ks, best)
    }

    fn solve(&self, alpha: f64) -> (DVec3, DVec3, f64) {
        let spec = self.basis(alpha);
        let mut kd = [0.0; 3];
        let mut ks = [0.0; 3];
        let mut loss = 0.0;
        for c in 0..3 {
            let (d, s, l) = self.solve_channel(c, &spec);
            kd[c] = d;
            ks[c] = s;
            loss += l;
        }
        (DVec3::from(kd), DVec3::from(ks), loss)
    }
}

/// 2x2 symmetric solve; a singular system (a basis that vanishes on the direction set) gives 0.
fn solve2(a11: f64, a12: f64, a22: f64, r1: f64, r2: f64) -> (f64, f64) {
    let det = a11 * a22 - a12 * a12;
    if !(det.abs() > 1e-300) {
        return (0.0, 0.0);
    }
    (
        ((a22 * r1 - a12 * r2) / det).max(0.0),
        ((a11 * r2 - a12 * r1) / det).max(0.0),
    )
}

/// Fit `model` to `material` over the documented direction set.
pub fn fit(material: &dyn Material, model: FitModel) -> FitResult {
    let pairs = fit_directions();
    let values: Vec<DVec3> = pairs.iter().map(|&(wi, wo)| material.eval(wi, wo)).collect();
    let weights = vec![1.0; pairs.len()];
    fit_samples(pairs, &values, &weights, model)
}

/// Fit `model` to sampled values `values[i]` = f(pairs[i]) (e.g. a scan's measurements), with the
/// loss of `fit` and pair i weighted by `weights[i]` (e.g. the solid angle a sample stands for, so
/// samples crowded into a peak do not outvote the rest of the hemisphere). Directions below the
/// horizon carry cos_o = 0 and drop out of the loss (both logs are 0). Panics if the lengths differ.
pub fn fit_samples(pairs: Vec<(DVec3, DVec3)>, values: &[DVec3], weights: &[f64], model: FitModel) -> FitResult {
    assert_eq!(pairs.len(), values.len(), "one value per direction pair");
    assert_eq!(pairs.len(), weights.len(), "one weight per direction pair");
    // Guard: a negative or non-finite weight counts as 0.
    let weight: Vec<f64> = weights
        .iter()
        .map(|&w| if w.is_finite() { w.max(0.0) } else { 0.0 })
        .collect();
    // Guard: a direction below the horizon (or a non-finite one) has weight cos = 0.
    let cos_o: Vec<f64> = pairs
        .iter()
        .map(|(_, wo)| if wo.z > 0.0 && wo.z.is_finite() { wo.z } else { 0.0 })
        .collect();
    // Guard: a non-finite reading (a fault upstream) counts as 0, as a negative one does.
    let values: Vec<DVec3> = values
        .iter()
        .map(|v| if v.is_finite() { *v } else { DVec3::ZERO })
        .collect();
    let target = [0, 1, 2].map(|c| {
        values
            .iter()
            .zip(&cos_o)
            .map(|(v, co)| (v[c].max(0.0) * co).ln_1p())
            .collect()
    });
    let problem = Problem {
        pairs,
        cos_o,
        weight,
        target,
        model,
    };

    // Coarse log grid, then golden section between the neighbours of the best node.
    let steps = 40;
    let grid: Vec<f64> = (0..=steps)
        .map(|i| (ALPHA_MIN.ln() + (ALPHA_MAX / ALPHA_MIN).ln() * i as f64 / steps as f64).exp())
        .collect();
    let losses: Vec<f64> = grid.iter().map(|&a| problem.solve(a).2).collect();
    let best = (0..grid.len())
        .min_by(|&a, &b| losses[a].total_cmp(&losses[b]))
        .unwrap_or(0);
    let (mut lo, mut hi) = (grid[best.saturating_sub(1)].ln(), grid[(best + 1).min(steps)].ln());
    let phi = 0.5 * (5f64.sqrt() - 1.0);
    let loss_at = |la: f64| problem.solve(la.exp()).2;
    let (mut x1, mut x2) = (hi - phi * (hi - lo), lo + phi * (hi - lo));
    let (mut f1, mut f2) = (loss_at(x1), loss_at(x2));
    for _ in 0..40 {
        if f1 < f2 {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - phi * (hi - lo);
            f1 = loss_at(x1);
        } else {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + phi * (hi - lo);
            f2 = loss_at(x2);
        }
    }
    let alpha = (0.5 * (lo + hi)).exp();
    let (kd, ks, loss) = problem.solve(alpha);
    let n = problem.pairs.len();
    let model = match model {
        FitModel::Ggx => Analytic::Ggx(Ggx {
            alpha,
            diffuse: kd,
            specular: ks,
        }),
        FitModel::Ward => Analytic::Ward(Ward {
            rho_d: kd,
            rho_s: ks,
            alpha,
        }),
    };
    FitResult {
        model,
        rms_log_error: (loss / (3 * n.max(1)) as f64).sqrt(),
        pairs: n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_its_own_parameters() {
        let ggx = Ggx {
            alpha: 0.15,
            diffuse: DVec3::new(0.1, 0.2, 0.3),
            specular: DVec3::new(0.9, 0.8, 0.7),
        };
        let r = fit(&ggx, FitModel::Ggx);
        let Analytic::Ggx(g) = &r.model else {
            panic!("not ggx: {:?}", r.model)
        };
        assert!((g.alpha / 0.15 - 1.0).abs() < 1e-3, "{g:?}");
        assert!((g.diffuse - ggx.diffuse).abs().max_element() < 1e-3, "{g:?}");
        assert!((g.specular - ggx.specular).abs().max_element() < 1e-3, "{g:?}");
        assert!(r.rms_log_error < 1e-6, "{}", r.rms_log_error);

        let ward = Ward {
            rho_d: DVec3::splat(0.3),
            rho_s: DVec3::splat(0.5),
            alpha: 0.3,
        };
        let r = fit(&ward, FitModel::Ward);
        let Analytic::Ward(w) = &r.model else {
            panic!("not ward: {:?}", r.model)
        };
        assert!(
            (w.alpha / 0.3 - 1.0).abs() < 1e-3 && (w.rho_d.x - 0.3).abs() < 1e-3,
            "{w:?}"
        );
        assert_eq!(r.pairs, 9 * 18 * 13);
    }

    /// `fit_samples` reads its weights: outliers at weight 0 leave the fit exact, the same outliers
    /// at weight 1 pull it away. Below-horizon pairs and non-finite readings stay harmless.
    #[test]
    fn sample_weights_decide_what_the_fit_listens_to() {
        let ggx = Ggx {
            alpha: 0.2,
            diffuse: DVec3::new(0.2, 0.3, 0.4),
            specular: DVec3::splat(0.8),
        };
        let mut pairs = fit_directions();
        pairs.retain(|(wi, _)| wi.z > 0.5);
        let mut values: Vec<DVec3> = pairs.iter().map(|&(wi, wo)| ggx.eval(wi, wo)).collect();
        let mut weights = vec![1.0; pairs.len()];
        // Every 7th reading ten times too bright, at weight 0.
        for i in (0..values.len()).step_by(7) {
            values[i] *= 10.0;
            weights[i] = 0.0;
        }
        // A below-horizon pair and a NaN reading (at weight 0) and a NaN weight.
        pairs.push((from_spherical(0.3, 0.0), DVec3::new(0.0, 0.6, -0.8)));
        values.push(DVec3::splat(5.0));
        weights.push(1.0);
        pairs.push((from_spherical(0.3, 0.0), from_spherical(0.4, 1.0)));
        values.push(DVec3::splat(f64::NAN));
        weights.push(0.0);
        weights[1] = f64::NAN;
        let r = fit_samples(pairs.clone(), &values, &weights, FitModel::Ggx);
        let Analytic::Ggx(g) = &r.model else {
            panic!("not ggx: {:?}", r.model)
        };
        assert!((g.alpha / 0.2 - 1.0).abs() < 1e-3, "{g:?}");
        assert!((g.diffuse - ggx.diffuse).abs().max_element() < 1e-3, "{g:?}");
        assert!(r.rms_log_error.is_finite());
        // The same outliers heard: the fit moves.
        let heard: Vec<f64> = weights.iter().map(|w| if *w == 0.0 { 1.0 } else { *w }).collect();
        let r = fit_samples(pairs, &values, &heard, FitModel::Ggx);
        let Analytic::Ggx(h) = &r.model else {
            panic!("not ggx: {:?}", r.model)
        };
        assert!(
            (h.alpha / 0.2 - 1.0).abs() > 0.05 || (h.diffuse - ggx.diffuse).abs().max_element() > 0.05,
            "{h:?}"
        );
    }
}
