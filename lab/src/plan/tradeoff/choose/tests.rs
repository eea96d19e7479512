use super::*;
use gonio::brdf::frame::from_spherical;
use gonio::instrument::default_instrument;
use gonio::plan::{ggx_estimate, square_grids};
use gonio::reconstruct::Reconstruction;

/// A sharp estimate (the mixture warp, `NestedFarRing`) and a rough one (the uniform grid).
const ALPHAS: [f64; 2] = [0.03, 0.3];

fn planner(alpha: f64) -> Planner {
    Planner::new(default_instrument(), ggx_estimate(alpha, 0.1)).expect("planner")
}

fn truth() -> Box<dyn Material> {
    ggx_estimate(0.08, 0.2).material()
}

/// The reconstructions agree at a spread of direction pairs.
fn assert_same(a: &Reconstruction, b: &Reconstruction, what: &str) {
    for ti in [0.0f64, 20.0, 47.0, 80.0] {
        for (to, po) in [(0.0f64, 0.0f64), (30.0, 10.0), (55.0, 170.0), (75.0, 260.0)] {
            let wi = from_spherical(ti.to_radians(), 0.3);
            let wo = from_spherical(to.to_radians(), po.to_radians());
            let (x, y) = (a.eval(wi, wo), b.eval(wi, wo));
            assert!(
                (x - y).abs().max_element() <= 1e-12 * (1.0 + x.abs().max_element()),
                "{what}: {x} vs {y}"
            );
        }
    }
}

fn measured(alpha: f64, schedule: &[(usize, usize)], fine_n: usize) -> (Plan, Vec<DVec3>) {
    let plan = planner(alpha)
        .plan(&config(Strategy::Auto, schedule, fine_n))
        .expect("plan");
    let values = plan.measure(truth().as_ref());
    (plan, values)
}

/// Nothing left out: the subset wrapper reconstructs exactly as the plan.
#[test]
fn leave_out_of_nothing_reconstructs_identically() {
    for alpha in ALPHAS {
        let (plan, values) = measured(alpha, &[(8, 2), (8, 4), (15, 4)], 8);
        for level in 1..=3 {
            let k = plan.level_nodes(level).unwrap().thetas.len();
            let all: Vec<usize> = (0..k).collect();
            let l = LeaveOut::new(&plan, level, &values, &all, false).expect("leave-out");
            assert_eq!(l.values.len(), plan.levels[level - 1].cumulative_directions);
            let a = reconstruct(&plan, level, &values).unwrap();
            let b = reconstruct(&l, level, &l.values).unwrap();
            assert_same(&a, &b, &format!("alpha {alpha} level {level}"));
        }
    }
}

/// Halving the outgoing grid of a level that kept its elevations gives the previous level; leaving
/// out every other elevation of a level that went 8 -> 15 gives the previous level too.
#[test]
fn leave_outs_give_the_previous_level_where_it_nests() {
    for alpha in ALPHAS {
        let (plan, values) = measured(alpha, &[(8, 2), (8, 4), (15, 4)], 8);
        let all: Vec<usize> = (0..8).collect();
        let halved = LeaveOut::new(&plan, 2, &values, &all, true).expect("halved");
        assert_eq!(halved.values.len(), plan.levels[0].cumulative_directions);
        assert_same(
            &reconstruct(&plan, 1, &values).unwrap(),
            &reconstruct(&halved, 2, &halved.values).unwrap(),
            &format!("alpha {alpha}: 8x4 halved"),
        );
        let keep = alternate_slices(15).unwrap();
        assert_eq!(keep, (0..15).step_by(2).collect::<Vec<_>>());
        let alt = LeaveOut::new(&plan, 3, &values, &keep, false).expect("alternate");
        assert_eq!(alt.values.len(), plan.levels[1].cumulative_directions);
        assert_same(
            &reconstruct(&plan, 2, &values).unwrap(),
            &reconstruct(&alt, 3, &alt.values).unwrap(),
            &format!("alpha {alpha}: 15x4 without odd elevations"),
        );
        // No coarser grid below 2 x 2; no interior elevation below 3.
        assert!(LeaveOut::new(&plan, 1, &values, &all, true).is_none());
        assert_eq!(alternate_slices(2), None);
        assert_eq!(alternate_slices(8), Some(vec![0, 2, 4, 6, 7]));
    }
}

/// A padded schedule's levels are the levels of any longer schedule with the same prefix, and
/// 8 elevations at every level is today's plan (square grids to 16 x 16).
#[test]
fn a_prefix_plans_the_same_levels_as_longer_schedules() {
    let same = |a: &Plan, b: &Plan, levels: usize, what: &str| {
        let end = a.levels[levels - 1].cumulative_directions;
        assert_eq!(end, b.levels[levels - 1].cumulative_directions, "{what}");
        for (x, y) in a.directions[..end].iter().zip(&b.directions[..end]) {
            assert_eq!((x.wi, x.wo, x.seconds), (y.wi, y.wo, y.seconds), "{what}");
        }
        assert_eq!(
            a.levels[levels - 1].cumulative_seconds,
            b.levels[levels - 1].cumulative_seconds
        );
    };
    for alpha in ALPHAS {
        let p = planner(alpha);
        let today = p
            .plan(&PlanConfig {
                grids: square_grids(4),
                ..PlanConfig::default()
            })
            .unwrap();
        let prefix = p.plan(&config(Strategy::Auto, &[(8, 2), (8, 4)], 16)).unwrap();
        same(&prefix, &today, 2, "8x2,8x4 vs today");
        let full = p
            .plan(&config(Strategy::Auto, &[(8, 2), (8, 4), (8, 8), (8, 16)], 16))
            .unwrap();
        assert_eq!(full.levels.len(), 4, "no padding at N = 16");
        same(&full, &today, 4, "8 elevations vs today");
        let short = p.plan(&config(Strategy::Auto, &[(8, 2), (8, 4), (15, 4)], 16)).unwrap();
        let long = p
            .plan(&config(Strategy::Auto, &[(8, 2), (8, 4), (15, 4), (29, 4)], 16))
            .unwrap();
        same(&short, &long, 3, "15x4 prefix");
        same(&short, &today, 2, "15x4's first levels vs today");
    }
}

fn s(e_in: f64, e_out: f64) -> Option<Sensitivity> {
    Some(Sensitivity { e_in, e_out })
}

/// Elevations first when e_in dominates by c, outgoing otherwise, never past `K_MAX`, and
/// without sensitivities (level 1) outgoing.
#[test]
fn the_rule_refines_the_dimension_that_dominates() {
    assert_eq!(options((8, 4), s(0.03, 0.02), 1.0), vec![(15, 4), (8, 8)]);
    assert_eq!(options((8, 4), s(0.03, 0.02), 2.0), vec![(8, 8), (15, 4)]);
    assert_eq!(options((8, 4), s(0.01, 0.02), 1.0), vec![(8, 8), (15, 4)]);
    assert_eq!(options((15, 8), s(0.05, 0.0), f64::INFINITY), vec![(15, 16), (29, 8)]);
    assert_eq!(options((29, 4), s(0.05, 0.01), 0.5), vec![(29, 8)]);
    assert_eq!(options((8, 2), None, 0.0), vec![(8, 4), (15, 2)]);
}

/// The chosen schedule stays within the uniform grid's count at every level; where the preferred
/// option is above it the other is taken; c = inf is today's schedule.
#[test]
fn choices_hold_the_direction_cap() {
    let p = planner(0.3);
    let material = truth();
    let mut explorer = Explorer::new(&p, material.as_ref(), Strategy::Uniform, 8).unwrap();
    let uniform: Vec<usize> = explorer
        .plan(&[(8, 2), (8, 4), (8, 8)])
        .unwrap()
        .0
        .levels
        .iter()
        .map(|l| l.cumulative_directions)
        .collect();
    let today = explorer.choose(f64::INFINITY, 3, &uniform).unwrap();
    assert_eq!(today.schedule, vec![(8, 2), (8, 4), (8, 8)]);
    assert!(today.sensitivities[0].is_none(), "level 1 has no coarser grid");
    assert!(today.sensitivities[1].is_some());
    let eager = explorer.choose(0.0, 3, &uniform).unwrap();
    assert_eq!(eager.schedule[1], (8, 4), "level 2 refines the outgoing grid");
    for c in [0.0, 1.0, f64::INFINITY] {
        let choice = explorer.choose(c, 3, &uniform).unwrap();
        let plan = &explorer.plan(&choice.schedule).unwrap().0;
        for (l, u) in plan.levels.iter().zip(&uniform) {
            assert!(l.cumulative_directions <= *u, "c {c}: {:?}", choice.schedule);
        }
    }
    // A cap below 8 x 8's count at level 3 leaves (15, 4) whatever the sensitivities say.
    let tight = [uniform[0], uniform[1], uniform[2] - 1];
    let capped = explorer.choose(f64::INFINITY, 3, &tight).unwrap();
    assert_eq!(capped.schedule, vec![(8, 2), (8, 4), (15, 4)]);
}
