//! The planner: estimate -> slice warps -> nested levels of nodes -> ordered, timed directions.

use super::order::{self, Candidates};
use super::{
    check_levels, incoming_thetas, node_layout, Dropped, Estimate, LevelSummary, Plan, PlanConfig, PlanError,
    PlannedDirection, Strategy, MIXTURE_TABLE_RES, NUDGE_MAX, NUDGE_STEP, PLAN_ALPHA_MIN, U_NUDGE_STEPS,
};
use crate::brdf::frame::{from_spherical, phi_of, theta_of};
use crate::brdf::grid::NodeLayout;
use crate::brdf::warp::{MixtureWarp, MixtureWeights, SliceWarp, Warp, WarpKind};
use glam::{DVec2, DVec3};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::kinematics::{Kinematics, Pose, Unreachable};
use gonio_shared::msg::Direction;
use std::collections::HashMap;

/// The planner: an instrument and an estimate.
pub struct Planner {
    kin: Kinematics<f64>,
    firmware: FirmwareCheck,
    estimate: Estimate,
    mixture: MixtureWeights,
}

/// A finest-level node (slice k, i, j).
type NodeKey = (usize, usize, usize);

/// A unique direction to measure, in generation (raster) order.
struct Generated {
    k: usize,
    i: usize,
    j: usize,
    wi: DVec3,
    wo: DVec3,
    candidates: Candidates,
}

/// Every level's unique directions in generation order, and where each node's measurement is.
#[derive(Default)]
struct Generation {
    dirs: Vec<Generated>,
    /// Node -> index in `dirs`, or None where the node is dropped.
    node_gen: HashMap<NodeKey, Option<usize>>,
    /// Quantised direction within a slice -> index in `dirs`: nodes on one direction share it.
    seen: HashMap<(usize, [i64; 3]), Option<usize>>,
    /// Per level: (level, n, m, first, end) in `dirs`.
    ranges: Vec<(usize, usize, usize, usize, usize)>,
    dropped: Dropped,
}

/// The slices and node layout every level shares.
struct Slices<'a> {
    thetas: &'a [f64],
    warps: &'a [SliceWarp],
    layout: NodeLayout,
    fine: (usize, usize),
}

/// Every level ordered and timed: the directions, the level summaries and the order (indices in `dirs`).
struct Ordered {
    directions: Vec<PlannedDirection>,
    levels: Vec<LevelSummary>,
    order: Vec<usize>,
}

/// Where the ordering stands between levels: the last pose of both orders and the running totals.
struct Cursor {
    pose: Pose<f64>,
    raster_pose: Pose<f64>,
    seconds: f64,
    raster_seconds: f64,
}

impl Planner {
    pub fn new(instrument: InstrumentConfig<f64>, estimate: Estimate) -> Result<Self, PlanError> {
        let kin = Kinematics::new(instrument).map_err(|e| PlanError::Invalid(format!("instrument: {e:?}")))?;
        let firmware = FirmwareCheck::new(&instrument)?;
        Ok(Self {
            kin,
            firmware,
            estimate,
            mixture: MixtureWeights::PRODUCT,
        })
    }

    /// The same planner with other mixture weights (the lab's trials; the product keeps `PRODUCT`).
    pub fn with_mixture_weights(self, mixture: MixtureWeights) -> Self {
        Self { mixture, ..self }
    }

    /// A direction the planner may use: reachable in f64 (its IK candidates, for ordering and
    /// timing) and accepted by the firmware's own test.
    fn reachable(&self, wi: DVec3, wo: DVec3) -> Result<Candidates, Unreachable> {
        let c = Candidates::of(&self.kin, wi, wo)?;
        self.firmware.accepts(wi, wo)?;
        Ok(c)
    }

    pub fn kinematics(&self) -> &Kinematics<f64> {
        &self.kin
    }

    /// The slice warp for incoming elevation theta.
    pub fn slice_warp(&self, strategy: Strategy, theta: f64) -> SliceWarp {
        let wi = from_spherical(theta, 0.0);
        let alpha = self.estimate.alpha();
        match strategy.resolve(alpha) {
            // `resolve` never returns Auto; the arm keeps the match total without a panic.
            Strategy::Uniform | Strategy::Auto => WarpKind::Uniform.for_incident(wi),
            Strategy::Mixture => {
                let m = self.estimate.material();
                SliceWarp::Mixture(std::sync::Arc::new(MixtureWarp::with_weights(
                    wi,
                    alpha.max(PLAN_ALPHA_MIN),
                    m.as_ref(),
                    MIXTURE_TABLE_RES,
                    self.mixture,
                )))
            }
        }
    }

    /// Build, order and time the plan.
    pub fn plan(&self, config: &PlanConfig) -> Result<Plan, PlanError> {
        if config.k == 0 || config.k > 64 {
            return Err(PlanError::Invalid(format!("incoming count {} not in 1..=64", config.k)));
        }
        check_levels(&config.grids, &config.incoming, config.k)?;
        let thetas = incoming_thetas(config.k);
        let warps: Vec<SliceWarp> = thetas.iter().map(|&t| self.slice_warp(config.strategy, t)).collect();
        let fine = *config.grids.last().expect("checked non-empty");
        let warp = config.strategy.resolve(self.estimate.alpha());
        let layout = node_layout(warp, fine.0);
        let slices = Slices {
            thetas: &thetas,
            warps: &warps,
            layout,
            fine,
        };
        let strides: Vec<usize> = (1..=config.grids.len()).map(|l| config.incoming_stride(l)).collect();
        let generation = self.generate(&config.grids, &strides, &slices);
        let Ordered {
            directions,
            levels,
            order,
        } = self.order_levels(&generation)?;
        // dirs index -> order index.
        let mut where_ = vec![0usize; generation.dirs.len()];
        for (o, &g) in order.iter().enumerate() {
            where_[g] = o;
        }
        let node_dir = generation
            .node_gen
            .into_iter()
            .filter_map(|(key, d)| d.map(|d| (key, where_[d])))
            .collect();
        Ok(Plan {
            config: config.clone(),
            warp,
            directions,
            levels,
            dropped: generation.dropped,
            node_dir,
            settle_exposure_seconds: self.settle_exposure(),
            estimate_alpha: self.estimate.alpha().max(PLAN_ALPHA_MIN),
            layout,
            blocking_angle: self.kin.config().blocking_angle,
            incoming_subsets: subsets(&strides, &thetas, &warps),
            thetas,
            slices: warps,
        })
    }

    /// Settle plus exposure time per direction (s).
    fn settle_exposure(&self) -> f64 {
        let cfg = self.kin.config();
        cfg.settle_ms as f64 * 1e-3 + cfg.exposure_us as f64 * 1e-6
    }

    /// Unique directions per level, in generation (raster) order: k, then j, then i; level L
    /// holds the slices k that are multiples of `strides[L]`.
    fn generate(&self, grids: &[(usize, usize)], strides: &[usize], slices: &Slices<'_>) -> Generation {
        let mut g = Generation::default();
        let (fine_n, fine_m) = slices.fine;
        for (level0, &(n, m)) in grids.iter().enumerate() {
            let start = g.dirs.len();
            let stride = strides.get(level0).copied().unwrap_or(1).max(1);
            for (k, warp) in slices.warps.iter().enumerate().step_by(stride) {
                let wi = from_spherical(slices.thetas[k], 0.0);
                for j in 0..m {
                    for i in 0..n {
                        let key = (k, slices.layout.fine_index(i, n, fine_n), j * (fine_m / m));
                        if g.node_gen.contains_key(&key) {
                            continue;
                        }
                        let u = DVec2::new(slices.layout.node_x(i, n), j as f64 / m as f64);
                        let entry = self.place(&mut g, key, wi, sample_or_nudge(warp, u, fine_n));
                        g.node_gen.insert(key, entry);
                    }
                }
            }
            g.ranges.push((level0 + 1, n, m, start, g.dirs.len()));
        }
        g
    }

    /// Add node `key`'s direction `wo` (None: below the horizon) to the generation, nudged if
    /// unreachable; its index in `dirs`, or None if it is dropped.
    fn place(&self, g: &mut Generation, key: NodeKey, wi: DVec3, wo: Option<DVec3>) -> Option<usize> {
        let Some(wo) = wo else {
            g.dropped.below_horizon += 1;
            return None;
        };
        // Nodes within 1e-9 rad of a direction already planned share its measurement.
        let q = (wo * 1e9).round();
        let dkey = (key.0, [q.x as i64, q.y as i64, q.z as i64]);
        if let Some(&d) = g.seen.get(&dkey) {
            return d;
        }
        let placed = match self.reachable(wi, wo) {
            Ok(c) => Some((wo, c)),
            Err(reason) => {
                let nudged = nudge(&|wi, wo| self.reachable(wi, wo), wi, wo);
                match nudged {
                    Some(_) => g.dropped.nudged += 1,
                    None => match reason {
                        Unreachable::BelowHorizon { .. } | Unreachable::NotFinite => g.dropped.below_horizon += 1,
                        Unreachable::Blocked => g.dropped.blocked += 1,
                        Unreachable::Limit(_) => g.dropped.limit += 1,
                    },
                }
                nudged
            }
        };
        let entry = placed.map(|(wo, candidates)| {
            g.dirs.push(Generated {
                k: key.0,
                i: key.1,
                j: key.2,
                wi,
                wo,
                candidates,
            });
            g.dirs.len() - 1
        });
        g.seen.insert(dkey, entry);
        entry
    }

    /// Order each level's directions after the previous level's last pose; time both orders by
    /// replaying the IK.
    fn order_levels(&self, g: &Generation) -> Result<Ordered, PlanError> {
        let rest = self.kin.rest_pose();
        let mut cursor = Cursor {
            pose: rest,
            raster_pose: rest,
            seconds: 0.0,
            raster_seconds: 0.0,
        };
        let mut order: Vec<usize> = Vec::with_capacity(g.dirs.len());
        let mut directions: Vec<PlannedDirection> = Vec::with_capacity(g.dirs.len());
        let mut levels = Vec::new();
        for &range in &g.ranges {
            levels.push(self.order_level(g, range, &mut cursor, &mut directions, &mut order)?);
        }
        Ok(Ordered {
            directions,
            levels,
            order,
        })
    }

    /// Order and time one level (`range` = (level, n, m, first, end) in `dirs`), appending its
    /// directions and their `dirs` indices.
    fn order_level(
        &self,
        g: &Generation,
        (level, n, m, a, b): (usize, usize, usize, usize, usize),
        cursor: &mut Cursor,
        directions: &mut Vec<PlannedDirection>,
        order: &mut Vec<usize>,
    ) -> Result<LevelSummary, PlanError> {
        let cfg = *self.kin.config();
        let settle_exposure = self.settle_exposure();
        let items: Vec<Candidates> = g.dirs[a..b].iter().map(|x| x.candidates.clone()).collect();
        let ordered = order::optimise(&cfg, &Candidates(vec![cursor.pose]), &items);
        let perm = ordered.perm;
        let pairs: Vec<(DVec3, DVec3)> = perm.iter().map(|&p| (g.dirs[a + p].wi, g.dirs[a + p].wo)).collect();
        let (poses, moves) =
            order::simulate(&self.kin, cursor.pose, &pairs).map_err(|(i, reason)| PlanError::Unreachable {
                index: directions.len() + i,
                reason,
            })?;
        let raster_pairs: Vec<(DVec3, DVec3)> = g.dirs[a..b].iter().map(|x| (x.wi, x.wo)).collect();
        let (rposes, rmoves) = order::simulate(&self.kin, cursor.raster_pose, &raster_pairs)
            .map_err(|(i, reason)| PlanError::Unreachable { index: a + i, reason })?;
        let motion: f64 = moves.iter().sum();
        let raster: f64 = rmoves.iter().sum();
        cursor.seconds += motion + settle_exposure * items.len() as f64;
        cursor.raster_seconds += raster + settle_exposure * items.len() as f64;
        let first = directions.len();
        for (o, &p) in perm.iter().enumerate() {
            let x = &g.dirs[a + p];
            order.push(a + p);
            directions.push(PlannedDirection {
                level,
                k: x.k,
                i: x.i,
                j: x.j,
                wi: x.wi,
                wo: x.wo,
                pose: poses[o],
                move_seconds: moves[o],
                seconds: moves[o] + settle_exposure,
            });
        }
        if let Some(last) = poses.last() {
            cursor.pose = *last;
        }
        if let Some(last) = rposes.last() {
            cursor.raster_pose = *last;
        }
        Ok(LevelSummary {
            level,
            n,
            m,
            cumulative_directions: directions.len(),
            first,
            count: items.len(),
            motion_seconds: motion,
            raster_motion_seconds: raster,
            lower_bound_motion_seconds: ordered.bound,
            cumulative_seconds: cursor.seconds,
            cumulative_raster_seconds: cursor.raster_seconds,
        })
    }
}

/// The elevations and warps of each level stride other than 1 (`Plan::incoming_subsets`).
fn subsets(strides: &[usize], thetas: &[f64], warps: &[SliceWarp]) -> Vec<(usize, Vec<f64>, Vec<SliceWarp>)> {
    let mut out: Vec<(usize, Vec<f64>, Vec<SliceWarp>)> = Vec::new();
    for &s in strides.iter().filter(|&&s| s > 1) {
        if out.iter().all(|o| o.0 != s) {
            let t = thetas.iter().copied().step_by(s).collect();
            let w = warps.iter().step_by(s).cloned().collect();
            out.push((s, t, w));
        }
    }
    out
}

/// The warp's direction at `u`, or, if it has none, at the first of `U_NUDGE_STEPS` points from
/// u toward the pole (u.x decreasing) up to half a cell of a grid with `fine_n` columns.
fn sample_or_nudge(warp: &SliceWarp, u: DVec2, fine_n: usize) -> Option<DVec3> {
    warp.sample(u).or_else(|| {
        (1..=U_NUDGE_STEPS).find_map(|s| {
            let dx = 0.5 / fine_n as f64 * s as f64 / U_NUDGE_STEPS as f64;
            warp.sample(DVec2::new((u.x - dx).max(0.0), u.y))
        })
    })
}

/// The unreachable rule's nudge: the nearest reachable direction to `wo` on two paths (away from
/// `wi` in their common plane, out of the blocked cone; toward the normal, inside the limits and the
/// horizon margin), `NUDGE_STEP` at a time up to `NUDGE_MAX`.
fn nudge(
    reachable: &dyn Fn(DVec3, DVec3) -> Result<Candidates, Unreachable>,
    wi: DVec3,
    wo: DVec3,
) -> Option<(DVec3, Candidates)> {
    // Axis of the rotation away from wi; wo parallel to wi (the pole at normal incidence) has no
    // plane with it, so take the one through the normal and x (any plane serves: isotropy).
    let away = wi.cross(wo).try_normalize().unwrap_or(DVec3::Y);
    // Toward the normal: rotate about z x wo; at the pole wo is the normal already.
    let down = wo.cross(DVec3::Z).try_normalize();
    let steps = (NUDGE_MAX / NUDGE_STEP).round() as usize;
    for s in 1..=steps {
        let angle = s as f64 * NUDGE_STEP;
        let tries = [
            Some(glam::DQuat::from_axis_angle(away, angle) * wo),
            down.map(|d| glam::DQuat::from_axis_angle(d, angle) * wo),
        ];
        for w in tries.into_iter().flatten() {
            if let Ok(c) = reachable(wi, w) {
                return Some((w, c));
            }
        }
    }
    None
}

/// The firmware's acceptance test of one direction (`gonio_shared::acceptance::check_direction`: f32
/// IK, step rounding, soft limits, separation guard band), from the rest pose: the f64 kinematics
/// alone accept directions at the blocked cone's exact edge that the guard band refuses.
pub(super) struct FirmwareCheck {
    pub(super) kin: Kinematics<f32>,
    pub(super) guard: gonio_shared::separation::SeparationGuard,
}

impl FirmwareCheck {
    pub(super) fn new(instrument: &InstrumentConfig<f64>) -> Result<Self, PlanError> {
        let kin = Kinematics::<f32>::new(instrument.cast::<f32>())
            .map_err(|e| PlanError::Invalid(format!("instrument: {e:?}")))?;
        let guard = gonio_shared::separation::SeparationGuard::new(&kin);
        Ok(Self { kin, guard })
    }

    pub(super) fn rest_steps(&self) -> Result<gonio_shared::kinematics::Steps, Unreachable> {
        self.kin.to_steps(&self.kin.rest_pose())
    }

    fn accepts(&self, wi: DVec3, wo: DVec3) -> Result<(), Unreachable> {
        let d = Direction {
            theta_i: theta_of(wi) as f32,
            phi_i: phi_of(wi) as f32,
            theta_o: theta_of(wo) as f32,
            phi_o: phi_of(wo) as f32,
        };
        gonio_shared::acceptance::check_direction(&self.kin, &self.guard, &d, &self.rest_steps()?).map(|_| ())
    }
}
