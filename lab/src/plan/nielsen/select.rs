//! The peer's direction selection (Nielsen et al. 2015, section 5), restricted to bins whose centre
//! pair this instrument reaches: for n directions and k = min(n, K) leading components, a greedy
//! pass adds the candidate that most enlarges the volume spanned by the chosen rows of the basis
//! (pivoted QR: the largest residual after projecting out the rows already chosen, a cheap proxy of
//! the condition number that needs no SVD per candidate), then local moves swap a chosen bin for a
//! neighbouring one while the condition number of the n x k restricted basis falls. Past K
//! directions, candidates of largest leverage x^T (A^T A)^-1 x are added (D-optimal augmentation).

use super::basis::Basis;
use super::bins::{centre, index, N_PHI_D, N_THETA_D, N_THETA_H};
use gonio_shared::kinematics::Kinematics;
use gonio_shared::vec3::Vec3;
use nalgebra::DMatrix;
use rayon::prelude::*;

/// Local-move sweeps, and the largest n they run for (each move needs an SVD of n x k).
const SWEEPS: usize = 2;
const LOCAL_MOVES_MAX_N: usize = 104;

/// Bins whose centre pair the instrument reaches from its rest pose (the firmware's IK and limits).
pub fn reachable_bins(basis: &Basis, kin: &Kinematics<f64>) -> Vec<usize> {
    let rest = kin.rest_pose();
    (0..basis.valid.len())
        .into_par_iter()
        .filter(|&b| basis.valid[b])
        .filter(|&b| {
            centre(b).is_some_and(|(wi, wo)| {
                let v = |w: glam::DVec3| Vec3::new(w.x, w.y, w.z);
                kin.inverse(v(wi), v(wo), &rest)
                    .and_then(|p| kin.check_pose(&p).map(|_| p))
                    .is_ok()
            })
        })
        .collect()
}

/// Condition number of the basis rows `set`, first `k` components (infinite if rank-deficient).
pub fn condition(basis: &Basis, set: &[usize], k: usize) -> f64 {
    let m = DMatrix::from_fn(set.len(), k, |i, j| basis.row(set[i])[j] as f64);
    let s = m.singular_values();
    let (hi, lo) = s
        .iter()
        .fold((0.0f64, f64::INFINITY), |(a, b), &x| (a.max(x), b.min(x)));
    if lo > 0.0 {
        hi / lo
    } else {
        f64::INFINITY
    }
}

/// `n` bins out of `candidates` (see the module doc).
pub fn select(basis: &Basis, candidates: &[usize], n: usize) -> Vec<usize> {
    let n = n.min(candidates.len());
    let k_all = basis.k();
    let k = n.min(k_all);
    let mut set = greedy_volume(basis, candidates, n.min(k), k);
    if n <= LOCAL_MOVES_MAX_N {
        local_moves(basis, candidates, &mut set, k);
    }
    if n > set.len() {
        augment(basis, candidates, &mut set, n);
    }
    set
}

/// Pivoted QR over the candidates' first k components: `n` <= k rows.
fn greedy_volume(basis: &Basis, candidates: &[usize], n: usize, k: usize) -> Vec<usize> {
    let mut resid: Vec<Vec<f64>> = candidates
        .iter()
        .map(|&b| basis.row(b)[..k].iter().map(|&v| v as f64).collect())
        .collect();
    let mut chosen = vec![false; candidates.len()];
    let mut set = Vec::with_capacity(n);
    for _ in 0..n {
        let best = resid
            .par_iter()
            .enumerate()
            .filter(|(i, _)| !chosen[*i])
            .map(|(i, r)| (r.iter().map(|x| x * x).sum::<f64>(), i))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        let Some((norm2, i)) = best else { break };
        if !(norm2 > 1e-24) {
            break;
        }
        chosen[i] = true;
        set.push(candidates[i]);
        let q: Vec<f64> = resid[i].iter().map(|x| x / norm2.sqrt()).collect();
        resid.par_iter_mut().for_each(|r| {
            let d: f64 = r.iter().zip(&q).map(|(a, b)| a * b).sum();
            r.iter_mut().zip(&q).for_each(|(a, b)| *a -= d * b);
        });
    }
    set
}

/// The bins next to `b` (one step in each coordinate; phi_d wraps).
fn neighbours(b: usize) -> Vec<usize> {
    let (pd, td, th) = (b % N_PHI_D, (b / N_PHI_D) % N_THETA_D, b / (N_PHI_D * N_THETA_D));
    let mut out = vec![
        index(th, td, (pd + 1) % N_PHI_D),
        index(th, td, (pd + N_PHI_D - 1) % N_PHI_D),
    ];
    if td + 1 < N_THETA_D {
        out.push(index(th, td + 1, pd));
    }
    if td > 0 {
        out.push(index(th, td - 1, pd));
    }
    if th + 1 < N_THETA_H {
        out.push(index(th + 1, td, pd));
    }
    if th > 0 {
        out.push(index(th - 1, td, pd));
    }
    out
}

/// Swap chosen bins for reachable neighbours while the condition number falls.
fn local_moves(basis: &Basis, candidates: &[usize], set: &mut [usize], k: usize) {
    let allowed: std::collections::HashSet<usize> = candidates.iter().copied().collect();
    let mut best = condition(basis, set, k);
    for _ in 0..SWEEPS {
        let mut improved = false;
        for i in 0..set.len() {
            for nb in neighbours(set[i]) {
                if !allowed.contains(&nb) || set.contains(&nb) {
                    continue;
                }
                let old = set[i];
                set[i] = nb;
                let c = condition(basis, set, k);
                if c < best {
                    best = c;
                    improved = true;
                } else {
                    set[i] = old;
                }
            }
        }
        if !improved {
            break;
        }
    }
}

/// Add candidates of largest leverage under all K components until `set` has `n`.
fn augment(basis: &Basis, candidates: &[usize], set: &mut Vec<usize>, n: usize) {
    let k = basis.k();
    let row = |b: usize| -> Vec<f64> { basis.row(b).iter().map(|&v| v as f64).collect() };
    // M = (A^T A + delta I)^-1: delta keeps it defined before the set spans all K components.
    let mut ata = DMatrix::<f64>::identity(k, k) * 1e-6;
    for &b in set.iter() {
        let r = nalgebra::DVector::from_vec(row(b));
        ata += &r * r.transpose();
    }
    let Some(mut m) = ata.try_inverse() else { return };
    let mut taken: std::collections::HashSet<usize> = set.iter().copied().collect();
    let xs: Vec<nalgebra::DVector<f64>> = candidates
        .iter()
        .map(|&b| nalgebra::DVector::from_vec(row(b)))
        .collect();
    let mut lev: Vec<f64> = xs.par_iter().map(|x| x.dot(&(&m * x))).collect();
    while set.len() < n {
        let Some((i, _)) = lev
            .iter()
            .enumerate()
            .filter(|(i, _)| !taken.contains(&candidates[*i]))
            .max_by(|a, b| a.1.total_cmp(b.1))
        else {
            break;
        };
        let v = &m * &xs[i];
        let denom = 1.0 + xs[i].dot(&v);
        // Sherman-Morrison: M -= v v^T / denom, and every leverage drops by (x . v)^2 / denom.
        lev.par_iter_mut().zip(&xs).for_each(|(l, x)| {
            let d = x.dot(&v);
            *l -= d * d / denom;
        });
        m -= &v * v.transpose() / denom;
        taken.insert(candidates[i]);
        set.push(candidates[i]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::nielsen::tests::small;

    /// The greedy set is far better conditioned than the first bins in index order, local moves
    /// never make it worse, and augmentation reaches the count with distinct bins.
    #[test]
    fn selection_is_well_conditioned_and_distinct() {
        let basis = small();
        let candidates: Vec<usize> = (0..basis.valid.len()).filter(|&b| basis.valid[b]).collect();
        let k = basis.k();
        let greedy = greedy_volume(&basis, &candidates, k, k);
        let naive: Vec<usize> = candidates.iter().copied().take(k).collect();
        let (cg, cn) = (condition(&basis, &greedy, k), condition(&basis, &naive, k));
        assert!(cg < cn / 10.0, "greedy {cg} vs first bins {cn}");
        let mut moved = greedy.clone();
        local_moves(&basis, &candidates, &mut moved, k);
        assert!(condition(&basis, &moved, k) <= cg);
        let set = select(&basis, &candidates, 3 * k);
        assert_eq!(set.len(), 3 * k);
        let distinct: std::collections::HashSet<_> = set.iter().collect();
        assert_eq!(distinct.len(), set.len());
    }
}
