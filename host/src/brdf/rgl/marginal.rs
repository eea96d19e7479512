//! Mitsuba's continuous `Marginal2D` warp (RGL-FORMAT.md section 4): a bilinear density on [0,1]^2
//! with conditional and marginal CDFs, sliced by conditional parameters that are interpolated
//! linearly (data and CDFs blended, not rebuilt). Built in f64, stored in f32 like Mitsuba.

use glam::DVec2;

#[derive(Clone, Debug)]
pub struct Marginal2D {
    w: usize,
    h: usize,
    /// Node values of each parameter dimension, outermost first.
    params: Vec<Vec<f64>>,
    data: Vec<f32>,
    /// Conditional CDFs, per slice h x (w - 1); empty without CDFs.
    cond: Vec<f32>,
    /// Marginal CDFs, per slice h - 1; empty without CDFs.
    marg: Vec<f32>,
    normalized: bool,
}

/// `seg(s, k, v0, v1)`: solve (v0 t + (v1 - v0) t^2 / 2) / k = s for t in a linear segment.
/// Guard: a vanishing divisor (a zero segment) returns 0.
fn seg(s: f64, k: f64, v0: f64, v1: f64) -> f64 {
    let t = if (v0 - v1).abs() > 1e-4 * (v0 + v1) {
        (v0 - (v0 * v0 + 2.0 * k * s * (v1 - v0)).max(0.0).sqrt()) / (v0 - v1)
    } else {
        2.0 * k * s / (v0 + v1)
    };
    if t.is_finite() {
        t
    } else {
        0.0
    }
}

fn lerp(a: f64, b: f64, t: f64) -> f64 {
    (1.0 - t) * a + t * b
}

impl Marginal2D {
    /// `data` is P0 x P1 x ... x h x w in C order. With `build_cdf`, each slice gets its CDFs and,
    /// if `normalize`, is scaled to integrate to 1. Returns the index of a slice that integrates to
    /// 0 (which cannot be normalised) as the error.
    pub fn new(
        data: Vec<f32>,
        w: usize,
        h: usize,
        params: Vec<Vec<f64>>,
        normalize: bool,
        build_cdf: bool,
    ) -> Result<Self, usize> {
        let slices: usize = params.iter().map(Vec::len).product();
        let mut data = data;
        let (mut cond, mut marg) = (Vec::new(), Vec::new());
        if build_cdf {
            cond = vec![0.0f32; slices * h * (w - 1)];
            marg = vec![0.0f32; slices * (h - 1)];
            for s in 0..slices {
                let d = &mut data[s * w * h..(s + 1) * w * h];
                let c = &mut cond[s * h * (w - 1)..(s + 1) * h * (w - 1)];
                let mut c64 = vec![0.0f64; h * (w - 1)];
                for y in 0..h {
                    let mut acc = 0.0f64;
                    for x in 0..w - 1 {
                        acc += (d[y * w + x] as f64 + d[y * w + x + 1] as f64) / (2.0 * (w - 1) as f64);
                        c64[y * (w - 1) + x] = acc;
                    }
                }
                let mut m64 = vec![0.0f64; h - 1];
                let mut acc = 0.0f64;
                for y in 0..h - 1 {
                    acc += (c64[y * (w - 1) + w - 2] + c64[(y + 1) * (w - 1) + w - 2]) / (2.0 * (h - 1) as f64);
                    m64[y] = acc;
                }
                let norm = if normalize {
                    if !(acc > 0.0) {
                        return Err(s);
                    }
                    (1.0 / acc) as f32
                } else {
                    1.0
                };
                for (ci, v) in c.iter_mut().zip(&c64) {
                    *ci = *v as f32 * norm;
                }
                for (mi, v) in marg[s * (h - 1)..(s + 1) * (h - 1)].iter_mut().zip(&m64) {
                    *mi = *v as f32 * norm;
                }
                if normalize {
                    d.iter_mut().for_each(|v| *v *= norm);
                }
            }
        }
        Ok(Self {
            w,
            h,
            params,
            data,
            cond,
            marg,
            normalized: normalize,
        })
    }

    /// The slices and weights that blend to the parameter point `param` (one value per dimension).
    /// A dimension with one node is ignored; otherwise the bracketing pair, clamped at the ends.
    fn slice_weights(&self, param: &[f64]) -> Vec<(usize, f64)> {
        let mut out = vec![(0usize, 1.0f64)];
        for (dim, nodes) in self.params.iter().enumerate() {
            let size = nodes.len();
            let x = param.get(dim).copied().unwrap_or(0.0);
            let (idx, t) = if size == 1 {
                (0, 0.0)
            } else {
                let idx = nodes[1..].iter().filter(|&&v| v < x).count().min(size - 2);
                let span = nodes[idx + 1] - nodes[idx];
                let t = if span > 0.0 {
                    ((x - nodes[idx]) / span).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                (idx, t)
            };
            let mut next = Vec::with_capacity(out.len() * 2);
            for &(s, w) in &out {
                next.push((s * size + idx, w * (1.0 - t)));
                if size > 1 {
                    next.push((s * size + idx + 1, w * t));
                }
            }
            out = next;
        }
        out
    }

    fn blend(arr: &[f32], stride: usize, weights: &[(usize, f64)], i: usize) -> f64 {
        weights
            .iter()
            .map(|&(s, w)| if w == 0.0 { 0.0 } else { w * arr[s * stride + i] as f64 })
            .sum()
    }

    fn d(&self, wts: &[(usize, f64)], y: usize, x: usize) -> f64 {
        Self::blend(&self.data, self.w * self.h, wts, y * self.w + x)
    }
    fn c(&self, wts: &[(usize, f64)], y: usize, x: usize) -> f64 {
        Self::blend(&self.cond, self.h * (self.w - 1), wts, y * (self.w - 1) + x)
    }
    fn m(&self, wts: &[(usize, f64)], y: usize) -> f64 {
        Self::blend(&self.marg, self.h - 1, wts, y)
    }

    /// Cell and fractions of a clamped point.
    fn locate(&self, p: DVec2) -> (usize, usize, f64, f64) {
        let p = p.clamp(DVec2::ZERO, DVec2::ONE);
        let px = p.x * (self.w - 1) as f64;
        let py = p.y * (self.h - 1) as f64;
        let ix = (px.floor() as usize).min(self.w - 2);
        let iy = (py.floor() as usize).min(self.h - 2);
        (ix, iy, px - ix as f64, py - iy as f64)
    }

    /// Plain bilinear interpolation of the (blended) data.
    pub fn eval(&self, p: DVec2, param: &[f64]) -> f64 {
        let wts = self.slice_weights(param);
        let (ix, iy, fx, fy) = self.locate(p);
        let r0 = lerp(self.d(&wts, iy, ix), self.d(&wts, iy, ix + 1), fx);
        let r1 = lerp(self.d(&wts, iy + 1, ix), self.d(&wts, iy + 1, ix + 1), fx);
        lerp(r0, r1, fy)
    }

    /// The inverse warp: the sample-space point s that `sample` maps to p, and the density at p.
    pub fn invert(&self, p: DVec2, param: &[f64]) -> (DVec2, f64) {
        let wts = self.slice_weights(param);
        let (ix, iy, fx, fy) = self.locate(p);
        let (w1, h1) = ((self.w - 1) as f64, (self.h - 1) as f64);
        let c0 = lerp(self.d(&wts, iy, ix), self.d(&wts, iy + 1, ix), fy);
        let c1 = lerp(self.d(&wts, iy, ix + 1), self.d(&wts, iy + 1, ix + 1), fy);
        let pdf = lerp(c0, c1, fx);
        let mut sx = fx * (c0 + 0.5 * fx * (c1 - c0)) / w1;
        if ix > 0 {
            sx += lerp(self.c(&wts, iy, ix - 1), self.c(&wts, iy + 1, ix - 1), fy);
        }
        let (r0, r1) = (self.c(&wts, iy, self.w - 2), self.c(&wts, iy + 1, self.w - 2));
        let row = lerp(r0, r1, fy);
        // A row of zero mass: every point in it maps to its start.
        sx = if row > 0.0 { sx / row } else { 0.0 };
        let mut sy = fy * (r0 + 0.5 * fy * (r1 - r0)) / h1;
        if iy > 0 {
            sy += self.m(&wts, iy - 1);
        }
        if !self.normalized {
            let total = self.m(&wts, self.h - 2);
            sy = if total > 0.0 { sy / total } else { 0.0 };
        }
        (DVec2::new(sx, sy), pdf)
    }

    /// The forward warp V: sample space -> [0,1]^2, with the density at the result.
    pub fn sample(&self, s: DVec2, param: &[f64]) -> (DVec2, f64) {
        let wts = self.slice_weights(param);
        let eps = 2f64.powi(-24);
        let mut s = s.clamp(DVec2::splat(eps), DVec2::splat(1.0 - eps));
        let (w1, h1) = ((self.w - 1) as f64, (self.h - 1) as f64);
        if !self.normalized {
            s.y *= self.m(&wts, self.h - 2);
        }
        let row = (0..self.h - 1).find(|&r| self.m(&wts, r) >= s.y).unwrap_or(self.h - 2);
        if row > 0 {
            s.y -= self.m(&wts, row - 1);
        }
        let (r0, r1) = (self.c(&wts, row, self.w - 2), self.c(&wts, row + 1, self.w - 2));
        let ty = seg(s.y, h1, r0, r1);
        s.x *= lerp(r0, r1, ty);
        let chat = |j: usize| lerp(self.c(&wts, row, j), self.c(&wts, row + 1, j), ty);
        let col = (0..self.w - 1).find(|&j| chat(j) >= s.x).unwrap_or(self.w - 2);
        if col > 0 {
            s.x -= chat(col - 1);
        }
        let c0 = lerp(self.d(&wts, row, col), self.d(&wts, row + 1, col), ty);
        let c1 = lerp(self.d(&wts, row, col + 1), self.d(&wts, row + 1, col + 1), ty);
        let tx = seg(s.x, w1, c0, c1);
        (
            DVec2::new((col as f64 + tx) / w1, (row as f64 + ty) / h1),
            lerp(c0, c1, tx),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_and_invert_are_inverse_and_blend_slices() {
        // Two 5 x 4 slices with different shapes, parameter nodes 0 and 1.
        let mut data = Vec::new();
        for s in 0..2 {
            for y in 0..4 {
                for x in 0..5 {
                    data.push(1.0 + (x * (s + 1)) as f32 + 0.5 * y as f32);
                }
            }
        }
        let m = Marginal2D::new(data, 5, 4, vec![vec![0.0, 1.0]], true, true).expect("non-zero");
        for param in [0.0, 0.3, 1.0] {
            for (a, b) in [(0.1, 0.2), (0.5, 0.5), (0.9, 0.05), (0.33, 0.77)] {
                let s = DVec2::new(a, b);
                let (p, pdf) = m.sample(s, &[param]);
                let (back, pdf2) = m.invert(p, &[param]);
                assert!((back - s).length() < 1e-5, "param {param}: {s} -> {p} -> {back}");
                assert!((pdf - pdf2).abs() < 1e-5 * pdf, "{pdf} {pdf2}");
                assert!((m.eval(p, &[param]) - pdf).abs() < 1e-5 * pdf);
            }
        }
        // A zero slice cannot be normalised.
        assert_eq!(
            Marginal2D::new(vec![0.0; 8], 2, 2, vec![vec![0.0, 1.0]], true, true).err(),
            Some(0)
        );
    }
}
