//! Step 2 of the pipeline: from estimated BRDF parameters to an ordered, timed direction list
//! (docs/planner.md).
//!
//! * Incoming: 1 phi x K theta at equal angle steps.
//! * Outgoing: per incoming theta, nested levels of N x M nodes in u-space through the slice warp
//!   of the `Strategy`; each level's nodes are nodes of the next, so a scan can stop after any level.
//! * Unreachable nodes are nudged toward a reachable direction or dropped (`Dropped`).
//! * Order and time: `order` within each level, timed by replaying the firmware's IK.

pub mod closed_loop;
pub mod file;
pub mod order;
mod planner;
pub mod predict;

pub use planner::Planner;

use crate::brdf::analytic::Ggx;
use crate::brdf::frame::{phi_of, theta_of};
use crate::brdf::grid::{NodeLayout, THETA_I_MAX};
use crate::brdf::spec::Analytic;
use crate::brdf::warp::SliceWarp;
use crate::brdf::Material;
use crate::reconstruct::{LevelNodes, Levels};
use glam::DVec3;
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::kinematics::{Pose, Unreachable};
use gonio_shared::msg::Direction;
use planner::FirmwareCheck;
use std::collections::HashMap;
use std::fmt;

/// Smallest alpha of the mixture's visible-normal part (below it the warp is a delta, no inverse).
pub const PLAN_ALPHA_MIN: f64 = 0.01;
/// Table resolution of the mixture warp (vertices per side).
pub const MIXTURE_TABLE_RES: usize = 48;
/// Most levels a plan can have (N = 2^6 = 64).
pub const MAX_LEVEL: usize = 6;
/// Largest N or M of a level.
pub const MAX_GRID: usize = 1 << MAX_LEVEL;
/// Step and reach of the unreachable-node nudge (radians): 0.5 deg steps up to 10 deg.
pub const NUDGE_STEP: f64 = 0.5 * std::f64::consts::PI / 180.0;
pub const NUDGE_MAX: f64 = 10.0 * std::f64::consts::PI / 180.0;

#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error("plan: {0}")]
    Invalid(String),
    #[error("plan: direction {index} is unreachable on re-simulation ({reason:?})")]
    Unreachable { index: usize, reason: Unreachable },
    #[error(transparent)]
    Brdf(#[from] crate::brdf::BrdfError),
    #[error(transparent)]
    File(#[from] file::PlanFileError),
    #[error(transparent)]
    Reconstruct(#[from] crate::reconstruct::ReconstructError),
}

/// Which outgoing warp.
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::EnumString, strum::VariantNames)]
#[strum(serialize_all = "kebab-case")]
pub enum Strategy {
    /// The estimate decides: `mixture` for a lobe sharper than `AUTO_SHARP_ALPHA`, `uniform` for a rougher one.
    Auto,
    /// eq. 6: visible normals composed with a table of the estimate's f cos (whole lobe).
    Mixture,
    /// Equal steps in (theta_o, phi_o), blind to the material.
    Uniform,
}

/// Estimated alpha below which `Strategy::Auto` follows the lobe (docs/planner.md, "auto").
pub const AUTO_SHARP_ALPHA: f64 = 0.05;

impl Strategy {
    /// The warp this strategy plans with for an estimate of roughness `alpha` (`Auto` picks one;
    /// the others are themselves). Guard: a NaN alpha gets the material-blind uniform grid.
    pub fn resolve(self, alpha: f64) -> Strategy {
        match self {
            Strategy::Auto if alpha < AUTO_SHARP_ALPHA => Strategy::Mixture,
            Strategy::Auto => Strategy::Uniform,
            other => other,
        }
    }
}

impl fmt::Display for Strategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Strategy::Auto => "auto",
            Strategy::Mixture => "mixture",
            Strategy::Uniform => "uniform",
        })
    }
}

/// Spacing of the incoming elevations (recorded in plan and scan files).
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::EnumString, strum::VariantNames)]
#[strum(serialize_all = "kebab-case")]
pub enum Spacing {
    /// Equal steps in theta.
    Angle,
}

impl fmt::Display for Spacing {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Spacing::Angle => "angle",
        })
    }
}

/// K incoming elevations from 0 to THETA_I_MAX in equal steps.
pub fn incoming_thetas(k: usize) -> Vec<f64> {
    if k <= 1 {
        return vec![0.0];
    }
    (0..k).map(|i| i as f64 / (k - 1) as f64 * THETA_I_MAX).collect()
}

/// The estimate a plan is built from: an analytic model (from the encoder or a fit).
#[derive(Clone, Debug)]
pub struct Estimate {
    pub model: Analytic,
}

impl Estimate {
    pub fn alpha(&self) -> f64 {
        match &self.model {
            Analytic::Ggx(m) => m.alpha,
            Analytic::Ward(m) => m.alpha,
            Analytic::Lambert(_) => 1.0,
        }
    }
    pub fn material(&self) -> Box<dyn Material> {
        self.model.clone().into_material()
    }
}

/// What to plan.
#[derive(Clone, Debug)]
pub struct PlanConfig {
    pub strategy: Strategy,
    pub spacing: Spacing,
    /// Number of incoming elevations of the deepest level.
    pub k: usize,
    /// The levels' outgoing grids (N, M), coarsest first; each level's N and M divide the next's.
    pub grids: Vec<(usize, usize)>,
    /// Per level, its incoming elevations (nested: each level's are among the next's, the last is
    /// `k`); empty: `k` at every level. A level's new elevations get the full grid of that level.
    pub incoming: Vec<usize>,
}

impl PlanConfig {
    /// Incoming elevations of level `level` (1-based).
    pub fn incoming_at(&self, level: usize) -> usize {
        level
            .checked_sub(1)
            .and_then(|l| self.incoming.get(l))
            .copied()
            .unwrap_or(self.k)
    }

    /// Step, in the deepest level's elevations, between level `level`'s elevations (slice k of
    /// the plan is on that level when k is a multiple of it).
    pub fn incoming_stride(&self, level: usize) -> usize {
        let here = self.incoming_at(level);
        // Guard: one elevation (theta 0) has no step; it is slice 0 alone.
        if here <= 1 {
            return self.k.max(1);
        }
        (self.k.max(2) - 1) / (here - 1)
    }
}

impl Default for PlanConfig {
    fn default() -> Self {
        Self {
            strategy: Strategy::Auto,
            spacing: Spacing::Angle,
            k: crate::brdf::grid::DEFAULT_K,
            grids: square_grids(4),
            incoming: Vec::new(),
        }
    }
}

/// Square levels 2x2, 4x4, ..., 2^max_level x 2^max_level.
pub fn square_grids(max_level: usize) -> Vec<(usize, usize)> {
    (1..=max_level).map(|l| (1usize << l, 1usize << l)).collect()
}

/// Checks a level list: 1..=MAX_LEVEL levels, 2 <= N <= MAX_GRID, 1 <= M <= MAX_GRID, and every
/// level's N and M divide the next level's (so the levels nest) with more nodes than it.
pub fn check_grids(grids: &[(usize, usize)]) -> Result<(), PlanError> {
    check_levels(grids, &[], 1)
}

/// `check_grids` with per-level incoming counts (`PlanConfig::incoming`, deepest `k`): each
/// level's elevations are among the next's ((K' - 1) a multiple of (K - 1)), and a level that
/// adds elevations may keep the previous level's grid.
pub fn check_levels(grids: &[(usize, usize)], incoming: &[usize], k: usize) -> Result<(), PlanError> {
    if !incoming.is_empty() {
        if incoming.len() != grids.len() || incoming.last() != Some(&k) {
            return Err(PlanError::Invalid(format!(
                "incoming per level {incoming:?}: expected one count per level ({}), the last {k}",
                grids.len()
            )));
        }
        for w in incoming.windows(2) {
            let (a, b) = (w[0], w[1]);
            let nested = a == b || (a >= 2 && b > a && (b - 1) % (a - 1) == 0) || a == 1;
            if !nested || a == 0 {
                return Err(PlanError::Invalid(format!(
                    "incoming {a} -> {b}: each level's elevations must be among the next's"
                )));
            }
        }
    }
    let grows = |l: usize| incoming.get(l + 1).zip(incoming.get(l)).is_some_and(|(b, a)| b > a);
    if grids.is_empty() || grids.len() > MAX_LEVEL {
        return Err(PlanError::Invalid(format!(
            "{} levels, expected 1..={MAX_LEVEL}",
            grids.len()
        )));
    }
    for &(n, m) in grids {
        if !(2..=MAX_GRID).contains(&n) || !(1..=MAX_GRID).contains(&m) {
            return Err(PlanError::Invalid(format!(
                "grid {n}x{m}: N must be in 2..={MAX_GRID} and M in 1..={MAX_GRID}"
            )));
        }
    }
    for (l, w) in grids.windows(2).enumerate() {
        let ((n0, m0), (n1, m1)) = (w[0], w[1]);
        if n1 % n0 != 0 || m1 % m0 != 0 || (n1 * m1 <= n0 * m0 && !(n1 * m1 == n0 * m0 && grows(l))) {
            return Err(PlanError::Invalid(format!(
                "grid {n1}x{m1} does not contain {n0}x{m0}: each level's N and M must divide the next's"
            )));
        }
    }
    Ok(())
}

/// One direction of the plan, in execution order.
#[derive(Clone, Debug)]
pub struct PlannedDirection {
    /// First level that contains it (1-based).
    pub level: usize,
    /// Slice and node at the finest level (i in 0..N, j in 0..M of the last grid).
    pub k: usize,
    pub i: usize,
    pub j: usize,
    pub wi: DVec3,
    pub wo: DVec3,
    /// The pose the firmware's IK reaches it with, from the previous direction's pose.
    pub pose: Pose<f64>,
    pub move_seconds: f64,
    /// move + settle + exposure.
    pub seconds: f64,
}

impl PlannedDirection {
    /// The wire form.
    pub fn wire(&self) -> Direction {
        Direction {
            theta_i: theta_of(self.wi) as f32,
            phi_i: phi_of(self.wi) as f32,
            theta_o: theta_of(self.wo) as f32,
            phi_o: phi_of(self.wo) as f32,
        }
    }
}

/// Per level: where its new directions sit in the order, and its times.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LevelSummary {
    pub level: usize,
    pub n: usize,
    pub m: usize,
    /// Directions measured up to and including this level.
    pub cumulative_directions: usize,
    /// This level's new directions: order[first..first + count].
    pub first: usize,
    pub count: usize,
    pub motion_seconds: f64,
    pub raster_motion_seconds: f64,
    pub lower_bound_motion_seconds: f64,
    /// Whole plan up to this level (move + settle + exposure), optimised order.
    pub cumulative_seconds: f64,
    pub cumulative_raster_seconds: f64,
}

/// A plan's totals (optimised order, raster order, bound).
#[derive(Clone, Debug, serde::Serialize)]
pub struct PlanSummary {
    pub directions: usize,
    pub total_seconds: f64,
    pub motion_seconds: f64,
    pub raster_total_seconds: f64,
    pub raster_motion_seconds: f64,
    pub lower_bound_motion_seconds: f64,
}

/// Nodes dropped by the unreachable rule, by reason, and nodes nudged (unique directions).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Dropped {
    pub below_horizon: usize,
    pub blocked: usize,
    pub limit: usize,
    /// Unreachable nodes measured at a nudged direction instead (not dropped).
    pub nudged: usize,
}

/// Steps of the u-space nudge of a node whose warp gives no direction.
pub const U_NUDGE_STEPS: usize = 8;

/// A complete plan.
#[derive(Clone, Debug)]
pub struct Plan {
    pub config: PlanConfig,
    /// The warp the plan was built with: `config.strategy` resolved for the estimate (`Auto`
    /// becomes `Mixture` or `Uniform`).
    pub warp: Strategy,
    pub thetas: Vec<f64>,
    pub slices: Vec<SliceWarp>,
    pub directions: Vec<PlannedDirection>,
    pub levels: Vec<LevelSummary>,
    pub dropped: Dropped,
    /// Finest-level node (k, i, j) -> index in `directions`, for every node that is measured.
    node_dir: HashMap<(usize, usize, usize), usize>,
    pub settle_exposure_seconds: f64,
    /// The estimate's alpha, floored at `PLAN_ALPHA_MIN` (the prior's sharp-lobe floor reads it).
    estimate_alpha: f64,
    /// Where each level's nodes sit in u (`node_layout`).
    layout: NodeLayout,
    /// The arms' blocked cone around wi (rad, the instrument's blocking angle).
    blocking_angle: f64,
    /// The elevations and warps of levels with fewer elevations than the plan: (stride, thetas, slices).
    incoming_subsets: Vec<(usize, Vec<f64>, Vec<SliceWarp>)>,
}

/// The node layout of a plan with this warp and finest N: the mixture's first level measures the
/// pole and u.x = 3/4 (`NestedFarRing`, when 3/4 is a node of the finest level); others `Nested`.
fn node_layout(warp: Strategy, fine_n: usize) -> NodeLayout {
    if warp == Strategy::Mixture && fine_n % 4 == 0 {
        NodeLayout::NestedFarRing
    } else {
        NodeLayout::Nested
    }
}

impl Plan {
    /// The strategy as reports show it: `auto (mixture)` for an `Auto` plan, else its name.
    pub fn strategy_label(&self) -> String {
        if self.config.strategy == Strategy::Auto {
            format!("auto ({})", self.warp)
        } else {
            self.warp.to_string()
        }
    }

    pub fn wire(&self) -> Vec<Direction> {
        self.directions.iter().map(PlannedDirection::wire).collect()
    }

    /// Where the levels' nodes sit in u.
    pub fn layout(&self) -> NodeLayout {
        self.layout
    }

    /// The plan up to `level` (its directions are a prefix of the order).
    pub fn level(&self, level: usize) -> Option<&LevelSummary> {
        self.levels.get(level.checked_sub(1)?)
    }

    /// The plan up to and including `level` (a prefix of the order; later levels dropped).
    pub fn truncate(mut self, level: usize) -> Plan {
        let level = level.clamp(1, self.levels.len().max(1));
        if let Some(l) = self.levels.get(level - 1) {
            let keep = l.cumulative_directions;
            self.directions.truncate(keep);
            self.node_dir.retain(|_, d| *d < keep);
        }
        self.levels.truncate(level);
        self
    }

    /// Totals over the plan's levels.
    pub fn summary(&self) -> PlanSummary {
        let sum = |f: fn(&LevelSummary) -> f64| self.levels.iter().map(f).sum::<f64>();
        PlanSummary {
            directions: self.directions.len(),
            total_seconds: self.total_seconds(),
            motion_seconds: sum(|l| l.motion_seconds),
            raster_total_seconds: self.levels.last().map_or(0.0, |l| l.cumulative_raster_seconds),
            raster_motion_seconds: sum(|l| l.raster_motion_seconds),
            lower_bound_motion_seconds: sum(|l| l.lower_bound_motion_seconds),
        }
    }

    /// The deepest level whose whole plan (move + settle + exposure) fits `budget` seconds.
    pub fn level_within_budget(&self, budget: f64) -> Option<usize> {
        self.levels
            .iter()
            .take_while(|l| l.cumulative_seconds <= budget)
            .last()
            .map(|l| l.level)
    }

    pub fn total_seconds(&self) -> f64 {
        self.levels.last().map_or(0.0, |l| l.cumulative_seconds)
    }

    /// Measure `material` at every planned direction (the virtual scan without effects).
    pub fn measure(&self, material: &dyn Material) -> Vec<DVec3> {
        self.directions.iter().map(|d| material.eval(d.wi, d.wo)).collect()
    }

    /// Re-simulate the encoded plan as the firmware will run it (f32 kinematics from the decoded
    /// f32 directions, from the rest pose): every pose within limits and with valid step targets.
    /// Returns the motion time of the replay (f64 timing of the f32 poses).
    pub fn check_encoded(&self, instrument: &InstrumentConfig<f64>, bytes: &[u8]) -> Result<f64, PlanError> {
        let decoded = file::decode_plan(bytes)?;
        if decoded != self.wire() {
            return Err(PlanError::Invalid(
                "encoded plan does not decode to the planned directions".into(),
            ));
        }
        // The firmware's own test, in plan order, each direction from the previous one's steps
        // (the controller's plan intake does the same).
        let fw = FirmwareCheck::new(instrument)?;
        let mut cur = fw
            .rest_steps()
            .map_err(|reason| PlanError::Unreachable { index: 0, reason })?;
        let mut motion = 0.0;
        let to64 = |q: Pose<f32>| Pose::from_array(q.to_array().map(f64::from));
        for (index, d) in decoded.iter().enumerate() {
            let next = gonio_shared::acceptance::check_direction(&fw.kin, &fw.guard, d, &cur)
                .map_err(|reason| PlanError::Unreachable { index, reason })?;
            motion += order::move_seconds(
                instrument,
                &to64(fw.kin.from_steps(&cur)),
                &to64(fw.kin.from_steps(&next)),
            );
            cur = next;
        }
        Ok(motion)
    }
}

impl Levels for Plan {
    fn level_nodes(&self, level: usize) -> Option<LevelNodes<'_>> {
        let summary = self.level(level)?;
        let (n, m, limit) = (summary.n, summary.m, summary.cumulative_directions);
        let (fine_n, fine_m) = self.config.grids.last().copied().unwrap_or((n, m));
        let stride = self.config.incoming_stride(level).max(1);
        let (thetas, slices) = self
            .incoming_subsets
            .iter()
            .find(|s| s.0 == stride)
            .map_or((&self.thetas[..], &self.slices[..]), |s| (&s.1[..], &s.2[..]));
        let mut node_measurement = Vec::with_capacity(thetas.len() * n * m);
        for k in 0..thetas.len() {
            for j in 0..m {
                for i in 0..n {
                    let key = (k * stride, self.layout.fine_index(i, n, fine_n), j * (fine_m / m));
                    node_measurement.push(self.node_dir.get(&key).copied().filter(|&d| d < limit));
                }
            }
        }
        Some(LevelNodes {
            slices,
            thetas,
            layout: self.layout,
            n,
            m,
            node_measurement,
            // Every direction up to this level is on one of its slices (the elevations nest).
            measured: self
                .directions
                .iter()
                .take(limit)
                .map(|d| (d.k / stride, d.wi, d.wo))
                .collect(),
            estimate_alpha: self.estimate_alpha,
            blocked_cone: self.blocking_angle,
        })
    }
}

/// The ground-truth-free estimate for a material spec: analytic specs are their own estimate;
/// anything else gets a GGX fit (what the encoder would approximate from a photo).
pub fn estimate_for(spec: &str) -> Result<Estimate, PlanError> {
    if let Ok(model) = crate::brdf::spec::parse_analytic(spec) {
        return Ok(Estimate { model });
    }
    let material = crate::brdf::parse_material(spec)?;
    let fit = crate::brdf::fit::fit(material.as_ref(), crate::brdf::fit::FitModel::Ggx);
    Ok(Estimate { model: fit.model })
}

/// A GGX estimate, for tests and benches.
pub fn ggx_estimate(alpha: f64, diffuse: f64) -> Estimate {
    Estimate {
        model: Analytic::Ggx(Ggx {
            alpha,
            diffuse: DVec3::splat(diffuse),
            specular: DVec3::ONE,
        }),
    }
}

#[cfg(test)]
mod tests;
