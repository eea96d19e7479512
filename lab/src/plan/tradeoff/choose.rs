//! Lab trial `choose` of `gonio-lab closed-loop` (issue 25, item 2): each scan's own measurements
//! choose, level by level, whether the next level refines the incoming elevations or the outgoing
//! grid.
//!
//! After level l (K elevations x N x N outgoing) two sensitivities are computed from the
//! measurements alone, each a point-light FLIP (`Scorer`, `ESTIMATE_SIZE` px, the capture scene)
//! between level l's reconstruction and a reconstruction of the same level with part of its
//! measurements left out (`LeaveOut`, a `Levels` that presents a subset of a level):
//! * `e_in`: every other interior elevation left out (slices 0, 2, 4, ... and the last kept);
//! * `e_out`: the outgoing grid halved (the N/2 x N/2 nodes of the same elevations kept).
//!
//! Each says what the last refinement of its dimension changed; the next level refines the
//! elevations, (K, N) -> (2K - 1, N), when `e_in > c * e_out`, else the outgoing grid,
//! (K, N) -> (K, 2N). Level 1's 2 x 2 grid has no coarser grid, so level 2 refines the outgoing
//! grid (today's 8 x 4). Elevations stop at `K_MAX`; an option whose cumulative direction count
//! is above the uniform 8-elevation grid's at that level is not taken.
//!
//! In simulation a dynamic schedule's levels equal a fixed schedule's with the same prefix, so a
//! prefix is planned with `PlanConfig::incoming` (`config`). The planner's nudge and the mixture's
//! node layout read the finest grid's N, so `config` pads every schedule with an unmeasured level
//! of the finest N (`fine_n` x the last N): the measured levels are then those the same prefix gives
//! in any longer schedule, and a schedule of 8 elevations at every level is today's plan.

use glam::DVec3;
use gonio::brdf::grid::NodeLayout;
use gonio::brdf::warp::SliceWarp;
use gonio::brdf::Material;
use gonio::plan::closed_loop::ESTIMATE_SIZE;
use gonio::plan::predict::{score, Scorer};
use gonio::plan::{Plan, PlanConfig, PlanError, Planner, Strategy};
use gonio::reconstruct::{reconstruct, LevelNodes, Levels};
use std::collections::HashMap;

/// Most incoming elevations a chosen schedule reaches (nested 8 -> 15 -> 29).
pub const K_MAX: usize = 29;
/// Incoming elevations and outgoing grid of level 1 (today's).
pub const FIRST: (usize, usize) = (8, 2);

/// One level of a measured plan with part of its measurements left out; `values` are the kept
/// measurements' values, indexed like its `measured`.
pub struct LeaveOut {
    level: usize,
    slices: Vec<SliceWarp>,
    thetas: Vec<f64>,
    layout: NodeLayout,
    n: usize,
    m: usize,
    node_measurement: Vec<Option<usize>>,
    measured: Vec<(usize, DVec3, DVec3)>,
    estimate_alpha: f64,
    blocked_cone: f64,
    pub values: Vec<DVec3>,
}

impl LeaveOut {
    /// Level `level` of `levels` on the slices `keep` (indices, increasing), with its outgoing grid
    /// halved in N and M when `halve` (the nested N/2 x M/2 nodes). Only measurements on a kept
    /// node stay. None if the level does not exist, `keep` is empty or N/2 < 2.
    pub fn new(levels: &dyn Levels, level: usize, values: &[DVec3], keep: &[usize], halve: bool) -> Option<LeaveOut> {
        let nodes = levels.level_nodes(level)?;
        let (n, m) = (nodes.n, nodes.m);
        let (n2, m2) = if halve { (n / 2, (m / 2).max(1)) } else { (n, m) };
        if keep.is_empty() || n2 < 2 || keep.iter().any(|&k| k >= nodes.thetas.len()) {
            return None;
        }
        let ring = |i: usize| if halve { nodes.layout.fine_index(i, n2, n) } else { i };
        let mut old = Vec::with_capacity(keep.len() * n2 * m2);
        for &k in keep {
            for j in 0..m2 {
                for i in 0..n2 {
                    old.push(nodes.node_measurement[(k * m + j * (m / m2)) * n + ring(i)]);
                }
            }
        }
        // The kept measurements in measurement order, and their new indices.
        let mut used: Vec<usize> = old.iter().flatten().copied().collect();
        used.sort_unstable();
        used.dedup();
        let index: HashMap<usize, usize> = used.iter().enumerate().map(|(new, &d)| (d, new)).collect();
        let slice: HashMap<usize, usize> = keep.iter().enumerate().map(|(new, &k)| (k, new)).collect();
        let measured = used
            .iter()
            .map(|&d| {
                let (k, wi, wo) = nodes.measured[d];
                (slice.get(&k).copied().unwrap_or(0), wi, wo)
            })
            .collect();
        Some(LeaveOut {
            level,
            slices: keep.iter().map(|&k| nodes.slices[k].clone()).collect(),
            thetas: keep.iter().map(|&k| nodes.thetas[k]).collect(),
            layout: nodes.layout,
            n: n2,
            m: m2,
            node_measurement: old.iter().map(|d| d.and_then(|d| index.get(&d).copied())).collect(),
            measured,
            estimate_alpha: nodes.estimate_alpha,
            blocked_cone: nodes.blocked_cone,
            values: used.iter().map(|&d| values[d]).collect(),
        })
    }
}

impl Levels for LeaveOut {
    fn level_nodes(&self, level: usize) -> Option<LevelNodes<'_>> {
        (level == self.level).then(|| LevelNodes {
            slices: &self.slices,
            thetas: &self.thetas,
            layout: self.layout,
            n: self.n,
            m: self.m,
            node_measurement: self.node_measurement.clone(),
            measured: self.measured.clone(),
            estimate_alpha: self.estimate_alpha,
            blocked_cone: self.blocked_cone,
        })
    }
}

/// Every other interior slice of `k` left out: 0, 2, 4, ... and the last (None below 3 slices).
pub fn alternate_slices(k: usize) -> Option<Vec<usize>> {
    if k < 3 {
        return None;
    }
    let mut keep: Vec<usize> = (0..k).step_by(2).collect();
    if keep.last() != Some(&(k - 1)) {
        keep.push(k - 1);
    }
    Some(keep)
}

/// A level's two sensitivities (point-light FLIP against the level's own reconstruction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sensitivity {
    /// Every other interior elevation left out.
    pub e_in: f64,
    /// The outgoing grid halved.
    pub e_out: f64,
}

/// `e_in` and `e_out` of `level` (None where either leave-out does not exist: fewer than 3
/// elevations, or a 2 x 2 grid).
pub fn sensitivity(
    levels: &dyn Levels,
    level: usize,
    values: &[DVec3],
    scorer: &mut Scorer,
) -> Result<Option<Sensitivity>, PlanError> {
    let Some(nodes) = levels.level_nodes(level) else {
        return Ok(None);
    };
    let all: Vec<usize> = (0..nodes.thetas.len()).collect();
    let (Some(alt), Some(coarse)) = (
        alternate_slices(all.len()).and_then(|keep| LeaveOut::new(levels, level, values, &keep, false)),
        LeaveOut::new(levels, level, values, &all, true),
    ) else {
        return Ok(None);
    };
    let full = scorer.render(Box::new(reconstruct(levels, level, values)?));
    let mut flip = |l: &LeaveOut| -> Result<f64, PlanError> {
        let image = scorer.render(Box::new(reconstruct(l, level, &l.values)?));
        Ok(score(&full, &image)?.flip)
    };
    Ok(Some(Sensitivity {
        e_in: flip(&alt)?,
        e_out: flip(&coarse)?,
    }))
}

/// The next level after `(k, n)`: the options in order of preference, elevations first when
/// `e_in > c * e_out` (c = inf: never), outgoing first otherwise (and without sensitivities).
pub fn options(current: (usize, usize), s: Option<Sensitivity>, c: f64) -> Vec<(usize, usize)> {
    let (k, n) = current;
    let outgoing = (k, 2 * n);
    let incoming = (2 * k - 1 <= K_MAX).then_some((2 * k - 1, n));
    let elevations_first = s.is_some_and(|s| s.e_in > c * s.e_out);
    let mut out = vec![outgoing];
    match incoming {
        Some(i) if elevations_first => out.insert(0, i),
        Some(i) => out.push(i),
        None => {}
    }
    out
}

/// The plan config of a schedule of (K, N) per level, padded with an unmeasured level of N =
/// `fine_n` (x the last N) when its last N is smaller (see the module doc).
pub fn config(strategy: Strategy, schedule: &[(usize, usize)], fine_n: usize) -> PlanConfig {
    let mut grids: Vec<(usize, usize)> = schedule.iter().map(|&(_, n)| (n, n)).collect();
    let mut incoming: Vec<usize> = schedule.iter().map(|&(k, _)| k).collect();
    let (k, n) = schedule.last().copied().unwrap_or(FIRST);
    if n < fine_n {
        grids.push((fine_n, n));
        incoming.push(k);
    }
    PlanConfig {
        strategy,
        grids,
        incoming,
        k,
        ..PlanConfig::default()
    }
}

/// A schedule as `8x2,8x4,15x4`.
pub fn label(schedule: &[(usize, usize)]) -> String {
    let list: Vec<String> = schedule.iter().map(|(k, n)| format!("{k}x{n}")).collect();
    list.join(",")
}

/// One chosen schedule and the sensitivities each choice read (None at level 1, or at the last).
#[derive(Clone, Debug)]
pub struct Choice {
    pub c: f64,
    pub schedule: Vec<(usize, usize)>,
    pub sensitivities: Vec<Option<Sensitivity>>,
}

/// A schedule, (K, N) per level.
pub type Schedule = Vec<(usize, usize)>;

/// Plans of schedules measured on one material, by schedule.
pub struct Explorer<'a> {
    planner: &'a Planner,
    truth: &'a dyn Material,
    strategy: Strategy,
    fine_n: usize,
    plans: HashMap<Schedule, (Plan, Vec<DVec3>)>,
    sens: HashMap<Schedule, Option<Sensitivity>>,
    scorer: Scorer,
}

impl<'a> Explorer<'a> {
    pub fn new(
        planner: &'a Planner,
        truth: &'a dyn Material,
        strategy: Strategy,
        fine_n: usize,
    ) -> Result<Self, PlanError> {
        Ok(Self {
            planner,
            truth,
            strategy,
            fine_n,
            plans: HashMap::new(),
            sens: HashMap::new(),
            scorer: Scorer::new(ESTIMATE_SIZE)?,
        })
    }

    /// The plan of `schedule` (padded) and the truth measured on it.
    pub fn plan(&mut self, schedule: &[(usize, usize)]) -> Result<&(Plan, Vec<DVec3>), PlanError> {
        if !self.plans.contains_key(schedule) {
            let plan = self.planner.plan(&config(self.strategy, schedule, self.fine_n))?;
            let values = plan.measure(self.truth);
            self.plans.insert(schedule.to_vec(), (plan, values));
        }
        Ok(&self.plans[schedule])
    }

    fn sensitivity(&mut self, schedule: &[(usize, usize)]) -> Result<Option<Sensitivity>, PlanError> {
        if let Some(s) = self.sens.get(schedule) {
            return Ok(*s);
        }
        self.plan(schedule)?;
        let (plan, values) = &self.plans[schedule];
        let s = sensitivity(plan, schedule.len(), values, &mut self.scorer)?;
        self.sens.insert(schedule.to_vec(), s);
        Ok(s)
    }

    /// The schedule of `max_level` levels the rule with constant `c` chooses; `uniform[l]` caps
    /// level l + 1's cumulative directions.
    pub fn choose(&mut self, c: f64, max_level: usize, uniform: &[usize]) -> Result<Choice, PlanError> {
        let mut schedule = vec![FIRST];
        let mut sensitivities = Vec::new();
        while schedule.len() < max_level {
            let s = self.sensitivity(&schedule)?;
            sensitivities.push(s);
            let current = *schedule.last().unwrap_or(&FIRST);
            let mut next = None;
            for option in options(current, s, c) {
                let mut longer = schedule.clone();
                longer.push(option);
                let count = self.plan(&longer)?.0.levels[schedule.len()].cumulative_directions;
                if uniform.get(schedule.len()).is_none_or(|&u| count <= u) {
                    next = Some(option);
                    break;
                }
            }
            let Some(next) = next else { break };
            schedule.push(next);
        }
        sensitivities.push(None);
        Ok(Choice {
            c,
            schedule,
            sensitivities,
        })
    }
}

#[cfg(test)]
mod tests;
