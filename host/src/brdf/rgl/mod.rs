//! RGL / Dupuy-Jakob 2018 measured BRDF files (`*.bsdf`, isotropic RGB), read and evaluated exactly
//! as Mitsuba 3's `measured` plugin does (`/work/shared/reference/RGL-FORMAT.md`, sections 1-5).
//! `tabulate_ggx` writes a file by the section-6 recipe; it exists for the tests and benches here,
//! the full writer comes with the end-to-end issue.

mod marginal;
pub mod tensor;

use super::frame::{from_spherical, half_vector, reflect};
use super::microfacet::{ndf, projected_area};
use super::{BrdfError, Material};
use glam::{DVec2, DVec3};
use marginal::Marginal2D;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;
use tensor::{Field, DTYPE_F32, DTYPE_U32, DTYPE_U8};

/// Square-root warp of the elevation: u = sqrt(theta / (pi/2)).
fn u_theta(theta: f64) -> f64 {
    (theta / FRAC_PI_2).max(0.0).sqrt()
}
fn theta_of_u(u: f64) -> f64 {
    u * u * FRAC_PI_2
}
fn u_phi(phi: f64) -> f64 {
    (phi + PI) / (2.0 * PI)
}
fn phi_of_u(u: f64) -> f64 {
    2.0 * PI * u - PI
}
/// Elevation of a unit vector, 2 asin(|d - z| / 2): stable near the pole, unlike acos(d.z).
fn elevation(d: DVec3) -> f64 {
    2.0 * (0.5 * (d - DVec3::Z).length()).min(1.0).asin()
}

pub struct RglBsdf {
    pub description: String,
    theta_i: Vec<f64>,
    ndf: Marginal2D,
    sigma: Marginal2D,
    vndf: Marginal2D,
    rgb: Marginal2D,
    jacobian: bool,
}

impl RglBsdf {
    pub fn read(path: &Path) -> Result<Self, BrdfError> {
        let bytes = std::fs::read(path).map_err(|e| BrdfError::io(path, e))?;
        Self::from_bytes(&bytes, path)
    }

    /// Parse and check the fields as Mitsuba does (its "Invalid file structure" checks, plus: the
    /// file must be isotropic and the warps normalisable).
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, BrdfError> {
        let fields = tensor::parse(bytes, path)?;
        let bad = |reason: String| BrdfError::format(path, format!("RGL file: {reason}"));
        let get = |name: &str, dtype: u8, ndim: usize| -> Result<&Field, BrdfError> {
            let f = fields.get(name).ok_or_else(|| bad(format!("missing field '{name}'")))?;
            if f.dtype != dtype || f.shape.len() != ndim {
                return Err(bad(format!(
                    "field '{name}' has dtype {} and {} dims, expected {dtype} and {ndim}",
                    f.dtype,
                    f.shape.len()
                )));
            }
            Ok(f)
        };
        let description = String::from_utf8_lossy(&get("description", DTYPE_U8, 1)?.bytes).into_owned();
        let phi_i: Vec<f64> = get("phi_i", DTYPE_F32, 1)?
            .as_f32()
            .into_iter()
            .map(f64::from)
            .collect();
        let theta_i: Vec<f64> = get("theta_i", DTYPE_F32, 1)?
            .as_f32()
            .into_iter()
            .map(f64::from)
            .collect();
        let jacobian = get("jacobian", DTYPE_U8, 1)?;
        let (ndf_f, sigma_f) = (get("ndf", DTYPE_F32, 2)?, get("sigma", DTYPE_F32, 2)?);
        let (vndf_f, lum_f, rgb_f) = (
            get("vndf", DTYPE_F32, 4)?,
            get("luminance", DTYPE_F32, 4)?,
            get("rgb", DTYPE_F32, 5)?,
        );
        if jacobian.shape[0] != 1 {
            return Err(bad("field 'jacobian' must have length 1".into()));
        }
        if phi_i.is_empty() || phi_i.len() > 2 {
            return Err(bad(format!(
                "{} phi_i values: only isotropic files (1 or 2) are supported",
                phi_i.len()
            )));
        }
        if theta_i.len() < 2 || !theta_i.windows(2).all(|w| w[0] < w[1]) || !theta_i.iter().all(|t| t.is_finite()) {
            return Err(bad("theta_i must hold at least 2 strictly increasing values".into()));
        }
        let (np, nt) = (phi_i.len(), theta_i.len());
        for f in [vndf_f, lum_f, rgb_f] {
            if f.shape[0] != np || f.shape[1] != nt {
                return Err(bad(format!(
                    "a table's leading dims {:?} are not (len(phi_i), len(theta_i)) = ({np}, {nt})",
                    &f.shape[..2]
                )));
            }
        }
        if rgb_f.shape[2] != 3 {
            return Err(bad(format!("rgb has {} channels, expected 3", rgb_f.shape[2])));
        }
        let n = rgb_f.shape[3];
        if lum_f.shape[2] != lum_f.shape[3] || lum_f.shape[2..] != rgb_f.shape[3..] {
            return Err(bad(format!(
                "luminance {:?} and rgb {:?} grids disagree or are not square",
                lum_f.shape, rgb_f.shape
            )));
        }
        let small = |s: &[usize]| s.iter().any(|&d| d < 2);
        if small(&ndf_f.shape) || small(&sigma_f.shape) || small(&vndf_f.shape[2..]) || small(&rgb_f.shape[3..]) {
            return Err(bad("every 2D table must be at least 2 x 2".into()));
        }
        let finite = |f: &Field| f.as_f32().iter().all(|v| v.is_finite());
        if ![ndf_f, sigma_f, vndf_f, rgb_f].into_iter().all(finite) {
            return Err(bad("a table holds a non-finite value".into()));
        }
        let table = |f: &Field, params: Vec<Vec<f64>>, normalize: bool, cdf: bool, name: &str| {
            let (h, w) = (f.shape[f.shape.len() - 2], f.shape[f.shape.len() - 1]);
            Marginal2D::new(f.as_f32(), w, h, params, normalize, cdf)
                .map_err(|s| bad(format!("{name} slice {s} integrates to 0 and cannot be normalised")))
        };
        let ndf = table(ndf_f, vec![], false, false, "ndf")?;
        let sigma = table(sigma_f, vec![], false, false, "sigma")?;
        let vndf = table(vndf_f, vec![phi_i.clone(), theta_i.clone()], true, true, "vndf")?;
        // Luminance only drives importance sampling; it is checked (normalisable), not kept.
        table(lum_f, vec![phi_i.clone(), theta_i.clone()], true, true, "luminance")?;
        let rgb = table(
            rgb_f,
            vec![phi_i, theta_i.clone(), vec![0.0, 1.0, 2.0]],
            false,
            false,
            "rgb",
        )?;
        let _ = n;
        Ok(Self {
            description,
            theta_i,
            ndf,
            sigma,
            vndf,
            rgb,
            jacobian: jacobian.bytes[0] != 0,
        })
    }

    /// The incident elevations of the file (radians).
    pub fn theta_i(&self) -> &[f64] {
        &self.theta_i
    }

    /// Mitsuba's `eval`: f cos theta of the second direction, with the data's incident axis the first.
    fn eval_projected(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let Some(m) = half_vector(wi, wo) else {
            return DVec3::ZERO;
        };
        let (theta_i, phi_i) = (elevation(wi), wi.y.atan2(wi.x));
        let (theta_m, phi_m) = (elevation(m), m.y.atan2(m.x));
        let u_wi = DVec2::new(u_theta(theta_i), u_phi(phi_i));
        let mut u_m = DVec2::new(u_theta(theta_m), u_phi(phi_m - phi_i));
        u_m.y -= u_m.y.floor();
        let (s, _) = self.vndf.invert(u_m, &[phi_i, theta_i]);
        let mut r = DVec3::new(
            self.rgb.eval(s, &[phi_i, theta_i, 0.0]),
            self.rgb.eval(s, &[phi_i, theta_i, 1.0]),
            self.rgb.eval(s, &[phi_i, theta_i, 2.0]),
        );
        if self.jacobian {
            // sigma(u_wi) >= its smallest node, positive in every valid file; a zero is refused here
            // rather than divided by.
            let sigma = self.sigma.eval(u_wi, &[]);
            if !(sigma > 0.0) {
                return DVec3::ZERO;
            }
            r *= self.ndf.eval(u_m, &[]) / (4.0 * sigma);
        }
        r
    }
}

impl Material for RglBsdf {
    /// f = (Mitsuba's f cos theta_o) / cos theta_o. The data's incident axis is wi (the light); the
    /// file's model is not reciprocal and nothing here symmetrises it.
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let f = self.eval_projected(wi, wo) / wo.z;
        // wo.z > 0 is tiny only at grazing exitance; keep the result finite whatever the data hold.
        if f.is_finite() {
            f
        } else {
            DVec3::ZERO
        }
    }
}

/// The RGL rule for incident elevations: `k` angles from 0 to `theta_max` (both included) with the
/// GGX projected area sigma(theta) equally spaced between its end values. sigma falls monotonically
/// with theta, so each angle is found by bisection (60 halvings: below f64 resolution).
pub fn sigma_spaced_thetas(alpha: f64, k: usize, theta_max: f64) -> Vec<f64> {
    if k <= 1 {
        return vec![0.0];
    }
    let sigma = |theta: f64| projected_area(from_spherical(theta, 0.0), alpha);
    let (s0, s1) = (sigma(0.0), sigma(theta_max));
    (0..k)
        .map(|i| {
            if i == 0 {
                return 0.0;
            }
            if i == k - 1 {
                return theta_max;
            }
            let target = s0 - i as f64 / (k - 1) as f64 * (s0 - s1);
            let (mut lo, mut hi) = (0.0, theta_max);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if sigma(mid) > target {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            0.5 * (lo + hi)
        })
        .collect()
}

/// Write an isotropic RGB file for `material` by RGL-FORMAT.md section 6, using a GGX alpha for the
/// warp: K incident elevations by the RGL sigma rule, n x n vndf/ndf/sigma tables, N x N rgb grid.
pub fn tabulate_ggx(material: &dyn Material, alpha: f64, k: usize, n: usize, grid: usize) -> Vec<u8> {
    let sigma_of = |theta: f64| projected_area(from_spherical(theta, 0.0), alpha);
    let d_of = |theta: f64| ndf(from_spherical(theta, 0.0), alpha);
    // 1. theta_i by the RGL sigma rule, stored and used as f32.
    let thetas: Vec<f64> = sigma_spaced_thetas(alpha, k, FRAC_PI_2)
        .into_iter()
        .map(|t| t as f32 as f64)
        .collect();
    // 2. ndf and sigma on the u_theta grid, two identical rows.
    let u: Vec<f64> = (0..n).map(|j| j as f64 / (n - 1) as f64).collect();
    let row = |f: &dyn Fn(f64) -> f64| -> Vec<f32> {
        u.iter().map(|&x| f(theta_of_u(x)) as f32).collect::<Vec<_>>().repeat(2)
    };
    let ndf_t = row(&d_of);
    let sigma_t = row(&sigma_of);
    // 3. vndf per slice, normalised to sum 1.
    let mut vndf = Vec::with_capacity(k * n * n);
    for &ti in &thetas {
        // f32(pi/2) lies just past the horizon, where sigma (an upper-hemisphere formula) is 0.
        let ti = ti.min(FRAC_PI_2);
        let wi = from_spherical(ti, 0.0);
        let mut slice = Vec::with_capacity(n * n);
        for y in 0..n {
            for &ux in &u {
                let (tm, pm) = (theta_of_u(ux), phi_of_u(y as f64 / (n - 1) as f64));
                let m = from_spherical(tm, pm);
                slice.push(d_of(tm) * wi.dot(m).max(0.0) / sigma_of(ti) * 2.0 * PI * PI * ux * tm.sin());
            }
        }
        let sum: f64 = slice.iter().sum();
        vndf.extend(slice.iter().map(|v| (v / sum) as f32));
    }
    let theta_params: Vec<f64> = thetas.clone();
    let ndf_m = Marginal2D::new(ndf_t.clone(), n, 2, vec![], false, false).ok();
    let sigma_m = Marginal2D::new(sigma_t.clone(), n, 2, vec![], false, false).ok();
    let vndf_m = Marginal2D::new(vndf.clone(), n, n, vec![vec![0.0], theta_params], true, true).ok();
    // 4. rgb at the warped nodes, with the tables' own interpolated D and sigma.
    let mut rgb = vec![0.0f32; k * 3 * grid * grid];
    let mut lum = vec![0.0f32; k * grid * grid];
    if let (Some(ndf_m), Some(sigma_m), Some(vndf_m)) = (ndf_m, sigma_m, vndf_m) {
        for (ki, &ti) in thetas.iter().enumerate() {
            // The last slice sits at f32(pi/2), just below the horizon: evaluate it slightly above.
            let t_eval = ti.min(FRAC_PI_2 - 1e-4);
            let wi = from_spherical(t_eval, 0.0);
            let sigma_hat = sigma_m.eval(DVec2::new(u_theta(t_eval), 0.5), &[]);
            for i in 0..grid {
                for j in 0..grid {
                    let s = DVec2::new(j as f64 / (grid - 1) as f64, i as f64 / (grid - 1) as f64);
                    let (um, _) = vndf_m.sample(s, &[0.0, ti]);
                    let m = from_spherical(theta_of_u(um.x), phi_of_u(um.y));
                    let wo = reflect(wi, m);
                    let d_hat = ndf_m.eval(um, &[]);
                    let r = if wo.z > 0.0 && d_hat > 0.0 {
                        material.eval(wi, wo) * wo.z * 4.0 * sigma_hat / d_hat
                    } else {
                        DVec3::ZERO
                    };
                    for c in 0..3 {
                        rgb[((ki * 3 + c) * grid + i) * grid + j] = r[c] as f32;
                    }
                    let y = 0.212671 * r.x + 0.715160 * r.y + 0.072169 * r.z;
                    lum[(ki * grid + i) * grid + j] = y.max(0.0) as f32;
                }
            }
            // 5. No all-zero luminance slice (it would not normalise).
            let sl = &mut lum[ki * grid * grid..(ki + 1) * grid * grid];
            if sl.iter().all(|&v| v == 0.0) {
                sl.iter_mut().for_each(|v| *v = 1.0);
            }
        }
    }
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let thetas_f32: Vec<f32> = thetas.iter().map(|&t| t as f32).collect();
    let valid_bits = (k * grid * grid).div_ceil(8);
    tensor::write(&[
        (
            "version",
            DTYPE_U32,
            vec![2],
            [1u32.to_le_bytes(), 0u32.to_le_bytes()].concat(),
        ),
        ("description", DTYPE_U8, vec![23], b"gonio tabulate_ggx test".to_vec()),
        ("phi_i", DTYPE_F32, vec![1], f32s(&[0.0])),
        ("theta_i", DTYPE_F32, vec![k], f32s(&thetas_f32)),
        ("sigma", DTYPE_F32, vec![2, n], f32s(&sigma_t)),
        ("ndf", DTYPE_F32, vec![2, n], f32s(&ndf_t)),
        ("vndf", DTYPE_F32, vec![1, k, n, n], f32s(&vndf)),
        ("luminance", DTYPE_F32, vec![1, k, grid, grid], f32s(&lum)),
        ("rgb", DTYPE_F32, vec![1, k, 3, grid, grid], f32s(&rgb)),
        ("jacobian", DTYPE_U8, vec![1], vec![1]),
        ("valid", DTYPE_U8, vec![valid_bits], vec![0xff; valid_bits]),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::analytic::Ggx;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn ggx() -> Ggx {
        Ggx {
            alpha: 0.3,
            diffuse: DVec3::ZERO,
            specular: DVec3::new(0.9, 0.7, 0.5),
        }
    }

    /// A file written by the section-6 recipe (real files' sizes: K 8, n 128, N 64) from an analytic
    /// GGX reads back and evaluates close to the analytic material: normal incidence (on the first
    /// slice) to 1e-3, and random pairs to a cosine-weighted relative RMS of a few percent, which
    /// grazing-grazing forward scattering dominates (there the file is ~35% low, as the RGL notes'
    /// 85-90 deg band warns).
    #[test]
    fn reads_back_a_tabulated_ggx() {
        let bytes = tabulate_ggx(&ggx(), 0.3, 8, 128, 64);
        let bsdf = RglBsdf::from_bytes(&bytes, Path::new("ggx.bsdf")).expect("valid file");
        assert_eq!(bsdf.theta_i().len(), 8);
        let (wi, wo) = (DVec3::Z, from_spherical(0.3, 1.0));
        let (got, want) = (bsdf.eval(wi, wo), ggx().eval(wi, wo));
        assert!((got - want).length() < 1e-3 * want.length(), "{got} vs {want}");
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let (mut err, mut norm) = (0.0, 0.0);
        for _ in 0..5000 {
            let wi = from_spherical(rng.random::<f64>().acos(), 0.0);
            let wo = from_spherical(rng.random::<f64>().acos(), 2.0 * PI * rng.random::<f64>());
            let (a, b) = (bsdf.eval(wi, wo) * wo.z, ggx().eval(wi, wo) * wo.z);
            assert!(a.is_finite());
            err += (a - b).length_squared();
            norm += b.length_squared();
        }
        let rel = (err / norm).sqrt();
        println!("RGL tabulated GGX alpha 0.3: cosine-weighted relative RMS {rel:.4}");
        assert!(rel < 0.06, "{rel}");
        // Away from grazing only the theta_i interpolation remains: within 3% up to 60 deg.
        for ti in [0.0_f64, 10.0, 31.0, 45.0, 60.0] {
            for to in [0.0_f64, 20.0, 40.0, 60.0] {
                for po in [0.0_f64, 90.0, 180.0] {
                    let (wi, wo) = (
                        from_spherical(ti.to_radians(), 0.0),
                        from_spherical(to.to_radians(), po.to_radians()),
                    );
                    let (a, b) = (bsdf.eval(wi, wo), ggx().eval(wi, wo));
                    assert!((a - b).length() < 0.03 * b.length(), "{ti} {to} {po}: {a} vs {b}");
                }
            }
        }
        assert_eq!(bsdf.eval(wi, -wo), DVec3::ZERO);
    }

    #[test]
    fn refuses_broken_files() {
        let bytes = tabulate_ggx(&ggx(), 0.3, 4, 16, 8);
        let p = Path::new("x.bsdf");
        let msg = |b: &[u8]| {
            RglBsdf::from_bytes(b, p)
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default()
        };
        assert_eq!(
            msg(b"not a tensor file at all"),
            "x.bsdf: RGL tensor file: bad magic (expected \"tensor_file\\0\")"
        );
        assert!(
            msg(&bytes[..bytes.len() - 4]).contains("past the end of the file"),
            "{}",
            msg(&bytes[..bytes.len() - 4])
        );
        let mut v = bytes.clone();
        v[13] = 1;
        assert_eq!(msg(&v), "x.bsdf: RGL tensor file: version 1.1, expected 1.0");
        let no_rgb = tensor::write(&[("theta_i", DTYPE_F32, vec![1], vec![0; 4])]);
        assert_eq!(msg(&no_rgb), "x.bsdf: RGL file: missing field 'description'");
        assert!(RglBsdf::from_bytes(&bytes, p).is_ok());
    }
}
