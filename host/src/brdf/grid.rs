//! The measurement grid a scan produces: per incoming slice, N x M nodes in the u-space of the
//! slice's warp, read back as a material by mapping wo to u and interpolating (docs/planner.md,
//! "The measurement grid").
//!
//! * `eval(wi, wo)`: rotate both by -phi_i, find the two slices bracketing theta_i (clamped beyond
//!   the ends), map wo to u through each slice's inverse warp, interpolate bilinearly in u
//!   (periodic in u.y), then in theta_i by a cubic Hermite through the bracketing slices (tangents
//!   from their neighbours). Nodes without a measurement are left out and the other weights
//!   renormalised; a slice that cannot map wo back is left out too (the other bracketing slice alone).
//! * A warp in the mirror limit has no inverse and is refused.

use super::frame::{from_spherical, phi_of, rotate_z, theta_of};
use super::warp::{SliceWarp, Warp};
use super::{BrdfError, Material};
use glam::{DVec2, DVec3};

const MIRROR_MSG: &str = "a slice warp is in the mirror limit and has no inverse";

/// Default number of incoming elevations.
pub const DEFAULT_K: usize = 8;
/// Largest incoming elevation measured (89 deg).
pub const THETA_I_MAX: f64 = 89.0 * std::f64::consts::PI / 180.0;

/// Where the nodes sit in u: u = (u.x of ring i, j / M).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NodeLayout {
    /// u.x = i / N: nested under doubling, pole included, rim excluded.
    Nested,
    /// As `Nested`, but N = 2 has u.x = 0 and 3/4.
    NestedFarRing,
}

/// u.x of `NestedFarRing`'s second ring at N = 2.
pub const FAR_RING_X: f64 = 0.75;

impl NodeLayout {
    /// The name files record (grid.json's `layout`).
    pub fn name(self) -> &'static str {
        match self {
            NodeLayout::Nested => "nested",
            NodeLayout::NestedFarRing => "nested-far-ring",
        }
    }

    /// u.x of ring i of an N-ring grid.
    pub fn node_x(self, i: usize, n: usize) -> f64 {
        match self {
            NodeLayout::NestedFarRing if n == 2 && i == 1 => FAR_RING_X,
            NodeLayout::Nested | NodeLayout::NestedFarRing => i as f64 / n as f64,
        }
    }

    /// Ring i of an N-ring level as a ring of the finest level's `fine_n` (nested layouts; N
    /// divides `fine_n`). `NestedFarRing` needs 4 | `fine_n` for its far ring to be a finest ring;
    /// the planner only picks it then (`plan::node_layout`), and without it this returns `Nested`'s.
    pub fn fine_index(self, i: usize, n: usize, fine_n: usize) -> usize {
        match self {
            NodeLayout::NestedFarRing if n == 2 && i == 1 && fine_n % 4 == 0 => 3 * fine_n / 4,
            _ => i * (fine_n / n.max(1)),
        }
    }

    /// Continuous ring coordinate of u.x in an N-ring grid, in [0, N - 1] (held beyond the last ring).
    fn ring_coordinate(self, ux: f64, n: usize) -> f64 {
        let ux = ux.clamp(0.0, 1.0);
        match self {
            NodeLayout::NestedFarRing if n == 2 => (ux / FAR_RING_X).min(1.0),
            NodeLayout::Nested | NodeLayout::NestedFarRing => (ux * n as f64).min((n - 1) as f64),
        }
    }
}

#[derive(Clone, Debug)]
pub struct MeasurementGrid {
    layout: NodeLayout,
    theta_i: Vec<f64>,
    n: usize,
    m: usize,
    /// Index (k M + j) N + i.
    values: Vec<DVec3>,
    valid: Vec<bool>,
    slices: Vec<SliceWarp>,
    /// Per node, a guide value the interpolation compares with the query's (`set_guide`); empty: none.
    guide: Vec<f64>,
    /// Width of the guide's Gaussian weight.
    guide_width: f64,
}

impl MeasurementGrid {
    /// A grid over slice warps (one per theta_i); `values` and `valid` are indexed (k M + j) N + i.
    pub fn from_slices(
        slices: Vec<SliceWarp>,
        layout: NodeLayout,
        theta_i: Vec<f64>,
        n: usize,
        m: usize,
        values: Vec<DVec3>,
        valid: Vec<bool>,
    ) -> Result<Self, BrdfError> {
        let bad = BrdfError::Grid;
        if n < 2 || m < 1 || theta_i.is_empty() || slices.len() != theta_i.len() {
            return Err(bad(format!(
                "grid needs N >= 2, M >= 1 and one warp per theta_i, got N {n}, M {m}, K {}, {} warps",
                theta_i.len(),
                slices.len()
            )));
        }
        if !theta_i.windows(2).all(|w| w[0] < w[1])
            || !theta_i.iter().all(|t| (0.0..=std::f64::consts::FRAC_PI_2).contains(t))
        {
            return Err(bad("theta_i must increase strictly within [0, pi/2]".into()));
        }
        let cells = theta_i.len() * n * m;
        if values.len() != cells || valid.len() != cells {
            return Err(bad(format!(
                "expected {cells} values and flags, got {} and {}",
                values.len(),
                valid.len()
            )));
        }
        // A mirror-limit warp sends every u to one direction and has no inverse: nothing to
        // reconstruct through.
        if slices.iter().any(Warp::is_delta) {
            return Err(bad(MIRROR_MSG.into()));
        }
        Ok(Self {
            layout,
            theta_i,
            n,
            m,
            values,
            valid,
            slices,
            guide: Vec::new(),
            guide_width: 1.0,
        })
    }

    /// Give each node (index (k M + j) N + i) a guide value: a guided lookup then weighs each of
    /// the four nodes around the query by exp(-((g_query - g_node) / width)^2) on top of bilinear.
    /// A non-finite node guide weighs 1. Panics if `guide` has not one value per node.
    pub fn set_guide(&mut self, guide: Vec<f64>, width: f64) {
        assert_eq!(guide.len(), self.values.len(), "one guide value per node");
        self.guide = guide;
        self.guide_width = width;
    }

    fn index(&self, k: usize, i: usize, j: usize) -> usize {
        (k * self.m + j) * self.n + i
    }

    pub fn theta_i(&self) -> &[f64] {
        &self.theta_i
    }
    /// (N, M).
    pub fn size(&self) -> (usize, usize) {
        (self.n, self.m)
    }

    /// The u of node (i, j).
    pub fn node_u(&self, i: usize, j: usize) -> DVec2 {
        DVec2::new(self.layout.node_x(i, self.n), j as f64 / self.m as f64)
    }

    /// Set node (k, i, j) (a measurement arriving); out-of-range indices are ignored.
    pub fn set_node(&mut self, k: usize, i: usize, j: usize, value: Option<DVec3>) {
        if k < self.theta_i.len() && i < self.n && j < self.m {
            let idx = self.index(k, i, j);
            self.values[idx] = value.unwrap_or(DVec3::ZERO);
            self.valid[idx] = value.is_some();
        }
    }

    /// Give every node without a measurement the value of the nearest measured node of its slice
    /// (distance in node steps, periodic in j). Filling beat dropping such nodes in the prototype:
    /// a dropped node leaves the cells around it to extrapolation from one side, or to black.
    pub fn fill_from_nearest(&mut self) {
        for k in 0..self.theta_i.len() {
            let measured: Vec<(usize, usize)> = (0..self.m)
                .flat_map(|j| (0..self.n).map(move |i| (i, j)))
                .filter(|&(i, j)| self.valid[self.index(k, i, j)])
                .collect();
            if measured.is_empty() {
                continue;
            }
            for j in 0..self.m {
                for i in 0..self.n {
                    let idx = self.index(k, i, j);
                    if self.valid[idx] {
                        continue;
                    }
                    let dist = |&(a, b): &(usize, usize)| {
                        let dj = a.abs_diff(i).pow(2);
                        let dy = b.abs_diff(j).min(self.m - b.abs_diff(j)).pow(2);
                        dj + dy
                    };
                    if let Some(&(a, b)) = measured.iter().min_by_key(|p| dist(p)) {
                        self.values[idx] = self.values[self.index(k, a, b)];
                        self.valid[idx] = true;
                    }
                }
            }
        }
    }

    /// The (wi, wo) pair node (k, i, j) measures, `None` if its direction is below the horizon.
    pub fn node_directions(&self, k: usize, i: usize, j: usize) -> Option<(DVec3, DVec3)> {
        if i >= self.n || j >= self.m {
            return None;
        }
        let wi = from_spherical(*self.theta_i.get(k)?, 0.0);
        self.slices.get(k)?.sample(self.node_u(i, j)).map(|wo| (wi, wo))
    }

    /// Stored value of node (k, i, j), if it exists and was measured.
    pub fn node_value(&self, k: usize, i: usize, j: usize) -> Option<DVec3> {
        if k >= self.theta_i.len() || i >= self.n || j >= self.m {
            return None;
        }
        let idx = self.index(k, i, j);
        self.valid[idx].then(|| self.values[idx])
    }

    /// Bilinear in u within slice k, over the valid nodes only, each node also weighed by its guide
    /// against `guide` when both are set; `None` if none of the four is valid.
    fn bilinear(&self, k: usize, u: DVec2, guide: Option<f64>) -> Option<DVec3> {
        let x = self.layout.ring_coordinate(u.x, self.n);
        let i0 = (x.floor() as usize).min(self.n - 2);
        let fx = x - i0 as f64;
        let y = u.y.rem_euclid(1.0) * self.m as f64;
        let j0 = (y.floor() as usize).min(self.m - 1);
        let fy = azimuth_weight(y - j0 as f64, self.m);
        let j1 = (j0 + 1) % self.m;
        let guided = |idx: usize| match (guide, self.guide.get(idx)) {
            (Some(q), Some(&g)) if q.is_finite() && g.is_finite() => (-((q - g) / self.guide_width).powi(2)).exp(),
            _ => 1.0,
        };
        let (mut acc, mut wsum) = (DVec3::ZERO, 0.0);
        for (i, wx) in [(i0, 1.0 - fx), (i0 + 1, fx)] {
            for (j, wy) in [(j0, 1.0 - fy), (j1, fy)] {
                let idx = self.index(k, i, j);
                if self.valid[idx] && wx * wy > 0.0 {
                    let w = wx * wy * guided(idx);
                    acc += w * self.values[idx];
                    wsum += w;
                }
            }
        }
        // Guard: guide weights that all underflow leave plain bilinear.
        if wsum <= 1e-300 && guide.is_some() {
            return self.bilinear(k, u, None);
        }
        (wsum > 0.0).then(|| acc / wsum)
    }

    /// The value of slice k at wo (already rotated to phi_i = 0), if the slice can map wo back.
    fn slice_value(&self, k: usize, wo: DVec3, guide: Option<f64>) -> Option<DVec3> {
        let u = self.slices[k].invert(wo)?;
        self.bilinear(k, u, guide)
    }
}

/// The weight of the next azimuth node at fraction `f` of the way to it, in an M-node ring: linear,
/// except at M = 2, where it is a + b cos(2 pi u.y) through the two antipodal nodes (docs/planner.md).
fn azimuth_weight(f: f64, m: usize) -> f64 {
    if m == 2 {
        0.5 * (1.0 - (std::f64::consts::PI * f).cos())
    } else {
        f
    }
}

/// Where slice k looks wo up: `u_of(k, wi, wo)` with wi and wo rotated to phi_i = 0.
pub type SliceLookup<'a> = dyn Fn(usize, DVec3, DVec3) -> Option<DVec2> + 'a;

impl MeasurementGrid {
    /// `eval` with slice k's u found by `u_of` (None: through slice k's own warp, as `eval`; the
    /// planner's lookup through the query's own wi, as RGL's files do, otherwise), the
    /// interpolation guided by the query's `guide` (`set_guide`; None: plain bilinear).
    pub fn eval_guided(&self, wi: DVec3, wo: DVec3, u_of: Option<&SliceLookup<'_>>, guide: Option<f64>) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let phi_i = phi_of(wi);
        let wi_local = rotate_z(wi, -phi_i);
        let wo = rotate_z(wo, -phi_i);
        self.eval_local(theta_of(wi), &|k: usize| match u_of {
            Some(u_of) => u_of(k, wi_local, wo).and_then(|u| self.bilinear(k, u, guide)),
            None => self.slice_value(k, wo, guide),
        })
    }
}

impl Material for MeasurementGrid {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        self.eval_guided(wi, wo, None, None)
    }
}

impl MeasurementGrid {
    /// In theta_i through the bracketing slices' values (`value(k)`): a cubic Hermite whose tangents
    /// are the differences across each bracketing slice's neighbours (the secant at the ends or
    /// where a neighbour has no value), so a residual that bends toward grazing incidence is not cut
    /// straight between slices; where one bracketing slice has no value, the other's alone, even
    /// where its weight is 0 (docs/planner.md).
    fn eval_local(&self, t: f64, value: &dyn Fn(usize) -> Option<DVec3>) -> DVec3 {
        let last = self.theta_i.len() - 1;
        // Bracketing slices and the weight of the upper one; clamped (no extrapolation) outside.
        let k0 = self
            .theta_i
            .partition_point(|&x| x <= t)
            .saturating_sub(1)
            .min(last.saturating_sub(1));
        let (k1, w1) = if last == 0 {
            (0, 0.0)
        } else {
            let (a, b) = (self.theta_i[k0], self.theta_i[k0 + 1]);
            (k0 + 1, ((t - a) / (b - a)).clamp(0.0, 1.0))
        };
        // A bracketing slice at weight 0 is read only where the other has no value.
        let v0 = if w1 < 1.0 { value(k0) } else { None };
        let v1 = if w1 > 0.0 || v0.is_none() { value(k1) } else { None };
        let v0 = if w1 >= 1.0 && v1.is_none() { value(k0) } else { v0 };
        match (v0, v1) {
            (Some(v0), Some(v1)) => {
                let (t0, t1) = (self.theta_i[k0], self.theta_i[k1]);
                let secant = (v1 - v0) / (t1 - t0);
                let m0 = match k0.checked_sub(1).and_then(|k| Some((k, value(k)?))) {
                    Some((k, before)) => (v1 - before) / (t1 - self.theta_i[k]),
                    None => secant,
                };
                let m1 = match (k1 < last).then(|| value(k1 + 1)).flatten() {
                    Some(after) => (after - v0) / (self.theta_i[k1 + 1] - t0),
                    None => secant,
                };
                let (s, h) = (w1, t1 - t0);
                let (s2, s3) = (s * s, s * s * s);
                (2.0 * s3 - 3.0 * s2 + 1.0) * v0
                    + (s3 - 2.0 * s2 + s) * h * m0
                    + (3.0 * s2 - 2.0 * s3) * v1
                    + (s3 - s2) * h * m1
            }
            (Some(v), None) | (None, Some(v)) => v,
            (None, None) => DVec3::ZERO,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::analytic::Ggx;
    use crate::brdf::warp::WarpKind;

    /// A nested grid of `warp`'s slices at `thetas`, every node holding `material`'s value.
    fn measured(material: &dyn Material, warp: WarpKind, thetas: Vec<f64>, n: usize, m: usize) -> MeasurementGrid {
        let mut grid = empty(warp, thetas, n, m).expect("grid");
        for k in 0..grid.theta_i.len() {
            for j in 0..m {
                for i in 0..n {
                    let v = grid.node_directions(k, i, j).map(|(wi, wo)| material.eval(wi, wo));
                    grid.set_node(k, i, j, v);
                }
            }
        }
        grid
    }

    /// A nested grid of `warp`'s slices at `thetas` without measurements.
    fn empty(warp: WarpKind, thetas: Vec<f64>, n: usize, m: usize) -> Result<MeasurementGrid, BrdfError> {
        let slices = thetas
            .iter()
            .map(|&t| warp.for_incident(from_spherical(t, 0.0)))
            .collect();
        let cells = thetas.len() * n * m;
        MeasurementGrid::from_slices(
            slices,
            NodeLayout::Nested,
            thetas,
            n,
            m,
            vec![DVec3::ZERO; cells],
            vec![false; cells],
        )
    }

    /// The far-ring layout moves only the second ring of a two-ring grid, to a node of every finer
    /// nested level, and interpolates between the pole and it (held beyond).
    #[test]
    fn the_far_ring_layout_moves_one_ring_and_nests() {
        use NodeLayout::{Nested, NestedFarRing};
        assert_eq!(NestedFarRing.node_x(1, 2), FAR_RING_X);
        assert_eq!(Nested.node_x(1, 2), 0.5);
        for n in [4, 8, 16] {
            for i in 0..n {
                assert_eq!(NestedFarRing.node_x(i, n), Nested.node_x(i, n));
                assert_eq!(NestedFarRing.fine_index(i, n, 16), Nested.fine_index(i, n, 16));
            }
            // The far ring is a ring of every finer level.
            let far = NestedFarRing.fine_index(1, 2, 16);
            assert_eq!(far, 12);
            assert!((0..n).any(|i| Nested.fine_index(i, n, 16) == far));
        }
        // A finest level without a ring at 3/4 (never paired with this layout: `plan::node_layout`)
        // keys Nested's ring rather than a wrong one.
        assert_eq!(NestedFarRing.fine_index(1, 2, 2), 1);
        for (ux, want) in [(0.0, 0.0), (0.375, 0.5), (0.75, 1.0), (1.0, 1.0)] {
            assert_eq!(NestedFarRing.ring_coordinate(ux, 2), want);
        }
        assert_eq!(Nested.ring_coordinate(0.375, 2), 0.75);
    }

    /// Two azimuth nodes (M = 2) interpolate as a + b cos(2 pi u.y) all the way round, the nodes
    /// themselves included; four (M = 4) stay linear.
    #[test]
    fn two_azimuth_nodes_interpolate_as_a_cosine() {
        let (r0, r1) = (DVec3::new(1.0, 2.0, -3.0), DVec3::new(5.0, -1.0, 0.5));
        let mut grid = empty(WarpKind::Cosine, vec![0.0], 2, 2).expect("grid");
        for i in 0..2 {
            grid.set_node(0, i, 0, Some(r0));
            grid.set_node(0, i, 1, Some(r1));
        }
        for step in 0..=16 {
            let uy = step as f64 / 16.0;
            let c = (std::f64::consts::TAU * uy).cos();
            let want = r0 * 0.5 * (1.0 + c) + r1 * 0.5 * (1.0 - c);
            let got = grid.bilinear(0, DVec2::new(0.0, uy), None).expect("valid nodes");
            assert!((got - want).abs().max_element() < 1e-12, "u.y {uy}: {got} vs {want}");
        }
        let mut grid = empty(WarpKind::Cosine, vec![0.0], 2, 4).expect("grid");
        for i in 0..2 {
            for j in 0..4 {
                grid.set_node(0, i, j, Some(if j == 0 { r0 } else { r1 }));
            }
        }
        let mid = grid.bilinear(0, DVec2::new(0.0, 0.125), None).expect("valid nodes");
        assert!((mid - 0.5 * (r0 + r1)).abs().max_element() < 1e-12, "{mid}");
        let quarter = grid.bilinear(0, DVec2::new(0.0, 0.0625), None).expect("valid nodes");
        assert!(
            (quarter - (0.75 * r0 + 0.25 * r1)).abs().max_element() < 1e-12,
            "{quarter}"
        );
    }

    /// A guided lookup leans toward the nodes whose guide matches the query's: halfway between a
    /// node of guide 0 and one of guide 3, a query of guide 0 reads (almost) the first; without a
    /// query guide, or without node guides, it is plain bilinear; at a node it is that node's value
    /// whatever the guides; guides that all underflow fall back to bilinear.
    #[test]
    fn a_guided_lookup_leans_toward_nodes_of_a_similar_guide() {
        let (a, b) = (DVec3::splat(-1.0), DVec3::splat(2.0));
        let mut grid = empty(WarpKind::Cosine, vec![0.0], 2, 4).expect("grid");
        for j in 0..4 {
            grid.set_node(0, 0, j, Some(a));
            grid.set_node(0, 1, j, Some(b));
        }
        let mid = DVec2::new(0.25, 0.0);
        let plain = 0.5 * (a + b);
        assert!((grid.bilinear(0, mid, Some(0.0)).unwrap() - plain).abs().max_element() < 1e-12);
        let guide: Vec<f64> = (0..8).map(|idx| if idx % 2 == 0 { 0.0 } else { 3.0 }).collect();
        grid.set_guide(guide, 1.0);
        assert!((grid.bilinear(0, mid, None).unwrap() - plain).abs().max_element() < 1e-12);
        let w = (-9.0f64).exp();
        let want = (a + w * b) / (1.0 + w);
        let got = grid.bilinear(0, mid, Some(0.0)).unwrap();
        assert!((got - want).abs().max_element() < 1e-12, "{got} vs {want}");
        assert!(
            (grid.bilinear(0, mid, Some(3.0)).unwrap() - (w * a + b) / (1.0 + w))
                .abs()
                .max_element()
                < 1e-12
        );
        assert_eq!(grid.bilinear(0, DVec2::new(0.5, 0.0), Some(0.0)).unwrap(), b);
        assert!(
            (grid.bilinear(0, mid, Some(1e200)).unwrap() - plain)
                .abs()
                .max_element()
                < 1e-12
        );
    }

    /// At every measured node (any phi_i), the reconstruction returns the measured value.
    #[test]
    fn exact_at_the_nodes() {
        let material = Ggx {
            alpha: 0.2,
            diffuse: DVec3::new(0.1, 0.2, 0.3),
            specular: DVec3::ONE,
        };
        for warp in [
            WarpKind::GgxVndf { alpha: 0.2 },
            WarpKind::Ward { alpha: 0.2 },
            WarpKind::Cosine,
        ] {
            let thetas = (0..8).map(|k| k as f64 / 7.0 * THETA_I_MAX).collect();
            let grid = measured(&material, warp, thetas, 9, 12);
            let mut checked = 0;
            for k in 0..8 {
                for j in 0..12 {
                    for i in 0..9 {
                        let Some((wi, wo)) = grid.node_directions(k, i, j) else {
                            continue;
                        };
                        let phi = 0.37 * (k + j) as f64;
                        let got = grid.eval(rotate_z(wi, phi), rotate_z(wo, phi));
                        let want = grid.node_value(k, i, j).expect("valid node");
                        assert!(
                            (got - want).length() <= 1e-9 * want.length().max(1e-12),
                            "{warp} node {k},{i},{j}: {got} vs {want}"
                        );
                        checked += 1;
                    }
                }
            }
            assert!(checked > 500, "{warp}: only {checked} valid nodes");
        }
    }

    /// A material whose value depends on theta_i alone, as `value(theta_i)` in every channel.
    struct ByIncidence(fn(f64) -> f64);

    impl Material for ByIncidence {
        fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
            if wi.z <= 0.0 || wo.z <= 0.0 {
                return DVec3::ZERO;
            }
            DVec3::splat((self.0)(theta_of(wi)))
        }
    }

    /// Between slices, theta_i is a cubic Hermite: exact on a quadratic between interior slices
    /// (the straight line misses it by c h^2 / 4 at mid-segment), the straight line itself with only
    /// two slices (both tangents are the secant), and a slice without values leaves its neighbours
    /// finite; outside the slices the end values are held.
    #[test]
    fn between_slices_the_interpolation_follows_curvature() {
        let quadratic = ByIncidence(|t| 1.0 + 0.5 * t + 2.0 * t * t);
        let thetas: Vec<f64> = (0..8).map(|k| k as f64 / 7.0 * THETA_I_MAX).collect();
        let h = thetas[1];
        let grid = measured(&quadratic, WarpKind::Cosine, thetas.clone(), 4, 4);
        let wo = from_spherical(0.4, 1.0);
        for k in 1..6 {
            let t = thetas[k] + 0.5 * h;
            let got = grid.eval(from_spherical(t, 0.3), rotate_z(wo, 0.3)).x;
            let want = (quadratic.0)(t);
            assert!((got - want).abs() < 1e-9, "segment {k}: {got} vs {want}");
            let straight = 0.5 * ((quadratic.0)(thetas[k]) + (quadratic.0)(thetas[k + 1]));
            assert!(
                (straight - want).abs() > 0.4 * h * h,
                "the line would miss by 2 h^2 / 4"
            );
        }
        let two = measured(&quadratic, WarpKind::Cosine, vec![thetas[2], thetas[3]], 4, 4);
        let t = thetas[2] + 0.25 * h;
        let line = 0.75 * (quadratic.0)(thetas[2]) + 0.25 * (quadratic.0)(thetas[3]);
        assert!((two.eval(from_spherical(t, 0.0), wo).x - line).abs() < 1e-9);
        let mut holed = grid.clone();
        for j in 0..4 {
            for i in 0..4 {
                holed.set_node(3, i, j, None);
            }
        }
        for t in [thetas[2] + 0.5 * h, thetas[3] + 0.5 * h, thetas[4] + 0.5 * h] {
            let v = holed.eval(from_spherical(t, 0.0), wo).x;
            assert!(v.is_finite() && v > 0.0, "theta_i {t}: {v}");
        }
        let beyond = grid.eval(from_spherical(THETA_I_MAX + 0.005, 0.0), wo).x;
        assert!((beyond - (quadratic.0)(THETA_I_MAX)).abs() < 1e-9);
    }

    /// A query on an end slice where that slice has no value reads the next slice, although its
    /// weight there is 0 (the normal-incidence slice's blocked peak, reconstruct::blocked_peak);
    /// with neither, the residual is 0.
    #[test]
    fn an_end_slice_without_a_value_reads_the_next_slice() {
        let linear = ByIncidence(|t| 1.0 + t);
        let thetas = vec![0.0, 0.2, 0.4];
        let mut grid = measured(&linear, WarpKind::Cosine, thetas.clone(), 4, 4);
        for j in 0..4 {
            grid.set_node(0, 0, j, None);
        }
        let pole = DVec3::Z;
        assert!((grid.eval(pole, pole).x - (linear.0)(thetas[1])).abs() < 1e-12);
        // Off the pole slice 0 still has its ring-1 nodes.
        let wo = from_spherical(0.5, 0.0);
        assert!((grid.eval(pole, wo).x - (linear.0)(0.0)).abs() < 1e-12);
        for j in 0..4 {
            grid.set_node(1, 0, j, None);
        }
        assert_eq!(grid.eval(pole, pole), DVec3::ZERO);
    }

    #[test]
    fn refuses_inconsistent_grids() {
        let w = WarpKind::Cosine;
        assert!(empty(w, vec![0.0], 1, 4).is_err());
        assert!(empty(w, vec![0.5, 0.2], 2, 2).is_err());
        let slices = vec![w.for_incident(DVec3::Z)];
        let bad = MeasurementGrid::from_slices(
            slices.clone(),
            NodeLayout::Nested,
            vec![0.0],
            2,
            2,
            vec![DVec3::ZERO; 3],
            vec![true; 4],
        );
        assert_eq!(
            bad.err().map(|e| e.to_string()).as_deref(),
            Some("measurement grid: expected 4 values and flags, got 3 and 4")
        );
        let ok = MeasurementGrid::from_slices(
            slices,
            NodeLayout::Nested,
            vec![0.0],
            2,
            2,
            vec![DVec3::ONE; 4],
            vec![true; 4],
        )
        .expect("consistent");
        assert_eq!(ok.node_value(0, 2, 0), None);
        assert_eq!(ok.node_directions(0, 0, 5), None);
        assert_eq!(ok.node_value(0, 1, 1), Some(DVec3::ONE));
        let mirror = empty(WarpKind::Ward { alpha: 0.0 }, vec![0.0], 2, 2);
        assert_eq!(
            mirror.err().map(|e| e.to_string()).as_deref(),
            Some(format!("measurement grid: {MIRROR_MSG}").as_str())
        );
    }
}
