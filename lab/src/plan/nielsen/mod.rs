//! The data-driven peer: Nielsen, Jensen, Ramamoorthi, "On optimal, minimal BRDF sampling for
//! reflectance acquisition" (TOG 2015), in the lab only (docs/nielsen2015.md says what is the same
//! as the paper and what differs, and why).
//!
//! * `bins`: the 32 x 32 x 64 (theta_h, theta_d, phi_d) bins, the log mapping, the binned BRDF.
//! * `basis`: the PCA basis of the training materials' tables (cached).
//! * `select`: the condition-number direction selection over the bins this instrument reaches.
//! * `selected`: the basis as a reconstruction prior, and the per-scan choice between it and the
//!   product's two-lobe prior by cross-validation over the scan's own measurements (issue 28).
//! * here: the ridge fit of the basis coefficients to measurements at a selected set (its normal
//!   equations factored once per set), and the caches.

pub mod basis;
pub mod bins;
pub mod select;
pub mod selected;

use basis::Basis;
use bins::{centre, cos_weight, map, unmap, BinnedBrdf, BINS};
use glam::DVec3;
use gonio::brdf::nbrdf::NeuralBrdf;
use gonio::brdf::Material;
use nalgebra::{Cholesky, DMatrix, DVector, Dyn};
use rayon::prelude::*;
use std::path::PathBuf;

/// Ridge weight: noise variance of a mapped measurement against the coefficients' unit-variance
/// prior (each component scaled by its training standard deviation). Not yet the cross-validated
/// value: `cargo run --release -p gonio-lab --example nielsen_check` (training materials only)
/// prefers 0.003 or lower; the committed side-by-side runs used this one (docs/nielsen2015.md).
pub const RIDGE: f64 = 0.03;

/// Version of the cache files: bump it when the bins, the mapping or the selection change.
const CACHE_VERSION: u32 = 1;

/// The training materials: the bundled MERL fits less the encoder's fifteen held-out ones (never
/// `../shared/data/rgl`).
pub fn training_names() -> Vec<&'static str> {
    let held: Vec<&str> = crate::plan::tradeoff::HELDOUT_MATERIALS
        .iter()
        .map(|m| m.trim_start_matches("nbrdf:"))
        .collect();
    NeuralBrdf::bundled_names().filter(|n| !held.contains(n)).collect()
}

/// Where the basis and the selections are cached: `$GONIO_LAB_CACHE`, else `target/gonio-lab-cache`.
pub fn cache_dir() -> PathBuf {
    std::env::var_os("GONIO_LAB_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target/gonio-lab-cache"))
}

/// The basis of the training materials, from the cache or built (about a minute) and cached.
pub fn training_basis() -> Result<Basis, String> {
    let names = training_names();
    let tag = format!("nielsen-basis v{CACHE_VERSION} {}", names.join(","));
    let path = cache_dir().join(format!("nielsen-basis-v{CACHE_VERSION}.bin"));
    Basis::load_or_build(&path, &tag, || {
        names
            .iter()
            .filter_map(|n| NeuralBrdf::bundled(n).ok())
            .map(|m| Box::new(m) as Box<dyn Material>)
            .collect()
    })
    .map_err(|e| format!("{}: {e}", path.display()))
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

/// Per bin: the clipped cosine product at its centre, 0 where the bin is invalid.
pub fn centre_weights(basis: &Basis) -> Vec<f64> {
    (0..BINS)
        .into_par_iter()
        .map(|b| match basis.valid[b].then(|| centre(b)).flatten() {
            Some((wi, wo)) => cos_weight(wi, wo),
            None => 0.0,
        })
        .collect()
}

/// The table of basis coefficients `coeffs` (per component, RGB), `weight` from `centre_weights`.
pub fn table(basis: &Basis, weight: &[f64], coeffs: &[[f32; 3]]) -> BinnedBrdf {
    let values = (0..BINS)
        .into_par_iter()
        .with_min_len(1024)
        .map(|b| {
            let w = weight[b];
            if w <= 0.0 {
                return [0.0f32; 3];
            }
            // The three channels in one pass over the bin's row (same sums, same order).
            let mut y = [-0.0f32; 3];
            for (u, co) in basis.row(b).iter().zip(coeffs) {
                for (yc, cc) in y.iter_mut().zip(co) {
                    *yc += u * cc;
                }
            }
            y.map(|y| (unmap(basis.mean[b] + y as f64, basis.median[b]) / w) as f32)
        })
        .collect();
    BinnedBrdf { values }
}

#[cfg(test)]
mod tests {
    use super::basis::tests::small;
    use super::*;
    use gonio::brdf::parse_material;

    /// A material inside the basis' span is recovered from a selected set of directions; the
    /// held-out training list never holds a held-out material.
    #[test]
    fn a_material_of_the_training_set_is_recovered_from_few_directions() {
        let basis = small();
        let candidates: Vec<usize> = (0..BINS).filter(|&b| basis.valid[b]).collect();
        let set = select::select(&basis, &candidates, 2 * basis.k());
        let design = Design::new(&basis, set, 1e-6).expect("design");
        let truth = parse_material("ggx:alpha=0.1,diffuse=0.2").expect("spec");
        let values: Vec<DVec3> = design.pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        let rec = design.fit(&basis, &values);
        let (wi, wo) = centre(bins::index(5, 10, 20)).expect("above the horizon");
        let (got, want) = (rec.eval(wi, wo), truth.eval(wi, wo));
        assert!(
            (got - want).abs().max_element() < 0.02 * want.max_element() + 1e-3,
            "{got} vs {want}"
        );
        let names = training_names();
        assert_eq!(names.len(), NeuralBrdf::bundled_names().count() - 15);
        assert!(!names.contains(&"tungsten-carbide"));
    }
}
