//! Tabulated warps: the invertible piecewise-linear `Marginal2D` (RGL's Marginal2D, continuous
//! variant, with vertex positions that need not be equally spaced), the `MixtureWarp` that composes
//! it with the GGX visible-normal warp (eq. 6 of Cao et al. as a bijection), and `UniformAngles`, the
//! plain (theta_o, phi_o) grid the planner compares against.

use super::{GgxVndf, Warp};
use crate::brdf::frame::{clamp_u, from_spherical, luminance, phi_of, theta_of, wrap_unit, ONE_MINUS_EPSILON};
use crate::brdf::Material;
use glam::{DVec2, DVec3};
use std::f64::consts::{FRAC_PI_2, PI};

/// A density on [0, 1]^2, bilinear between vertex values on a (possibly graded) rectangular grid,
/// sampled as marginal in x then conditional in y, each by inverting a piecewise-quadratic CDF.
/// Every vertex value must be > 0, which makes both CDFs strictly increasing: a bijection of
/// [0, 1]^2 with an exact inverse.
#[derive(Clone, Debug)]
pub struct Marginal2D {
    xs: Vec<f64>,
    ys: Vec<f64>,
    /// Vertex values, index iy * nx + ix, normalised so the density integrates to 1.
    d: Vec<f64>,
    /// Per column ix: the conditional CDF in y at each y vertex (unnormalised, ends at col_mass[ix]).
    col_cdf: Vec<f64>,
    col_mass: Vec<f64>,
    /// Marginal CDF in x at each x vertex (ends at 1).
    x_cdf: Vec<f64>,
}

/// Solve a t (in [0, 1]) with h (a t + (b - a) t^2 / 2) = r for a linear density a -> b over a cell
/// of width h. The rationalised root 2r/h / (a + sqrt(a^2 + 2 (b - a) r / h)) has no cancellation
/// when b ~ a; a, b > 0 keeps the denominator positive.
fn linear_cell_inverse(a: f64, b: f64, h: f64, r: f64) -> f64 {
    let q = r / h;
    let disc = (a * a + 2.0 * (b - a) * q).max(0.0);
    (2.0 * q / (a + disc.sqrt())).clamp(0.0, 1.0)
}

/// Cell index of `x` in the increasing vertex list `v` and the fraction across it.
fn locate(v: &[f64], x: f64) -> (usize, f64) {
    let i = v.partition_point(|&p| p <= x).saturating_sub(1).min(v.len() - 2);
    let t = ((x - v[i]) / (v[i + 1] - v[i])).clamp(0.0, 1.0);
    (i, t)
}

impl Marginal2D {
    /// `values[iy * xs.len() + ix]` at vertex (xs[ix], ys[iy]); xs and ys increase strictly from 0 to 1.
    pub fn new(xs: Vec<f64>, ys: Vec<f64>, values: Vec<f64>) -> Result<Self, String> {
        let (nx, ny) = (xs.len(), ys.len());
        let axis_ok =
            |v: &[f64]| v.len() >= 2 && v[0] == 0.0 && v[v.len() - 1] == 1.0 && v.windows(2).all(|w| w[0] < w[1]);
        if !axis_ok(&xs) || !axis_ok(&ys) {
            return Err("Marginal2D: vertex positions must increase strictly from 0 to 1".into());
        }
        if values.len() != nx * ny || !values.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(format!(
                "Marginal2D: need {} finite positive values, got {}",
                nx * ny,
                values.len()
            ));
        }
        let mut col_cdf = vec![0.0; nx * ny];
        let mut col_mass = vec![0.0; nx];
        for ix in 0..nx {
            let mut acc = 0.0;
            for iy in 1..ny {
                acc += 0.5 * (ys[iy] - ys[iy - 1]) * (values[(iy - 1) * nx + ix] + values[iy * nx + ix]);
                col_cdf[iy * nx + ix] = acc;
            }
            col_mass[ix] = acc;
        }
        let mut x_cdf = vec![0.0; nx];
        for ix in 1..nx {
            x_cdf[ix] = x_cdf[ix - 1] + 0.5 * (xs[ix] - xs[ix - 1]) * (col_mass[ix - 1] + col_mass[ix]);
        }
        let total = x_cdf[nx - 1];
        let scale = 1.0 / total;
        Ok(Self {
            xs,
            ys,
            d: values.iter().map(|v| v * scale).collect(),
            col_cdf: col_cdf.iter().map(|v| v * scale).collect(),
            col_mass: col_mass.iter().map(|v| v * scale).collect(),
            x_cdf: x_cdf.iter().map(|v| v * scale).collect(),
        })
    }

    fn nx(&self) -> usize {
        self.xs.len()
    }

    /// Conditional (unnormalised) CDF values and vertex densities of the y column at x = (cell i, t).
    fn column(&self, i: usize, t: f64, iy: usize) -> (f64, f64) {
        let nx = self.nx();
        let lerp = |v: &[f64]| v[iy * nx + i] * (1.0 - t) + v[iy * nx + i + 1] * t;
        (lerp(&self.col_cdf), lerp(&self.d))
    }

    /// Density at v (integrates to 1 over the square).
    pub fn eval(&self, v: DVec2) -> f64 {
        let (i, tx) = locate(&self.xs, v.x);
        let (j, ty) = locate(&self.ys, v.y);
        let (_, d0) = self.column(i, tx, j);
        let (_, d1) = self.column(i, tx, j + 1);
        d0 * (1.0 - ty) + d1 * ty
    }

    /// u (clamped to [0, 1 - eps]^2) to v.
    pub fn sample(&self, u: DVec2) -> DVec2 {
        let u = clamp_u(u);
        // Marginal in x: the cell whose CDF interval holds u.x, then the quadratic within it.
        let i = self
            .x_cdf
            .partition_point(|&c| c <= u.x)
            .saturating_sub(1)
            .min(self.nx() - 2);
        let (a, b) = (self.col_mass[i], self.col_mass[i + 1]);
        let h = self.xs[i + 1] - self.xs[i];
        let tx = linear_cell_inverse(a, b, h, u.x - self.x_cdf[i]);
        let x = self.xs[i] + tx * h;
        // Conditional in y at x: the columns' CDFs interpolate linearly in x like the values do.
        let mass = a * (1.0 - tx) + b * tx;
        let target = u.y * mass;
        let ny = self.ys.len();
        let (mut lo, mut hi) = (0usize, ny - 1);
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if self.column(i, tx, mid).0 <= target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let (c0, d0) = self.column(i, tx, lo);
        let (_, d1) = self.column(i, tx, lo + 1);
        let hy = self.ys[lo + 1] - self.ys[lo];
        let ty = linear_cell_inverse(d0, d1, hy, target - c0);
        DVec2::new(x, self.ys[lo] + ty * hy).min(DVec2::splat(ONE_MINUS_EPSILON))
    }

    /// v to the u that `sample` maps to it.
    pub fn invert(&self, v: DVec2) -> DVec2 {
        let (i, tx) = locate(&self.xs, v.x.clamp(0.0, 1.0));
        let (a, b) = (self.col_mass[i], self.col_mass[i + 1]);
        let h = self.xs[i + 1] - self.xs[i];
        let ux = self.x_cdf[i] + h * (a * tx + 0.5 * (b - a) * tx * tx);
        let mass = a * (1.0 - tx) + b * tx;
        let (j, ty) = locate(&self.ys, v.y.clamp(0.0, 1.0));
        let (c0, d0) = self.column(i, tx, j);
        let (_, d1) = self.column(i, tx, j + 1);
        let hy = self.ys[j + 1] - self.ys[j];
        let cy = c0 + hy * (d0 * ty + 0.5 * (d1 - d0) * ty * ty);
        DVec2::new(ux, cy / mass).clamp(DVec2::ZERO, DVec2::splat(ONE_MINUS_EPSILON))
    }
}

/// Weight of the plain visible-normal density in the mixture (eq. 6's w_s): the share of nodes that
/// stay where the pure-specular warp would put them, so a misestimated lobe still gets samples.
/// With the reconstruction's fitted prior (`reconstruct::TwoLobesPrior`) the peak's samples pay more
/// than the estimate's f cos share (now w_f = 0.1): the fit needs the peak's height and width.
/// Chosen on 14 MERL materials the encoder trained on (docs/tradeoff/README.md has the command),
/// adaptive against uniform brdf_log_err wins of 56: (w_s, w_u) = (0.15, 0.5) 40, (0.3, 0.5) 41,
/// (0.4, 0.5) 42, (0.5, 0.5) 43, (0.3, 0.6) 36; (0.4, 0.5) keeps a little f cos share and a worst
/// 2 x 2 FLIP ratio close to (0.15, 0.5)'s (6.5x against 6.1x). Re-swept in the closed loop
/// against point FLIP (`--trial mixture:`, docs/tradeoff/README.md): no pair wins all three metrics.
pub const MIXTURE_SPECULAR_WEIGHT: f64 = 0.4;
/// Weight of the equal-angle density (the uniform grid's layout): coverage of directions that
/// neither the estimate nor the peak would visit, where a misestimated material may still reflect.
/// Half the mass keeps a coarse level's outer ring (u.x = 1/2 at 2 x 2) out of a sharp peak: with
/// w_s = w_u = 0.25 the peak held over half of u.x and its value spread over the hemisphere (on the
/// encoder's 15 held-out MERL materials, `gonio tradeoff --preset heldout`, worst FLIP 8.0x the
/// uniform grid's at 2 x 2, against 3.0x with these weights).
pub const MIXTURE_UNIFORM_WEIGHT: f64 = 0.5;

/// The mixture's (w_s, w_u) (w_f = 1 - w_s - w_u); the product plans with `MixtureWeights::PRODUCT`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MixtureWeights {
    pub specular: f64,
    pub uniform: f64,
}

impl MixtureWeights {
    pub const PRODUCT: MixtureWeights = MixtureWeights {
        specular: MIXTURE_SPECULAR_WEIGHT,
        uniform: MIXTURE_UNIFORM_WEIGHT,
    };

    /// None unless both weights are in [0, 1] and their sum is at most 1.
    pub fn new(specular: f64, uniform: f64) -> Option<Self> {
        let unit = |w: f64| (0.0..=1.0).contains(&w);
        (unit(specular) && unit(uniform) && specular + uniform <= 1.0).then_some(Self { specular, uniform })
    }
}
/// Smallest alpha the mixture's visible-normal base uses. Below it, the whole hemisphere outside
/// the peak maps into a sliver of u.x near 1 narrower than any table could resolve; the table then
/// puts the peak's mass back where the estimate says it is.
pub const MIXTURE_BASE_ALPHA_MIN: f64 = 0.02;
/// Every table vertex gets at least this fraction of the mean value, so the CDFs increase strictly
/// (a bijection even where the estimate is black or the base warp points below the horizon).
const TABLE_FLOOR: f64 = 1e-4;

/// eq. 6 of Cao et al. as a bijection: wo = vndf(T(u)) with T a `Marginal2D` whose density in the
/// visible-normal warp's u-space is w_f f cos / p_vndf + w_s + w_u p_angles / p_vndf (each part
/// normalised over the square, the w_s part over where the base lands above the horizon), so that
/// the composed density over wo is p = w_f p_fcos + w_s p_vndf + w_u p_angles: the estimated
/// material's whole lobe, diffuse base included, plus the plain specular layout, plus the
/// equal-angle layout as a defensive share. pdf(wo) = T's density at vndf^-1(wo) times p_vndf(wo).
#[derive(Clone, Debug)]
pub struct MixtureWarp {
    base: GgxVndf,
    base_alpha: f64,
    table: Marginal2D,
}

impl MixtureWarp {
    /// Tabulate `estimate` for `wi` on a `res` x `res` vertex grid (x graded, see `table_xs`).
    pub fn new(wi: DVec3, alpha: f64, estimate: &dyn Material, res: usize) -> Self {
        Self::with_weights(wi, alpha, estimate, res, MixtureWeights::PRODUCT)
    }

    /// `new` with other weights (the lab's trials of them).
    pub fn with_weights(wi: DVec3, alpha: f64, estimate: &dyn Material, res: usize, weights: MixtureWeights) -> Self {
        let base_alpha = if alpha.is_finite() {
            alpha.max(MIXTURE_BASE_ALPHA_MIN)
        } else {
            1.0
        };
        let base = GgxVndf::new(wi, base_alpha);
        let xs = table_xs(base_alpha, res.max(4));
        let ys: Vec<f64> = (0..res.max(4)).map(|j| j as f64 / (res.max(4) - 1) as f64).collect();
        let (nx, ny) = (xs.len(), ys.len());
        let mut fcos = vec![0.0; nx * ny];
        let mut valid = vec![0.0; nx * ny];
        let mut angles = vec![0.0; nx * ny];
        let wos: Vec<Option<DVec3>> = ys
            .iter()
            .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
            .map(|(x, y)| base.sample(base_u(DVec2::new(x, y))))
            .collect();
        for iy in 0..ny {
            for ix in 0..nx {
                let Some(wo) = wos[iy * nx + ix] else { continue };
                let p = base.pdf(wo);
                let g = luminance(estimate.eval(wi, wo)).max(0.0) * wo.z;
                // p > 0 wherever the base lands above the horizon except on the rim, where the
                // ratio has no value: such a vertex carries only the specular share.
                if p > 0.0 && g.is_finite() {
                    fcos[iy * nx + ix] = g / p;
                    angles[iy * nx + ix] = pole_guarded_angles_pdf(wo, wos[iy * nx + (ix + 1).min(nx - 1)]) / p;
                }
                valid[iy * nx + ix] = 1.0;
            }
        }
        let integral = |v: &[f64]| -> f64 {
            let mut s = 0.0;
            for iy in 1..ny {
                for ix in 1..nx {
                    let c = v[(iy - 1) * nx + ix - 1] + v[(iy - 1) * nx + ix] + v[iy * nx + ix - 1] + v[iy * nx + ix];
                    s += 0.25 * c * (xs[ix] - xs[ix - 1]) * (ys[iy] - ys[iy - 1]);
                }
            }
            s
        };
        let (fi, vi, ai) = (integral(&fcos), integral(&valid), integral(&angles));
        // A black estimate has no f cos share; its weight goes to the specular layout.
        let (w_s, w_u) = if fi > 0.0 {
            (weights.specular, weights.uniform)
        } else {
            (1.0 - weights.uniform, weights.uniform)
        };
        let w_f = 1.0 - w_s - w_u;
        let mut values: Vec<f64> = (0..nx * ny)
            .map(|k| {
                let f = if fi > 0.0 { w_f * fcos[k] / fi } else { 0.0 };
                let s = if vi > 0.0 { w_s * valid[k] / vi } else { 1.0 };
                let a = if ai > 0.0 { w_u * angles[k] / ai } else { 0.0 };
                f + s + a
            })
            .collect();
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let floor = TABLE_FLOOR * if mean > 0.0 { mean } else { 1.0 };
        for v in &mut values {
            *v = v.max(floor);
        }
        // Positive, finite values on strictly increasing axes: `new` cannot fail.
        let table = Marginal2D::new(xs, ys, values).expect("mixture table is valid by construction");
        Self {
            base,
            base_alpha,
            table,
        }
    }

    /// The u of wo through this slice's table but the base warp re-centred on another incident
    /// direction `wi` (RGL's lookup: a query between two slices maps wo through the warp of its own
    /// wi, so a peak that moves with wi is found at the same u in both slices). `invert` is
    /// `invert_from(own wi, wo)`.
    pub fn invert_from(&self, wi: DVec3, wo: DVec3) -> Option<DVec2> {
        GgxVndf::new(wi, self.base_alpha)
            .invert(wo)
            .map(|v| self.table.invert(table_v(v)))
    }
}

/// The table's azimuth y starts a quarter turn into the visible-normal warp's: y = u.y - 1/4.
/// Why: the base warp's u.y = 0 is its disk's t1 axis, perpendicular to the incidence plane, so
/// its seam splits the disk into a forward and a backward half, whose f cos masses differ; the
/// table's conditional CDF in y then put the nodes u.y = 0 and 1/2 at two unrelated oblique
/// azimuths, different in every slice (at 2 x 2 of a sharp estimate: one beside the peak toward
/// grazing, one behind the normal). With the seam in the incidence plane the two halves are mirror
/// images (an isotropic estimate is symmetric about that plane), each holds half the mass, and
/// the node columns are symmetric about the plane at every level: u.y = 0 and 1/2 lie in it
/// (forward and backward, where an isotropic lobe's profile lies) and u.y, 1 - u.y are mirror
/// images (`mixture_nodes_are_symmetric_about_the_incidence_plane`).
const TABLE_AZIMUTH_OFFSET: f64 = 0.25;

/// The base warp's u of table point `v`.
fn base_u(v: DVec2) -> DVec2 {
    DVec2::new(v.x, (v.y + TABLE_AZIMUTH_OFFSET).rem_euclid(1.0))
}

/// The table point of the base warp's `u` (inverse of `base_u`).
fn table_v(u: DVec2) -> DVec2 {
    DVec2::new(u.x, (u.y - TABLE_AZIMUTH_OFFSET).rem_euclid(1.0))
}

/// The equal-angle density at a table vertex `wo`, read as the mean over the vertex's own cell near
/// the pole. Guard: 1 / sin theta is integrable but has no value at theta = 0, and at normal
/// incidence the vertices of the first column sit exactly on the pole (u.x = 0 is wo = z); a
/// pointwise value there (1e11 at `UNIFORM_MIN_SIN`) made the equal-angle share's normalising
/// integral all pole, so half the mixture's mass (w_u) collapsed into the first cell and every node
/// of the normal-incidence slice landed within 10 deg of the normal. Over a cap of radius d the
/// mean of 1 / sin theta is about 2 / d, so sin theta is held at half the angle to the next
/// vertex along x (`next`); away from the pole nothing changes.
fn pole_guarded_angles_pdf(wo: DVec3, next: Option<DVec3>) -> f64 {
    let spacing = next.map_or(0.0, |n| wo.dot(n).clamp(-1.0, 1.0).acos());
    angles_pdf(wo, (0.5 * spacing).max(UNIFORM_MIN_SIN))
}

/// The equal-angle density 1 / (pi^2 sin theta) per solid angle with sin theta held at `min_sin`
/// or above (its pole guard); 0 at and below the horizon.
fn angles_pdf(wo: DVec3, min_sin: f64) -> f64 {
    if !(wo.z > 0.0) || !wo.is_finite() {
        return 0.0;
    }
    1.0 / (PI * PI * theta_of(wo).sin().max(min_sin))
}

/// Table x vertices: half equally spaced in the visible-normal warp's u.x, half equally spaced in the
/// microfacet normal's angle theta_m (u.x = tan^2 / (alpha^2 + tan^2) at normal incidence), merged.
/// The first half resolves the peak, the second the far tail that a small alpha squeezes toward u.x = 1.
fn table_xs(alpha: f64, res: usize) -> Vec<f64> {
    let half = (res / 2).max(2);
    let mut xs: Vec<f64> = (0..half).map(|i| i as f64 / (half - 1) as f64).collect();
    for i in 1..half - 1 {
        let t = (FRAC_PI_2 * i as f64 / (half - 1) as f64).tan();
        xs.push(t * t / (alpha * alpha + t * t));
    }
    xs.sort_by(f64::total_cmp);
    // Merge vertices closer than 1e-9: they would make a zero-width cell.
    xs.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    if let Some(last) = xs.last_mut() {
        *last = 1.0;
    }
    xs
}

impl Warp for MixtureWarp {
    fn sample(&self, u: DVec2) -> Option<DVec3> {
        self.base.sample(base_u(self.table.sample(u)))
    }
    fn invert(&self, wo: DVec3) -> Option<DVec2> {
        self.base.invert(wo).map(|v| self.table.invert(table_v(v)))
    }
    fn pdf(&self, wo: DVec3) -> f64 {
        match self.base.invert(wo) {
            Some(v) => self.table.eval(table_v(v)) * self.base.pdf(wo),
            None => 0.0,
        }
    }
}

/// Equal steps in angle: theta_o = u.x pi/2, phi_o = 2 pi u.y; pdf = 1 / (pi^2 sin theta) per solid angle.
#[derive(Clone, Copy, Debug, Default)]
pub struct UniformAngles;

/// Below this sin theta the pdf is evaluated at it: the 1/sin pole is integrable and has no value
/// at theta = 0 itself.
const UNIFORM_MIN_SIN: f64 = 1e-12;

impl Warp for UniformAngles {
    fn sample(&self, u: DVec2) -> Option<DVec3> {
        let u = clamp_u(u);
        // u.x <= 1 - eps keeps theta < pi/2: every clamped u is above the horizon.
        Some(from_spherical(u.x * FRAC_PI_2, 2.0 * PI * u.y))
    }
    fn invert(&self, wo: DVec3) -> Option<DVec2> {
        if !(wo.z > 0.0) || !wo.is_finite() {
            return None;
        }
        Some(DVec2::new(
            (theta_of(wo) / FRAC_PI_2).min(ONE_MINUS_EPSILON),
            wrap_unit(phi_of(wo) / (2.0 * PI)),
        ))
    }
    fn pdf(&self, wo: DVec3) -> f64 {
        angles_pdf(wo, UNIFORM_MIN_SIN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::analytic::Ggx;
    use crate::brdf::chi2::{chi2_test, Chi2Config, Domain};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn materials() -> Vec<(&'static str, Ggx, f64)> {
        vec![
            (
                "sharp+diffuse",
                Ggx {
                    alpha: 0.03,
                    diffuse: DVec3::splat(0.3),
                    specular: DVec3::ONE,
                },
                0.03,
            ),
            (
                "rough",
                Ggx {
                    alpha: 0.6,
                    diffuse: DVec3::splat(0.05),
                    specular: DVec3::ONE,
                },
                0.6,
            ),
            (
                "mirror-estimate",
                Ggx {
                    alpha: 1e-4,
                    diffuse: DVec3::splat(0.1),
                    specular: DVec3::ONE,
                },
                1e-4,
            ),
            (
                "black",
                Ggx {
                    alpha: 0.2,
                    diffuse: DVec3::ZERO,
                    specular: DVec3::ZERO,
                },
                0.2,
            ),
        ]
    }

    #[test]
    fn marginal2d_round_trip_and_normalisation() {
        let xs = vec![0.0, 0.1, 0.5, 0.9, 1.0];
        let ys = vec![0.0, 0.25, 0.5, 0.75, 1.0];
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let values: Vec<f64> = (0..25).map(|_| rng.random::<f64>() * 5.0 + 0.01).collect();
        let m = Marginal2D::new(xs, ys, values).expect("valid");
        let n = 400;
        let mut integral = 0.0;
        for i in 0..n {
            for j in 0..n {
                integral += m.eval(DVec2::new((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64));
            }
        }
        integral /= (n * n) as f64;
        assert!((integral - 1.0).abs() < 1e-4, "integral {integral}");
        for a in [0.0, 1e-9, 0.3, 0.5, 0.77, ONE_MINUS_EPSILON, 1.0] {
            for b in [0.0, 0.2, 0.5, 0.999, ONE_MINUS_EPSILON, 1.0] {
                let u = DVec2::new(a, b);
                let v = m.sample(u);
                assert!(v.is_finite() && v.min_element() >= 0.0 && v.max_element() < 1.0);
                let back = m.invert(v);
                assert!((back - clamp_u(u)).abs().max_element() < 1e-9, "{u} -> {v} -> {back}");
            }
        }
        assert!(Marginal2D::new(vec![0.0, 1.0], vec![0.0, 1.0], vec![1.0, 0.0, 1.0, 1.0]).is_err());
        assert!(Marginal2D::new(vec![0.0, 0.5], vec![0.0, 1.0], vec![1.0; 4]).is_err());
    }

    /// Round trips, extremes (alpha 0 and 1e-4 estimates, theta_i 0 and 90 deg, u = 0 and 1 - eps):
    /// finite everywhere, invert(sample(u)) = u wherever sample is valid.
    #[test]
    fn mixture_round_trips_and_extremes() {
        let edge = [0.0, 0.25, 0.5, 0.9, ONE_MINUS_EPSILON, 1.0, f64::NAN];
        for (name, mat, alpha) in materials() {
            for t in [0.0_f64, 30.0, 75.0, 89.9, 90.0] {
                let wi = from_spherical(t.to_radians(), 0.0);
                let w = MixtureWarp::new(wi, alpha, &mat, 33);
                let mut valid = 0;
                for &a in &edge {
                    for &b in &edge {
                        let u = DVec2::new(a, b);
                        let Some(wo) = w.sample(u) else { continue };
                        assert!(wo.is_finite() && wo.z > 0.0, "{name} {t}: {wo}");
                        let p = w.pdf(wo);
                        assert!(p.is_finite() && p >= 0.0, "{name} {t}: pdf {p}");
                        let back = w.invert(wo).unwrap_or_else(|| panic!("{name} {t}: no inverse of {wo}"));
                        let again = w.sample(back).expect("valid");
                        assert!(
                            (again - wo).length() < 1e-7,
                            "{name} {t}: {u} -> {wo} -> {back} -> {again}"
                        );
                        valid += 1;
                    }
                }
                if t < 89.0 {
                    assert!(valid > 0, "{name} {t}: nothing valid");
                }
                for to in [0.0_f64, 45.0, 89.9, 90.0] {
                    let p = w.pdf(from_spherical(to.to_radians(), 1.0));
                    assert!(p.is_finite() && p >= 0.0);
                }
            }
        }
    }

    /// chi-square of the composed sampler against its pdf, and the pdf integral (in the harness)
    /// plus the invalid fraction equals 1.
    #[test]
    fn mixture_and_uniform_chi_square() {
        let mats = materials();
        // theta_i 0 and 70 deg: the quadrature of a tabulated pdf is the slow part of this test.
        let cases: Vec<(String, Box<dyn Warp>)> = [0.0_f64, 70.0]
            .iter()
            .flat_map(|&t| {
                let wi = from_spherical(t.to_radians(), 0.0);
                let mut v: Vec<(String, Box<dyn Warp>)> = mats
                    .iter()
                    .map(|(name, m, a)| {
                        (
                            format!("mixture {name} theta_i {t}"),
                            Box::new(MixtureWarp::new(wi, *a, m, 33)) as Box<dyn Warp>,
                        )
                    })
                    .collect();
                v.push((format!("uniform theta_i {t}"), Box::new(UniformAngles)));
                v
            })
            .collect();
        let mut failures = Vec::new();
        for (i, (name, w)) in cases.iter().enumerate() {
            let cfg = Chi2Config {
                res_z: 24,
                res_phi: 48,
                samples: 100_000,
                seed: 77 + i as u64,
                significance: 0.01,
                test_count: cases.len(),
            };
            let sample = |u: DVec2| w.sample(u);
            let pdf = |wo: DVec3| w.pdf(wo);
            let out = chi2_test(name, &sample, &pdf, &Domain::Hemisphere, &cfg);
            println!(
                "{name:<40} chi2 {:>8.1} dof {:>4} p {:.3} pdf-int {:.5} invalid {:.5}",
                out.statistic, out.dof, out.p_value, out.pdf_integral, out.outside_fraction
            );
            if !out.passed() {
                failures.push(out.report.clone());
            }
            if (out.pdf_integral + out.outside_fraction - 1.0).abs() > 1e-2 {
                failures.push(format!(
                    "{name}: pdf {} + invalid {}",
                    out.pdf_integral, out.outside_fraction
                ));
            }
        }
        assert!(failures.is_empty(), "{}", failures.join("\n"));
    }

    #[test]
    fn uniform_round_trip_and_extremes() {
        let w = UniformAngles;
        for a in [0.0, 0.3, 0.999, ONE_MINUS_EPSILON, 1.0, -1.0, f64::NAN] {
            for b in [0.0, 0.5, ONE_MINUS_EPSILON, 1.0] {
                let wo = w.sample(DVec2::new(a, b)).expect("always valid");
                assert!(wo.is_finite() && wo.z > 0.0);
                assert!(w.pdf(wo).is_finite());
                let back = w.invert(wo).expect("invertible");
                let u = clamp_u(DVec2::new(a, b));
                assert!((back.x - u.x).abs() < 1e-12);
                if u.x > 1e-6 {
                    let d = (back.y - u.y).abs();
                    assert!(d.min(1.0 - d) < 1e-9, "{u} {back}");
                }
            }
        }
        assert_eq!(w.pdf(DVec3::new(1.0, 0.0, 0.0)), 0.0);
        assert_eq!(w.invert(DVec3::new(1.0, 0.0, -0.1)), None);
    }

    /// The point of the mixture: for a sharp peak on a diffuse base, the pure visible-normal warp
    /// leaves the diffuse hemisphere almost empty; the mixture puts about its f cos share there
    /// (diffuse albedo 0.3 against a specular lobe of ~1, times w_f, plus most of w_u: ~0.3).
    #[test]
    fn mixture_covers_the_diffuse_base() {
        let (_, mat, alpha) = materials()[0].clone();
        let wi = from_spherical(0.5, 0.0);
        let mix = MixtureWarp::new(wi, alpha, &mat, 33);
        let spec = GgxVndf::new(wi, alpha);
        let mirror = DVec3::new(-wi.x, -wi.y, wi.z);
        let far = |w: &dyn Warp| {
            let mut rng = ChaCha8Rng::seed_from_u64(9);
            let n = 20_000;
            (0..n)
                .filter(|_| {
                    w.sample(DVec2::new(rng.random(), rng.random()))
                        .is_some_and(|wo| wo.dot(mirror) < 20f64.to_radians().cos())
                })
                .count() as f64
                / n as f64
        };
        let (fm, fs) = (far(&mix), far(&spec));
        println!("share of samples > 20 deg from the mirror direction: mixture {fm:.3}, vndf {fs:.3}");
        assert!(fm > 0.12 && fs < 0.05, "mixture {fm}, vndf {fs}");
    }

    /// Weights outside [0, 1] or summing above 1 are refused; the product's are `new`'s, and a
    /// larger equal-angle share sends more samples away from the peak.
    #[test]
    fn mixture_weights_are_checked_and_move_the_samples() {
        for (s, u) in [(0.6, 0.6), (-0.1, 0.5), (0.5, 1.1), (f64::NAN, 0.5)] {
            assert_eq!(MixtureWeights::new(s, u), None, "({s}, {u})");
        }
        assert_eq!(MixtureWeights::new(0.4, 0.5), Some(MixtureWeights::PRODUCT));
        let (_, mat, alpha) = materials()[0].clone();
        let wi = from_spherical(0.5, 0.0);
        let mirror = DVec3::new(-wi.x, -wi.y, wi.z);
        let far_share = |w: &MixtureWarp| {
            let n = 64;
            let far = (0..n * n)
                .filter_map(|k| {
                    w.sample(DVec2::new(
                        ((k % n) as f64 + 0.5) / n as f64,
                        ((k / n) as f64 + 0.5) / n as f64,
                    ))
                })
                .filter(|wo| wo.dot(mirror) < 20f64.to_radians().cos())
                .count();
            far as f64 / (n * n) as f64
        };
        let product = far_share(&MixtureWarp::new(wi, alpha, &mat, 33));
        let same = far_share(&MixtureWarp::with_weights(wi, alpha, &mat, 33, MixtureWeights::PRODUCT));
        let wider = far_share(&MixtureWarp::with_weights(
            wi,
            alpha,
            &mat,
            33,
            MixtureWeights::new(0.1, 0.85).unwrap(),
        ));
        println!("share of samples > 20 deg from the mirror direction: w_u 0.5 {product:.3}, w_u 0.85 {wider:.3}");
        assert_eq!(product, same);
        assert!(
            wider > product + 0.1,
            "far share: product {product:.3}, w_u 0.85 {wider:.3}"
        );
    }

    /// At normal incidence the first column of table vertices sits on the pole of the equal-angle
    /// density (1 / sin theta): read pointwise, it took the whole equal-angle share and put 90% of
    /// u within 10 deg of the normal. The share of samples far from the mirror direction must be
    /// the same at theta_i = 0 as just off it (the extremes the guard is for: 0, 1e-6, 1e-3).
    #[test]
    fn mixture_is_continuous_at_normal_incidence() {
        let (_, mat, alpha) = materials()[0].clone();
        let far_share = |theta: f64| {
            let wi = from_spherical(theta, 0.0);
            let mix = MixtureWarp::new(wi, alpha, &mat, 33);
            let mirror = DVec3::new(-wi.x, -wi.y, wi.z);
            let n = 100;
            let mut far = 0;
            for a in 0..n {
                for b in 0..n {
                    let u = DVec2::new((a as f64 + 0.5) / n as f64, (b as f64 + 0.5) / n as f64);
                    if mix
                        .sample(u)
                        .is_some_and(|wo| wo.dot(mirror) < 20f64.to_radians().cos())
                    {
                        far += 1;
                    }
                }
            }
            far as f64 / (n * n) as f64
        };
        let shares: Vec<f64> = [0.0, 1e-6, 1e-3, 0.05].into_iter().map(far_share).collect();
        println!("share > 20 deg from the mirror at theta_i 0 / 1e-6 / 1e-3 / 0.05: {shares:.3?}");
        for &s in &shares {
            assert!(s > 0.3, "{shares:?}");
            assert!((s - shares[3]).abs() < 0.03, "{shares:?}");
        }
    }

    /// The node columns of a mixture warp are symmetric about the incidence plane (y = 0), at
    /// normal, oblique and grazing incidence and for a sharp, a rough and a mirror-like estimate:
    /// u.y = 0 and 1/2 land in the plane, u.y and 1 - u.y on mirror images. Without the table's
    /// quarter-turn azimuth (`TABLE_AZIMUTH_OFFSET`) u.y = 0 at theta_i 38 deg of the sharp estimate
    /// lands 45 deg out of the plane.
    #[test]
    fn mixture_nodes_are_symmetric_about_the_incidence_plane() {
        for (name, mat, alpha) in materials() {
            for t in [0.0_f64, 38.0, 76.0, 89.0] {
                let wi = from_spherical(t.to_radians(), 0.0);
                let w = MixtureWarp::new(wi, alpha, &mat, 33);
                // The plane's normal: y for oblique wi. At normal incidence every plane through
                // the normal is a symmetry plane (isotropy); the table's is the one through its
                // u.y = 0 column (the base warp's t2 axis there).
                let n = if t > 0.0 {
                    DVec3::Y
                } else {
                    let a0 = w.sample(DVec2::new(0.5, 0.0)).expect("above the horizon");
                    DVec3::Z.cross(a0).normalize()
                };
                let mirror = |v: DVec3| v - 2.0 * v.dot(n) * n;
                for x in [0.0, 0.25, 0.5, 0.75, 0.9375] {
                    for y in [0.0, 0.0625, 0.25, 0.375, 0.5] {
                        let a = w.sample(DVec2::new(x, y));
                        let b = w.sample(DVec2::new(x, (1.0 - y).rem_euclid(1.0)));
                        match (a, b) {
                            (Some(a), Some(b)) => assert!(
                                (mirror(a) - b).length() < 1e-6,
                                "{name} theta_i {t} u ({x}, {y}): {a} and {b} are not mirror images"
                            ),
                            (None, None) => {}
                            _ => panic!("{name} theta_i {t} u ({x}, {y}): only one side lands above the horizon"),
                        }
                        if y == 0.0 || y == 0.5 {
                            if let Some(wo) = a {
                                assert!(
                                    wo.dot(n).abs() < 1e-6,
                                    "{name} theta_i {t} u ({x}, {y}): {wo} out of the plane"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
