//! Non-negative least squares on log(1 + f cos): the per-channel solver of `fit_lobes`.

/// Gauss-Newton iterations per solve (the linear start is usually close).
const GN_ITERATIONS: usize = 12;

/// Weighted sum of squared log residuals of coefficients `x` on columns `cols` (already times cos),
/// plus `offset` (empty: none).
fn loss<const N: usize>(cols: &[&[f64]; N], t: &[f64], w: &[f64], offset: &[f64], x: &[f64; N]) -> f64 {
    (0..t.len())
        .map(|i| {
            let f: f64 = offset.get(i).copied().unwrap_or(0.0) + (0..N).map(|p| x[p] * cols[p][i]).sum::<f64>();
            w[i] * (f.ln_1p() - t[i]).powi(2)
        })
        .sum()
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
    let n = t.len();
    let off = |i: usize| offset.get(i).copied().unwrap_or(0.0);
    let (a, r) = normal_equations(n, |i| {
        (std::array::from_fn(|p| cols[p][i]), t[i].exp_m1() - off(i), w[i])
    });
    let mut x = nnls(&a, &r);
    let mut best = loss(cols, t, w, offset, &x);
    for _ in 0..GN_ITERATIONS {
        // Linearised at x: minimise sum w (r_i + J_i (y - x))^2 over y >= 0, i.e. the NNLS with
        // right-hand side J_i . x - r_i.
        let (a, rhs) = normal_equations(n, |i| {
            let f: f64 = off(i) + (0..N).map(|p| x[p] * cols[p][i]).sum::<f64>();
            let d = 1.0 + f;
            let j: [f64; N] = std::array::from_fn(|p| cols[p][i] / d);
            let res = d.ln() - t[i];
            let jx: f64 = (0..N).map(|p| j[p] * x[p]).sum();
            (j, jx - res, w[i])
        });
        let y = nnls(&a, &rhs);
        let mut step = 1.0;
        let mut improved = false;
        while step > 1e-4 {
            let cand: [f64; N] = std::array::from_fn(|p| (x[p] + step * (y[p] - x[p])).max(0.0));
            let l = loss(cols, t, w, offset, &cand);
            if l < best {
                (x, best, improved) = (cand, l, true);
                break;
            }
            step *= 0.5;
        }
        if !improved {
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
            r[p] += wi * j[p] * y;
            for q in 0..N {
                a[p][q] += wi * j[p] * j[q];
            }
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
        let free: Vec<usize> = (0..N).filter(|&p| mask & (1 << p) != 0).collect();
        let Some(sol) = solve_block(a, r, &free) else {
            continue;
        };
        if sol.iter().any(|&v| !(v >= 0.0)) {
            continue;
        }
        let mut x = [0.0; N];
        for (k, &p) in free.iter().enumerate() {
            x[p] = sol[k];
        }
        let o = objective(&x);
        if o < best.1 {
            best = (x, o);
        }
    }
    best.0
}

/// Solve A[free, free] y = r[free] by Gaussian elimination with partial pivoting; None if singular.
fn solve_block<const N: usize>(a: &[[f64; N]; N], r: &[f64; N], free: &[usize]) -> Option<Vec<f64>> {
    let k = free.len();
    let mut m: Vec<Vec<f64>> = free
        .iter()
        .map(|&p| {
            let mut row: Vec<f64> = free.iter().map(|&q| a[p][q]).collect();
            row.push(r[p]);
            row
        })
        .collect();
    let scale = free.iter().map(|&p| a[p][p].abs()).fold(0.0, f64::max);
    for col in 0..k {
        let piv = (col..k).max_by(|&i, &j| m[i][col].abs().total_cmp(&m[j][col].abs()))?;
        if !(m[piv][col].abs() > 1e-12 * scale) {
            return None;
        }
        m.swap(col, piv);
        let pivot_row = m[col].clone();
        for row in m.iter_mut().skip(col + 1) {
            let f = row[col] / pivot_row[col];
            for (x, p) in row.iter_mut().zip(&pivot_row).skip(col) {
                *x -= f * p;
            }
        }
    }
    let mut y = vec![0.0; k];
    for row in (0..k).rev() {
        let s: f64 = (row + 1..k).map(|c| m[row][c] * y[c]).sum();
        y[row] = (m[row][k] - s) / m[row][row];
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
}
