//! Step 2 of the pipeline: from estimated BRDF parameters to an ordered, timed direction list.
//!
//! * Incoming: 1 phi x K theta, spaced by `Spacing` (cosine steps as the grid's default, equal angle
//!   steps, or RGL's equal steps in the GGX projected area sigma).
//! * Outgoing: per incoming theta, nested levels of N x N nodes (N = 2, 4, 8, ...) in u-space
//!   (`NodeLayout::Nested`: u = (i / N, j / N)), through the slice warp of the chosen `Strategy`.
//!   Level L's nodes are level L+1's even nodes, so a scan can stop after any level and keep all it
//!   measured. Nodes that land on the same direction (the pole u.x = 0 of every warp) are measured once.
//! * Unreachable rule: a node whose direction is below the horizon, inside the arms' blocked cone or
//!   beyond an axis limit is dropped (counted by reason) and, in the reconstruction, takes the value
//!   of the nearest measured node of its slice (`MeasurementGrid::fill_from_nearest`).
//! * Order and time: `order` (NN + 2-opt + Or-opt within each level, after the previous level's last
//!   pose), timed by replaying the firmware's IK and the shared motion profile.

pub mod cli;
pub mod file;
pub mod order;
pub mod photo;
pub mod report;

use crate::brdf::analytic::Ggx;
use crate::brdf::frame::{from_spherical, phi_of, theta_of};
use crate::brdf::grid::{incident_thetas, MeasurementGrid, NodeLayout, THETA_I_MAX};
use crate::brdf::spec::Analytic;
use crate::brdf::warp::{MixtureWarp, SliceWarp, Warp, WarpKind};
use crate::brdf::Material;
use glam::{DVec2, DVec3};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::kinematics::{Kinematics, Pose, Unreachable};
use gonio_shared::msg::Direction;
use order::Candidates;
use std::collections::HashMap;
use std::fmt;

/// Smallest alpha the planner builds a specular warp with: below it the warp is a delta (no
/// inverse); the estimate's own value still shapes the mixture's table.
pub const PLAN_ALPHA_MIN: f64 = 0.01;
/// Table resolution of the mixture warp (vertices per side).
pub const MIXTURE_TABLE_RES: usize = 48;
/// Most levels a plan can have (N = 2^6 = 64).
pub const MAX_LEVEL: usize = 6;

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
}

/// Which outgoing warp.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Strategy {
    /// The paper's warp: GGX visible normals of the estimated alpha.
    Specular,
    /// eq. 6: visible normals composed with a table of the estimate's f cos (whole lobe).
    Mixture,
    /// Equal steps in (theta_o, phi_o), blind to the material.
    Uniform,
}

impl fmt::Display for Strategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Strategy::Specular => "specular",
            Strategy::Mixture => "mixture",
            Strategy::Uniform => "uniform",
        })
    }
}

/// Spacing of the incoming elevations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Spacing {
    /// Equal steps in cos theta (the paper).
    Cosine,
    /// Equal steps in theta.
    Angle,
    /// Equal steps in the GGX projected area sigma(theta) of the estimate (RGL's files).
    Rgl,
}

impl fmt::Display for Spacing {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Spacing::Cosine => "cosine",
            Spacing::Angle => "angle",
            Spacing::Rgl => "rgl",
        })
    }
}

/// K incoming elevations from 0 to THETA_I_MAX.
pub fn spaced_thetas(spacing: Spacing, k: usize, alpha: f64) -> Vec<f64> {
    if k <= 1 {
        return vec![0.0];
    }
    let f = |i: usize| i as f64 / (k - 1) as f64;
    match spacing {
        Spacing::Cosine => incident_thetas(k),
        Spacing::Angle => (0..k).map(|i| f(i) * THETA_I_MAX).collect(),
        Spacing::Rgl => crate::brdf::rgl::sigma_spaced_thetas(alpha.clamp(PLAN_ALPHA_MIN, 1.0), k, THETA_I_MAX),
    }
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
    /// Number of incoming elevations.
    pub k: usize,
    /// Levels 1..=max_level, N = 2^level.
    pub max_level: usize,
    /// Compute the motion lower bound (O(n^2) per level; a scan does not need it). Without it the
    /// levels' `lower_bound_motion_seconds` are NaN.
    pub bound: bool,
}

impl Default for PlanConfig {
    fn default() -> Self {
        Self {
            strategy: Strategy::Mixture,
            // Equal angle steps beat cosine and RGL steps on every material of the report.
            spacing: Spacing::Angle,
            k: crate::brdf::grid::DEFAULT_K,
            max_level: 4,
            bound: true,
        }
    }
}

/// One direction of the plan, in execution order.
#[derive(Clone, Debug)]
pub struct PlannedDirection {
    /// First level that contains it (1-based).
    pub level: usize,
    /// Slice and node at the finest level (i, j in 0..2^max_level).
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

/// Nodes dropped by the unreachable rule, by reason (unique directions).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Dropped {
    pub below_horizon: usize,
    pub blocked: usize,
    pub limit: usize,
}

/// A complete plan.
#[derive(Clone, Debug)]
pub struct Plan {
    pub config: PlanConfig,
    pub thetas: Vec<f64>,
    pub slices: Vec<SliceWarp>,
    pub directions: Vec<PlannedDirection>,
    pub levels: Vec<LevelSummary>,
    pub dropped: Dropped,
    /// Finest-level node (k, i, j) -> index in `directions`, for every node that is measured.
    node_dir: HashMap<(usize, usize, usize), usize>,
    pub settle_exposure_seconds: f64,
}

/// The planner: an instrument and an estimate.
pub struct Planner {
    kin: Kinematics<f64>,
    estimate: Estimate,
}

impl Planner {
    pub fn new(instrument: InstrumentConfig<f64>, estimate: Estimate) -> Result<Self, PlanError> {
        let kin = Kinematics::new(instrument).map_err(|e| PlanError::Invalid(format!("instrument: {e:?}")))?;
        Ok(Self { kin, estimate })
    }

    pub fn kinematics(&self) -> &Kinematics<f64> {
        &self.kin
    }

    /// The slice warp for incoming elevation theta.
    pub fn slice_warp(&self, strategy: Strategy, theta: f64) -> SliceWarp {
        let wi = from_spherical(theta, 0.0);
        let alpha = self.estimate.alpha();
        match strategy {
            Strategy::Specular => WarpKind::GgxVndf {
                alpha: alpha.max(PLAN_ALPHA_MIN),
            }
            .for_incident(wi),
            Strategy::Uniform => WarpKind::Uniform.for_incident(wi),
            Strategy::Mixture => {
                let m = self.estimate.material();
                SliceWarp::Mixture(std::sync::Arc::new(MixtureWarp::new(
                    wi,
                    alpha.max(PLAN_ALPHA_MIN),
                    m.as_ref(),
                    MIXTURE_TABLE_RES,
                )))
            }
        }
    }

    /// Build, order and time the plan.
    pub fn plan(&self, config: &PlanConfig) -> Result<Plan, PlanError> {
        if config.k == 0 || config.k > 64 {
            return Err(PlanError::Invalid(format!("incoming count {} not in 1..=64", config.k)));
        }
        if config.max_level == 0 || config.max_level > MAX_LEVEL {
            return Err(PlanError::Invalid(format!(
                "level {} not in 1..={MAX_LEVEL}",
                config.max_level
            )));
        }
        let cfg = *self.kin.config();
        let thetas = spaced_thetas(config.spacing, config.k, self.estimate.alpha());
        let slices: Vec<SliceWarp> = thetas.iter().map(|&t| self.slice_warp(config.strategy, t)).collect();
        let fine = 1usize << config.max_level;
        let settle_exposure = cfg.settle_ms as f64 * 1e-3 + cfg.exposure_us as f64 * 1e-6;

        // Unique directions per level, in generation (raster) order: k, then j, then i.
        let mut node_dir_gen: HashMap<(usize, usize, usize), Option<usize>> = HashMap::new();
        let mut seen: HashMap<(usize, [i64; 3]), Option<usize>> = HashMap::new();
        let mut gen: Vec<(usize, usize, usize, usize, DVec3, DVec3, Candidates)> = Vec::new();
        let mut level_ranges = Vec::new();
        let mut dropped = Dropped::default();
        for level in 1..=config.max_level {
            let n = 1usize << level;
            let stride = fine / n;
            let start = gen.len();
            for (k, warp) in slices.iter().enumerate() {
                let wi = from_spherical(thetas[k], 0.0);
                for j in 0..n {
                    for i in 0..n {
                        let key = (k, i * stride, j * stride);
                        if node_dir_gen.contains_key(&key) {
                            continue;
                        }
                        let u = DVec2::new(i as f64 / n as f64, j as f64 / n as f64);
                        let Some(wo) = warp.sample(u) else {
                            dropped.below_horizon += 1;
                            node_dir_gen.insert(key, None);
                            continue;
                        };
                        // Nodes within 1e-9 rad of a direction already planned share its measurement.
                        let q = (wo * 1e9).round();
                        let dkey = (k, [q.x as i64, q.y as i64, q.z as i64]);
                        if let Some(&d) = seen.get(&dkey) {
                            node_dir_gen.insert(key, d);
                            continue;
                        }
                        let entry = match Candidates::of(&self.kin, wi, wo) {
                            Ok(c) => {
                                gen.push((level, k, key.1, key.2, wi, wo, c));
                                Some(gen.len() - 1)
                            }
                            Err(reason) => {
                                match reason {
                                    Unreachable::BelowHorizon { .. } | Unreachable::NotFinite => {
                                        dropped.below_horizon += 1
                                    }
                                    Unreachable::Blocked => dropped.blocked += 1,
                                    Unreachable::Limit(_) => dropped.limit += 1,
                                }
                                None
                            }
                        };
                        seen.insert(dkey, entry);
                        node_dir_gen.insert(key, entry);
                    }
                }
            }
            level_ranges.push((level, n, start, gen.len()));
        }

        // Order within each level; time both orders by replaying the IK.
        let rest = self.kin.rest_pose();
        let rest_c = Candidates(vec![rest]);
        let mut order: Vec<usize> = Vec::with_capacity(gen.len());
        let mut levels = Vec::new();
        let (mut cur, mut cur_raster) = (rest, rest);
        let mut cur_c = rest_c.clone();
        let (mut cum, mut cum_raster) = (0.0, 0.0);
        let mut directions: Vec<PlannedDirection> = Vec::with_capacity(gen.len());
        for &(level, n, a, b) in &level_ranges {
            let items: Vec<Candidates> = gen[a..b].iter().map(|g| g.6.clone()).collect();
            let perm = order::optimise(&cfg, &cur_c, &items);
            let pairs: Vec<(DVec3, DVec3)> = perm.iter().map(|&p| (gen[a + p].4, gen[a + p].5)).collect();
            let (poses, moves) =
                order::simulate(&self.kin, cur, &pairs).map_err(|(i, reason)| PlanError::Unreachable {
                    index: directions.len() + i,
                    reason,
                })?;
            let raster_pairs: Vec<(DVec3, DVec3)> = gen[a..b].iter().map(|g| (g.4, g.5)).collect();
            let (rposes, rmoves) = order::simulate(&self.kin, cur_raster, &raster_pairs)
                .map_err(|(i, reason)| PlanError::Unreachable { index: a + i, reason })?;
            // Bound: entry edge from any earlier pose (or the rest pose) + MST of the new directions.
            let earlier: Vec<&Candidates> = std::iter::once(&rest_c).chain(gen[..a].iter().map(|g| &g.6)).collect();
            let entry = if !config.bound {
                f64::NAN
            } else if items.is_empty() {
                0.0
            } else {
                earlier
                    .iter()
                    .flat_map(|e| items.iter().map(move |it| (e, it)))
                    .map(|(e, it)| order::metric(&cfg, e, it))
                    .fold(f64::INFINITY, f64::min)
            };
            let refs: Vec<&Candidates> = items.iter().collect();
            let bound = if config.bound {
                entry + order::mst_seconds(&cfg, &refs)
            } else {
                f64::NAN
            };
            let motion: f64 = moves.iter().sum();
            let raster: f64 = rmoves.iter().sum();
            cum += motion + settle_exposure * items.len() as f64;
            cum_raster += raster + settle_exposure * items.len() as f64;
            let first = directions.len();
            for (o, &p) in perm.iter().enumerate() {
                let g = &gen[a + p];
                order.push(a + p);
                directions.push(PlannedDirection {
                    level,
                    k: g.1,
                    i: g.2,
                    j: g.3,
                    wi: g.4,
                    wo: g.5,
                    pose: poses[o],
                    move_seconds: moves[o],
                    seconds: moves[o] + settle_exposure,
                });
            }
            if let Some(last) = poses.last() {
                cur = *last;
                cur_c = Candidates(vec![*last]);
            }
            if let Some(last) = rposes.last() {
                cur_raster = *last;
            }
            levels.push(LevelSummary {
                level,
                n,
                m: n,
                cumulative_directions: directions.len(),
                first,
                count: items.len(),
                motion_seconds: motion,
                raster_motion_seconds: raster,
                lower_bound_motion_seconds: bound,
                cumulative_seconds: cum,
                cumulative_raster_seconds: cum_raster,
            });
        }
        // gen index -> order index.
        let mut where_ = vec![0usize; gen.len()];
        for (o, &g) in order.iter().enumerate() {
            where_[g] = o;
        }
        let node_dir = node_dir_gen
            .into_iter()
            .filter_map(|(key, d)| d.map(|d| (key, where_[d])))
            .collect();
        Ok(Plan {
            config: config.clone(),
            thetas,
            slices,
            directions,
            levels,
            dropped,
            node_dir,
            settle_exposure_seconds: settle_exposure,
        })
    }
}

impl Plan {
    pub fn wire(&self) -> Vec<Direction> {
        self.directions.iter().map(PlannedDirection::wire).collect()
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

    /// Reconstruct level `level` from the measured values (indexed like `directions`; only the
    /// prefix up to the level is read). Unmeasured nodes take their nearest measured neighbour's value.
    pub fn reconstruct(&self, level: usize, values: &[DVec3]) -> Result<MeasurementGrid, PlanError> {
        let summary = self
            .level(level)
            .ok_or_else(|| PlanError::Invalid(format!("no level {level}")))?;
        let limit = summary.cumulative_directions;
        if values.len() < limit {
            return Err(PlanError::Invalid(format!(
                "level {level} needs {limit} values, got {}",
                values.len()
            )));
        }
        let n = summary.n;
        let stride = (1usize << self.config.max_level) / n;
        let k_count = self.thetas.len();
        let cells = k_count * n * n;
        let mut grid = MeasurementGrid::from_slices(
            self.slices.clone(),
            NodeLayout::Nested,
            self.thetas.clone(),
            n,
            n,
            vec![DVec3::ZERO; cells],
            vec![false; cells],
        )?;
        for k in 0..k_count {
            for j in 0..n {
                for i in 0..n {
                    let v = self
                        .node_dir
                        .get(&(k, i * stride, j * stride))
                        .filter(|&&d| d < limit)
                        .map(|&d| values[d]);
                    grid.set_node(k, i, j, v);
                }
            }
        }
        grid.fill_from_nearest();
        Ok(grid)
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
        let cfg32 = instrument.cast::<f32>();
        let kin = Kinematics::<f32>::new(cfg32).map_err(|e| PlanError::Invalid(format!("instrument: {e:?}")))?;
        let mut cur = kin.rest_pose();
        let mut motion = 0.0;
        for (index, d) in decoded.iter().enumerate() {
            let p = kin
                .inverse_angles(d.theta_i, d.phi_i, d.theta_o, d.phi_o, &cur)
                .map_err(|reason| PlanError::Unreachable { index, reason })?;
            kin.check_pose(&p)
                .and_then(|_| kin.to_steps(&p))
                .map_err(|reason| PlanError::Unreachable { index, reason })?;
            let to64 = |q: Pose<f32>| Pose::from_array(q.to_array().map(f64::from));
            motion += order::move_seconds(instrument, &to64(cur), &to64(p));
            cur = p;
        }
        Ok(motion)
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
