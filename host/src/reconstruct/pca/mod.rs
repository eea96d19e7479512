//! A data-driven prior after Nielsen, Jensen, Ramamoorthi, "On optimal, minimal BRDF sampling for
//! reflectance acquisition" (TOG 2015): a PCA basis of the training MERL fits, fitted to a level's
//! measurements, and the per-level choice between it and the two lobes (issue 28; what is the same
//! as the paper, what differs and the figures: docs/nielsen2015.md).
//!
//! * `bins`: the 32 x 32 x 64 (theta_h, theta_d, phi_d) bins, the log mapping, the binned BRDF.
//! * `basis`: the PCA basis of a set of materials' tables, and its cache file.
//! * `selected`: the basis as a prior, and the product's choice between it and the two lobes.
//! * here: the training basis (built once per machine and cached) and the table of coefficients.

pub mod basis;
pub mod bins;
pub mod selected;

use crate::brdf::nbrdf::{NeuralBrdf, HELDOUT_MATERIALS};
use crate::brdf::Material;
use basis::Basis;
use bins::{centre, cos_weight, unmap, BinnedBrdf, BINS};
use rayon::prelude::*;
use std::path::PathBuf;

/// Version of the basis cache file: bump it when the bins, the mapping or the build change.
const CACHE_VERSION: u32 = 1;

/// The materials the basis is built from: the bundled MERL fits less the fifteen held-out ones,
/// which every claim is tested on (never `../shared/data/rgl`).
pub fn training_names() -> Vec<&'static str> {
    let held: Vec<&str> = HELDOUT_MATERIALS
        .iter()
        .map(|m| m.trim_start_matches("nbrdf:"))
        .collect();
    NeuralBrdf::bundled_names().filter(|n| !held.contains(n)).collect()
}

/// Where the basis is cached: `$GONIO_CACHE`, else the user's cache directory's `gonio/`; None
/// when neither is known (the basis is then built for this process only).
pub fn cache_dir() -> Option<PathBuf> {
    match std::env::var_os("GONIO_CACHE") {
        Some(dir) => Some(PathBuf::from(dir)),
        None => dirs::cache_dir().map(|d| d.join("gonio")),
    }
}

/// The basis of the training materials: read from the cache, or built (about 5 s in a release
/// build, once per machine) and cached; an error names the cache file that could not be written.
pub fn training_basis() -> Result<Basis, String> {
    let names = training_names();
    let tag = format!("gonio pca basis v{CACHE_VERSION} {}", names.join(","));
    // Every training material or an error: a basis silently missing one would still carry the tag.
    let build = || -> Result<Vec<Box<dyn Material>>, String> {
        names
            .iter()
            .map(|n| {
                NeuralBrdf::bundled(n)
                    .map(|m| Box::new(m) as Box<dyn Material>)
                    .map_err(|e| format!("training material {n}: {e}"))
            })
            .collect()
    };
    let Some(dir) = cache_dir() else {
        return Ok(Basis::build(&build()?));
    };
    let path = dir.join(format!("pca-basis-v{CACHE_VERSION}.bin"));
    Basis::load_or_build(&path, &tag, build).map_err(|e| format!("the PCA basis cache {}: {e}", path.display()))
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
            // Guard: an invalid bin (below the horizon) has no value.
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
    use super::*;

    /// The basis never sees a held-out material.
    #[test]
    fn the_training_materials_exclude_the_held_out_fifteen() {
        let names = training_names();
        assert_eq!(names.len(), NeuralBrdf::bundled_names().count() - 15);
        assert!(!names.contains(&"tungsten-carbide"));
        assert!(names.contains(&"chrome"));
    }
}
