//! Non-negative least squares on log(1 + f cos): the per-channel solver of `fit_lobes`.

/// Gauss-Newton iterations per solve at most (the linear start is usually close).
const GN_ITERATIONS: usize = 12;
/// A Gauss-Newton step that lowers the loss by less than this share of it ends the solve: later
/// steps barely move the fit (tested below) and cost most of a level's host time (docs/scan.md).
const GN_TOLERANCE: f64 = 1e-9;

/// The offset at sample i (`offset` empty: none, 0).
#[inline(always)]
fn offset_at(offset: &[f64], i: usize) -> f64 {
    offset.get(i).copied().unwrap_or(0.0)
}

/// The model's f cos = offset + sum x_p cols_p at sample i (`offset` empty: none).
#[inline(always)]
fn model_at<const N: usize>(cols: &[&[f64]; N], offset: &[f64], x: &[f64; N], i: usize) -> f64 {
    offset_at(offset, i) + (0..N).map(|p| x[p] * cols[p][i]).sum::<f64>()
}

/// Weighted sum of squared log residuals of coefficients `x` on columns `cols` (already times cos),
/// plus `offset` (empty: none); each sample's 1 + f cos and log residual are written to `at` (the
/// next Gauss-Newton step reuses them: the logarithms are most of the fit's time).
fn loss<const N: usize>(
    cols: &[&[f64]; N],
    t: &[f64],
    w: &[f64],
    offset: &[f64],
    x: &[f64; N],
    at: &mut [(f64, f64)],
) -> f64 {
    let mut sum = 0.0;
    for i in 0..t.len() {
        let f = model_at(cols, offset, x, i);
        let r = f.ln_1p() - t[i];
        at[i] = (1.0 + f, r);
        sum += w[i] * r * r;
    }
    sum
}

/// `solve_channel` with the first coefficient (the Lambert term) at most `cap`: when the free
/// optimum exceeds it, the coefficient is held at the cap and the others are solved again around it
/// (the loss is smooth, so a bound-violating free optimum puts the bounded one on the bound).
pub(super) fn solve_capped<const N: usize>(cols: &[&[f64]; N], t: &[f64], w: &[f64], cap: f64) -> ([f64; N], f64) {
    let free = solve_channel(cols, t, w, &[]);
    if !(free.0[0] > cap) {
        return free;
    }
    let offset: Vec<f64> = cols[0].iter().map(|c| cap * c).collect();
    // The Lambert column's coefficient is pinned by zeroing its column: it lives in the offset.
    let zero = vec![0.0; t.len()];
    let mut pinned: [&[f64]; N] = *cols;
    pinned[0] = &zero;
    let (mut x, l) = solve_channel(&pinned, t, w, &offset);
    x[0] = cap;
    (x, l)
}

/// Best non-negative coefficients for one channel and their loss, for f cos = offset + sum x_p
/// cols_p (`offset` empty: none): a linear least-squares start on exp(t) - 1 - offset, then
/// projected Gauss-Newton on the log loss with step halving.
fn solve_channel<const N: usize>(cols: &[&[f64]; N], t: &[f64], w: &[f64], offset: &[f64]) -> ([f64; N], f64) {
    solve_channel_to(cols, t, w, offset, GN_TOLERANCE)
}

/// `solve_channel`, stopping once a step gains less than `tolerance` of the loss.
fn solve_channel_to<const N: usize>(
    cols: &[&[f64]; N],
    t: &[f64],
    w: &[f64],
    offset: &[f64],
    tolerance: f64,
) -> ([f64; N], f64) {
    let n = t.len();
    let (a, r) = normal_equations(n, |i| {
        (
            std::array::from_fn(|p| cols[p][i]),
            t[i].exp_m1() - offset_at(offset, i),
            w[i],
        )
    });
    let mut x = nnls(&a, &r);
    // (1 + f cos, log residual) of each sample at x, and at a candidate.
    let (mut at, mut cand_at) = (vec![(0.0, 0.0); n], vec![(0.0, 0.0); n]);
    let mut best = loss(cols, t, w, offset, &x, &mut at);
    for _ in 0..GN_ITERATIONS {
        // Linearised at x: minimise sum w (r_i + J_i (y - x))^2 over y >= 0, i.e. the NNLS with
        // right-hand side J_i . x - r_i.
        let (a, rhs) = normal_equations(n, |i| {
            let (d, res) = at[i];
            let j: [f64; N] = std::array::from_fn(|p| cols[p][i] / d);
            let jx: f64 = (0..N).map(|p| j[p] * x[p]).sum();
            (j, jx - res, w[i])
        });
        let y = nnls(&a, &rhs);
        let mut step = 1.0;
        let mut keep_going = false;
        while step > 1e-4 {
            let cand: [f64; N] = std::array::from_fn(|p| (x[p] + step * (y[p] - x[p])).max(0.0));
            let l = loss(cols, t, w, offset, &cand, &mut cand_at);
            if l < best {
                keep_going = best - l > tolerance * best;
                (x, best) = (cand, l);
                std::mem::swap(&mut at, &mut cand_at);
                break;
            }
            step *= 0.5;
        }
        if !keep_going {
            break;
        }
    }
    (x, best)
}

/// The weighted normal equations (sum w J^T J, sum w J y) of rows `jac(i)` = (J_i, y_i, w_i), i < n:
/// generic, not `dyn`, so the row is inlined (the two-lobe fit's hot loop).
fn normal_equations<const N: usize>(
    n: usize,
    jac: impl Fn(usize) -> ([f64; N], f64, f64),
) -> ([[f64; N]; N], [f64; N]) {
    let mut a = [[0.0; N]; N];
    let mut r = [0.0; N];
    for i in 0..n {
        let (j, y, wi) = jac(i);
        for p in 0..N {
            let wj = wi * j[p];
            r[p] += wj * y;
            for q in p..N {
                a[p][q] += wj * j[q];
            }
        }
    }
    // Symmetric: the lower triangle mirrors the upper one.
    let upper = a;
    for (p, row) in a.iter_mut().enumerate() {
        for (q, v) in row.iter_mut().enumerate().take(p) {
            *v = upper[q][p];
        }
    }
    (a, r)
}

/// Exact non-negative least squares in N (a handful of) unknowns from the normal equations
/// A x = r: every active set (which unknowns are free) is solved on its free block, and the best
/// feasible one is kept. Guard: a singular block (a column that vanishes on the samples) is
/// skipped; the empty set (x = 0) is always feasible.
fn nnls<const N: usize>(a: &[[f64; N]; N], r: &[f64; N]) -> [f64; N] {
    // Objective up to a constant: x^T A x - 2 r^T x.
    let objective = |x: &[f64; N]| -> f64 {
        let mut s = 0.0;
        for p in 0..N {
            s -= 2.0 * r[p] * x[p];
            for q in 0..N {
                s += x[p] * a[p][q] * x[q];
            }
        }
        s
    };
    let mut best = ([0.0; N], 0.0);
    for mask in 1usize..(1 << N) {
        let mut free = [0usize; N];
        let mut k = 0;
        for p in (0..N).filter(|&p| mask & (1 << p) != 0) {
            free[k] = p;
            k += 1;
        }
        let Some(sol) = solve_block(a, r, &free[..k]) else {
            continue;
        };
        if sol[..k].iter().any(|&v| !(v >= 0.0)) {
            continue;
        }
        let mut x = [0.0; N];
        for (&p, &v) in free[..k].iter().zip(&sol) {
            x[p] = v;
        }
        let o = objective(&x);
        if o < best.1 {
            best = (x, o);
        }
    }
    best.0
}

/// Solve A[free, free] y = r[free] by Gaussian elimination with partial pivoting (y's first
/// `free.len()` entries); None if singular. On the stack: it runs 2^N - 1 times per NNLS.
fn solve_block<const N: usize>(a: &[[f64; N]; N], r: &[f64; N], free: &[usize]) -> Option<[f64; N]> {
    let k = free.len();
    let (mut m, mut rhs) = ([[0.0; N]; N], [0.0; N]);
    for (row, &p) in free.iter().enumerate() {
        for (col, &q) in free.iter().enumerate() {
            m[row][col] = a[p][q];
        }
        rhs[row] = r[p];
    }
    let scale = free.iter().map(|&p| a[p][p].abs()).fold(0.0, f64::max);
    for col in 0..k {
        let piv = (col..k).max_by(|&i, &j| m[i][col].abs().total_cmp(&m[j][col].abs()))?;
        if !(m[piv][col].abs() > 1e-12 * scale) {
            return None;
        }
        m.swap(col, piv);
        rhs.swap(col, piv);
        let pivot_row = m[col];
        for row in col + 1..k {
            let f = m[row][col] / pivot_row[col];
            for c in col..k {
                m[row][c] -= f * pivot_row[c];
            }
            rhs[row] -= f * rhs[col];
        }
    }
    let mut y = [0.0; N];
    for row in (0..k).rev() {
        let s: f64 = (row + 1..k).map(|c| m[row][c] * y[c]).sum();
        y[row] = (rhs[row] - s) / m[row][row];
    }
    Some(y)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nnls_matches_the_unconstrained_solution_and_clamps() {
        // A = I: the solution is r with negatives set to 0.
        let a = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert_eq!(nnls(&a, &[1.0, -2.0, 3.0]), [1.0, 0.0, 3.0]);
        // Singular A (two equal columns): still a feasible minimiser.
        let a = [[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 2.0]];
        let x = nnls(&a, &[2.0, 2.0, 2.0]);
        assert!((x[0] + x[1] - 2.0).abs() < 1e-12 && (x[2] - 1.0).abs() < 1e-12, "{x:?}");
    }

    /// The early stop changes no fit that matters: on data the columns cannot represent exactly
    /// (a GGX lobe between the two candidate roughnesses, over Lambert), the coefficients and the
    /// model's values with `GN_TOLERANCE` agree with all 12 steps to parts in 10^6.
    #[test]
    fn the_early_stop_moves_the_fit_by_parts_in_a_million() {
        use crate::brdf::analytic::ggx_specular;
        use crate::brdf::fit::fit_directions;
        let pairs = fit_directions();
        let col = |f: &dyn Fn(glam::DVec3, glam::DVec3) -> f64| -> Vec<f64> {
            pairs.iter().map(|&(wi, wo)| f(wi, wo) * wo.z).collect()
        };
        let lambert = col(&|_, _| std::f64::consts::FRAC_1_PI);
        let (sharp, broad) = (
            col(&|wi, wo| ggx_specular(wi, wo, 0.1)),
            col(&|wi, wo| ggx_specular(wi, wo, 0.4)),
        );
        let truth = col(&|wi, wo| 0.3 * std::f64::consts::FRAC_1_PI + 0.8 * ggx_specular(wi, wo, 0.17));
        let t: Vec<f64> = truth.iter().map(|v| v.ln_1p()).collect();
        let w = vec![1.0; t.len()];
        let cols = [&lambert[..], &sharp[..], &broad[..]];
        let (early, l_early) = solve_channel_to(&cols, &t, &w, &[], GN_TOLERANCE);
        let (full, l_full) = solve_channel_to(&cols, &t, &w, &[], 0.0);
        assert!(l_full > 1e-6, "the columns must not fit exactly: {l_full}");
        assert!(l_early <= l_full * (1.0 + 1e-6), "{l_early} {l_full}");
        for i in 0..t.len() {
            let (a, b) = (model_at(&cols, &[], &early, i), model_at(&cols, &[], &full, i));
            assert!((a - b).abs() <= 1e-6 * b.abs().max(1e-3), "sample {i}: {a} {b}");
        }
    }

    #[test]
    fn a_solve_recovers_exact_coefficients_and_the_cap_pins_the_first() {
        // Three columns over 200 samples, values made by x = [0.3, 0, 2.0]: the log loss is zero there.
        let n = 200;
        let col = |k: usize| -> Vec<f64> {
            (0..n)
                .map(|i| {
                    let u = i as f64 / n as f64;
                    [0.3 + u, (-20.0 * (u - 0.5).powi(2)).exp(), u * u][k]
                })
                .collect()
        };
        let (c0, c1, c2) = (col(0), col(1), col(2));
        let cols = [&c0[..], &c1[..], &c2[..]];
        let truth = [0.3, 0.0, 2.0];
        let t: Vec<f64> = (0..n).map(|i| model_at(&cols, &[], &truth, i).ln_1p()).collect();
        let w = vec![1.0; n];
        let (x, l) = solve_capped(&cols, &t, &w, f64::INFINITY);
        assert!(l < 1e-20, "loss {l}");
        for (got, want) in x.iter().zip(truth) {
            assert!((got - want).abs() < 1e-8, "{x:?}");
        }
        // A cap below the truth's first coefficient holds it there; the others still fit, with a loss.
        let (x, l) = solve_capped(&cols, &t, &w, 0.1);
        assert_eq!(x[0], 0.1);
        assert!(l > 0.0 && l.is_finite() && x.iter().all(|v| *v >= 0.0), "{x:?} {l}");
    }
}
