//! Levels planned from the measurements (issue 25, item 2), a lab trial beside the product's loop:
//! level 1 is the photo's plan; from level 2 on, the new directions are those of a plan seeded by
//! the two-lobe prior fitted to level 1's measurements instead of the photo's estimate. Level 1's
//! measurements are kept: the fit reads them where they were measured, and the re-seeded plan's
//! own level-1 nodes take the residual of the nearest of them in their slice, so no direction is
//! measured twice and the cumulative count stays the uniform grid's (docs/tradeoff/README.md).

use gonio::brdf::analytic::Ggx;
use gonio::brdf::spec::Analytic;
use gonio::plan::{Estimate, LevelSummary, Plan, PlanConfig, PlanError, Planner, Strategy};
use gonio::reconstruct::{FittedPrior, LevelNodes, Levels};
use gonio_shared::instrument::InstrumentConfig;

/// The GGX estimate a fitted prior re-seeds the planner with: its diffuse base and the lobe
/// carrying the larger specular colour (mean over RGB); None for a prior of another kind.
pub fn estimate_from_prior(prior: &FittedPrior) -> Option<Estimate> {
    let FittedPrior::TwoLobes(t) = prior else {
        return None;
    };
    let mean = |v: glam::DVec3| v.element_sum() / 3.0;
    let (alpha, specular) = if mean(t.sharp) >= mean(t.broad) {
        (t.sharp_alpha, t.sharp)
    } else {
        (t.broad_alpha, t.broad)
    };
    // Guard: a fit that left no finite lobe re-seeds nothing (the photo's plan goes on).
    if !alpha.is_finite() || alpha <= 0.0 {
        return None;
    }
    Some(Estimate {
        model: Analytic::Ggx(Ggx {
            alpha,
            diffuse: t.diffuse + t.coated,
            specular,
        }),
    })
}

/// What the nodes of the second plan's own level 1 (never measured) read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SkippedNodes {
    /// The nearest level-1 measurement of the first plan in their slice (`reseed`).
    NearestFirst,
    /// A level-1 measurement of the first plan at the same direction (the zenith of the normal
    /// slice, where every warp has its pole), else nothing: the grid fills them from their
    /// nearest measured node (`confirm`).
    SameOrUnmeasured,
}

/// Two directions closer than this (cosine; ~0.03 deg) are one direction.
const SAME_DIRECTION_COS: f64 = 1.0 - 1e-7;

/// Level 1 of the photo's plan, then levels 2.. of another plan (re-seeded from level 1's fit).
pub struct Reseeded<'a> {
    first: &'a Plan,
    next: &'a Plan,
    /// Directions of `first`'s level 1 (the measurements every later level starts from).
    first_count: usize,
    /// Directions of `next`'s own level 1 (never measured: their nodes read `skipped_nodes`).
    skipped: usize,
    skipped_nodes: SkippedNodes,
}

impl<'a> Reseeded<'a> {
    /// None unless both plans have the same incoming elevations and at least one level.
    pub fn new(first: &'a Plan, next: &'a Plan, skipped_nodes: SkippedNodes) -> Option<Self> {
        if first.thetas != next.thetas {
            return None;
        }
        Some(Self {
            first,
            next,
            first_count: first.levels.first()?.cumulative_directions,
            skipped: next.levels.first()?.cumulative_directions,
            skipped_nodes,
        })
    }

    /// Where `next`'s direction `d` is measured, in the measurement order of `Reseeded`: after
    /// level 1's, or for `next`'s own level-1 directions as `skipped_nodes` says.
    fn measurement_of(&self, d: usize) -> Option<usize> {
        if d >= self.skipped {
            return Some(self.first_count + d - self.skipped);
        }
        let target = self.next.directions.get(d)?;
        let (i, p) = self.first.directions[..self.first_count]
            .iter()
            .enumerate()
            .filter(|(_, p)| p.k == target.k)
            .max_by(|(_, a), (_, b)| a.wo.dot(target.wo).total_cmp(&b.wo.dot(target.wo)))?;
        let same = p.wo.dot(target.wo) >= SAME_DIRECTION_COS;
        (same || self.skipped_nodes == SkippedNodes::NearestFirst).then_some(i)
    }

    /// The per-level summaries: level 1 of `first`, then `next`'s levels without its level 1
    /// (times: level 1's, plus `next`'s later levels as planned from the rest pose).
    pub fn levels(&self) -> Vec<LevelSummary> {
        let (Some(f1), Some(n1)) = (self.first.levels.first(), self.next.levels.first()) else {
            return Vec::new();
        };
        let mut out = vec![f1.clone()];
        for l in self.next.levels.iter().skip(1) {
            let mut s = l.clone();
            s.cumulative_directions = self.first_count + l.cumulative_directions - self.skipped;
            s.first = self.first_count + l.first - self.skipped;
            s.cumulative_seconds = f1.cumulative_seconds + l.cumulative_seconds - n1.cumulative_seconds;
            s.cumulative_raster_seconds =
                f1.cumulative_raster_seconds + l.cumulative_raster_seconds - n1.cumulative_raster_seconds;
            out.push(s);
        }
        out
    }

    /// Every direction in measurement order: level 1 of `first`, then `next`'s later levels.
    pub fn pairs(&self) -> Vec<(glam::DVec3, glam::DVec3)> {
        let first = self.first.directions[..self.first_count].iter();
        let next = self.next.directions[self.skipped..].iter();
        first.chain(next).map(|d| (d.wi, d.wo)).collect()
    }
}

impl Levels for Reseeded<'_> {
    fn level_nodes(&self, level: usize) -> Option<LevelNodes<'_>> {
        if level <= 1 {
            return self.first.level_nodes(level);
        }
        let nodes = self.next.level_nodes(level)?;
        let limit = nodes.measured.len();
        let mut measured: Vec<_> = self.first.directions[..self.first_count]
            .iter()
            .map(|d| (d.k, d.wi, d.wo))
            .collect();
        measured.extend_from_slice(nodes.measured.get(self.skipped..limit)?);
        let node_measurement = nodes
            .node_measurement
            .iter()
            .map(|d| d.and_then(|d| self.measurement_of(d)))
            .collect();
        Some(LevelNodes {
            node_measurement,
            measured,
            ..nodes
        })
    }
}

/// The photo's plan `first` re-seeded after level 1 from the prior fitted to `values` (level 1's
/// measurements): the re-seeded plan, or None when the fit gives no estimate.
pub fn replan(
    instrument: &InstrumentConfig<f64>,
    config: &PlanConfig,
    fitted: Option<&FittedPrior>,
) -> Result<Option<Plan>, PlanError> {
    let Some(estimate) = fitted.and_then(estimate_from_prior) else {
        return Ok(None);
    };
    Planner::new(*instrument, estimate)?.plan(config).map(Some)
}

/// Trial `confirm`: the uniform grid for levels 2.. when `first` follows a lobe (mixture) that
/// level 1's fit does not confirm (its stronger lobe is rough enough for `auto` to plan the
/// uniform grid); None (the photo's plan goes on) otherwise, and for a fit of another kind.
pub fn unconfirmed(
    first: &Plan,
    instrument: &InstrumentConfig<f64>,
    photo: &Estimate,
    config: &PlanConfig,
    fitted: Option<&FittedPrior>,
) -> Result<Option<Plan>, PlanError> {
    let rough = fitted
        .and_then(estimate_from_prior)
        .is_some_and(|e| Strategy::Auto.resolve(e.alpha()) == Strategy::Uniform);
    if first.warp != Strategy::Mixture || !rough {
        return Ok(None);
    }
    let uniform = PlanConfig {
        strategy: Strategy::Uniform,
        ..config.clone()
    };
    Planner::new(*instrument, photo.clone())?.plan(&uniform).map(Some)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::tradeoff::auto_plan;
    use gonio::brdf::{parse_material, Material};
    use gonio::reconstruct::reconstruct;

    /// Re-seeded levels keep every level-1 measurement, measure none of the new plan's level-1
    /// directions, point every node at a measurement of its own slice, and reconstruct finitely.
    #[test]
    fn reseeded_levels_keep_level_one_and_skip_the_new_plans_level_one() {
        let (first, next) = (auto_plan(0.3, 3), auto_plan(0.02, 3));
        let r = Reseeded::new(&first, &next, SkippedNodes::NearestFirst).unwrap();
        let levels = r.levels();
        let pairs = r.pairs();
        assert_eq!(levels.len(), 3);
        assert_eq!(levels.last().unwrap().cumulative_directions, pairs.len());
        let c1 = first.levels[0].cumulative_directions;
        for (a, b) in pairs[..c1].iter().zip(&first.directions[..c1]) {
            assert_eq!(*a, (b.wi, b.wo));
        }
        let truth = parse_material("ggx:alpha=0.05,diffuse=0.3,specular=1").unwrap();
        let values: Vec<_> = pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        for l in &levels {
            let nodes = r.level_nodes(l.level).unwrap();
            assert_eq!(nodes.measured.len(), l.cumulative_directions);
            for (idx, d) in nodes.node_measurement.iter().enumerate() {
                if let Some(d) = d {
                    let k = idx / (nodes.n * nodes.m);
                    assert_eq!(nodes.measured[*d].0, k, "node of slice {k} reads another slice");
                }
            }
            let rec = reconstruct(&r, l.level, &values[..l.cumulative_directions]).unwrap();
            let v = rec.eval(pairs[0].0, pairs[0].1);
            assert!(v.is_finite(), "{v}");
        }
    }

    /// Under `SameOrUnmeasured` the second plan's own level-1 nodes read a level-1 measurement only
    /// at the same direction (the zenith of the normal slice); under `NearestFirst` every one reads one.
    #[test]
    fn skipped_nodes_read_level_one_only_at_the_same_direction() {
        let (first, next) = (auto_plan(0.02, 3), auto_plan(0.3, 3));
        let skipped = next.levels[0].cumulative_directions;
        let count = |rule| {
            let r = Reseeded::new(&first, &next, rule).unwrap();
            (0..skipped).filter(|&d| r.measurement_of(d).is_some()).count()
        };
        assert_eq!(count(SkippedNodes::NearestFirst), skipped);
        let same = count(SkippedNodes::SameOrUnmeasured);
        assert!(same >= 1 && same < skipped, "{same} of {skipped}");
        let r = Reseeded::new(&first, &next, SkippedNodes::SameOrUnmeasured).unwrap();
        for d in (0..skipped).filter(|&d| r.measurement_of(d).is_some()) {
            let i = r.measurement_of(d).unwrap();
            assert!(first.directions[i].wo.dot(next.directions[d].wo) >= SAME_DIRECTION_COS);
        }
    }

    /// `confirm` switches a lobe-following plan to the uniform grid only when level 1's stronger
    /// lobe is rough; a sharp fit, a plan already uniform and a fit of no lobe keep the photo's plan.
    #[test]
    fn only_an_unconfirmed_sharp_plan_switches_to_the_uniform_grid() {
        let instrument = gonio::instrument::default_instrument();
        let config = PlanConfig {
            strategy: Strategy::Auto,
            grids: gonio::plan::square_grids(2),
            ..PlanConfig::default()
        };
        let (sharp, rough) = (auto_plan(0.02, 2), auto_plan(0.3, 2));
        assert_eq!((sharp.warp, rough.warp), (Strategy::Mixture, Strategy::Uniform));
        let photo = gonio::plan::ggx_estimate(0.02, 0.5);
        let fit = |alpha: f64| {
            FittedPrior::TwoLobes(gonio::brdf::fit_lobes::TwoLobes {
                diffuse: glam::DVec3::splat(0.2),
                sharp_alpha: alpha,
                sharp: glam::DVec3::ONE,
                broad_alpha: 0.5,
                broad: glam::DVec3::splat(0.1),
                sharp_grazing: glam::DVec3::ONE,
                broad_grazing: glam::DVec3::splat(0.1),
                coated: glam::DVec3::ZERO,
            })
        };
        let switch = |first: &Plan, fitted: Option<&FittedPrior>| {
            unconfirmed(first, &instrument, &photo, &config, fitted).unwrap()
        };
        let next = switch(&sharp, Some(&fit(0.2))).expect("a rough fit of a sharp plan switches");
        assert_eq!(next.warp, Strategy::Uniform);
        assert_eq!(next.thetas, sharp.thetas);
        assert!(
            switch(&sharp, Some(&fit(0.02))).is_none(),
            "a sharp fit confirms the plan"
        );
        assert!(switch(&rough, Some(&fit(0.2))).is_none(), "the uniform grid stays");
        assert!(switch(&sharp, None).is_none(), "no fit, no switch");
    }

    /// A two-lobe prior re-seeds with the lobe of the larger colour and its diffuse base.
    #[test]
    fn the_estimate_follows_the_stronger_lobe() {
        let fitted = |sharp: f64, broad: f64| {
            FittedPrior::TwoLobes(gonio::brdf::fit_lobes::TwoLobes {
                diffuse: glam::DVec3::splat(0.2),
                sharp_alpha: 0.02,
                sharp: glam::DVec3::splat(sharp),
                broad_alpha: 0.3,
                broad: glam::DVec3::splat(broad),
                sharp_grazing: glam::DVec3::splat(sharp),
                broad_grazing: glam::DVec3::splat(broad),
                coated: glam::DVec3::ZERO,
            })
        };
        assert_eq!(estimate_from_prior(&fitted(1.0, 0.1)).unwrap().alpha(), 0.02);
        assert_eq!(estimate_from_prior(&fitted(0.1, 1.0)).unwrap().alpha(), 0.3);
    }
}
