//! The peer's basis as a reconstruction prior, and the per-scan choice between it and the product's
//! two-lobe prior (issue 28; figures in docs/nielsen2015.md).
//!
//! `PcaPrior`: the ridge fit of the basis coefficients to a level's measurements, each measured
//! pair read at the bin it falls in, the reconstruction the binned table (trilinear).
//! `SelectedPrior`: K-fold cross-validation over the level's own measurements (folds interleaved
//! in measurement order), each prior fitted on K - 1 folds and scored on the left-out one by the
//! two-lobe fit's own error (|log(1 + f cos_o) - log(1 + f_rec cos_o)|, weighted by the equal-angle
//! measure each sample stands for); the prior with the lower total is fitted to all measurements.
//! An optional `Guard` (the "guarded" trial) also refuses the basis when the scan looks outside its
//! span: the basis fit's in-sample residual in the basis' own (log-mapped) space above a bound, or
//! the basis winning the cross-validation on too few folds. No ground truth is read.

use super::basis::Basis;
use super::bins::{coords, cos_weight, index, map, unmap, N_PHI_D, N_THETA_D, N_THETA_H};
use super::{centre_weights, table};
use glam::DVec3;
use gonio::brdf::Material;
use gonio::reconstruct::{FittedPrior, LevelSamples, OtherModel, Prior, TwoLobesPrior};
use nalgebra::{Cholesky, DMatrix, DVector};
use std::sync::Arc;

/// Ridge of `PcaPrior` (a noise variance against the unit prior of each component): chosen by
/// `cargo run --release -p gonio-lab --example prior_choice_check` on the training materials.
pub const PCA_RIDGE: f64 = 0.1;
/// Folds of `SelectedPrior`'s cross-validation, and how much larger than the two lobes' the
/// basis' cross-validated error may be and still be picked (both chosen by the same check).
pub const FOLDS: usize = 5;
pub const THRESHOLD: f64 = 1.0;
/// `guarded_prior`'s guard, chosen by the same check on the training materials only (the most
/// cautious guard within 0.005 summed log ratio of the unguarded trial): the basis fit may leave at
/// most 20 % of the scan's centred log-mapped values unexplained (relative in-sample residual).
pub const GUARD: Guard = Guard {
    max_rms: f64::INFINITY,
    max_relative: 0.2,
    majority: false,
};

/// The training basis' model, loaded once per process.
pub fn training_model() -> Result<Arc<PcaModel>, String> {
    static MODEL: std::sync::OnceLock<Result<Arc<PcaModel>, String>> = std::sync::OnceLock::new();
    MODEL
        .get_or_init(|| super::training_basis().map(|b| Arc::new(PcaModel::new(b))))
        .clone()
}

/// `PcaPrior` of the training basis at `PCA_RIDGE`.
pub fn pca_prior() -> Result<PcaPrior, String> {
    Ok(PcaPrior {
        model: training_model()?,
        ridge: PCA_RIDGE,
    })
}

/// `SelectedPrior` of the training basis at `PCA_RIDGE` and `FOLDS`.
pub fn selected_prior() -> Result<SelectedPrior, String> {
    Ok(SelectedPrior {
        pca: pca_prior()?,
        folds: FOLDS,
        threshold: THRESHOLD,
        guard: None,
    })
}

/// `selected_prior` with `GUARD`.
pub fn guarded_prior() -> Result<SelectedPrior, String> {
    Ok(SelectedPrior {
        guard: Some(GUARD),
        ..selected_prior()?
    })
}

/// The basis with its per-bin centre weights (computed once).
pub struct PcaModel {
    pub basis: Basis,
    weight: Vec<f64>,
}

impl PcaModel {
    pub fn new(basis: Basis) -> Self {
        let weight = centre_weights(&basis);
        Self { basis, weight }
    }

    /// The bin a pair falls in (nearest: its continuous coordinates floored, clamped), None if the
    /// pair has no half vector or the bin is invalid.
    fn bin_of(&self, wi: DVec3, wo: DVec3) -> Option<usize> {
        let c = coords(wi, wo)?;
        let at = |x: f64, n: usize| (x.max(0.0) as usize).min(n - 1);
        let b = index(at(c[0], N_THETA_H), at(c[1], N_THETA_D), at(c[2], N_PHI_D));
        self.basis.valid[b].then_some(b)
    }

    /// Ridge-fitted coefficients (per component, RGB) of `values` at `pairs`; None when no pair
    /// lands in a valid bin or the system is singular.
    pub fn coefficients(&self, pairs: &[(DVec3, DVec3)], values: &[DVec3], ridge: f64) -> Option<Vec<[f32; 3]>> {
        self.fit(pairs, values, ridge).map(|(c, _)| c)
    }

    /// The basis fit's in-sample residual on `values` at `pairs` (see `SpanResidual`).
    pub fn span_residual(&self, pairs: &[(DVec3, DVec3)], values: &[DVec3], ridge: f64) -> Option<SpanResidual> {
        self.fit(pairs, values, ridge).map(|(_, r)| r)
    }

    /// `coefficients` with the fit's in-sample residual.
    fn fit(&self, pairs: &[(DVec3, DVec3)], values: &[DVec3], ridge: f64) -> Option<(Vec<[f32; 3]>, SpanResidual)> {
        let basis = &self.basis;
        let k = basis.k();
        let rows: Vec<(usize, DVec3, f64)> = pairs
            .iter()
            .zip(values)
            .filter(|(_, v)| v.is_finite())
            .filter_map(|(&(wi, wo), &v)| Some((self.bin_of(wi, wo)?, v, cos_weight(wi, wo))))
            .collect();
        if rows.is_empty() || k == 0 {
            return None;
        }
        let a = DMatrix::from_fn(rows.len(), k, |i, j| basis.row(rows[i].0)[j] as f64 * basis.sigma[j]);
        let normal = a.transpose() * &a + DMatrix::identity(k, k) * ridge;
        let chol = Cholesky::new(normal)?;
        let mut coeffs = vec![[0.0f32; 3]; k];
        let (mut res2, mut obs2) = (0.0, 0.0);
        for c in 0..3 {
            let r = DVector::from_fn(rows.len(), |i, _| {
                let (b, v, w) = rows[i];
                map(v[c] * w, basis.median[b]) - basis.mean[b]
            });
            let x = chol.solve(&(a.transpose() * &r));
            res2 += (&r - &a * &x).norm_squared();
            obs2 += r.norm_squared();
            for (j, co) in coeffs.iter_mut().enumerate() {
                co[c] = (x[j] * basis.sigma[j]) as f32;
            }
        }
        let residual = SpanResidual {
            rms: (res2 / (3 * rows.len()) as f64).sqrt(),
            relative: if obs2 > 0.0 { (res2 / obs2).sqrt() } else { 0.0 },
        };
        let finite = coeffs.iter().all(|c| c.iter().all(|x| x.is_finite())) && residual.rms.is_finite();
        finite.then_some((coeffs, residual))
    }

    /// The fit's value at a pair (its bin's), without building the table: for cross-validation.
    fn value_at(&self, coeffs: &[[f32; 3]], wi: DVec3, wo: DVec3) -> DVec3 {
        let Some(b) = self.bin_of(wi, wo) else {
            return DVec3::ZERO;
        };
        let row = self.basis.row(b);
        let w = cos_weight(wi, wo);
        DVec3::from_array(std::array::from_fn(|c| {
            let y: f64 = row.iter().zip(coeffs).map(|(u, co)| *u as f64 * co[c] as f64).sum();
            unmap(self.basis.mean[b] + y, self.basis.median[b]) / w
        }))
    }
}

/// The basis fit as a prior.
pub struct PcaPrior {
    pub model: Arc<PcaModel>,
    pub ridge: f64,
}

impl Prior for PcaPrior {
    fn name(&self) -> &'static str {
        "pca"
    }
    fn about(&self) -> &'static str {
        " (each level's measurements are fitted with the ridge fit of the nielsen2015 PCA basis of the \
         75 training MERL fits, each pair read at its 32 x 32 x 64 bin; the grid interpolates the \
         residuals and the binned table is evaluated at the query)"
    }
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        let coeffs = self.model.coefficients(&s.pairs, s.values, self.ridge)?;
        Some(FittedPrior::Other(OtherModel {
            model: Arc::new(table(&self.model.basis, &self.model.weight, &coeffs)),
            describe: format!("pca ridge={} k={}", self.ridge, self.model.basis.k()),
        }))
    }
}

/// How far a scan's measurements are from the basis' span, in the basis' own space: the ridge
/// fit's residual over the measured pairs' bins and the three channels, each value log-mapped and
/// centred as the basis' observations are (so 0.1 is about 10 % in f cos), as an RMS and relative
/// to the RMS of the centred values themselves (the share of the scan the basis leaves unexplained).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SpanResidual {
    pub rms: f64,
    pub relative: f64,
}

/// When the basis may be picked besides winning the cross-validation on the total: its
/// `SpanResidual` at most `max_rms` and `max_relative`, and (with `majority`) lower error than the
/// two lobes on more than half of the folds. All measured on the level's own measurements.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Guard {
    pub max_rms: f64,
    pub max_relative: f64,
    pub majority: bool,
}

impl Guard {
    /// Whether the guard lets the basis be picked, given its residual and per-fold errors
    /// ((two lobes, basis) per fold).
    pub fn allows(&self, residual: Option<SpanResidual>, folds: &[(f64, f64)]) -> bool {
        let wins = folds.iter().filter(|(lobes, pca)| pca < lobes).count();
        residual.is_some_and(|r| r.rms <= self.max_rms && r.relative <= self.max_relative)
            && (!self.majority || 2 * wins > folds.len())
    }
}

/// Which prior the cross-validation picked, with both totals, and what the guard saw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Choice {
    pub pca: bool,
    pub two_lobes_err: f64,
    pub pca_err: f64,
    /// The basis fit's in-sample residual on all the level's measurements (None: no fit).
    pub residual: Option<SpanResidual>,
    /// Folds on which the basis had the lower error.
    pub pca_fold_wins: usize,
}

/// The per-scan choice between `TwoLobesPrior` and `PcaPrior` (see the module doc).
pub struct SelectedPrior {
    pub pca: PcaPrior,
    pub folds: usize,
    /// The basis is picked when its CV error is below `threshold` x the two lobes'.
    pub threshold: f64,
    /// None: today's trial (`two-lobes-or-pca`); Some: `two-lobes-or-pca-guarded`.
    pub guard: Option<Guard>,
}

impl SelectedPrior {
    /// The cross-validated errors of both priors on `s`, and the choice (two lobes when neither
    /// has an error: too few samples, or when the guard refuses the basis).
    pub fn choose(&self, s: &LevelSamples<'_>) -> Choice {
        let per_fold: Vec<(f64, f64)> = cross_validate_folds(&self.pca.model, s, self.folds, &[self.pca.ridge])
            .into_iter()
            .map(|(lobes, pca)| (lobes, pca[0]))
            .collect();
        let (two_lobes_err, pca_err) = per_fold.iter().fold((0.0, 0.0), |(a, b), (l, p)| (a + l, b + p));
        let residual = match self.guard {
            Some(_) => self.pca.model.span_residual(&s.pairs, s.values, self.pca.ridge),
            None => None,
        };
        let guard_allows = self.guard.is_none_or(|g| g.allows(residual, &per_fold));
        Choice {
            pca: pca_err < self.threshold * two_lobes_err && guard_allows,
            two_lobes_err,
            pca_err,
            residual,
            pca_fold_wins: per_fold.iter().filter(|(l, p)| p < l).count(),
        }
    }
}

/// K-fold cross-validated total error of the two-lobe prior and of the basis fit at each of
/// `ridges` on `s` (see the module doc); zeros (two lobes are kept) with fewer usable samples than
/// two per fold.
pub fn cross_validate(model: &PcaModel, s: &LevelSamples<'_>, folds: usize, ridges: &[f64]) -> (f64, Vec<f64>) {
    let mut total = (0.0, vec![0.0; ridges.len()]);
    for (lobes, pca) in cross_validate_folds(model, s, folds, ridges) {
        total.0 += lobes;
        total.1.iter_mut().zip(pca).for_each(|(t, e)| *t += e);
    }
    total
}

/// `cross_validate` per fold: (two lobes, per ridge) on each left-out fold; empty with fewer
/// usable samples than two per fold.
pub fn cross_validate_folds(
    model: &PcaModel,
    s: &LevelSamples<'_>,
    folds: usize,
    ridges: &[f64],
) -> Vec<(f64, Vec<f64>)> {
    let usable: Vec<usize> = (0..s.pairs.len())
        .filter(|&i| s.weights[i] > 0.0 && s.values[i].is_finite() && s.pairs[i].1.z > 0.0)
        .collect();
    let k = folds.max(2);
    if usable.len() < 2 * k {
        return Vec::new();
    }
    let mut out = Vec::with_capacity(k);
    for fold in 0..k {
        let (mut lobes_err, mut pca_err) = (0.0, vec![0.0; ridges.len()]);
        let (test, train): (Vec<_>, Vec<_>) = usable.iter().enumerate().partition(|(n, _)| n % k == fold);
        let train: Vec<usize> = train.into_iter().map(|(_, &i)| i).collect();
        let values: Vec<DVec3> = train.iter().map(|&i| s.values[i]).collect();
        let sub = LevelSamples {
            pairs: train.iter().map(|&i| s.pairs[i]).collect(),
            values: &values,
            weights: train.iter().map(|&i| s.weights[i]).collect(),
            estimate_alpha: s.estimate_alpha,
        };
        let lobes = TwoLobesPrior.fit(&sub);
        let coeffs: Vec<_> = ridges
            .iter()
            .map(|&r| model.coefficients(&sub.pairs, &values, r))
            .collect();
        for &(_, &i) in &test {
            let (wi, wo) = s.pairs[i];
            let err = |f: DVec3| weighted_log_err(s.values[i], f, wo.z, s.weights[i]);
            lobes_err += lobes.as_ref().map_or(f64::INFINITY, |p| err(p.eval(wi, wo)));
            for (e, c) in pca_err.iter_mut().zip(&coeffs) {
                *e += c.as_ref().map_or(f64::INFINITY, |c| err(model.value_at(c, wi, wo)));
            }
        }
        out.push((lobes_err, pca_err));
    }
    out
}

/// The two-lobe fit's error of `got` against `want` at cos_o, times the sample's weight (RGB mean).
fn weighted_log_err(want: DVec3, got: DVec3, cos_o: f64, weight: f64) -> f64 {
    let l = |v: DVec3| (v.max(DVec3::ZERO) * cos_o).to_array().map(f64::ln_1p);
    let (a, b) = (l(want), l(got));
    weight * (0..3).map(|c| (a[c] - b[c]).abs()).sum::<f64>() / 3.0
}

impl Prior for SelectedPrior {
    fn name(&self) -> &'static str {
        match self.guard {
            None => "two-lobes-or-pca",
            Some(_) => "two-lobes-or-pca-guarded",
        }
    }
    fn about(&self) -> &'static str {
        match self.guard {
            None => {
                " (per level, two-lobes or pca, whichever has the lower K-fold cross-validated log error \
                 over the level's own measurements, weighted as the two-lobe fit weighs them; then the \
                 grid interpolates the residuals of the chosen one)"
            }
            Some(_) => {
                " (as two-lobes-or-pca, but pca only where the level's measurements look inside the \
                 basis' span: the basis fit's in-sample log-mapped residual within the guard's bounds, \
                 and the cross-validation won on the guard's share of folds)"
            }
        }
    }
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        match self.choose(s).pca {
            true => self.pca.fit(s).or_else(|| TwoLobesPrior.fit(s)),
            false => TwoLobesPrior.fit(s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio::brdf::{parse_material, Material};

    /// A retro-reflective lobe plus Lambert: what two GGX lobes cannot fit.
    struct Retro {
        k: f64,
        kd: f64,
    }

    impl Material for Retro {
        fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
            if wi.z <= 0.0 || wo.z <= 0.0 {
                return DVec3::ZERO;
            }
            DVec3::splat(self.kd / std::f64::consts::PI + self.k * (-(wi - wo).length_squared() / 0.05).exp())
        }
    }

    fn retro_basis() -> Basis {
        let family = [(1.0, 0.1), (0.5, 0.3), (2.0, 0.05), (0.2, 0.5)];
        Basis::build(
            &family
                .iter()
                .map(|&(k, kd)| Box::new(Retro { k, kd }) as Box<dyn Material>)
                .collect::<Vec<_>>(),
        )
    }

    /// 150 pairs spread over both hemispheres (incoming 0.1 .. 1.3 rad, outgoing all azimuths).
    fn pairs() -> Vec<(DVec3, DVec3)> {
        let n = 150;
        let d = |t: f64, p: f64| DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
        (0..n)
            .map(|i| {
                let ti = 0.1 + 1.2 * ((i * 7) % n) as f64 / n as f64;
                let to = 0.05 + 1.3 * ((i * 11) % n) as f64 / n as f64;
                (d(ti, 0.0), d(to, 0.37 * i as f64))
            })
            .collect()
    }

    /// The selected prior on `retro_basis`, 5 folds, threshold 1.
    fn retro_prior(guard: Option<Guard>) -> SelectedPrior {
        SelectedPrior {
            pca: PcaPrior {
                model: Arc::new(PcaModel::new(retro_basis())),
                ridge: 1e-3,
            },
            folds: 5,
            threshold: 1.0,
            guard,
        }
    }

    /// `f` on the samples of `m` at `pairs()`, each weighted 1.
    fn with_samples<R>(m: &dyn Material, f: impl FnOnce(&LevelSamples<'_>) -> R) -> R {
        let pairs = pairs();
        let values: Vec<DVec3> = pairs.iter().map(|&(wi, wo)| m.eval(wi, wo)).collect();
        f(&LevelSamples {
            pairs,
            values: &values,
            weights: vec![1.0; values.len()],
            estimate_alpha: 0.1,
        })
    }

    /// A material in the basis' span (retro-reflection) picks the basis; one it cannot span but
    /// two lobes fit exactly (a sharp GGX lobe) picks the two lobes; degenerate inputs stay finite.
    #[test]
    fn the_choice_follows_which_prior_predicts_left_out_samples() {
        let prior = retro_prior(None);
        let run = |m: &dyn Material| with_samples(m, |s| (prior.choose(s), prior.fit(s).map(|p| p.describe())));
        let (inside, described) = run(&Retro { k: 0.8, kd: 0.2 });
        assert!(inside.pca, "{inside:?}");
        assert!(described.is_some_and(|d| d.starts_with("pca")));
        let ggx = parse_material("ggx:alpha=0.05,diffuse=0.1,specular=1").expect("spec");
        let (outside, _) = run(ggx.as_ref());
        assert!(!outside.pca, "{outside:?}");
        let zeros = vec![DVec3::ZERO; 3];
        let s = LevelSamples {
            pairs: vec![(DVec3::Z, DVec3::Z); 3],
            values: &zeros,
            weights: vec![0.0, f64::NAN, 1.0],
            estimate_alpha: 0.0,
        };
        assert!(!prior.choose(&s).pca);
        let fitted = prior.fit(&s).expect("two lobes");
        assert!(fitted.eval(DVec3::Z, DVec3::Z).is_finite());
        assert!(prior.pca.fit(&s).is_none_or(|p| p.eval(DVec3::Z, DVec3::Z).is_finite()));
    }

    /// A retro lobe of width `w` over a sharp GGX-like highlight (exp of the half vector's tilt):
    /// neither the retro basis nor two lobes span it exactly.
    struct Outside {
        w: f64,
        spec: f64,
    }

    impl Material for Outside {
        fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
            if wi.z <= 0.0 || wo.z <= 0.0 {
                return DVec3::ZERO;
            }
            let h = (wi + wo).normalize();
            let retro = (-(wi - wo).length_squared() / self.w).exp();
            let spec = self.spec * (-(1.0 - h.z * h.z) / 0.002).exp();
            DVec3::new(0.9, 0.3, 0.05) * (0.3 + retro) + DVec3::splat(spec)
        }
    }

    fn choose_on(prior: &SelectedPrior, m: &dyn Material) -> Choice {
        with_samples(m, |s| prior.choose(s))
    }

    /// A material outside the basis' span that still wins the cross-validation against two lobes
    /// (neither prior fits it: a wide tinted retro lobe under a sharp highlight) is refused the
    /// basis by the residual bound; one inside it keeps the basis under the same guard.
    #[test]
    fn the_guard_keeps_two_lobes_outside_the_span() {
        let guard = Guard {
            max_rms: 0.3,
            max_relative: f64::INFINITY,
            majority: false,
        };
        let mut prior = retro_prior(None);
        let outside = Outside { w: 0.2, spec: 10.0 };
        let inside = Retro { k: 0.8, kd: 0.2 };
        let unguarded = choose_on(&prior, &outside);
        assert!(unguarded.pca && unguarded.residual.is_none(), "{unguarded:?}");
        prior.guard = Some(guard);
        assert_eq!(prior.name(), "two-lobes-or-pca-guarded");
        let refused = choose_on(&prior, &outside);
        assert!(!refused.pca, "{refused:?}");
        assert!(refused.residual.is_some_and(|r| r.rms > 0.3), "{refused:?}");
        assert_eq!(refused.pca_err, unguarded.pca_err);
        let kept = choose_on(&prior, &inside);
        assert!(kept.pca, "{kept:?}");
        assert!(kept.residual.is_some_and(|r| r.rms < 0.15), "{kept:?}");
        assert_eq!(kept.pca_fold_wins, 5);
    }

    /// Each part of the guard: the residual bounds, no fit at all, and the majority of folds.
    #[test]
    fn the_guard_needs_every_condition() {
        let guard = Guard {
            max_rms: 0.3,
            max_relative: 0.5,
            majority: true,
        };
        let r = |rms, relative| Some(SpanResidual { rms, relative });
        let wins3 = [(1.0, 0.5), (1.0, 0.5), (1.0, 0.5), (1.0, 2.0), (1.0, 2.0)];
        let wins2 = [(1.0, 0.5), (1.0, 0.5), (1.0, 2.0), (1.0, 2.0), (1.0, 2.0)];
        assert!(guard.allows(r(0.2, 0.4), &wins3));
        assert!(!guard.allows(r(0.2, 0.4), &wins2));
        assert!(!guard.allows(r(0.4, 0.4), &wins3));
        assert!(!guard.allows(r(0.2, 0.6), &wins3));
        assert!(!guard.allows(None, &wins3));
        assert!(!guard.allows(r(0.2, 0.4), &[]));
        let no_majority = Guard {
            majority: false,
            ..guard
        };
        assert!(no_majority.allows(r(0.2, 0.4), &wins2));
        assert!(!no_majority.allows(r(f64::NAN, 0.4), &wins2));
    }
}
