//! The data-driven peer: Nielsen, Jensen, Ramamoorthi, "On optimal, minimal BRDF sampling for
//! reflectance acquisition" (TOG 2015), in the lab only (docs/nielsen2015.md says what is the same
//! as the paper and what differs, and why).
//!
//! * `gonio::reconstruct::pca` (the product's since issue 28, re-exported here): the bins, the
//!   log mapping, the PCA basis of the training materials and the basis as a prior.
//! * `select`: the condition-number direction selection over the bins this instrument reaches.
//! * here: the ridge fit of the basis coefficients to measurements at a selected set (its normal
//!   equations factored once per set), and the selections' cache.

pub mod select;

pub use gonio::reconstruct::pca::{basis, bins, centre_weights, selected, table, training_basis, training_names};

use basis::Basis;
use bins::{centre, cos_weight, map, BinnedBrdf};
use glam::DVec3;
use nalgebra::{Cholesky, DMatrix, DVector, Dyn};
use std::path::PathBuf;

/// Ridge weight: noise variance of a mapped measurement against the coefficients' unit-variance
/// prior (each component scaled by its training standard deviation). The best mean of
/// `cargo run --release -p gonio-lab --example nielsen_check` (5-fold cross-validation over the
/// training materials only; flat from 0.001 to 0.003, 0.0003 worse; docs/nielsen2015.md).
pub const RIDGE: f64 = 0.001;

/// Where the selections are cached: `$GONIO_LAB_CACHE`, else `target/gonio-lab-cache` (the basis
/// is the product's, cached by `gonio::reconstruct::pca::cache_dir`).
pub fn cache_dir() -> PathBuf {
    std::env::var_os("GONIO_LAB_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target/gonio-lab-cache"))
}

/// A selected direction set with its ridge system factored once: fitting a material is then a
/// product, a triangular solve per channel and the basis times the coefficients.
pub struct Design {
    /// The selected bins, and their centre pairs (phi_i = 0).
    pub bins: Vec<usize>,
    pub pairs: Vec<(DVec3, DVec3)>,
    /// A = rows of the basis at `bins`, each component scaled by its sigma (n x K).
    a: DMatrix<f64>,
    chol: Cholesky<f64, Dyn>,
    /// Per bin: the clipped cosine product at its centre, 0 below the horizon (computed once per
    /// set, not per fit: the centres' trigonometry cost more than the fit's algebra).
    weight: Vec<f64>,
}

impl Design {
    pub fn new(basis: &Basis, bins: Vec<usize>, ridge: f64) -> Result<Self, String> {
        let k = basis.k();
        let pairs = bins
            .iter()
            .map(|&b| centre(b).ok_or_else(|| format!("bin {b} lies below the horizon")))
            .collect::<Result<Vec<_>, _>>()?;
        let a = DMatrix::from_fn(bins.len(), k, |i, j| basis.row(bins[i])[j] as f64 * basis.sigma[j]);
        let normal = a.transpose() * &a + DMatrix::identity(k, k) * ridge;
        let chol = Cholesky::new(normal).ok_or("the ridge system is not positive definite")?;
        let weight = centre_weights(basis);
        Ok(Self {
            bins,
            pairs,
            a,
            chol,
            weight,
        })
    }

    /// The reconstruction from `values[i]` = f(pairs[i]) (RGB, 1/sr).
    pub fn fit(&self, basis: &Basis, values: &[DVec3]) -> BinnedBrdf {
        let k = basis.k();
        // Per channel: residual of the mapped measurement against the mean, then the coefficients.
        let mut coeffs = vec![[0.0f32; 3]; k];
        for c in 0..3 {
            let r = DVector::from_fn(self.bins.len(), |i, _| {
                let b = self.bins[i];
                let (wi, wo) = self.pairs[i];
                map(values[i][c] * cos_weight(wi, wo), basis.median[b]) - basis.mean[b]
            });
            let a = self.chol.solve(&(self.a.transpose() * r));
            for (j, co) in coeffs.iter_mut().enumerate() {
                co[c] = (a[j] * basis.sigma[j]) as f32;
            }
        }
        table(basis, &self.weight, &coeffs)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use gonio::brdf::{parse_material, Material};

    /// The host's four-material fixture basis: quick to build in a debug test.
    pub(crate) fn small() -> Basis {
        Basis::small_analytic()
    }

    /// A material inside the basis' span is recovered from a selected set of directions.
    #[test]
    fn a_material_of_the_training_set_is_recovered_from_few_directions() {
        let basis = small();
        let candidates: Vec<usize> = (0..bins::BINS).filter(|&b| basis.valid[b]).collect();
        let set = select::select(&basis, &candidates, 2 * basis.k());
        let design = Design::new(&basis, set, 1e-6).expect("design");
        let truth = parse_material(basis::SMALL_ANALYTIC[0]).expect("spec");
        let values: Vec<DVec3> = design.pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        let rec = design.fit(&basis, &values);
        let (wi, wo) = centre(bins::index(5, 10, 20)).expect("above the horizon");
        let (got, want) = (rec.eval(wi, wo), truth.eval(wi, wo));
        assert!(
            (got - want).abs().max_element() < 0.02 * want.max_element() + 1e-3,
            "{got} vs {want}"
        );
    }
}
