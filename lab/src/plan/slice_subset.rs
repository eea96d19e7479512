//! A measured level with some of its incoming elevations left out (`examples/first_level_check.rs`:
//! can level 1 estimate its own error from itself without every other elevation?).

use glam::DVec3;
use gonio::brdf::grid::NodeLayout;
use gonio::brdf::warp::SliceWarp;
use gonio::reconstruct::{LevelNodes, Levels};

/// One level of `Levels` restricted to the slices `keep` accepts, with its values re-indexed.
#[derive(Clone, Debug)]
pub struct SliceSubset {
    level: usize,
    slices: Vec<SliceWarp>,
    thetas: Vec<f64>,
    layout: NodeLayout,
    n: usize,
    m: usize,
    node_measurement: Vec<Option<usize>>,
    measured: Vec<(usize, DVec3, DVec3)>,
    estimate_alpha: f64,
    values: Vec<DVec3>,
    /// Measurement indices (of the whole level) left out.
    left_out: Vec<usize>,
}

impl SliceSubset {
    /// Level `level` of `levels` without the slices `keep` rejects; None if the level is missing,
    /// `values` is short, or fewer than two slices would remain.
    pub fn new(levels: &dyn Levels, level: usize, values: &[DVec3], keep: impl Fn(usize) -> bool) -> Option<Self> {
        let nodes = levels.level_nodes(level)?;
        if values.len() < nodes.measured.len() {
            return None;
        }
        let kept: Vec<usize> = (0..nodes.thetas.len()).filter(|&k| keep(k)).collect();
        if kept.len() < 2 {
            return None;
        }
        let new_slice = |k: usize| kept.iter().position(|&c| c == k);
        let (mut measured, mut subset_values, mut new_index, mut left_out) =
            (Vec::new(), Vec::new(), vec![None; nodes.measured.len()], Vec::new());
        for (d, &(k, wi, wo)) in nodes.measured.iter().enumerate() {
            match new_slice(k) {
                Some(s) => {
                    new_index[d] = Some(measured.len());
                    measured.push((s, wi, wo));
                    subset_values.push(values[d]);
                }
                None => left_out.push(d),
            }
        }
        let cells = nodes.n * nodes.m;
        let node_measurement = kept
            .iter()
            .flat_map(|&k| &nodes.node_measurement[k * cells..(k + 1) * cells])
            .map(|d| d.and_then(|d| new_index[d]))
            .collect();
        Some(Self {
            level,
            slices: kept.iter().map(|&k| nodes.slices[k].clone()).collect(),
            thetas: kept.iter().map(|&k| nodes.thetas[k]).collect(),
            layout: nodes.layout,
            n: nodes.n,
            m: nodes.m,
            node_measurement,
            measured,
            estimate_alpha: nodes.estimate_alpha,
            values: subset_values,
            left_out,
        })
    }

    /// The kept measurements' values, indexed like this subset's measurements.
    pub fn values(&self) -> &[DVec3] {
        &self.values
    }

    /// Indices (into the whole level's measurements) of the measurements left out.
    pub fn left_out(&self) -> &[usize] {
        &self.left_out
    }
}

impl Levels for SliceSubset {
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
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio::brdf::{parse_material, Material};
    use gonio::instrument::default_instrument;
    use gonio::plan::{estimate_for, square_grids, PlanConfig, Planner};
    use gonio::reconstruct::reconstruct;

    fn measured_plan() -> (gonio::plan::Plan, Vec<DVec3>) {
        let spec = "ggx:alpha=0.2,diffuse=0.15/0.08/0.04";
        let config = PlanConfig {
            grids: square_grids(2),
            ..PlanConfig::default()
        };
        let plan = Planner::new(default_instrument(), estimate_for(spec).unwrap())
            .unwrap()
            .plan(&config)
            .unwrap();
        let values = plan.measure(parse_material(spec).unwrap().as_ref());
        (plan, values)
    }

    #[test]
    fn keeping_every_slice_reconstructs_as_the_level_itself() {
        let (plan, values) = measured_plan();
        let subset = SliceSubset::new(&plan, 2, &values, |_| true).unwrap();
        assert!(subset.left_out().is_empty());
        let (whole, part) = (
            reconstruct(&plan, 2, &values).unwrap(),
            reconstruct(&subset, 2, subset.values()).unwrap(),
        );
        let nodes = plan.level_nodes(2).unwrap();
        for &(_, wi, wo) in nodes.measured.iter().step_by(7) {
            assert_eq!(whole.eval(wi, wo), part.eval(wi, wo));
        }
    }

    #[test]
    fn left_out_slices_take_their_measurements_with_them() {
        let (plan, values) = measured_plan();
        let nodes = plan.level_nodes(1).unwrap();
        let subset = SliceSubset::new(&plan, 1, &values, |k| k % 2 == 0).unwrap();
        let odd: Vec<usize> = (0..nodes.measured.len())
            .filter(|&d| nodes.measured[d].0 % 2 == 1)
            .collect();
        assert!(!odd.is_empty());
        assert_eq!(subset.left_out(), &odd[..]);
        assert_eq!(subset.values().len() + odd.len(), nodes.measured.len());
        let kept = subset.level_nodes(1).unwrap();
        assert_eq!(kept.thetas.len(), nodes.thetas.len().div_ceil(2));
        assert!(kept.node_measurement.iter().flatten().all(|&d| d < kept.measured.len()));
        assert!(subset.level_nodes(2).is_none());
        // Fewer than two slices, or short values: no subset.
        assert!(SliceSubset::new(&plan, 1, &values, |k| k == 0).is_none());
        assert!(SliceSubset::new(&plan, 1, &values[..3], |_| true).is_none());
    }
}
