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
                s += ((f * self.cos_o[i]).ln_1p() - t[i]).powi(2);
            }
            s
        };
        // Start: linear least squares on f cos = exp(t) - 1, projected to >= 0.
        let (mut a11, mut a12, mut a22, mut r1, mut r2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..spec.len() {
            let (x1, x2) = (FRAC_1_PI * self.cos_o[i], spec[i] * self.cos_o[i]);
            let y = t[i].exp_m1();
            a11 += x1 * x1;
            a12 += x1 * x2;
            a22 += x2 * x2;
            r1 += x1 * y;
            r2 += x2 * y;
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
                a11 += j1 * j1;
                a12 += j1 * j2;
                a22 += j2 * j2;
                g1 += j1 * r;
                g2 += j2 * r;
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
    let cos_o: Vec<f64> = pairs.iter().map(|(_, wo)| wo.z).collect();
    let values: Vec<DVec3> = pairs.iter().map(|&(wi, wo)| material.eval(wi, wo)).collect();
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
        rms_log_error: (loss / (3 * n) as f64).sqrt(),
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
}
