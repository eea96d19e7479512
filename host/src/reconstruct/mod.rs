//! Step 4 of the pipeline: a level's measurements -> a material (docs/planner.md, "Reconstruction").
//!
//! A prior fitted to the level's own measurements (`prior`) gives the shape; the measurement grid
//! holds each node's residual against it as a ratio, looked up through the warp re-centred on the
//! query's own wi where the fitted lobes make f, through each slice's own warp elsewhere. This
//! module never reads the planner: it reads a level through `Levels`.

pub mod pca;
pub mod prior;

pub use prior::{FittedPrior, LevelSamples, NoPrior, OtherModel, Prior, TwoLobesPrior, SHARP_FLOOR_SHARE};

use crate::brdf::frame::theta_of;
use crate::brdf::grid::{MeasurementGrid, NodeLayout};
use crate::brdf::warp::{SliceWarp, UniformAngles, Warp};
use crate::brdf::{BrdfError, Material};
use glam::DVec3;

#[derive(Debug, thiserror::Error)]
pub enum ReconstructError {
    #[error("reconstruct: no level {0}")]
    NoLevel(usize),
    #[error("reconstruct: level {level} needs {need} values, got {got}")]
    TooFewValues { level: usize, need: usize, got: usize },
    #[error(transparent)]
    Brdf(#[from] BrdfError),
    #[error("reconstruct: {0}")]
    Basis(String),
}

/// One measured level as the reconstruction reads it.
#[derive(Clone, Debug)]
pub struct LevelNodes<'a> {
    pub slices: &'a [SliceWarp],
    pub thetas: &'a [f64],
    pub layout: NodeLayout,
    /// The level's N x M nodes per slice.
    pub n: usize,
    pub m: usize,
    /// The measurement of node (k, i, j), at `(k * m + j) * n + i`; None where nothing was measured.
    pub node_measurement: Vec<Option<usize>>,
    /// (slice, wi, wo) of every measurement up to this level, in measurement order.
    pub measured: Vec<(usize, DVec3, DVec3)>,
    /// Roughness of the estimate the plan was built from (the prior's sharp-lobe floor reads it).
    pub estimate_alpha: f64,
    /// Half-angle (rad) of the arms' blocked cone around wi (`blocked_peak`); 0: none.
    pub blocked_cone: f64,
}

/// Whatever holds measured levels (a plan).
pub trait Levels {
    /// Level `level` (1-based); None if there is none.
    fn level_nodes(&self, level: usize) -> Option<LevelNodes<'_>>;
}

impl<'a> LevelNodes<'a> {
    /// The level with only the measurements `keep` accepts (by measurement index), the others read
    /// as unmeasured, and their values: what a scan that skipped them would have reconstructed from.
    pub fn subset(&self, values: &[DVec3], keep: impl Fn(usize) -> bool) -> (LevelNodes<'a>, Vec<DVec3>) {
        let mut index = vec![None; self.measured.len()];
        let (mut measured, mut kept) = (Vec::new(), Vec::new());
        for (d, m) in self.measured.iter().enumerate() {
            if keep(d) {
                if let Some(&v) = values.get(d) {
                    index[d] = Some(measured.len());
                    measured.push(*m);
                    kept.push(v);
                }
            }
        }
        let node_measurement = self
            .node_measurement
            .iter()
            .map(|d| d.and_then(|d| index.get(d).copied().flatten()))
            .collect();
        (
            LevelNodes {
                slices: self.slices,
                thetas: self.thetas,
                layout: self.layout,
                n: self.n,
                m: self.m,
                node_measurement,
                measured,
                estimate_alpha: self.estimate_alpha,
                blocked_cone: self.blocked_cone,
            },
            kept,
        )
    }
}

/// One level standing alone (a subset of a measured one) as `Levels` reads it.
pub struct SingleLevel<'a> {
    pub level: usize,
    pub nodes: LevelNodes<'a>,
}

impl Levels for SingleLevel<'_> {
    fn level_nodes(&self, level: usize) -> Option<LevelNodes<'_>> {
        (level == self.level).then(|| self.nodes.clone())
    }
}

/// Floor (sr^-1) of the ratio residual: ln(f + RATIO_FLOOR) guards the log and ignores noise-sized ratios.
pub const RATIO_FLOOR: f64 = 1e-3;

/// A value in the interpolated (ratio) space; a negative reading (noise) is clamped at 0.
fn forward(v: DVec3) -> DVec3 {
    v.max(DVec3::ZERO).map(|x| (x + RATIO_FLOOR).ln())
}

/// The value of a point of the interpolated space.
fn inverse(v: DVec3) -> DVec3 {
    v.map(|x| x.exp() - RATIO_FLOOR)
}

/// Width (in ln f) of the residual lookup's guide: each of the four nodes around a query weighs
/// exp(-((ln prior at the query - ln prior at the node) / width)^2) on top of bilinear, so a lobe's
/// misfit at its flank does not spill onto a shoulder the prior already fits (docs/planner.md).
pub const GUIDE_WIDTH: f64 = 1.0;

/// The guide value of a prior's value: the mean of its channels in the interpolated space.
fn guide_of(prior: DVec3) -> f64 {
    forward(prior).element_sum() / 3.0
}

/// Whether node direction (wi, wo) stands on a specular peak the instrument cannot see: wo inside the
/// arms' blocked cone around wi (half-angle `cone`) in a slice whose mirror direction is inside it
/// too (theta_i < cone / 2: normal incidence). Its measurement was nudged out of the cone, onto the
/// peak's far tail; the lobe's height there is read from the next slice, whose peak is measured.
pub fn blocked_peak(wi: DVec3, wo: DVec3, cone: f64) -> bool {
    theta_of(wi) < 0.5 * cone && wi.angle_between(wo) < cone
}

/// Whether a level of `n` rings laid out as `layout` keeps its residual grid on top of a fitted
/// prior: not the first level of a lobe-following plan, which is the fit alone (docs/planner.md).
pub fn level_keeps_residual(layout: NodeLayout, n: usize) -> bool {
    !(layout == NodeLayout::NestedFarRing && n == 2)
}

/// The product reconstruction's settings in one line (a scan records them; a resume compares them).
pub fn settings() -> String {
    format!(
        "prior {} ({} folds, ridge {}, unexplained <= {}), ratio residual (floor {RATIO_FLOOR} /sr), lookup blended by the lobes' share (guide width {GUIDE_WIDTH}), cubic between incoming slices, normal-incidence peak from the next slice",
        pca::selected::NAME,
        pca::selected::FOLDS,
        pca::selected::PCA_RIDGE,
        pca::selected::MAX_UNEXPLAINED
    )
}

/// The product's reconstruction of `level` from `values` (indexed like the measurements): on
/// top of `pca::selected::product_prior`, whose basis is read (or built once) on first use.
pub fn reconstruct(levels: &dyn Levels, level: usize, values: &[DVec3]) -> Result<Reconstruction, ReconstructError> {
    let prior = pca::selected::product_prior().map_err(ReconstructError::Basis)?;
    reconstruct_with(levels, level, values, &prior)
}

/// `reconstruct` on top of another prior. Unmeasured nodes take their nearest measured neighbour's value.
pub fn reconstruct_with(
    levels: &dyn Levels,
    level: usize,
    values: &[DVec3],
    prior: &dyn Prior,
) -> Result<Reconstruction, ReconstructError> {
    let nodes = levels.level_nodes(level).ok_or(ReconstructError::NoLevel(level))?;
    let need = nodes.measured.len();
    if values.len() < need {
        return Err(ReconstructError::TooFewValues {
            level,
            need,
            got: values.len(),
        });
    }
    let cells = nodes.thetas.len() * nodes.n * nodes.m;
    let mut grid = MeasurementGrid::from_slices(
        nodes.slices.to_vec(),
        nodes.layout,
        nodes.thetas.to_vec(),
        nodes.n,
        nodes.m,
        vec![DVec3::ZERO; cells],
        vec![false; cells],
    )?;
    let values = &values[..need];
    let fitted = prior.fit(&samples_of(&nodes, values));
    // Without a prior the grid is the whole reconstruction, so it always keeps the values.
    let residual = fitted.is_none() || level_keeps_residual(nodes.layout, nodes.n);
    let mut holes = Vec::new();
    for k in 0..nodes.thetas.len() {
        for j in 0..nodes.m {
            for i in 0..nodes.n {
                if grid
                    .node_directions(k, i, j)
                    .is_some_and(|(wi, wo)| blocked_peak(wi, wo, nodes.blocked_cone))
                {
                    holes.push((k, i, j));
                    continue;
                }
                let v = nodes.node_measurement[(k * nodes.m + j) * nodes.n + i].map(|d| {
                    // A fit-alone level stores zero residuals.
                    if !residual {
                        return DVec3::ZERO;
                    }
                    let base = match &fitted {
                        Some(p) => forward(p.eval(nodes.measured[d].1, nodes.measured[d].2)),
                        None => DVec3::ZERO,
                    };
                    forward(values[d]) - base
                });
                grid.set_node(k, i, j, v);
            }
        }
    }
    grid.fill_from_nearest();
    // After the fill: a blocked peak's node stays empty, so the lookup reads the next slice there.
    for &(k, i, j) in &holes {
        grid.set_node(k, i, j, None);
    }
    if let (Some(p), true) = (&fitted, residual) {
        let guide = (0..nodes.thetas.len())
            .flat_map(|k| (0..nodes.m).flat_map(move |j| (0..nodes.n).map(move |i| (k, i, j))))
            .map(|(k, i, j)| {
                grid.node_directions(k, i, j)
                    .map_or(f64::NAN, |(wi, wo)| guide_of(p.eval(wi, wo)))
            })
            .collect();
        grid.set_guide(guide, GUIDE_WIDTH);
    }
    Ok(Reconstruction {
        grid,
        slices: nodes.slices.to_vec(),
        prior: fitted,
    })
}

/// The level's samples with the equal-angle measure each stands for (p_angles / p_warp), so a fit
/// weighs the hemisphere as brdf_log_err does however densely the plan crowds a peak.
fn samples_of<'a>(nodes: &LevelNodes<'_>, values: &'a [DVec3]) -> LevelSamples<'a> {
    let pairs = nodes.measured.iter().map(|&(_, wi, wo)| (wi, wo)).collect();
    let weights = nodes
        .measured
        .iter()
        .map(|&(k, _, wo)| {
            let p = nodes.slices[k].pdf(wo);
            let w = UniformAngles.pdf(wo) / p;
            // Guard: a zero or non-finite density gets weight 0.
            if p > 0.0 && w.is_finite() {
                w
            } else {
                0.0
            }
        })
        .collect();
    LevelSamples {
        pairs,
        values,
        weights,
        estimate_alpha: nodes.estimate_alpha,
    }
}

/// A level's measurements as a material: the fitted prior times the interpolated ratio grid.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    grid: MeasurementGrid,
    slices: Vec<SliceWarp>,
    prior: Option<FittedPrior>,
}

impl Reconstruction {
    pub fn grid(&self) -> &MeasurementGrid {
        &self.grid
    }

    /// The reconstruction's value (BRDF, 1/sr) at node (k, i, j); None where the node has no
    /// direction. A node left empty (`blocked_peak`) has the value the lookup reads there.
    pub fn node_value(&self, k: usize, i: usize, j: usize) -> Option<DVec3> {
        let (wi, wo) = self.grid.node_directions(k, i, j)?;
        Some(self.eval(wi, wo))
    }

    /// The model fitted to the measurements, if the prior fitted one.
    pub fn prior(&self) -> Option<&FittedPrior> {
        self.prior.as_ref()
    }
}

impl Reconstruction {
    /// The interpolated residual at (wi, wo). On a lobe-following plan each slice can look wo up
    /// two ways: through its warp re-centred on the query's own wi (a lobe that moves with wi is
    /// then found at the same u in both bracketing slices) or through its own warp (as its nodes
    /// were placed; far from the lobe the re-centred warp maps grazing back-scatter into a sliver
    /// of u). The fitted lobes' share of the prior at (wi, wo) weighs the first, the rest of f the
    /// second; a basis prior, which has no lobes to follow, keeps the first (docs/planner.md).
    fn residual(&self, wi: DVec3, wo: DVec3, guide: Option<f64>) -> DVec3 {
        if !self.slices.iter().any(|s| matches!(s, SliceWarp::Mixture(_))) {
            return self.grid.eval_guided(wi, wo, None, guide);
        }
        let lookup = |k: usize, wi: DVec3, wo: DVec3| match self.slices.get(k)? {
            SliceWarp::Mixture(m) => m.invert_from(wi, wo),
            other => other.invert(wo),
        };
        let query = self.grid.eval_guided(wi, wo, Some(&lookup), guide);
        let share = match &self.prior {
            Some(FittedPrior::TwoLobes(t)) => t.lobe_share(wi, wo),
            _ => 1.0,
        };
        if share >= 1.0 {
            return query;
        }
        share * query + (1.0 - share) * self.grid.eval_guided(wi, wo, None, guide)
    }
}

impl Material for Reconstruction {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        let (base, guide) = match &self.prior {
            Some(p) => {
                let f = p.eval(wi, wo);
                (forward(f), Some(guide_of(f)))
            }
            None => (DVec3::ZERO, None),
        };
        let v = self.residual(wi, wo, guide);
        // Guard: a residual from a node where the prior overshoots can take the sum below 0.
        inverse(base + v).max(DVec3::ZERO)
    }
}

#[cfg(test)]
mod tests;
