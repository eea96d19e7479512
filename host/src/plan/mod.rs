//! Step 2 of the pipeline: from estimated BRDF parameters to an ordered, timed direction list.
//!
//! * Incoming: 1 phi x K theta, spaced by `Spacing` (cosine steps as the grid's default, equal angle
//!   steps, or RGL's equal steps in the GGX projected area sigma).
//! * Outgoing: per incoming theta, nested levels of N x M nodes in u-space (`NodeLayout::Nested`:
//!   u = (i / N, j / M); the mixture's plans use `NodeLayout::NestedFarRing`, whose first level has
//!   its second ring at u.x = 3/4), through the slice warp of the chosen `Strategy`. By default the levels are
//!   square, N = M = 2, 4, 8, ...; any list works whose every level's N and M divide the next
//!   level's (e.g. the paper's 2x2, 4x4, 8x4, 8x8): then each level's nodes are nodes of the next,
//!   so a scan can stop after any level and keep all it measured. Nodes that land on the same
//!   direction (the pole u.x = 0 of every warp) are measured once.
//! * Unreachable rule: a node whose warp gives no direction (below the horizon) is moved toward the
//!   pole in u, `U_NUDGE_STEPS` steps of up to half a cell of the finest grid in all, and dropped
//!   if it still has none (the mixture's table keeps a small floor density over the base warp's
//!   below-horizon region, which a node may hit; the pure-specular warp's large below-horizon
//!   region, ~27% of a rough lobe's square, stays dropped, as in the paper). A node
//!   whose direction the instrument cannot reach (inside the arms' blocked cone around wi, beyond an
//!   axis limit, or under the IK's horizon margin) is nudged to the nearest reachable direction on
//!   two paths, away from wi in the (wi, wo) plane and toward the normal, in `NUDGE_STEP` steps up
//!   to `NUDGE_MAX` (counted in `Dropped::nudged`; its value stands for the node's); only if both
//!   fail is it dropped (counted by reason). Dropped nodes take, in the reconstruction, the value of
//!   the nearest measured node of its slice (`MeasurementGrid::fill_from_nearest`). Nudging keeps
//!   the direction count of every warp that maps the whole square onto the hemisphere (mixture,
//!   uniform) equal at equal grids, so strategies compare at the same cost.
//! * Order and time: `order` (NN + 2-opt + Or-opt within each level, after the previous level's last
//!   pose), timed by replaying the firmware's IK and the shared motion profile.

pub mod file;
pub mod order;
pub mod photo;
pub mod photo_samples;
pub mod predict;

use crate::brdf::analytic::Ggx;
use crate::brdf::frame::{from_spherical, phi_of, theta_of};
use crate::brdf::grid::{incident_thetas, MeasurementGrid, NodeLayout, THETA_I_MAX};
use crate::brdf::spec::Analytic;
use crate::brdf::warp::{GgxVndf, MixtureWarp, SliceWarp, UniformAngles, Warp, WarpKind};
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
}

/// Which outgoing warp.
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::EnumString, strum::VariantNames)]
#[strum(serialize_all = "kebab-case")]
pub enum Strategy {
    /// The estimate decides: `mixture` for a lobe sharper than alpha = 0.05 (`AUTO_SHARP_ALPHA`),
    /// `uniform` for a rougher one, where equal angles fed the fitted prior better (docs/tradeoff).
    Auto,
    /// The paper's warp: GGX visible normals of the estimated alpha.
    Specular,
    /// eq. 6: visible normals composed with a table of the estimate's f cos (whole lobe).
    Mixture,
    /// Equal steps in (theta_o, phi_o), blind to the material.
    Uniform,
}

/// Below this estimated alpha `Strategy::Auto` follows the lobe (`Mixture`), from it on it takes
/// equal angles (`Uniform`). With the reconstruction's fitted prior, the mixture's brdf_log_err is
/// 0.35-0.80x the uniform grid's (geometric mean over the levels) on every training-set material
/// estimated below 0.04 (docs/tradeoff/training: chrome, specular-blue-phenolic, blue-acrylic,
/// nickel, white-paint, alum-bronze, gold-metallic-paint2, two-layer-silver), with point-light FLIP
/// up to 1.8x worse; from 0.1 up it is 0.69-1.47x there and 1.16-1.55x on every such material of
/// docs/tradeoff/default, with FLIP no better. 0.05 sits in the gap. Chosen on training-set runs
/// (first with the v2 encoder, rechecked with v3); the held-out set only reports it.
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
            Strategy::Specular => "specular",
            Strategy::Mixture => "mixture",
            Strategy::Uniform => "uniform",
        })
    }
}

/// Spacing of the incoming elevations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::EnumString, strum::VariantNames)]
#[strum(serialize_all = "kebab-case")]
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

/// How a reconstruction finds a query's u in the two bracketing incoming slices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::EnumString, strum::VariantNames)]
#[strum(serialize_all = "kebab-case")]
pub enum Lookup {
    /// Through each slice's own warp (built for the slice's wi).
    Slice,
    /// Through the warp re-centred on the query's own wi, in both slices (RGL's files do this): a
    /// lobe that moves with wi sits at the same u in both, so interpolating between slices does not
    /// split a peak into two half-peaks at the slices' mirror directions. The uniform warp does not
    /// depend on wi: there both lookups agree.
    Query,
}

impl fmt::Display for Lookup {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Lookup::Slice => "slice",
            Lookup::Query => "query",
        })
    }
}

/// What the reconstruction interpolates between nodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::EnumString, strum::VariantNames)]
#[strum(serialize_all = "kebab-case")]
pub enum Interp {
    /// The measured values f.
    Linear,
    /// log(1 + f) per channel, mapped back with exp - 1: a node on a sharp peak (f ~ 100s) then
    /// decays toward its neighbours geometrically instead of spreading a linear ramp of peak-sized
    /// values over the whole cell, which at coarse levels covers much of the hemisphere.
    Log,
    /// log(f + RATIO_FLOOR) per channel: over a fitted prior the grid then holds the ratio
    /// measured / prior (up to the floor), so a node's correction scales with the prior where it is
    /// carried to. In log(1 + f) the residual is an absolute difference wherever f << 1: a node on a
    /// peak the prior underestimates then lifts every dark point of its cells by about that
    /// difference, which at coarse levels is most of the hemisphere (docs/tradeoff/README.md).
    Ratio,
}

/// `Interp::Ratio`'s floor (sr^-1): below it a ratio is not trusted. The guard of its log (f is
/// clamped at 0, so f + floor > 0), and the scale where a measurement's noise would make a ratio
/// to a near-zero prior meaningless. Chosen on the training set: 1e-4 and 1e-3 tie, 1e-2 is worse.
pub const RATIO_FLOOR: f64 = 1e-3;

impl fmt::Display for Interp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Interp::Linear => "linear",
            Interp::Log => "log",
            Interp::Ratio => "ratio",
        })
    }
}

/// What the reconstruction interpolates on top of.
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::EnumString, strum::VariantNames)]
#[strum(serialize_all = "kebab-case")]
pub enum Prior {
    /// Nothing: the grid interpolates the measured values themselves.
    None,
    /// A GGX lobe (plus Lambert) fitted to the level's own measurements (`brdf::fit::fit_samples`,
    /// the same log(1 + f cos) loss as `gonio brdf fit`; no ground truth involved). The grid
    /// interpolates the residual of each measurement against the lobe, in the `Interp` space, and
    /// the lobe, evaluated at the query's own (wi, wo), supplies the shape between nodes and
    /// between incoming slices: a peak that moves with wi is found where it is, not averaged from
    /// the two slices' mirror directions, and a coarse level's few nodes correct the lobe's level
    /// instead of having to describe its shape.
    Fit,
    /// As `Fit` with Lambert plus two GGX lobes (`brdf::fit_lobes`): a sharp peak and a broad halo,
    /// the shape of most paints and plastics, each with a bounded Fresnel rise toward grazing, over
    /// a diffuse base that may darken toward grazing (`fit_lobes::coated_diffuse_shape`).
    TwoLobes,
    /// `TwoLobes` without the Fresnel rise (the lobes keep one colour at every angle): the
    /// ablation that shows what the rise is worth (docs/tradeoff/README.md).
    TwoLobesPlain,
    /// `TwoLobes` with the Lambert term no brighter than the darkest measurement within 80 deg of
    /// the normal (`fit_lobes::DiffuseBound::BelowDarkest`): a trial, not the default.
    TwoLobesCapped,
    /// `TwoLobes` fitted to the level's measurements and to the capture photo's pixels
    /// (`photo_samples`, given with `Plan::set_photo`), the photo's total weight
    /// `PHOTO_WEIGHT` times the measurements': a trial, not the default. The photo sees the
    /// highlight's shoulder that a coarse level misses, but it is taken under the capture light,
    /// the light of the point-light score, so that score is no longer independent of the fit's data
    /// (docs/tradeoff/README.md).
    TwoLobesPhoto,
}

impl fmt::Display for Prior {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Prior::None => "none",
            Prior::Fit => "fit",
            Prior::TwoLobes => "two-lobes",
            Prior::TwoLobesPlain => "two-lobes-plain",
            Prior::TwoLobesCapped => "two-lobes-capped",
            Prior::TwoLobesPhoto => "two-lobes-photo",
        })
    }
}

/// The lobe a reconstruction fitted to its measurements (`Prior`).
#[derive(Clone, Debug)]
pub enum FittedPrior {
    Lobe(Analytic),
    TwoLobes(crate::brdf::fit_lobes::TwoLobes),
}

impl FittedPrior {
    /// The fitted lobe's value (BRDF, 1/sr), without the grid's residual.
    pub fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        match self {
            FittedPrior::Lobe(m) => m.eval(wi, wo),
            FittedPrior::TwoLobes(m) => m.eval(wi, wo),
        }
    }

    /// One line for reports (a material spec for the one-lobe prior).
    pub fn describe(&self) -> String {
        match self {
            FittedPrior::Lobe(m) => m.to_spec(),
            FittedPrior::TwoLobes(m) => m.describe(),
        }
    }
}

/// What to plan.
#[derive(Clone, Debug)]
pub struct PlanConfig {
    pub strategy: Strategy,
    pub spacing: Spacing,
    /// Number of incoming elevations.
    pub k: usize,
    /// The levels' outgoing grids (N, M), coarsest first; each level's N and M divide the next's.
    pub grids: Vec<(usize, usize)>,
    /// The reconstruction's u lookup.
    pub lookup: Lookup,
    /// The reconstruction's interpolated quantity.
    pub interp: Interp,
    /// What the reconstruction interpolates on top of.
    pub prior: Prior,
}

impl Default for PlanConfig {
    fn default() -> Self {
        Self {
            strategy: Strategy::Auto,
            // Equal angle steps beat cosine and RGL steps on every material of the report.
            spacing: Spacing::Angle,
            k: crate::brdf::grid::DEFAULT_K,
            grids: square_grids(4),
            lookup: Lookup::Query,
            interp: Interp::Ratio,
            prior: Prior::TwoLobes,
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
    for w in grids.windows(2) {
        let ((n0, m0), (n1, m1)) = (w[0], w[1]);
        if n1 % n0 != 0 || m1 % m0 != 0 || n1 * m1 <= n0 * m0 {
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

/// The firmware's acceptance test of one direction (`gonio_firmware::plan::check_direction`: f32
/// IK, rounding to steps, the soft limits of the pose the steps reach, and the arms' separation
/// guard band), from the rest pose. The f64 kinematics alone accept directions at the blocked
/// cone's exact edge, where nudged nodes land, and the firmware's guard band refuses them.
struct FirmwareCheck {
    kin: Kinematics<f32>,
    guard: gonio_firmware::separation::SeparationGuard,
}

impl FirmwareCheck {
    fn new(instrument: &InstrumentConfig<f64>) -> Result<Self, PlanError> {
        let kin = Kinematics::<f32>::new(instrument.cast::<f32>())
            .map_err(|e| PlanError::Invalid(format!("instrument: {e:?}")))?;
        let guard = gonio_firmware::separation::SeparationGuard::new(&kin);
        Ok(Self { kin, guard })
    }

    fn rest_steps(&self) -> Result<gonio_shared::kinematics::Steps, Unreachable> {
        self.kin.to_steps(&self.kin.rest_pose())
    }

    fn accepts(&self, wi: DVec3, wo: DVec3) -> Result<(), Unreachable> {
        let d = Direction {
            theta_i: theta_of(wi) as f32,
            phi_i: phi_of(wi) as f32,
            theta_o: theta_of(wo) as f32,
            phi_o: phi_of(wo) as f32,
        };
        gonio_firmware::plan::check_direction(&self.kin, &self.guard, &d, &self.rest_steps()?).map(|_| ())
    }
}

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
    /// The alpha of the pure-specular slice warps (to re-centre them on a query's wi).
    specular_alpha: f64,
    /// Where each level's nodes sit in u (`node_layout`).
    layout: NodeLayout,
    /// The capture photo's pixels for `Prior::TwoLobesPhoto` (`set_photo`).
    photo: Option<photo_samples::PhotoSamples>,
}

/// The node layout of a plan with this warp and finest N: the mixture's first level measures the
/// pole and u.x = 3/4 (`NodeLayout::NestedFarRing`, when 3/4 is a node of the finest level);
/// every other warp, and the equal-angle grid whose u.x = 1/2 is already theta_o = 45 deg, keeps
/// `Nested`.
fn node_layout(warp: Strategy, fine_n: usize) -> NodeLayout {
    if warp == Strategy::Mixture && fine_n % 4 == 0 {
        NodeLayout::NestedFarRing
    } else {
        NodeLayout::Nested
    }
}

/// A level's measurements as a material: the measurement grid, read through `Lookup`.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    grid: MeasurementGrid,
    slices: Vec<SliceWarp>,
    lookup: Lookup,
    interp: Interp,
    specular_alpha: f64,
    /// The fitted lobe under the grid (`Prior::Fit`, `Prior::TwoLobes`); the grid then holds residuals.
    prior: Option<FittedPrior>,
}

impl Reconstruction {
    pub fn grid(&self) -> &MeasurementGrid {
        &self.grid
    }

    /// The reconstruction's value (BRDF, 1/sr) at node (k, i, j): the grid itself holds values in
    /// the interpolation space (log(1 + f), less the prior's), so read it back through `eval`.
    /// None where the node has no direction (below the horizon) or no value.
    pub fn node_value(&self, k: usize, i: usize, j: usize) -> Option<DVec3> {
        self.grid.node_value(k, i, j)?;
        let (wi, wo) = self.grid.node_directions(k, i, j)?;
        Some(self.eval(wi, wo))
    }

    /// The lobe fitted to the measurements, if the reconstruction uses one.
    pub fn prior(&self) -> Option<&FittedPrior> {
        self.prior.as_ref()
    }
}

impl Interp {
    /// A value in the interpolated space. Guard: a negative reading (noise) has no log; clamp it at 0.
    fn forward(self, v: DVec3) -> DVec3 {
        match self {
            Interp::Linear => v,
            Interp::Log => v.max(DVec3::ZERO).map(f64::ln_1p),
            Interp::Ratio => v.max(DVec3::ZERO).map(|x| (x + RATIO_FLOOR).ln()),
        }
    }
    fn inverse(self, v: DVec3) -> DVec3 {
        match self {
            Interp::Linear => v,
            Interp::Log => v.map(f64::exp_m1),
            Interp::Ratio => v.map(|x| x.exp() - RATIO_FLOOR),
        }
    }
}

impl Material for Reconstruction {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        let v = match self.lookup {
            Lookup::Slice => self.grid.eval(wi, wo),
            Lookup::Query => self
                .grid
                .eval_with_lookup(wi, wo, &|k, wi, wo| match self.slices.get(k)? {
                    SliceWarp::Mixture(m) => m.invert_from(wi, wo),
                    SliceWarp::GgxVndf(_) => GgxVndf::new(wi, self.specular_alpha).invert(wo),
                    other => other.invert(wo),
                }),
        };
        let base = match &self.prior {
            Some(p) => self.interp.forward(p.eval(wi, wo)),
            None => DVec3::ZERO,
        };
        // Guard: a residual interpolated from a node where the prior overshoots can take the sum
        // below 0 (f < 0) where the prior is small; a BRDF is never negative.
        self.interp.inverse(base + v).max(DVec3::ZERO)
    }
}

/// The planner: an instrument and an estimate.
pub struct Planner {
    kin: Kinematics<f64>,
    firmware: FirmwareCheck,
    estimate: Estimate,
}

impl Planner {
    pub fn new(instrument: InstrumentConfig<f64>, estimate: Estimate) -> Result<Self, PlanError> {
        let kin = Kinematics::new(instrument).map_err(|e| PlanError::Invalid(format!("instrument: {e:?}")))?;
        let firmware = FirmwareCheck::new(&instrument)?;
        Ok(Self {
            kin,
            firmware,
            estimate,
        })
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
            Strategy::Specular => WarpKind::GgxVndf {
                alpha: alpha.max(PLAN_ALPHA_MIN),
            }
            .for_incident(wi),
            // `resolve` never returns Auto; the arm keeps the match total without a panic.
            Strategy::Uniform | Strategy::Auto => WarpKind::Uniform.for_incident(wi),
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
        check_grids(&config.grids)?;
        let cfg = *self.kin.config();
        let thetas = spaced_thetas(config.spacing, config.k, self.estimate.alpha());
        let slices: Vec<SliceWarp> = thetas.iter().map(|&t| self.slice_warp(config.strategy, t)).collect();
        let (fine_n, fine_m) = *config.grids.last().expect("checked non-empty");
        let settle_exposure = cfg.settle_ms as f64 * 1e-3 + cfg.exposure_us as f64 * 1e-6;
        let layout = node_layout(config.strategy.resolve(self.estimate.alpha()), fine_n);

        // Unique directions per level, in generation (raster) order: k, then j, then i.
        let mut node_dir_gen: HashMap<(usize, usize, usize), Option<usize>> = HashMap::new();
        let mut seen: HashMap<(usize, [i64; 3]), Option<usize>> = HashMap::new();
        let mut gen: Vec<(usize, usize, usize, usize, DVec3, DVec3, Candidates)> = Vec::new();
        let mut level_ranges = Vec::new();
        let mut dropped = Dropped::default();
        for (level0, &(n, m)) in config.grids.iter().enumerate() {
            let level = level0 + 1;
            let stride_j = fine_m / m;
            let start = gen.len();
            for (k, warp) in slices.iter().enumerate() {
                let wi = from_spherical(thetas[k], 0.0);
                for j in 0..m {
                    for i in 0..n {
                        let key = (k, layout.fine_index(i, n, fine_n), j * stride_j);
                        if node_dir_gen.contains_key(&key) {
                            continue;
                        }
                        let u = DVec2::new(layout.node_x(i, n), j as f64 / m as f64);
                        let Some(wo) = sample_or_nudge(warp, u, fine_n) else {
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
                        let entry = match self.reachable(wi, wo) {
                            Ok(c) => {
                                gen.push((level, k, key.1, key.2, wi, wo, c));
                                Some(gen.len() - 1)
                            }
                            Err(reason) => match nudge(&|wi, wo| self.reachable(wi, wo), wi, wo) {
                                Some((nudged, c)) => {
                                    dropped.nudged += 1;
                                    gen.push((level, k, key.1, key.2, wi, nudged, c));
                                    Some(gen.len() - 1)
                                }
                                None => {
                                    match reason {
                                        Unreachable::BelowHorizon { .. } | Unreachable::NotFinite => {
                                            dropped.below_horizon += 1
                                        }
                                        Unreachable::Blocked => dropped.blocked += 1,
                                        Unreachable::Limit(_) => dropped.limit += 1,
                                    }
                                    None
                                }
                            },
                        };
                        seen.insert(dkey, entry);
                        node_dir_gen.insert(key, entry);
                    }
                }
            }
            level_ranges.push((level, n, m, start, gen.len()));
        }

        // Order within each level; time both orders by replaying the IK.
        let rest = self.kin.rest_pose();
        let mut order: Vec<usize> = Vec::with_capacity(gen.len());
        let mut levels = Vec::new();
        let (mut cur, mut cur_raster) = (rest, rest);
        let mut cur_c = Candidates(vec![rest]);
        let (mut cum, mut cum_raster) = (0.0, 0.0);
        let mut directions: Vec<PlannedDirection> = Vec::with_capacity(gen.len());
        for &(level, n, m, a, b) in &level_ranges {
            let items: Vec<Candidates> = gen[a..b].iter().map(|g| g.6.clone()).collect();
            let ordered = order::optimise(&cfg, &cur_c, &items);
            let perm = ordered.perm;
            let pairs: Vec<(DVec3, DVec3)> = perm.iter().map(|&p| (gen[a + p].4, gen[a + p].5)).collect();
            let (poses, moves) =
                order::simulate(&self.kin, cur, &pairs).map_err(|(i, reason)| PlanError::Unreachable {
                    index: directions.len() + i,
                    reason,
                })?;
            let raster_pairs: Vec<(DVec3, DVec3)> = gen[a..b].iter().map(|g| (g.4, g.5)).collect();
            let (rposes, rmoves) = order::simulate(&self.kin, cur_raster, &raster_pairs)
                .map_err(|(i, reason)| PlanError::Unreachable { index: a + i, reason })?;
            let bound = ordered.bound;
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
                m,
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
            warp: config.strategy.resolve(self.estimate.alpha()),
            thetas,
            slices,
            directions,
            levels,
            dropped,
            node_dir,
            settle_exposure_seconds: settle_exposure,
            specular_alpha: self.estimate.alpha().max(PLAN_ALPHA_MIN),
            layout,
            photo: None,
        })
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

    /// Give the reconstruction the capture photo's pixels (read by `Prior::TwoLobesPhoto` only).
    pub fn set_photo(&mut self, photo: photo_samples::PhotoSamples) {
        self.photo = Some(photo);
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

    /// Reconstruct level `level` from the measured values (indexed like `directions`; only the
    /// prefix up to the level is read). Unmeasured nodes take their nearest measured neighbour's value.
    pub fn reconstruct(&self, level: usize, values: &[DVec3]) -> Result<Reconstruction, PlanError> {
        self.reconstruct_with(level, values, self.config.prior)
    }

    /// `reconstruct` with another prior than the plan's.
    pub fn reconstruct_with(&self, level: usize, values: &[DVec3], prior: Prior) -> Result<Reconstruction, PlanError> {
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
        let (n, m) = (summary.n, summary.m);
        let (fine_n, fine_m) = self.config.grids.last().copied().unwrap_or((n, m));
        let stride_j = fine_m / m;
        let k_count = self.thetas.len();
        let cells = k_count * n * m;
        let mut grid = MeasurementGrid::from_slices(
            self.slices.clone(),
            self.layout,
            self.thetas.clone(),
            n,
            m,
            vec![DVec3::ZERO; cells],
            vec![false; cells],
        )?;
        let prior = match prior {
            Prior::None => None,
            Prior::Fit | Prior::TwoLobes | Prior::TwoLobesPlain | Prior::TwoLobesCapped | Prior::TwoLobesPhoto => {
                let measured = &self.directions[..limit];
                let pairs: Vec<(DVec3, DVec3)> = measured.iter().map(|d| (d.wi, d.wo)).collect();
                // Each sample stands for the equal-angle measure its warp gives it (p_angles / p_warp):
                // the loss then weighs the hemisphere as `gonio brdf fit` and brdf_log_err do, however
                // densely the plan crowds a peak. Guard: a zero or non-finite density gets weight 0.
                let weights: Vec<f64> = measured
                    .iter()
                    .map(|d| {
                        let p = self.slices[d.k].pdf(d.wo);
                        let w = UniformAngles.pdf(d.wo) / p;
                        if p > 0.0 && w.is_finite() {
                            w
                        } else {
                            0.0
                        }
                    })
                    .collect();
                let values = &values[..limit];
                Some(if prior == Prior::Fit {
                    let fit = crate::brdf::fit::fit_samples(pairs, values, &weights, crate::brdf::fit::FitModel::Ggx);
                    FittedPrior::Lobe(fit.model)
                } else {
                    // The floor reads the plan's own samples only (the photo's are not the plan's).
                    let min_alpha = sharp_lobe_floor(self.specular_alpha, &pairs);
                    let mut fit_data = (pairs, values.to_vec(), weights);
                    if prior == Prior::TwoLobesPhoto {
                        let photo = self.photo.as_ref().ok_or_else(|| {
                            PlanError::Invalid(
                                "the two-lobes-photo prior needs the capture photo (Plan::set_photo)".into(),
                            )
                        })?;
                        photo_samples::append_weighted(&mut fit_data, photo, PHOTO_WEIGHT);
                    }
                    FittedPrior::TwoLobes(
                        crate::brdf::fit_lobes::fit_two_lobes_bounded(
                            &fit_data.0,
                            &fit_data.1,
                            &fit_data.2,
                            min_alpha,
                            if prior == Prior::TwoLobesPlain {
                                crate::brdf::fit_lobes::LobeFresnel::None
                            } else {
                                crate::brdf::fit_lobes::LobeFresnel::Bounded
                            },
                            if prior == Prior::TwoLobesCapped {
                                crate::brdf::fit_lobes::DiffuseBound::BelowDarkest
                            } else {
                                crate::brdf::fit_lobes::DiffuseBound::Free
                            },
                        )
                        .model,
                    )
                })
            }
        };
        let interp = self.config.interp;
        // Without a prior the grid is the whole reconstruction, so it always keeps the values.
        let residual = prior.is_none() || level_keeps_residual(self.layout, n);
        for k in 0..k_count {
            for j in 0..m {
                for i in 0..n {
                    let v = self
                        .node_dir
                        .get(&(k, self.layout.fine_index(i, n, fine_n), j * stride_j))
                        .filter(|&&d| d < limit)
                        .map(|&d| {
                            // A fit-alone level stores zero residuals (no prior evaluation needed).
                            if !residual {
                                return DVec3::ZERO;
                            }
                            let base = match &prior {
                                Some(p) => {
                                    let dir = &self.directions[d];
                                    interp.forward(p.eval(dir.wi, dir.wo))
                                }
                                None => DVec3::ZERO,
                            };
                            interp.forward(values[d]) - base
                        });
                    grid.set_node(k, i, j, v);
                }
            }
        }
        grid.fill_from_nearest();
        Ok(Reconstruction {
            grid,
            slices: self.slices.clone(),
            lookup: self.config.lookup,
            interp: self.config.interp,
            specular_alpha: self.specular_alpha,
            prior,
        })
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
            let next = gonio_firmware::plan::check_direction(&fw.kin, &fw.guard, d, &cur)
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

/// Whether a level of `n` rings laid out as `layout` keeps its residual grid on top of a fitted
/// prior. Not the first level of a lobe-following plan (`NodeLayout::NestedFarRing` at n = 2): its
/// three nodes per slice (the peak, the far field beyond it and behind the normal) all feed the
/// fit, and a grid that coarse spreads each node's misfit over a quarter of the hemisphere, across
/// the shoulder no node sees, as arcs in a render; that level's reconstruction is the fit alone.
/// Chosen on the training sets (docs/tradeoff/README.md, the quick command there), 2 x 2 adaptive
/// brdf_log_err / point-light FLIP / environment FLIP, residual kept -> fit alone: `training/`
/// 0.00468 / 0.0189 / 0.0361 -> 0.00448 / 0.0179 / 0.0334, `training-pool/` 0.00423 / 0.0178 /
/// 0.0448 -> 0.00429 / 0.0154 / 0.0380 (white-paint's FLIP 0.0575 -> 0.0206). Half the residual
/// lay between (0.00452 / 0.0180 / 0.0342, 0.00412 / 0.0160 / 0.0400); dropping only the peak's
/// or only the far nodes' residual did not help (pool FLIP 0.0184, 0.0191). From 4 x 4 on the grid
/// pays: three quarters of the residual at 4 x 4 raised training's FLIP 0.0135 -> 0.0155.
pub fn level_keeps_residual(layout: NodeLayout, n: usize) -> bool {
    !(layout == NodeLayout::NestedFarRing && n == 2)
}

/// The sharpest lobe the two-lobe prior may fit to a level's measurements `pairs`, for a plan built
/// on an estimate of roughness `estimate_alpha`: the smaller of half the estimate and half the
/// roughness the samples resolve (`fit_lobes::resolvable_alpha`, from the nearest off-peak sample
/// of each slice). A lobe far sharper than both is unconstrained between the samples: fitted to a
/// few of them it puts a spike at every mirror direction they missed. Half the estimate alone (the
/// rule before) kept the fit from the true peak wherever the encoder overestimated alpha, and gave
/// the uniform grid, which places nothing by the estimate, a floor from it. In practice the
/// mixture's floor is the samples' from the first level on (in oblique slices its u.x = 0 node,
/// the visible-normal warp's disk centre, sits just off the mirror direction: the floor is 0.0095
/// for an estimate of 0.1), and the uniform grid's falls from half the estimate as its nodes close
/// in (`plan::tests`). Chosen on the 14 training-set MERL materials of docs/tradeoff/README.md.
pub fn sharp_lobe_floor(estimate_alpha: f64, pairs: &[(DVec3, DVec3)]) -> f64 {
    (SHARP_FLOOR_SHARE * estimate_alpha).min(SHARP_FLOOR_SHARE * crate::brdf::fit_lobes::resolvable_alpha(pairs))
}

/// `Prior::TwoLobesPhoto`: the photo's samples together weigh this many times the level's
/// measurements. Chosen on training and training-pool against 0.3, 1, 3 and 10 with every 8th
/// pixel (3 with every 4th won), on environment FLIP and brdf_log_err: the point-light score
/// shares the photo's light (docs/tradeoff/README.md).
pub const PHOTO_WEIGHT: f64 = 3.0;

/// The share of the estimate's and of the samples' resolvable roughness below which the prior's
/// sharp lobe may not go (`sharp_lobe_floor`).
pub const SHARP_FLOOR_SHARE: f64 = 0.5;

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
