//! Lab trial `designed` of `gonio-lab closed-loop` (issue 28: the peer's idea as the first level):
//! level 1 measures the peer's condition-number design (`peer::design`, the same directions
//! `nielsen2015` measures at that count) instead of the photo plan's level 1; from level 2 on, the
//! photo plan's later levels are measured on top. Every designed direction is kept: the prior is
//! fitted to all of them at every level, each filed under the plan's slice nearest its incoming
//! elevation. The photo plan's own level-1 nodes are never measured, so its later levels read them
//! as unmeasured nodes (the grid's nearest measured neighbour) and the cumulative count stays the
//! uniform grid's. Level 1 is the fitted prior alone (no grid: its nodes are not the plan's).
//! `Designed::mixed` keeps the plan's level 1 beside the design (the `level_one_fit` example's
//! `mixed` rows: a smaller photo level plus the design of the remaining count).

use glam::DVec3;
use gonio::brdf::grid::NodeLayout;
use gonio::plan::{LevelSummary, Plan};
use gonio::reconstruct::{LevelNodes, Levels};

/// The photo plan with its level 1 replaced by designed directions.
pub struct Designed<'a> {
    plan: &'a Plan,
    /// (slice, wi, wo) of each designed direction, in measurement order.
    design: Vec<(usize, DVec3, DVec3)>,
    /// Instrument seconds of measuring the design from the rest pose.
    design_seconds: f64,
    /// Directions of the plan's own level 1 never measured (all of them, or none when mixed).
    skipped: usize,
}

impl<'a> Designed<'a> {
    /// None unless the plan has a level and every designed direction lies above the horizon.
    pub fn new(plan: &'a Plan, pairs: &[(DVec3, DVec3)], design_seconds: f64) -> Option<Self> {
        let skipped = plan.levels.first()?.cumulative_directions;
        Self::with_skipped(plan, pairs, design_seconds, skipped)
    }

    /// Trial `mixed`: the design measured before the plan's own level 1, which is kept; level 1
    /// is both (fitted alone, as the plan's level 1 is). Times add (the design is not re-ordered
    /// with the plan's level: an upper bound).
    pub fn mixed(plan: &'a Plan, pairs: &[(DVec3, DVec3)], design_seconds: f64) -> Option<Self> {
        plan.levels.first()?;
        Self::with_skipped(plan, pairs, design_seconds, 0)
    }

    fn with_skipped(plan: &'a Plan, pairs: &[(DVec3, DVec3)], design_seconds: f64, skipped: usize) -> Option<Self> {
        let nearest = |wi: DVec3| {
            let theta = wi.z.clamp(-1.0, 1.0).acos();
            (0..plan.thetas.len()).min_by(|&a, &b| {
                (plan.thetas[a] - theta)
                    .abs()
                    .total_cmp(&(plan.thetas[b] - theta).abs())
            })
        };
        let design = pairs
            .iter()
            .map(|&(wi, wo)| {
                if wi.z > 0.0 && wo.z > 0.0 {
                    nearest(wi).map(|k| (k, wi, wo))
                } else {
                    None
                }
            })
            .collect::<Option<Vec<_>>>()?;
        Some(Self {
            plan,
            design,
            design_seconds,
            skipped,
        })
    }

    /// The per-level summaries: the design as level 1, then the plan's later levels after it
    /// (times: the design's, plus the plan's later levels as planned from the rest pose).
    pub fn levels(&self) -> Vec<LevelSummary> {
        let Some(p1) = self.plan.levels.first() else {
            return Vec::new();
        };
        let d = self.design.len();
        // Seconds of the plan's level 1 this run does not spend.
        let (skipped_s, skipped_raster) = match self.skipped {
            0 => (0.0, 0.0),
            _ => (p1.cumulative_seconds, p1.cumulative_raster_seconds),
        };
        let mut first = p1.clone();
        first.cumulative_directions = d + p1.cumulative_directions - self.skipped;
        first.first = 0;
        first.count = first.cumulative_directions;
        first.cumulative_seconds = self.design_seconds + p1.cumulative_seconds - skipped_s;
        first.cumulative_raster_seconds = self.design_seconds + p1.cumulative_raster_seconds - skipped_raster;
        let mut out = vec![first];
        for l in self.plan.levels.iter().skip(1) {
            let mut s = l.clone();
            s.cumulative_directions = d + l.cumulative_directions - self.skipped;
            s.first = d + l.first - self.skipped;
            s.cumulative_seconds = self.design_seconds + l.cumulative_seconds - skipped_s;
            s.cumulative_raster_seconds = self.design_seconds + l.cumulative_raster_seconds - skipped_raster;
            out.push(s);
        }
        out
    }

    /// Every direction in measurement order: the design, then the plan's later levels.
    pub fn pairs(&self) -> Vec<(DVec3, DVec3)> {
        let design = self.design.iter().map(|&(_, wi, wo)| (wi, wo));
        let next = self.plan.directions[self.skipped..].iter().map(|d| (d.wi, d.wo));
        design.chain(next).collect()
    }
}

impl Levels for Designed<'_> {
    fn level_nodes(&self, level: usize) -> Option<LevelNodes<'_>> {
        let nodes = self.plan.level_nodes(level)?;
        let d = self.design.len();
        if level <= 1 && self.skipped > 0 {
            // The fitted prior alone: a two-ring far-ring level keeps no residual grid.
            return Some(LevelNodes {
                layout: NodeLayout::NestedFarRing,
                node_measurement: vec![None; nodes.node_measurement.len()],
                measured: self.design.clone(),
                ..nodes
            });
        }
        let mut measured = self.design.clone();
        measured.extend_from_slice(nodes.measured.get(self.skipped..)?);
        let node_measurement = nodes
            .node_measurement
            .iter()
            .map(|m| m.and_then(|i| i.checked_sub(self.skipped)).map(|i| d + i))
            .collect();
        Some(LevelNodes {
            node_measurement,
            measured,
            ..nodes
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::tradeoff::auto_plan;
    use gonio::brdf::frame::from_spherical;
    use gonio::brdf::{parse_material, Material};

    /// `n` pairs above the horizon: pair i's incoming at polar angle `ti.0 + i ti.1` (phi 0), its
    /// outgoing at polar angle `to.0` and azimuth `i to.1`.
    fn fan(n: usize, ti: (f64, f64), to: (f64, f64)) -> Vec<(DVec3, DVec3)> {
        (0..n)
            .map(|i| {
                let i = i as f64;
                (from_spherical(ti.0 + i * ti.1, 0.0), from_spherical(to.0, i * to.1))
            })
            .collect()
    }
    use gonio::reconstruct::reconstruct;

    /// The design is level 1 and stays in every later level; the plan's level-1 nodes are read as
    /// unmeasured; counts never exceed the plan's; every level reconstructs finitely.
    #[test]
    fn the_design_replaces_level_one_and_stays_measured() {
        let plan = auto_plan(0.02, 3);
        let c1 = plan.levels[0].cumulative_directions;
        let pairs = fan(c1, (0.1, 0.05), (0.3, 0.2));
        let designed = Designed::new(&plan, &pairs, 10.0).unwrap();
        let levels = designed.levels();
        let all = designed.pairs();
        assert_eq!(levels.len(), 3);
        assert_eq!(levels[0].cumulative_directions, c1);
        assert_eq!(levels.last().unwrap().cumulative_directions, all.len());
        for (a, p) in levels.iter().zip(&plan.levels) {
            assert!(a.cumulative_directions <= p.cumulative_directions);
        }
        assert_eq!(&all[..c1], &pairs[..]);
        let truth = parse_material("ggx:alpha=0.05,diffuse=0.3,specular=1").unwrap();
        let values: Vec<_> = all.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        for l in &levels {
            let nodes = designed.level_nodes(l.level).unwrap();
            assert_eq!(nodes.measured.len(), l.cumulative_directions);
            assert_eq!(
                &nodes.measured[..c1].iter().map(|m| (m.1, m.2)).collect::<Vec<_>>(),
                &pairs
            );
            for &m in nodes.node_measurement.iter().flatten() {
                assert!(m >= c1, "a node reads a designed direction");
                assert!(m < l.cumulative_directions);
            }
            let rec = reconstruct(&designed, l.level, &values[..l.cumulative_directions]).unwrap();
            assert!(rec.eval(pairs[0].0, pairs[0].1).is_finite());
        }
        let below = [(DVec3::new(0.0, 0.0, -1.0), DVec3::Z)];
        assert!(Designed::new(&plan, &below, 1.0).is_none());
        assert!(Designed::mixed(&plan, &below, 1.0).is_none());
    }

    /// Mixed: the design is measured first and the plan's level 1 is kept, so every level holds
    /// the plan's own measurements behind the design's, its nodes read the plan's directions, and
    /// counts and seconds are the plan's plus the design's.
    #[test]
    fn mixed_keeps_the_plans_first_level_beside_the_design() {
        let plan = auto_plan(0.02, 2);
        let pairs = fan(5, (0.2, 0.1), (0.5, 0.9));
        let mixed = Designed::mixed(&plan, &pairs, 7.0).unwrap();
        let levels = mixed.levels();
        let all = mixed.pairs();
        assert_eq!(all.len(), 5 + plan.directions.len());
        assert_eq!(&all[..5], &pairs[..]);
        for (a, p) in levels.iter().zip(&plan.levels) {
            assert_eq!(a.cumulative_directions, 5 + p.cumulative_directions);
            assert!((a.cumulative_seconds - (7.0 + p.cumulative_seconds)).abs() < 1e-9);
            let nodes = mixed.level_nodes(a.level).unwrap();
            let own = plan.level_nodes(a.level).unwrap();
            assert_eq!(nodes.layout, own.layout);
            assert_eq!(nodes.measured.len(), a.cumulative_directions);
            for (m, o) in nodes.node_measurement.iter().zip(&own.node_measurement) {
                assert_eq!(*m, o.map(|i| i + 5));
                if let Some(m) = m {
                    assert_eq!(nodes.measured[*m], own.measured[m - 5]);
                }
            }
        }
        let truth = parse_material("ggx:alpha=0.05,diffuse=0.3,specular=1").unwrap();
        let values: Vec<_> = all.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        let rec = reconstruct(&mixed, 1, &values[..levels[0].cumulative_directions]).unwrap();
        assert!(rec.eval(pairs[0].0, pairs[0].1).is_finite());
    }
}
