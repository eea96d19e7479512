//! The PCA basis as a reconstruction prior, and the product's per-level choice between it and the
//! two-lobe prior (issue 28; figures in docs/nielsen2015.md).
//!
//! `PcaPrior`: the ridge fit of the basis coefficients to a level's measurements, each measured
//! pair read at the bin it falls in, the reconstruction the binned table (trilinear).
//! `SelectedPrior`: K-fold cross-validation over the level's own measurements (folds interleaved
//! in measurement order), each prior fitted on K - 1 folds and scored on the left-out one by the
//! two-lobe fit's own error (|log(1 + f cos_o) - log(1 + f_rec cos_o)|, weighted by the equal-angle
//! measure each sample stands for). The basis is picked when it has the lower total **and** the
//! scan looks inside its span: its fit leaves at most `max_unexplained` of the level's log-mapped
//! values unexplained (`SpanResidual::relative`). No ground truth is read.

use super::basis::Basis;
use super::bins::{coords, cos_weight, index, map, unmap, DIMS};
use super::{centre_weights, table};
use crate::brdf::merl::layout_nearest;
use crate::brdf::Material;
use crate::reconstruct::{FittedPrior, LevelSamples, Prior, TwoLobesPrior};
use glam::DVec3;
use nalgebra::{Cholesky, DMatrix, DVector};
use rayon::prelude::*;
use std::sync::Arc;

/// Ridge of `PcaPrior` (a noise variance against the unit prior of each component), and the
/// folds of `SelectedPrior`'s cross-validation: both chosen on the training materials by
/// `cargo run --release -p gonio-lab --example prior_choice_check`.
pub const PCA_RIDGE: f64 = 0.1;
pub const FOLDS: usize = 5;
/// The largest share of a level's centred log-mapped values the basis fit may leave unexplained and
/// still be picked: chosen by the same check (the most cautious bound that cost the training
/// materials nothing); it refuses the basis on materials outside its span, e.g. the real iris paint.
pub const MAX_UNEXPLAINED: f64 = 0.2;

/// The product prior's name (`--prior`, reports, the scan's settings).
pub const NAME: &str = "two-lobes-or-pca-guarded";

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

/// The product's prior: `SelectedPrior` of the training basis at `PCA_RIDGE`, `FOLDS` and
/// `MAX_UNEXPLAINED`.
pub fn product_prior() -> Result<SelectedPrior, String> {
    Ok(SelectedPrior {
        pca: pca_prior()?,
        folds: FOLDS,
        max_unexplained: MAX_UNEXPLAINED,
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
        let [h, d, q] = layout_nearest(coords(wi, wo)?, DIMS);
        let b = index(h, d, q);
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
        Some(FittedPrior::Basis(Arc::new(table(
            &self.model.basis,
            &self.model.weight,
            &coeffs,
        ))))
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

/// Which prior the cross-validation picked, with both totals and the basis fit's residual.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Choice {
    pub pca: bool,
    pub two_lobes_err: f64,
    pub pca_err: f64,
    /// The basis fit's in-sample residual on all the level's measurements (None: no fit).
    pub residual: Option<SpanResidual>,
}

/// The per-level choice between `TwoLobesPrior` and `PcaPrior` (see the module doc).
pub struct SelectedPrior {
    pub pca: PcaPrior,
    pub folds: usize,
    /// The basis is refused above this relative residual (`MAX_UNEXPLAINED` in the product).
    pub max_unexplained: f64,
}

impl SelectedPrior {
    /// The cross-validated totals (two lobes, basis) on `s`; zeros with too few samples.
    fn cross_validated(&self, s: &LevelSamples<'_>) -> (f64, f64) {
        cross_validate_folds(&self.pca.model, s, self.folds, &[self.pca.ridge])
            .into_iter()
            .fold((0.0, 0.0), |(a, b), (l, p)| (a + l, b + p[0]))
    }

    /// The cross-validated errors of both priors on `s`, and the choice (two lobes when neither
    /// has an error: too few samples, or when the scan looks outside the basis' span).
    pub fn choose(&self, s: &LevelSamples<'_>) -> Choice {
        let (two_lobes_err, pca_err) = self.cross_validated(s);
        let residual = self.pca.model.span_residual(&s.pairs, s.values, self.pca.ridge);
        let inside = residual.is_some_and(|r| r.relative <= self.max_unexplained);
        Choice {
            pca: pca_err < two_lobes_err && inside,
            two_lobes_err,
            pca_err,
            residual,
        }
    }
}

/// K-fold cross-validated error (see the module doc) per fold: (two lobes, the basis fit at each of
/// `ridges`) on each left-out fold; empty (two lobes are kept) with fewer
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
    // The folds are independent fits: in parallel (the two-lobe fits are most of a level's host time).
    (0..k)
        .into_par_iter()
        .map(|fold| {
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
            (lobes_err, pca_err)
        })
        .collect()
}

/// The two-lobe fit's error of `got` against `want` at cos_o, times the sample's weight (RGB mean).
fn weighted_log_err(want: DVec3, got: DVec3, cos_o: f64, weight: f64) -> f64 {
    let l = |v: DVec3| (v.max(DVec3::ZERO) * cos_o).to_array().map(f64::ln_1p);
    let (a, b) = (l(want), l(got));
    weight * (0..3).map(|c| (a[c] - b[c]).abs()).sum::<f64>() / 3.0
}

impl Prior for SelectedPrior {
    fn name(&self) -> &'static str {
        NAME
    }
    fn about(&self) -> &'static str {
        " (per level, two-lobes or the PCA basis of the training MERL fits, whichever has the lower \
         K-fold cross-validated log error over the level's own measurements, the basis only where \
         its fit explains all but a bounded share of them; then the grid interpolates the residuals \
         of the chosen one)"
    }
    /// As `choose`, but the cross-validation is skipped when the bound already refuses the basis,
    /// and the two lobes are fitted to all samples beside the folds: the same choice, in about the
    /// time of the folds alone (issue 25's host time between levels).
    fn fit(&self, s: &LevelSamples<'_>) -> Option<FittedPrior> {
        let residual = self.pca.model.span_residual(&s.pairs, s.values, self.pca.ridge);
        if !residual.is_some_and(|r| r.relative <= self.max_unexplained) {
            return TwoLobesPrior.fit(s);
        }
        let (lobes, (lobes_err, pca_err)) = rayon::join(|| TwoLobesPrior.fit(s), || self.cross_validated(s));
        match pca_err < lobes_err {
            true => self.pca.fit(s).or(lobes),
            false => lobes,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{parse_material, Material};

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
    fn retro_prior(max_unexplained: f64) -> SelectedPrior {
        SelectedPrior {
            pca: PcaPrior {
                model: Arc::new(PcaModel::new(retro_basis())),
                ridge: 1e-3,
            },
            folds: 5,
            max_unexplained,
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
        let prior = retro_prior(f64::INFINITY);
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

    /// The mean two-lobe-fit error of `m` against `truth` over 3,000 pairs spread over both
    /// hemispheres (none of them `pairs()`).
    fn true_err(truth: &dyn Material, m: &dyn Material) -> f64 {
        let d = |t: f64, p: f64| DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
        let n = 3000;
        (0..n)
            .map(|i| {
                let wi = d(0.05 + 1.35 * ((i * 37) % n) as f64 / n as f64, 0.0);
                let wo = d(0.02 + 1.45 * ((i * 101) % n) as f64 / n as f64, 0.61 * i as f64);
                weighted_log_err(truth.eval(wi, wo), m.eval(wi, wo), wo.z, 1.0)
            })
            .sum::<f64>()
            / n as f64
    }

    /// The bound overrides the cross-validation only above it: a tinted retro lobe under a
    /// highlight leaves 0.2-0.3 of the scan unexplained by the retro basis; the cross-validation
    /// prefers the basis, the bound 0.2 refuses it and a bound of 0.3 lets it through.
    #[test]
    fn the_bound_overrides_the_cross_validation_only_above_it() {
        let m = Outside { w: 0.05, spec: 1.0 };
        let unguarded_prior = retro_prior(f64::INFINITY);
        let unguarded = choose_on(&unguarded_prior, &m);
        let r = unguarded.residual.expect("a basis fit").relative;
        assert!(unguarded.pca && r > 0.2 && r < 0.3, "{unguarded:?}");
        let guarded = choose_on(&retro_prior(0.2), &m);
        assert!(!guarded.pca, "{guarded:?}");
        assert_eq!(guarded.pca_err, unguarded.pca_err);
        assert!(choose_on(&retro_prior(0.3), &m).pca);
        // What the caution costs here: against the truth the refused basis is the closer prior.
        let (basis, lobes) = with_samples(&m, |s| (unguarded_prior.pca.fit(s), TwoLobesPrior.fit(s)));
        let (basis, lobes) = (
            true_err(&m, &basis.expect("a fit")),
            true_err(&m, &lobes.expect("a fit")),
        );
        println!("retro basis, share {r:.3}: true error basis {basis:.4}, two lobes {lobes:.4}");
        assert!(basis < lobes);
    }

    /// A material outside both priors (a wide tinted retro lobe under a sharp highlight) leaves the
    /// training basis a large RMS residual but a small share unexplained: the product picks the basis,
    /// and against the truth the basis is the closer of the two (the relative bound, not an RMS one,
    /// is right to let it through; docs/nielsen2015.md).
    #[test]
    fn out_of_span_material_the_basis_fits_better_passes_the_bound() {
        let prior = product_prior().expect("training basis");
        let m = Outside { w: 0.2, spec: 10.0 };
        let (c, fitted, lobes) = with_samples(&m, |s| (prior.choose(s), prior.fit(s), TwoLobesPrior.fit(s)));
        let r = c.residual.expect("a basis fit");
        assert!(c.pca && r.relative <= MAX_UNEXPLAINED && r.rms > 0.25, "{c:?}");
        let fitted = fitted.expect("a fit");
        assert_eq!(fitted.kind(), "pca");
        let (basis, lobes) = (true_err(&m, &fitted), true_err(&m, &lobes.expect("two lobes")));
        println!("training basis, {c:?}: true error basis {basis:.4}, two lobes {lobes:.4}");
        assert!(basis < lobes);
    }

    /// The product's prior on the training basis (read from the cache, or built once per machine):
    /// a training material (a felt) lies well inside its span; a sharp analytic highlight keeps two lobes.
    #[test]
    fn a_training_felt_lies_inside_the_span_and_a_sharp_highlight_keeps_two_lobes() {
        let prior = product_prior().expect("training basis");
        assert_eq!(prior.name(), "two-lobes-or-pca-guarded");
        let felt = crate::brdf::nbrdf::NeuralBrdf::bundled("pink-felt").expect("bundled");
        let (c, fitted) = with_samples(&felt, |s| (prior.choose(s), prior.fit(s).expect("a fit")));
        assert!(c.residual.is_some_and(|r| r.relative < 0.5 * MAX_UNEXPLAINED), "{c:?}");
        assert_eq!(fitted.kind() == "pca", c.pca, "fit follows choose");
        assert!(c.pca_err.is_finite() && c.two_lobes_err.is_finite(), "{c:?}");
        let sharp = parse_material("ggx:alpha=0.03,diffuse=0.05,specular=1").expect("spec");
        let c = choose_on(&prior, sharp.as_ref());
        assert!(!c.pca, "{c:?}");
    }
}
