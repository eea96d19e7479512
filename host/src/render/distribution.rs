//! Piecewise-constant densities on [0,1] and [0,1]^2 (pbrt's `PiecewiseConstant1D/2D`), sampled by
//! inverting their CDFs with a binary search. The environment map is importance-sampled with these.
//! (`brdf::rgl::Marginal2D` is bilinear and searches linearly, which suits its small tables but not a
//! map of tens of thousands of texels sampled millions of times per image.)

use crate::brdf::frame::ONE_MINUS_EPSILON;
use glam::DVec2;

/// A density proportional to non-negative weights on n equal cells of [0,1].
#[derive(Clone, Debug)]
pub struct Distribution1D {
    /// Cell weights as given (negative and NaN taken as 0).
    func: Vec<f64>,
    /// cdf[0] = 0, cdf[n] = 1.
    cdf: Vec<f64>,
    /// Integral of `func` over [0,1] (sum / n).
    integral: f64,
}

impl Distribution1D {
    /// `weights` must not be empty. All-zero weights give the uniform density (so sampling still
    /// works and the integral, 0, tells the caller there is nothing to sample).
    pub fn new(weights: &[f64]) -> Self {
        let n = weights.len().max(1);
        let func: Vec<f64> = (0..n)
            .map(|i| {
                weights
                    .get(i)
                    .copied()
                    .filter(|w| *w > 0.0 && w.is_finite())
                    .unwrap_or(0.0)
            })
            .collect();
        let mut cdf = Vec::with_capacity(n + 1);
        cdf.push(0.0);
        let mut acc = 0.0;
        for f in &func {
            acc += f / n as f64;
            cdf.push(acc);
        }
        let integral = acc;
        if integral > 0.0 {
            cdf.iter_mut().for_each(|c| *c /= integral);
        } else {
            cdf.iter_mut().enumerate().for_each(|(i, c)| *c = i as f64 / n as f64);
        }
        // Rounding may leave the last entry a hair off 1; the search relies on it being exactly 1.
        cdf[n] = 1.0;
        Self { func, cdf, integral }
    }

    pub fn len(&self) -> usize {
        self.func.len()
    }

    pub fn is_empty(&self) -> bool {
        self.func.is_empty()
    }

    pub fn integral(&self) -> f64 {
        self.integral
    }

    /// Density at cell `i` (w.r.t. [0,1]).
    pub fn pdf_cell(&self, i: usize) -> f64 {
        if self.integral > 0.0 {
            self.func.get(i).copied().unwrap_or(0.0) / self.integral
        } else {
            1.0
        }
    }

    /// Continuous sample x in [0,1) and its cell, for u in [0,1).
    pub fn sample(&self, u: f64) -> (f64, usize) {
        let u = if u.is_nan() {
            0.0
        } else {
            u.clamp(0.0, ONE_MINUS_EPSILON)
        };
        // The last index with cdf[i] <= u, kept within the cells.
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .saturating_sub(1)
            .min(self.len() - 1);
        let width = self.cdf[i + 1] - self.cdf[i];
        // A zero-width cell is never chosen by u in [cdf[i], cdf[i+1]), except by rounding: its start.
        let t = if width > 0.0 {
            ((u - self.cdf[i]) / width).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let x = ((i as f64 + t) / self.len() as f64).min(ONE_MINUS_EPSILON);
        (x, i)
    }
}

/// A density on [0,1]^2 proportional to a w x h grid of weights (row-major, row = y): a marginal over
/// rows and one conditional over the columns of each row.
#[derive(Clone, Debug)]
pub struct Distribution2D {
    rows: Vec<Distribution1D>,
    marginal: Distribution1D,
}

impl Distribution2D {
    pub fn new(weights: &[f64], w: usize, h: usize) -> Self {
        let rows: Vec<Distribution1D> = (0..h.max(1))
            .map(|y| Distribution1D::new(weights.get(y * w..(y + 1) * w).unwrap_or(&[])))
            .collect();
        let marginal = Distribution1D::new(&rows.iter().map(Distribution1D::integral).collect::<Vec<_>>());
        Self { rows, marginal }
    }

    pub fn integral(&self) -> f64 {
        self.marginal.integral()
    }

    /// A point of [0,1)^2 and its density w.r.t. area on [0,1]^2.
    pub fn sample(&self, u: DVec2) -> (DVec2, f64) {
        let (y, iy) = self.marginal.sample(u.y);
        let row = &self.rows[iy];
        let (x, ix) = row.sample(u.x);
        (DVec2::new(x, y), self.marginal.pdf_cell(iy) * row.pdf_cell(ix))
    }

    /// Density at p in [0,1]^2 (coordinates clamped into the grid).
    pub fn pdf(&self, p: DVec2) -> f64 {
        let cell = |v: f64, n: usize| ((v.max(0.0) * n as f64) as usize).min(n - 1);
        let iy = cell(p.y, self.rows.len());
        let row = &self.rows[iy];
        self.marginal.pdf_cell(iy) * row.pdf_cell(cell(p.x, row.len()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn sampling_follows_the_weights_and_pdf_matches() {
        let weights = [0.0, 1.0, 3.0, 0.0, 4.0, 0.0];
        let d = Distribution2D::new(&weights, 3, 2);
        assert!((d.integral() - 8.0 / 6.0).abs() < 1e-12);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut counts = [0usize; 6];
        let n = 80_000;
        for _ in 0..n {
            let (p, pdf) = d.sample(DVec2::new(rng.random(), rng.random()));
            assert!((pdf - d.pdf(p)).abs() < 1e-12, "sample pdf equals pdf at the point");
            let (ix, iy) = ((p.x * 3.0) as usize, (p.y * 2.0) as usize);
            counts[iy * 3 + ix] += 1;
        }
        for (c, w) in counts.iter().zip(weights) {
            let expect = n as f64 * w / 8.0;
            // 5 standard deviations of a binomial count.
            assert!((*c as f64 - expect).abs() <= 5.0 * expect.sqrt() + 1e-9, "{counts:?}");
        }
        // Extreme u and all-zero weights stay finite and in range.
        for u in [0.0, 1.0, ONE_MINUS_EPSILON, f64::NAN] {
            let (p, pdf) = d.sample(DVec2::splat(u));
            assert!(p.x < 1.0 && p.y < 1.0 && pdf > 0.0, "{u}: {p} {pdf}");
        }
        let zero = Distribution2D::new(&[0.0; 4], 2, 2);
        let (p, pdf) = zero.sample(DVec2::new(0.3, 0.9));
        assert!(p.is_finite() && pdf == 1.0 && zero.integral() == 0.0);
    }
}
