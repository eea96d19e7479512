//! The time model and the ordering of directions.
//!
//! * Cost of a direction = the synchronised move from the previous pose (`gonio_shared::motion`) +
//!   settle + exposure (from the instrument file). Settle and exposure are the same for every order;
//!   only the motion differs.
//! * The pose of a direction is what the firmware's inverse kinematics picks: the branch nearest
//!   the current pose. `simulate` replays an order exactly so (this is the plan's time).
//! * Metric for ordering and bounds: d(a, b) = the smallest synchronised move time over every pose
//!   that reaches a and every pose that reaches b (`Candidates`: both IK branches, every unwinding).
//!   Any order's move a -> b takes at least d(a, b), whatever branch the firmware picks.
//! * Order: nearest neighbour from the start pose, then 2-opt and Or-opt (segments of 1-3) over
//!   neighbour lists (K nearest by d, from a bucket grid over the poses, `PoseGrid`) until no move
//!   improves, on the open path (start fixed, end free). When every listed neighbour is visited,
//!   the nearest neighbour step asks the same grid, with visited points taken out, for the nearest
//!   point left: exact, and no full scan (at N = 32 the scans were a third of the ordering time).
//! * Lower bound (`degree_bound`): in a path through the n directions every direction but the two
//!   ends has two edges, each end one, so the path is at least half the sum over directions of their
//!   two shortest edges, less the two largest second-shortest. It reads the exact neighbour lists the
//!   ordering already computed (no O(n^2) pass), and holds for any entry pose: with levels, each
//!   level's segment is an entry edge (>= 0) plus a path through its new directions, and the plan's
//!   bound is the sum over levels.

use glam::DVec3;
use gonio_shared::instrument::{InstrumentConfig, AXES};
use gonio_shared::kinematics::{Kinematics, Pose, Unreachable};
use gonio_shared::motion::sync_move_time;
use gonio_shared::vec3::Vec3;
use rayon::prelude::*;
use std::f64::consts::TAU;

/// How many nearest neighbours the local search looks at.
const NEIGHBOURS: usize = 10;
/// An improvement must beat this (seconds) to count, so rounding cannot cycle the search.
const MIN_GAIN: f64 = 1e-9;

fn v3(w: DVec3) -> Vec3<f64> {
    Vec3::new(w.x, w.y, w.z)
}

/// Move time between two poses, with a continuous (unwinding) axis taking the short way as the IK does.
pub fn move_seconds(cfg: &InstrumentConfig<f64>, from: &Pose<f64>, to: &Pose<f64>) -> f64 {
    let a = from.to_array();
    let mut b = to.to_array();
    for axis in AXES {
        if cfg.axis(axis).continuous {
            let i = axis.index();
            b[i] = a[i] + gonio_shared::real::wrap_pi(b[i] - a[i]);
        }
    }
    sync_move_time(cfg, &a, &b)
}

/// Every pose that reaches (wi, wo) on this instrument.
#[derive(Clone, Debug)]
pub struct Candidates(pub Vec<Pose<f64>>);

impl Candidates {
    /// All IK solutions: the two plane-normal signs times the detector's unwindings, found by
    /// asking the shared IK from a probe pose near each (it returns the valid solution nearest the
    /// probe, so every returned pose is one the firmware could pick).
    pub fn of(kin: &Kinematics<f64>, wi: DVec3, wo: DVec3) -> Result<Self, Unreachable> {
        let rest = kin.rest_pose();
        let first = kin.inverse(v3(wi), v3(wo), &rest)?;
        // The other branch: the plane normal flipped negates tilt and both arm angles (and the arms'
        // separation becomes 2 pi - separation).
        let sep = first.light - first.detector;
        let mut probes = Vec::new();
        for (tilt, det, sep) in [
            (first.tilt, first.detector, sep),
            (-first.tilt, -first.detector, TAU - sep),
        ] {
            for k in [-1.0, 0.0, 1.0] {
                let detector = det + k * TAU;
                probes.push(Pose {
                    light: detector + sep,
                    detector,
                    tilt,
                    azimuth: first.azimuth,
                });
            }
        }
        let mut out: Vec<Pose<f64>> = vec![first];
        for p in probes {
            if let Ok(q) = kin.inverse(v3(wi), v3(wo), &p) {
                let same = |a: &Pose<f64>| {
                    a.to_array()
                        .iter()
                        .zip(q.to_array().iter())
                        .all(|(x, y)| (x - y).abs() < 1e-9)
                };
                if !out.iter().any(same) {
                    out.push(q);
                }
            }
        }
        Ok(Self(out))
    }
}

/// d(a, b): the least move time between any pose of a and any pose of b.
pub fn metric(cfg: &InstrumentConfig<f64>, a: &Candidates, b: &Candidates) -> f64 {
    let mut best = f64::INFINITY;
    for p in &a.0 {
        for q in &b.0 {
            best = best.min(move_seconds(cfg, p, q));
        }
    }
    best
}

/// Poses and move times of a replay.
pub type Replay = (Vec<Pose<f64>>, Vec<f64>);

/// The poses and move times the firmware would produce for `order`, starting at `start`; on
/// failure, the index of the first unreachable direction and why.
pub fn simulate(
    kin: &Kinematics<f64>,
    start: Pose<f64>,
    pairs: &[(DVec3, DVec3)],
) -> Result<Replay, (usize, Unreachable)> {
    let cfg = kin.config();
    let mut current = start;
    let mut poses = Vec::with_capacity(pairs.len());
    let mut moves = Vec::with_capacity(pairs.len());
    for (idx, &(wi, wo)) in pairs.iter().enumerate() {
        let p = kin.inverse(v3(wi), v3(wo), &current).map_err(|e| (idx, e))?;
        kin.check_pose(&p).map_err(|e| (idx, e))?;
        moves.push(move_seconds(cfg, &current, &p));
        poses.push(p);
        current = p;
    }
    Ok((poses, moves))
}

/// Points for ordering: index 0 is the fixed start, 1..=n the directions.
struct Points<'a> {
    cfg: &'a InstrumentConfig<f64>,
    pts: Vec<&'a Candidates>,
}

impl Points<'_> {
    fn d(&self, a: usize, b: usize) -> f64 {
        metric(self.cfg, self.pts[a], self.pts[b])
    }

    /// The K nearest points of every point under d with their distances, nearest first
    /// (`PoseGrid::nearest`), in parallel.
    fn neighbours(&self, grid: &PoseGrid) -> Vec<Vec<(f64, usize)>> {
        let n = self.pts.len();
        let k = NEIGHBOURS.min(n - 1);
        // Queries are independent: in parallel, each worker with its own visit stamps.
        (0..n)
            .into_par_iter()
            .map_init(
                || vec![usize::MAX; n],
                |stamp, q| grid.nearest(self, q, k, stamp, |j| j != q),
            )
            .collect()
    }
}

/// A bucket grid over the points' poses (arm and tilt angles), with cells of `CELL_SECONDS` of
/// travel at each axis's top speed; every pose of every point is filed in its cell.
///
/// Why a nearest search over it is exact: a point s + 1 or more cells (Chebyshev) away from every
/// cell of the query's poses needs some axis to travel more than s cells, which takes at least that
/// axis's rest-to-rest time for s cells (a synchronised move is never faster than any one axis
/// alone), so the search stops once the K-th best found is within that. About O(K) per query
/// instead of O(n).
struct PoseGrid {
    lo: [f64; 3],
    h: [f64; 3],
    dims: [usize; 3],
    cells: Vec<Vec<usize>>,
    /// shell_bound[s]: least move time to any pose beyond shell s of a query's cell.
    shell_bound: Vec<f64>,
}

/// The grid's axes: light, detector, tilt. Only the azimuth may be continuous
/// (`InstrumentConfig::validate`), and a grid over it would need wrapping; leaving it out only
/// makes the cells coarser, never the search inexact.
const GRID_AXES: [usize; 3] = [0, 1, 2];

impl PoseGrid {
    fn new(p: &Points) -> Self {
        let h = GRID_AXES.map(|a| p.cfg.axes[a].max_speed * CELL_SECONDS);
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for c in &p.pts {
            for q in &c.0 {
                let v = q.to_array();
                for a in GRID_AXES {
                    lo[a] = lo[a].min(v[a]);
                    hi[a] = hi[a].max(v[a]);
                }
            }
        }
        let dims = GRID_AXES.map(|a| (((hi[a] - lo[a]) / h[a]).floor() as usize + 1).max(1));
        let mut grid = Self {
            lo,
            h,
            dims,
            cells: vec![Vec::new(); dims[0] * dims[1] * dims[2]],
            shell_bound: Vec::new(),
        };
        for (i, c) in p.pts.iter().enumerate() {
            for q in &c.0 {
                let f = grid.flat(grid.cell_of(q));
                if grid.cells[f].last() != Some(&i) {
                    grid.cells[f].push(i);
                }
            }
        }
        let max_shell = *dims.iter().max().unwrap_or(&1);
        // Least time to points beyond shell s: some axis travels at least s cells, from rest to rest.
        grid.shell_bound = (0..=max_shell)
            .map(|s| {
                GRID_AXES
                    .iter()
                    .map(|&a| {
                        let c = &p.cfg.axes[a];
                        gonio_shared::motion::move_time(s as f64 * h[a], c.max_speed, c.max_accel)
                    })
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        grid
    }

    fn cell_of(&self, p: &Pose<f64>) -> [usize; 3] {
        let v = p.to_array();
        GRID_AXES.map(|a| (((v[a] - self.lo[a]) / self.h[a]).floor().max(0.0) as usize).min(self.dims[a] - 1))
    }

    fn flat(&self, c: [usize; 3]) -> usize {
        (c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]
    }

    /// The `k` nearest points to `q` under d among those `accept` admits, nearest first, with
    /// their distances (fewer if fewer are filed). `stamp` (one slot per point, never holding `q`
    /// before the call) marks the points already measured in this query.
    fn nearest(
        &self,
        p: &Points,
        q: usize,
        k: usize,
        stamp: &mut [usize],
        accept: impl Fn(usize) -> bool,
    ) -> Vec<(f64, usize)> {
        let mut best: Vec<(f64, usize)> = Vec::with_capacity(k + 1);
        if k == 0 {
            return best;
        }
        let centres: Vec<[usize; 3]> = p.pts[q].0.iter().map(|c| self.cell_of(c)).collect();
        for (shell, &reach) in self.shell_bound.iter().enumerate() {
            for c in &centres {
                for_shell(*c, shell, self.dims, |cell| {
                    for &j in &self.cells[self.flat(cell)] {
                        if stamp[j] == q {
                            continue;
                        }
                        stamp[j] = q;
                        if !accept(j) {
                            continue;
                        }
                        let d = p.d(q, j);
                        if best.len() < k || d < best[best.len() - 1].0 {
                            let at = best.partition_point(|x| x.0 <= d);
                            best.insert(at, (d, j));
                            best.truncate(k);
                        }
                    }
                });
            }
            if best.len() == k && best[k - 1].0 <= reach {
                break;
            }
        }
        best
    }

    /// Take point `i` out of the grid (its every cell), so later searches skip it for free.
    fn remove(&mut self, p: &Points, i: usize) {
        for c in &p.pts[i].0 {
            let f = self.flat(self.cell_of(c));
            self.cells[f].retain(|&x| x != i);
        }
    }
}

/// Cell size of the neighbour search, in seconds of travel at an axis's top speed. Any size is
/// exact; this one is the fastest of 0.06, 0.1, 0.15, 0.25 and 0.4 s on the 6016-direction last
/// level of a mixture plan at N = 32 (`cargo bench -p gonio --bench plan`): smaller cells mean
/// more empty cells per shell, larger ones more points per cell.
const CELL_SECONDS: f64 = 0.15;

/// Call `f` on every cell at Chebyshev distance exactly `s` from `c` inside `dims`.
fn for_shell(c: [usize; 3], s: usize, dims: [usize; 3], mut f: impl FnMut([usize; 3])) {
    let range = |a: usize| (c[a].saturating_sub(s), (c[a] + s).min(dims[a] - 1));
    let (r0, r1, r2) = (range(0), range(1), range(2));
    for x in r0.0..=r0.1 {
        for y in r1.0..=r1.1 {
            let edge_xy = x.abs_diff(c[0]) == s || y.abs_diff(c[1]) == s;
            if edge_xy {
                for z in r2.0..=r2.1 {
                    f([x, y, z]);
                }
            } else {
                // Only the two z faces are at distance s.
                if c[2] >= s {
                    f([x, y, c[2] - s]);
                }
                if s > 0 && c[2] + s < dims[2] {
                    f([x, y, c[2] + s]);
                }
            }
        }
    }
}

/// What `optimise` returns.
#[derive(Clone, Debug)]
pub struct Ordered {
    /// A permutation of 0..items.len(): the order to measure them in.
    pub perm: Vec<usize>,
    /// A lower bound on the motion of every order of the items, from any start pose
    /// (`degree_bound`); seconds.
    pub bound: f64,
}

/// Order `items` (candidate sets of the directions) starting from the pose set `start`.
pub fn optimise(cfg: &InstrumentConfig<f64>, start: &Candidates, items: &[Candidates]) -> Ordered {
    let n = items.len();
    if n <= 1 {
        return Ordered {
            perm: (0..n).collect(),
            bound: 0.0,
        };
    }
    let mut pts = vec![start];
    pts.extend(items.iter());
    let p = Points { cfg, pts };
    // Nearest neighbour: the nearest unvisited point among the neighbour list, else (all visited)
    // the nearest unvisited point by a grid search over the points not yet visited.
    let mut grid = PoseGrid::new(&p);
    let nb = p.neighbours(&grid);
    let mut path = vec![0usize];
    let mut used = vec![false; n + 1];
    used[0] = true;
    grid.remove(&p, 0);
    let mut stamp = vec![usize::MAX; n + 1];
    for _ in 0..n {
        let last = path[path.len() - 1];
        let next = nb[last].iter().map(|&(_, b)| b).find(|&b| !used[b]).or_else(|| {
            grid.nearest(&p, last, 1, &mut stamp, |j| !used[j])
                .first()
                .map(|&(_, j)| j)
        });
        // Every unvisited point is filed in the grid, so the search finds one while any remain.
        let Some(next) = next else { break };
        used[next] = true;
        grid.remove(&p, next);
        path.push(next);
    }
    local_search(&p, &nb, &mut path);
    Ordered {
        perm: path[1..].iter().map(|&i| i - 1).collect(),
        bound: degree_bound(&nb),
    }
}

/// Lower bound on the length under d of any open path through the items (points 1..=n of `p`) that
/// enters them from any pose at all. Each item's path edges to other items: two for every item but
/// the first and the last, one for those two (the first's other edge comes from the start, >= 0).
/// Two distinct edges at an item are at least its nearest and second-nearest item distances d1 + d2,
/// and the path's item edges are half the sum of every item's, so
///   length >= 1/2 (sum over items of (d1 + d2) - the two largest d2).
/// d1, d2 come from the exact neighbour lists (`PoseGrid::nearest`, start point left out), so the
/// bound costs nothing beyond the ordering; it is the degree relaxation of the path (every vertex
/// keeps its two cheapest edges), usually tighter than the minimum spanning tree on grid-like sets.
fn degree_bound(nb: &[Vec<(f64, usize)>]) -> f64 {
    let mut sum = 0.0;
    let mut largest_d2 = [0.0f64; 2];
    for list in nb.iter().skip(1) {
        let mut near = list.iter().filter(|&&(_, w)| w != 0).map(|&(d, _)| d);
        let d1 = near.next().unwrap_or(0.0);
        // Guard: an item with a single other item has no second edge (n = 2): d2 = 0.
        let d2 = near.next().unwrap_or(0.0);
        sum += d1 + d2;
        if d2 > largest_d2[0] {
            largest_d2 = [d2, largest_d2[0]];
        } else if d2 > largest_d2[1] {
            largest_d2[1] = d2;
        }
    }
    (0.5 * (sum - largest_d2[0] - largest_d2[1])).max(0.0)
}

fn edge(p: &Points, path: &[usize], a: usize) -> f64 {
    if a + 1 < path.len() {
        p.d(path[a], path[a + 1])
    } else {
        0.0
    }
}

fn local_search(p: &Points, nb: &[Vec<(f64, usize)>], path: &mut Vec<usize>) {
    let len = path.len();
    let mut pos = vec![0usize; len];
    let reindex = |path: &[usize], pos: &mut [usize]| {
        for (i, &c) in path.iter().enumerate() {
            pos[c] = i;
        }
    };
    reindex(path, &mut pos);
    // Don't-look bits (Bentley): a point whose moves found no gain is skipped until a move changes
    // one of its path edges; [0] for 2-opt, [s] for Or-opt segments of length s starting at it.
    // Without them every round re-tries every point, and the late rounds that find a handful of
    // gains cost as much as the first.
    let mut active = [vec![true; len], vec![true; len], vec![true; len], vec![true; len]];
    let wake = |active: &mut [Vec<bool>; 4], points: &[usize]| {
        for &x in points {
            for a in active.iter_mut() {
                a[x] = true;
            }
        }
    };
    for _round in 0..50 {
        let mut improved = false;
        // 2-opt: reverse path[a+1..=b] so that path[a] meets path[b].
        for a in 0..len - 1 {
            if !active[0][path[a]] {
                continue;
            }
            let mut moved = false;
            let edge_a = edge(p, path, a);
            for &(d_ac, c) in &nb[path[a]] {
                let b = pos[c];
                if b <= a + 1 {
                    continue;
                }
                let old = edge_a + edge(p, path, b);
                let new = d_ac
                    + if b + 1 < len {
                        p.d(path[a + 1], path[b + 1])
                    } else {
                        0.0
                    };
                if old - new > MIN_GAIN {
                    let touched = [
                        path[a],
                        path[a + 1],
                        path[b],
                        path.get(b + 1).copied().unwrap_or(path[b]),
                    ];
                    path[a + 1..=b].reverse();
                    reindex(path, &mut pos);
                    wake(&mut active, &touched);
                    improved = true;
                    moved = true;
                    break;
                }
            }
            if !moved {
                active[0][path[a]] = false;
            }
        }
        // Or-opt: move a segment of 1-3 (maybe reversed) next to a neighbour of its first node.
        for s in 1..=3usize {
            let mut i = 1;
            while i + s <= len {
                if !active[s][path[i]] {
                    i += 1;
                    continue;
                }
                let seg: Vec<usize> = path[i..i + s].to_vec();
                let (first, last) = (seg[0], seg[s - 1]);
                let prev = path[i - 1];
                let next = path.get(i + s).copied();
                let removed_gain =
                    p.d(prev, first) + next.map_or(0.0, |x| p.d(last, x)) - next.map_or(0.0, |x| p.d(prev, x));
                let mut best: Option<(f64, usize, bool)> = None;
                for &(d_cf, c) in &nb[first] {
                    let j = pos[c];
                    if (i..i + s).contains(&j) || j + 1 == i {
                        continue;
                    }
                    // Insert between path[j] and path[j + 1] (or at the end).
                    let after = path.get(j + 1).copied().filter(|&x| x != first);
                    let d_c_after = after.map_or(0.0, |x| p.d(c, x));
                    // A single node has one orientation.
                    for reversed in [false, true].into_iter().take(if s == 1 { 1 } else { 2 }) {
                        let (d_ch, t) = if reversed { (p.d(c, last), first) } else { (d_cf, last) };
                        let add = d_ch + after.map_or(0.0, |x| p.d(t, x)) - d_c_after;
                        let gain = removed_gain - add;
                        if gain > MIN_GAIN && best.is_none_or(|(g, _, _)| gain > g) {
                            best = Some((gain, j, reversed));
                        }
                    }
                }
                if let Some((_, j, reversed)) = best {
                    let target = path[j];
                    let after = path.get(j + 1).copied().unwrap_or(target);
                    wake(&mut active, &[prev, first, last, next.unwrap_or(last), target, after]);
                    let mut seg = seg;
                    if reversed {
                        seg.reverse();
                    }
                    path.drain(i..i + s);
                    let at = path.iter().position(|&x| x == target).map_or(path.len(), |q| q + 1);
                    for (o, c) in seg.into_iter().enumerate() {
                        path.insert(at + o, c);
                    }
                    reindex(path, &mut pos);
                    improved = true;
                } else {
                    active[s][first] = false;
                }
                i += 1;
            }
        }
        if !improved {
            break;
        }
    }
}

/// Length under d of the minimum spanning tree of `items` (Prim, O(n^2)): the tests' reference bound.
#[cfg(test)]
fn mst_seconds(cfg: &InstrumentConfig<f64>, items: &[&Candidates]) -> f64 {
    let n = items.len();
    if n <= 1 {
        return 0.0;
    }
    let mut in_tree = vec![false; n];
    let mut best = vec![f64::INFINITY; n];
    best[0] = 0.0;
    let mut total = 0.0;
    for _ in 0..n {
        let Some(u) = (0..n)
            .filter(|&i| !in_tree[i])
            .min_by(|&a, &b| best[a].total_cmp(&best[b]))
        else {
            break;
        };
        in_tree[u] = true;
        total += best[u];
        for v in 0..n {
            if !in_tree[v] {
                let d = metric(cfg, items[u], items[v]);
                if d < best[v] {
                    best[v] = d;
                }
            }
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::frame::from_spherical;
    use crate::instrument::default_instrument;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// `n` random directions this instrument reaches: wi in the phi = 0 plane and wo anywhere, both
    /// with theta below `max_theta`.
    fn reachable_items(kin: &Kinematics<f64>, rng: &mut ChaCha8Rng, n: usize, max_theta: f64) -> Vec<Candidates> {
        let mut items = Vec::new();
        while items.len() < n {
            let wi = from_spherical(rng.random::<f64>() * max_theta, 0.0);
            let wo = from_spherical(rng.random::<f64>() * max_theta, rng.random::<f64>() * TAU);
            if let Ok(c) = Candidates::of(kin, wi, wo) {
                items.push(c);
            }
        }
        items
    }

    /// The degree bound never exceeds the shortest open path through the items from any entry
    /// (brute force over every order), on random small sets; printed beside the MST bound.
    #[test]
    fn degree_bound_is_below_every_path() {
        let cfg = default_instrument();
        let kin = Kinematics::new(cfg).expect("kin");
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let start = Candidates(vec![kin.rest_pose()]);
        for trial in 0..40 {
            let n = 2 + trial % 6;
            let items = reachable_items(&kin, &mut rng, n, 1.4);
            let bound = optimise(&cfg, &start, &items).bound;
            // Shortest open path over every permutation (Heap's algorithm), entry edge free.
            let mut perm: Vec<usize> = (0..n).collect();
            let len =
                |perm: &[usize]| -> f64 { perm.windows(2).map(|w| metric(&cfg, &items[w[0]], &items[w[1]])).sum() };
            let mut best = len(&perm);
            let mut c = vec![0usize; n];
            let mut i = 0;
            while i < n {
                if c[i] < i {
                    if i % 2 == 0 {
                        perm.swap(0, i);
                    } else {
                        perm.swap(c[i], i);
                    }
                    best = best.min(len(&perm));
                    c[i] += 1;
                    i = 0;
                } else {
                    c[i] = 0;
                    i += 1;
                }
            }
            let refs: Vec<&Candidates> = items.iter().collect();
            let mst = mst_seconds(&cfg, &refs);
            assert!(
                bound <= best + 1e-9,
                "n {n}: degree bound {bound} > shortest path {best}"
            );
            assert!(mst <= best + 1e-9, "n {n}: mst {mst} > shortest path {best}");
            assert!(bound > 0.0, "n {n}: a bound of 0 bounds nothing");
            if trial % 6 == 5 {
                println!("n {n}: shortest {best:.3} s, degree bound {bound:.3}, mst {mst:.3}");
            }
        }
    }

    /// The bucketed neighbour lists are the exact K nearest: same distances as a full scan.
    #[test]
    fn bucketed_neighbours_are_exact() {
        let cfg = default_instrument();
        let kin = Kinematics::new(cfg).expect("kin");
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let items = reachable_items(&kin, &mut rng, 400, 1.5);
        let p = Points {
            cfg: &cfg,
            pts: items.iter().collect(),
        };
        let nb = p.neighbours(&PoseGrid::new(&p));
        for (a, list) in nb.iter().enumerate() {
            let mut all: Vec<f64> = (0..items.len()).filter(|&b| b != a).map(|b| p.d(a, b)).collect();
            all.sort_by(f64::total_cmp);
            let got: Vec<f64> = list.iter().map(|&(d, _)| d).collect();
            for &(d, b) in list {
                assert_eq!(d, p.d(a, b), "point {a}: stored distance to {b}");
            }
            assert_eq!(got.len(), NEIGHBOURS);
            for (g, w) in got.iter().zip(&all) {
                assert!((g - w).abs() < 1e-12, "point {a}: {got:?} vs {:?}", &all[..NEIGHBOURS]);
            }
        }
    }

    /// The nearest-neighbour fallback's search (the grid with visited points taken out) finds the
    /// nearest of the points left, as a full scan does, however many have been taken out.
    #[test]
    fn the_grid_finds_the_nearest_point_left() {
        let cfg = default_instrument();
        let kin = Kinematics::new(cfg).expect("kin");
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let items = reachable_items(&kin, &mut rng, 300, 1.5);
        let p = Points {
            cfg: &cfg,
            pts: items.iter().collect(),
        };
        let mut grid = PoseGrid::new(&p);
        let mut gone = vec![false; items.len()];
        let mut stamp = vec![usize::MAX; items.len()];
        // Take points out in a random order; after each, query from a random point.
        let mut checked = 0;
        for _ in 0..items.len() - 1 {
            let i = rng.random_range(0..items.len());
            if !gone[i] {
                gone[i] = true;
                grid.remove(&p, i);
            }
            let q = rng.random_range(0..items.len());
            let want = (0..items.len())
                .filter(|&j| !gone[j] && j != q)
                .map(|j| p.d(q, j))
                .fold(f64::INFINITY, f64::min);
            // Fresh stamps per query: the same q may come twice here, unlike in `optimise`.
            stamp.iter_mut().for_each(|s| *s = usize::MAX);
            let got = grid.nearest(&p, q, 1, &mut stamp, |j| !gone[j] && j != q);
            match got.first() {
                Some(&(d, j)) => {
                    assert!(!gone[j] && j != q);
                    assert_eq!(d, want, "query {q}: nearest left {d} vs full scan {want}");
                    checked += 1;
                }
                None => assert!(want.is_infinite(), "query {q}: nothing found, full scan {want}"),
            }
        }
        assert!(checked > 100, "only {checked} queries had a point left");
    }
}
