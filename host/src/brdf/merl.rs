//! The MERL `.binary` BRDF table (Matusik et al. 2003), read and written exactly:
//! little-endian header of three i32 (90, 90, 180) = (n_theta_h, n_theta_d, n_phi_d), then
//! 3 x 1,458,000 f64, channel-major (R, G, B), index phi_d + 180 (theta_d + 90 theta_h),
//! value = raw x (1/1500, 1.15/1500, 1.66/1500). Negative raw values mean "not measured" and read as 0.
//!
//! Bins: theta_h_i = floor(90 sqrt(theta_h / (pi/2))), theta_d_i = floor(theta_d / (pi/2) 90),
//! phi_d_i = floor(phi_d / pi 180) after phi_d += pi for phi_d < 0 (reciprocity), each clamped.
//! A bin's value is taken to be the BRDF at the bin's centre (index + 1/2 in these coordinates):
//! `tabulate` evaluates there, the nearest-bin lookup returns it for the whole bin, and the
//! trilinear lookup interpolates between centres (phi_d periodic with period pi, the other two
//! clamped at the first and last centre).

use super::half_diff::{from_half_diff, to_half_diff};
use super::{BrdfError, Material};
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;

pub const N_THETA_H: usize = 90;
pub const N_THETA_D: usize = 90;
pub const N_PHI_D: usize = 180;
const CELLS: usize = N_THETA_H * N_THETA_D * N_PHI_D;
const HEADER_BYTES: usize = 12;
/// 34,992,012 bytes.
pub const FILE_BYTES: usize = HEADER_BYTES + 3 * CELLS * 8;
/// Raw-to-physical factors per channel.
pub const SCALE: [f64; 3] = [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0];

#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Lookup {
    /// The reference reader's nearest bin.
    #[default]
    Nearest,
    /// Trilinear between bin centres.
    Trilinear,
}

#[derive(Clone, Debug)]
pub struct MerlTable {
    /// Raw values as stored, channel-major.
    raw: Vec<f64>,
    pub lookup: Lookup,
}

/// Continuous bin coordinates (bin i spans [i, i + 1)) of a pair, `None` without a half vector.
fn bin_coords(wi: DVec3, wo: DVec3) -> Option<[f64; 3]> {
    layout_coords(wi, wo, [N_THETA_H, N_THETA_D, N_PHI_D])
}

/// Continuous bin coordinates of a pair in MERL's layout at any resolution `[theta_h, theta_d,
/// phi_d]` (theta_h on a square-root scale, phi_d folded into [0, pi)); `None` without a half vector.
pub fn layout_coords(wi: DVec3, wo: DVec3, dims: [usize; 3]) -> Option<[f64; 3]> {
    let hd = to_half_diff(wi, wo)?;
    let th = (hd.theta_h.max(0.0) / FRAC_PI_2).sqrt() * dims[0] as f64;
    let td = hd.theta_d.max(0.0) / FRAC_PI_2 * dims[1] as f64;
    let pd = if hd.phi_d < 0.0 { hd.phi_d + PI } else { hd.phi_d };
    Some([th, td, pd / PI * dims[2] as f64])
}

/// The bin a pair's continuous coordinates `b` fall in (floored, clamped to the grid of `dims`).
pub fn layout_nearest(b: [f64; 3], dims: [usize; 3]) -> [usize; 3] {
    std::array::from_fn(|i| (b[i].floor().max(0.0) as usize).min(dims[i] - 1))
}

/// Trilinear lookup between bin centres of a MERL-layout grid of `dims` bins: phi_d periodic, the
/// other two clamped at the first and last centre; `bin(th, td, pd)` reads one bin.
pub fn layout_trilinear(b: [f64; 3], dims: [usize; 3], bin: impl Fn(usize, usize, usize) -> DVec3) -> DVec3 {
    // Position relative to the centres: centre i sits at i + 1/2.
    let clamped = |x: f64, n: usize| {
        let p = (x - 0.5).clamp(0.0, (n - 1) as f64);
        let i = (p.floor() as usize).min(n - 2);
        (i, i + 1, p - i as f64)
    };
    let (h0, h1, fh) = clamped(b[0], dims[0]);
    let (d0, d1, fd) = clamped(b[1], dims[1]);
    let p = (b[2] - 0.5).rem_euclid(dims[2] as f64);
    let p0 = (p.floor() as usize).min(dims[2] - 1);
    let (p1, fp) = ((p0 + 1) % dims[2], p - p0 as f64);
    let mut acc = DVec3::ZERO;
    for (h, wh) in [(h0, 1.0 - fh), (h1, fh)] {
        for (d, wd) in [(d0, 1.0 - fd), (d1, fd)] {
            for (q, wp) in [(p0, 1.0 - fp), (p1, fp)] {
                acc += wh * wd * wp * bin(h, d, q);
            }
        }
    }
    acc
}

fn index(th: usize, td: usize, pd: usize) -> usize {
    pd + N_PHI_D * (td + N_THETA_D * th)
}

impl MerlTable {
    pub fn read(path: &Path) -> Result<Self, BrdfError> {
        let bytes = std::fs::read(path).map_err(|e| BrdfError::io(path, e))?;
        Self::from_bytes(&bytes, path)
    }

    /// Parse a whole file; the header must be exactly (90, 90, 180) and the size exactly FILE_BYTES.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, BrdfError> {
        if bytes.len() < HEADER_BYTES {
            return Err(BrdfError::format(
                path,
                format!("not a MERL .binary: {} bytes, shorter than the header", bytes.len()),
            ));
        }
        let dim = |k: usize| i32::from_le_bytes([bytes[4 * k], bytes[4 * k + 1], bytes[4 * k + 2], bytes[4 * k + 3]]);
        let dims = (dim(0), dim(1), dim(2));
        if dims != (N_THETA_H as i32, N_THETA_D as i32, N_PHI_D as i32) {
            return Err(BrdfError::format(
                path,
                format!("not a MERL .binary: header {dims:?}, expected (90, 90, 180)"),
            ));
        }
        if bytes.len() != FILE_BYTES {
            return Err(BrdfError::format(
                path,
                format!("MERL .binary of {} bytes, expected {FILE_BYTES}", bytes.len()),
            ));
        }
        let raw = bytes[HEADER_BYTES..]
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
            .collect();
        Ok(Self {
            raw,
            lookup: Lookup::Nearest,
        })
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(FILE_BYTES);
        for d in [N_THETA_H, N_THETA_D, N_PHI_D] {
            out.extend_from_slice(&(d as i32).to_le_bytes());
        }
        for v in &self.raw {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// Write to `path` through a temporary file in the same folder and a rename, so a reader never
    /// sees a half-written table.
    pub fn write(&self, path: &Path) -> Result<(), BrdfError> {
        crate::fsio::write_bytes_atomically(path, &self.to_bytes()).map_err(|e| BrdfError::io(path, e))
    }

    /// Tabulate any material at the bin centres (phi_h = 0: the table is isotropic), symmetrised:
    /// each bin holds (f(wi, wo) + f(wo, wi)) / 2. The format folds phi_d by pi, i.e. it assumes
    /// reciprocity (swapping wi and wo maps phi_d to phi_d + pi, the same bin); a reconstruction
    /// is not exactly reciprocal, and writing one direction alone would hand a reader f(wi, wo) for
    /// (wo, wi) too. Pairs whose centre lies below the horizon get whatever the material returns
    /// there, 0 for every model here. Bins run in parallel (rayon).
    pub fn tabulate(material: &dyn Material) -> Self {
        let values: Vec<DVec3> = (0..CELLS)
            .into_par_iter()
            .map(|i| {
                let (pd, td, th) = (i % N_PHI_D, (i / N_PHI_D) % N_THETA_D, i / (N_PHI_D * N_THETA_D));
                let u = (th as f64 + 0.5) / N_THETA_H as f64;
                let theta_h = u * u * FRAC_PI_2;
                let theta_d = (td as f64 + 0.5) / N_THETA_D as f64 * FRAC_PI_2;
                let phi_d = (pd as f64 + 0.5) / N_PHI_D as f64 * PI;
                let (wi, wo) = from_half_diff(theta_h, theta_d, phi_d);
                (material.eval(wi, wo) + material.eval(wo, wi)) * 0.5
            })
            .collect();
        let mut raw = vec![0.0; 3 * CELLS];
        for (i, f) in values.iter().enumerate() {
            for (c, v) in f.to_array().into_iter().enumerate() {
                raw[c * CELLS + i] = v / SCALE[c];
            }
        }
        Self {
            raw,
            lookup: Lookup::Nearest,
        }
    }

    /// Physical value of one bin; "not measured" (negative) reads as 0.
    fn bin(&self, i: usize) -> DVec3 {
        let v = |c: usize| (self.raw[c * CELLS + i] * SCALE[c]).max(0.0);
        DVec3::new(v(0), v(1), v(2))
    }

    fn nearest(&self, b: [f64; 3]) -> DVec3 {
        let [h, d, q] = layout_nearest(b, [N_THETA_H, N_THETA_D, N_PHI_D]);
        self.bin(index(h, d, q))
    }

    fn trilinear(&self, b: [f64; 3]) -> DVec3 {
        layout_trilinear(b, [N_THETA_H, N_THETA_D, N_PHI_D], |h, d, q| self.bin(index(h, d, q)))
    }
}

impl Material for MerlTable {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let Some(b) = bin_coords(wi, wo) else {
            return DVec3::ZERO;
        };
        match self.lookup {
            Lookup::Nearest => self.nearest(b),
            Lookup::Trilinear => self.trilinear(b),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::analytic::{Ggx, Lambert};
    use crate::brdf::frame::from_spherical;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The nearest bin clamps every extreme into the grid: below 0, at and past the last bin, NaN.
    #[test]
    fn nearest_bin_clamps_into_the_grid() {
        let dims = [4, 5, 6];
        assert_eq!(layout_nearest([0.0, 0.99, 5.5], dims), [0, 0, 5]);
        assert_eq!(layout_nearest([-3.0, 5.0, 1e9], dims), [0, 4, 5]);
        assert_eq!(layout_nearest([f64::NAN, f64::INFINITY, -0.0], dims), [0, 4, 0]);
    }

    fn random_pair(rng: &mut ChaCha8Rng) -> (DVec3, DVec3) {
        let mut dir = || from_spherical(rng.random::<f64>().acos(), 2.0 * PI * rng.random::<f64>());
        (dir(), dir())
    }

    /// tabulate -> write -> read -> eval: exact at the bin centres; elsewhere the nearest lookup
    /// returns the source at the centre of the bin the pair falls in (the binning error, nothing
    /// more), and trilinear beats nearest on a smooth material.
    #[test]
    fn round_trip_through_a_file() {
        let source = Ggx {
            alpha: 0.3,
            diffuse: DVec3::new(0.2, 0.3, 0.4),
            specular: DVec3::new(0.9, 0.8, 0.7),
        };
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("ggx.binary");
        MerlTable::tabulate(&source).write(&path).expect("write");
        assert_eq!(std::fs::metadata(&path).map(|m| m.len()).ok(), Some(FILE_BYTES as u64));
        let mut table = MerlTable::read(&path).expect("read back");
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (mut err_near, mut err_tri, mut norm, mut n) = (0.0, 0.0, 0.0, 0);
        for _ in 0..20_000 {
            let (wi, wo) = random_pair(&mut rng);
            let Some(b) = bin_coords(wi, wo) else { continue };
            table.lookup = Lookup::Nearest;
            let got = table.eval(wi, wo);
            // The centre of this pair's bin, evaluated on the source.
            let c = b.map(|x| x.floor() + 0.5);
            let u = c[0] / N_THETA_H as f64;
            let (ci, co) = from_half_diff(
                u * u * FRAC_PI_2,
                c[1] / N_THETA_D as f64 * FRAC_PI_2,
                c[2] / N_PHI_D as f64 * PI,
            );
            let want = source.eval(ci, co);
            assert!(
                (got - want).length() <= 1e-12 * want.length().max(1e-300),
                "{got} vs centre {want}"
            );
            table.lookup = Lookup::Trilinear;
            let tri = table.eval(wi, wo);
            // Errors weighted by cos_i cos_o, as the values enter a rendering.
            let (truth, w) = (source.eval(wi, wo), wi.z * wo.z);
            err_near += (w * (got - truth)).length_squared();
            err_tri += (w * (tri - truth)).length_squared();
            norm += (w * truth).length_squared();
            n += 1;
        }
        let (rel_near, rel_tri) = ((err_near / norm).sqrt(), (err_tri / norm).sqrt());
        println!("MERL round trip over {n} random pairs: cosine-weighted relative RMS nearest {rel_near:.4}, trilinear {rel_tri:.4}");
        assert!(
            rel_near < 0.05 && rel_tri < rel_near,
            "nearest {rel_near}, trilinear {rel_tri}"
        );
    }

    #[test]
    fn refuses_bad_size_and_header() {
        let good = MerlTable::tabulate(&Lambert {
            albedo: DVec3::splat(0.5),
        })
        .to_bytes();
        let p = Path::new("t.binary");
        assert!(MerlTable::from_bytes(&good, p).is_ok());
        let short = MerlTable::from_bytes(&good[..good.len() - 8], p)
            .err()
            .map(|e| e.to_string());
        assert_eq!(
            short,
            Some(format!(
                "t.binary: MERL .binary of {} bytes, expected 34992012",
                FILE_BYTES - 8
            ))
        );
        let mut bad = good.clone();
        bad[0..4].copy_from_slice(&91_i32.to_le_bytes());
        let msg = MerlTable::from_bytes(&bad, p).err().map(|e| e.to_string());
        assert_eq!(
            msg,
            Some("t.binary: not a MERL .binary: header (91, 90, 180), expected (90, 90, 180)".into())
        );
        assert!(MerlTable::from_bytes(&good[..5], p).is_err());
        assert!(matches!(
            MerlTable::read(Path::new("/nonexistent/x.binary")),
            Err(BrdfError::Io { .. })
        ));
    }

    /// The exported table is reciprocal, whatever the material: a material that depends on wi only
    /// (f = 1 + 3 cos^2 theta_i, far from reciprocal) is written as the mean of both orders, so a
    /// reader gets the same value for (wi, wo) and (wo, wi), and that value is the mean at the bin centre.
    #[test]
    fn the_exported_table_is_reciprocal() {
        struct LightSide;
        impl Material for LightSide {
            fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
                if wi.z <= 0.0 || wo.z <= 0.0 {
                    return DVec3::ZERO;
                }
                DVec3::new(1.0, 0.5, 0.25) * (1.0 + 3.0 * wi.z * wi.z)
            }
        }
        let table = MerlTable::tabulate(&LightSide);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (mut checked, mut skewed) = (0, 0);
        for _ in 0..5_000 {
            let (wi, wo) = random_pair(&mut rng);
            let (Some(b), Some(s)) = (bin_coords(wi, wo), bin_coords(wo, wi)) else {
                continue;
            };
            // Pairs near a phi_d bin edge may fold into the neighbouring bin: not this test's subject.
            if b.map(|x| x.floor()) != s.map(|x| x.floor()) {
                continue;
            }
            let (ab, ba) = (table.eval(wi, wo), table.eval(wo, wi));
            assert!((ab - ba).length() <= 1e-12 * ab.length(), "{ab} vs {ba}");
            // The bin's value is the mean of both orders at its centre.
            let c = b.map(|x| x.floor() + 0.5);
            let u = c[0] / N_THETA_H as f64;
            let (ci, co) = from_half_diff(
                u * u * FRAC_PI_2,
                c[1] / N_THETA_D as f64 * FRAC_PI_2,
                c[2] / N_PHI_D as f64 * PI,
            );
            let (f, g) = (LightSide.eval(ci, co), LightSide.eval(co, ci));
            assert!((ab - (f + g) * 0.5).length() <= 1e-9 * ab.length(), "{ab} vs {f} / {g}");
            // The source itself is not reciprocal here: a one-order table would have failed.
            if (f - g).length() > 0.1 * f.length() {
                skewed += 1;
            }
            checked += 1;
        }
        assert!(
            checked > 4_000 && skewed > 1_000,
            "{checked} pairs, {skewed} non-reciprocal"
        );
    }

    /// Negative raw values ("not measured") read as 0, and the per-channel scales apply.
    #[test]
    fn scales_and_unmeasured_bins() {
        let mut t = MerlTable::tabulate(&Lambert {
            albedo: DVec3::splat(PI),
        });
        let (wi, wo) = (from_spherical(0.2, 0.0), from_spherical(0.3, 2.0));
        assert!((t.eval(wi, wo) - DVec3::ONE).length() < 1e-12);
        let b = bin_coords(wi, wo).expect("pair");
        let i = index(b[0] as usize, b[1] as usize, b[2] as usize);
        t.raw[i] = -1.0;
        assert_eq!(t.eval(wi, wo).x, 0.0);
        t.raw[CELLS + i] = 1500.0;
        assert!((t.eval(wi, wo).y - 1.15).abs() < 1e-12);
    }
}
