//! A PCA basis of measured BRDFs (Nielsen et al. 2015, section 4): every training material tabulated at the
//! bin centres, each bin's f cos_i cos_o log-mapped against the training set's per-bin median, each
//! colour channel an observation, mean-centred, and the principal components from the Gram matrix
//! of the observations (225 x 225 for 75 materials: far cheaper than an SVD over 65,536 bins).
//! Built once and cached (`load_or_build`).

use super::bins::{centre, cos_weight, map, BINS};
use crate::brdf::Material;
use nalgebra::{DMatrix, SymmetricEigen};
use rayon::prelude::*;
use std::io::Read;
use std::path::Path;

/// Components whose variance is below this fraction of the largest are dropped (numerical rank).
const RANK_TOL: f64 = 1e-9;

/// The specs of `Basis::small_analytic` (the first is inside its span by construction).
pub const SMALL_ANALYTIC: [&str; 4] = [
    "ggx:alpha=0.1,diffuse=0.2",
    "ggx:alpha=0.3,diffuse=0.05",
    "ggx:alpha=0.05,diffuse=0.5/0.3/0.1",
    "lambert:albedo=0.4",
];

/// The basis: per bin its median, mean and the components' values.
#[derive(Clone, Debug, PartialEq)]
pub struct Basis {
    /// Per bin: the training median of f cos (before mapping).
    pub median: Vec<f64>,
    /// Per bin: the mean of the mapped observations.
    pub mean: Vec<f64>,
    /// BINS x k, bin-major: orthonormal principal components (unit norm over the bins).
    pub components: Vec<f32>,
    /// Standard deviation of each component's coefficient over the training observations.
    pub sigma: Vec<f64>,
    /// Whether the bin's centre is above the horizon on both sides.
    pub valid: Vec<bool>,
}

impl Basis {
    pub fn k(&self) -> usize {
        self.sigma.len()
    }

    /// Component values of one bin.
    pub fn row(&self, bin: usize) -> &[f32] {
        let k = self.k();
        &self.components[bin * k..(bin + 1) * k]
    }

    /// Build from `materials` (every material gives three observations, one per channel).
    pub fn build(materials: &[Box<dyn Material>]) -> Self {
        Self::from_observations(&tabulate(materials))
    }

    /// A basis of four analytic materials (`SMALL_ANALYTIC`), seconds to build in a debug build:
    /// the fixture of this module's tests and of the lab's peer tests.
    pub fn small_analytic() -> Self {
        let materials: Vec<Box<dyn Material>> = SMALL_ANALYTIC
            .iter()
            .filter_map(|s| crate::brdf::parse_material(s).ok())
            .collect();
        Self::build(&materials)
    }

    /// Build from observations (`tabulate`'s rows: BINS values of f cos each).
    pub fn from_observations(obs: &[Vec<f64>]) -> Self {
        let valid: Vec<bool> = (0..BINS).map(|b| centre(b).is_some()).collect();
        let n = obs.len();
        let median: Vec<f64> = (0..BINS)
            .into_par_iter()
            .map(|b| {
                let mut v: Vec<f64> = obs.iter().map(|o| o[b]).collect();
                v.sort_by(f64::total_cmp);
                match n {
                    0 => 0.0,
                    _ if n % 2 == 1 => v[n / 2],
                    _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
                }
            })
            .collect();
        let mapped: Vec<Vec<f64>> = obs
            .iter()
            .map(|o| o.iter().zip(&median).map(|(&x, &m)| map(x, m)).collect())
            .collect();
        let mean: Vec<f64> = (0..BINS)
            .map(|b| mapped.iter().map(|o| o[b]).sum::<f64>() / n.max(1) as f64)
            .collect();
        let centred: Vec<Vec<f64>> = mapped
            .into_iter()
            .map(|o| o.iter().zip(&mean).map(|(x, m)| x - m).collect())
            .collect();
        // Gram matrix of the observations and its eigenvectors: component j = Y v_j / sqrt(lambda_j).
        let gram = DMatrix::from_fn(n, n, |i, j| {
            if j < i {
                return 0.0;
            }
            centred[i].iter().zip(&centred[j]).map(|(a, b)| a * b).sum::<f64>()
        });
        let gram = DMatrix::from_fn(n, n, |i, j| if j >= i { gram[(i, j)] } else { gram[(j, i)] });
        let eig = SymmetricEigen::new(gram);
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let top = order.first().map_or(0.0, |&i| eig.eigenvalues[i]);
        let keep: Vec<usize> = order
            .into_iter()
            .filter(|&i| eig.eigenvalues[i] > RANK_TOL * top && eig.eigenvalues[i] > 0.0)
            .collect();
        let k = keep.len();
        let mut components = vec![0f32; BINS * k];
        components.par_chunks_mut(k.max(1)).enumerate().for_each(|(b, row)| {
            for (j, &e) in keep.iter().enumerate() {
                let lambda = eig.eigenvalues[e];
                let v = eig.eigenvectors.column(e);
                let dot: f64 = (0..n).map(|o| centred[o][b] * v[o]).sum();
                row[j] = (dot / lambda.sqrt()) as f32;
            }
        });
        let sigma = keep.iter().map(|&e| (eig.eigenvalues[e] / n as f64).sqrt()).collect();
        Self {
            median,
            mean,
            components,
            sigma,
            valid,
        }
    }

    /// Read the cache at `path` if it holds a basis with this `tag`, else build and write it. One
    /// process builds while the others wait on a lock beside the file (parallel tests on a cold machine).
    pub fn load_or_build(
        path: &Path,
        tag: &str,
        materials: impl FnOnce() -> Result<Vec<Box<dyn Material>>, String>,
    ) -> std::io::Result<Self> {
        if let Ok(b) = Self::read(path, tag) {
            return Ok(b);
        }
        std::fs::create_dir_all(crate::fsio::parent_dir(path))?;
        let lock = std::fs::File::create(path.with_extension("lock"))?;
        // fs4's, not std's `File::lock` (Rust 1.89, above the workspace's rust-version).
        fs4::FileExt::lock(&lock)?;
        if let Ok(b) = Self::read(path, tag) {
            return Ok(b);
        }
        let b = Self::build(&materials().map_err(std::io::Error::other)?);
        b.write(path, tag)?;
        Ok(b)
    }

    fn write(&self, path: &Path, tag: &str) -> std::io::Result<()> {
        let mut out = Vec::with_capacity(self.components.len() * 4 + BINS * 17 + 64);
        let put_u64 = |out: &mut Vec<u8>, v: u64| out.extend_from_slice(&v.to_le_bytes());
        put_u64(&mut out, tag.len() as u64);
        out.extend_from_slice(tag.as_bytes());
        put_u64(&mut out, self.k() as u64);
        for v in self.median.iter().chain(&self.mean).chain(&self.sigma) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in &self.components {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend(self.valid.iter().map(|&v| v as u8));
        crate::fsio::write_bytes_atomically(path, &out)
    }

    fn read(path: &Path, tag: &str) -> std::io::Result<Self> {
        let mut bytes = Vec::new();
        std::fs::File::open(path)?.read_to_end(&mut bytes)?;
        let bad = || std::io::Error::new(std::io::ErrorKind::InvalidData, "not this basis");
        let mut at = 0usize;
        let mut take = |n: usize| -> std::io::Result<&[u8]> {
            let s = bytes.get(at..at + n).ok_or_else(bad)?;
            at += n;
            Ok(s)
        };
        let u64_of = |s: &[u8]| u64::from_le_bytes(s.try_into().unwrap_or([0; 8]));
        let len = u64_of(take(8)?) as usize;
        if take(len)? != tag.as_bytes() {
            return Err(bad());
        }
        let k = u64_of(take(8)?) as usize;
        if k > 100_000 {
            return Err(bad());
        }
        let mut f64s = |n: usize| -> std::io::Result<Vec<f64>> {
            Ok(take(8 * n)?
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
                .collect())
        };
        let median = f64s(BINS)?;
        let mean = f64s(BINS)?;
        let sigma = f64s(k)?;
        let components = take(4 * BINS * k)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap_or([0; 4])))
            .collect();
        let valid = take(BINS)?.iter().map(|&v| v != 0).collect();
        Ok(Self {
            median,
            mean,
            components,
            sigma,
            valid,
        })
    }
}

/// Each material's f cos_i cos_o (cosine product clipped, `bins::cos_weight`) at every bin centre,
/// one row per channel (0 where the centre is below the horizon).
pub fn tabulate(materials: &[Box<dyn Material>]) -> Vec<Vec<f64>> {
    materials
        .iter()
        .flat_map(|m| {
            let table: Vec<[f64; 3]> = (0..BINS)
                .into_par_iter()
                .map(|b| match centre(b) {
                    Some((wi, wo)) => (m.eval(wi, wo) * cos_weight(wi, wo)).to_array(),
                    None => [0.0; 3],
                })
                .collect();
            (0..3).map(move |c| table.iter().map(|v| v[c]).collect::<Vec<f64>>())
        })
        .collect()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::brdf::parse_material;

    /// Components are orthonormal over the bins, the cache reads back what was written, and a
    /// cache with another tag is rebuilt.
    #[test]
    fn components_are_orthonormal_and_the_cache_round_trips() {
        assert!(SMALL_ANALYTIC.iter().all(|s| parse_material(s).is_ok()));
        let b = Basis::small_analytic();
        assert!(b.k() >= 2 && b.k() <= 12, "{}", b.k());
        for i in 0..b.k() {
            for j in 0..b.k() {
                let dot: f64 = (0..BINS).map(|x| b.row(x)[i] as f64 * b.row(x)[j] as f64).sum();
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((dot - want).abs() < 1e-3, "{i} {j} {dot}");
            }
        }
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("basis.bin");
        b.write(&path, "t1").expect("write");
        assert_eq!(Basis::read(&path, "t1").expect("read"), b);
        assert!(Basis::read(&path, "t2").is_err());
        let again =
            Basis::load_or_build(&path, "t1", || panic!("the cache holds t1: nothing to build")).expect("cached");
        assert_eq!(again.k(), b.k());
        // A builder that fails is an error, and the cache is left as it was.
        let failed = Basis::load_or_build(&path, "t2", || Err("no material".into()));
        assert!(failed.is_err_and(|e| e.to_string().contains("no material")));
        assert_eq!(Basis::read(&path, "t1").expect("read"), b);
    }
}
