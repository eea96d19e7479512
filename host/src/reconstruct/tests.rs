use super::*;
use crate::brdf::analytic::Ggx;
use crate::brdf::frame::from_spherical;
use crate::brdf::warp::WarpKind;

/// A hand-made level: `k` uniform slices of 2 x 2 nodes, every node measured (nothing planned).
struct Uniform2x2 {
    slices: Vec<SliceWarp>,
    thetas: Vec<f64>,
    measured: Vec<(usize, DVec3, DVec3)>,
}

impl Uniform2x2 {
    fn new(thetas: Vec<f64>) -> Self {
        let slices: Vec<SliceWarp> = thetas
            .iter()
            .map(|&t| WarpKind::Uniform.for_incident(from_spherical(t, 0.0)))
            .collect();
        let grid = MeasurementGrid::from_slices(
            slices.clone(),
            NodeLayout::Nested,
            thetas.clone(),
            2,
            2,
            vec![DVec3::ZERO; thetas.len() * 4],
            vec![false; thetas.len() * 4],
        )
        .expect("grid");
        let mut measured = Vec::new();
        for k in 0..thetas.len() {
            for j in 0..2 {
                for i in 0..2 {
                    let (wi, wo) = grid.node_directions(k, i, j).expect("node above the horizon");
                    measured.push((k, wi, wo));
                }
            }
        }
        Self {
            slices,
            thetas,
            measured,
        }
    }
}

impl Levels for Uniform2x2 {
    fn level_nodes(&self, level: usize) -> Option<LevelNodes<'_>> {
        (level == 1).then(|| LevelNodes {
            slices: &self.slices,
            thetas: &self.thetas,
            layout: NodeLayout::Nested,
            n: 2,
            m: 2,
            node_measurement: (0..self.measured.len()).map(Some).collect(),
            measured: self.measured.clone(),
            estimate_alpha: 0.2,
            blocked_cone: 0.0,
        })
    }
}

/// A GGX lobe of roughness `alpha` on a coloured diffuse base: a truth two lobes fit.
fn coloured_ggx(alpha: f64) -> Ggx {
    Ggx {
        alpha,
        diffuse: DVec3::new(0.3, 0.2, 0.1),
        specular: DVec3::ONE,
    }
}

/// The ratio space maps back to the value it came from at the extremes: 0, far under the floor, a
/// mirror peak; a negative (noisy) reading comes back as 0.
#[test]
fn the_ratio_space_inverts_at_the_extremes() {
    for f in [0.0, 1e-9, RATIO_FLOOR, 0.3, 1e4] {
        let v = DVec3::new(f, 2.0 * f, 0.5 * f);
        let back = inverse(forward(v));
        assert!(
            back.is_finite() && (back - v).abs().max_element() <= 1e-12 * (1.0 + v.max_element()),
            "{f}: {back}"
        );
    }
    assert!(inverse(forward(DVec3::splat(-0.1))).abs().max_element() < 1e-15);
}

#[test]
fn only_the_far_ring_first_level_is_the_fit_alone() {
    assert!(!level_keeps_residual(NodeLayout::NestedFarRing, 2));
    assert!(level_keeps_residual(NodeLayout::NestedFarRing, 4));
    assert!(level_keeps_residual(NodeLayout::Nested, 2));
}

/// A subset keeps the accepted measurements in order, renumbered, with their own values; the
/// nodes of the others read as unmeasured, and the subset reconstructs (a skipped node is filled).
#[test]
fn a_subset_keeps_its_measurements_renumbered_and_reconstructs() {
    let level = Uniform2x2::new(vec![0.0, 0.6, 1.2]);
    let values: Vec<DVec3> = (0..level.measured.len())
        .map(|d| DVec3::splat(0.1 + d as f64))
        .collect();
    let nodes = level.level_nodes(1).expect("level");
    let (half, kept) = nodes.subset(&values, |d| d % 2 == 1);
    assert_eq!(half.measured.len(), 6);
    assert_eq!(kept, (0..6).map(|i| values[2 * i + 1]).collect::<Vec<_>>());
    for (node, d) in half.node_measurement.iter().enumerate() {
        // Node `node` was measurement `node` in the full level.
        assert_eq!(*d, (node % 2 == 1).then_some(node / 2), "node {node}");
    }
    assert_eq!(half.measured[2], nodes.measured[5]);
    let rec = reconstruct_with(&SingleLevel { level: 1, nodes: half }, 1, &kept, &NoPrior).expect("rec");
    for (d, &(_, wi, wo)) in level.measured.iter().enumerate().filter(|(d, _)| d % 2 == 1) {
        assert!(
            (rec.eval(wi, wo) - values[d]).abs().max_element() < 1e-9,
            "measurement {d}"
        );
    }
    assert!(rec.eval(level.measured[0].1, level.measured[0].2).is_finite());
    // Nothing kept: an empty subset.
    let (none, v) = nodes.subset(&values, |_| false);
    assert!(none.measured.is_empty() && v.is_empty() && none.node_measurement.iter().all(Option::is_none));
}

/// At every node the reconstruction returns its measurement, with a prior and without.
#[test]
fn a_node_returns_its_measurement() {
    let level = Uniform2x2::new(vec![0.0, 0.6, 1.2]);
    let truth = coloured_ggx(0.3);
    let values: Vec<DVec3> = level.measured.iter().map(|&(_, wi, wo)| truth.eval(wi, wo)).collect();
    for prior in [&NoPrior as &dyn Prior, &TwoLobesPrior] {
        let rec = reconstruct_with(&level, 1, &values, prior).expect("rec");
        assert_eq!(rec.prior().is_some(), prior.name() == "two-lobes");
        for (&(_, wi, wo), v) in level.measured.iter().zip(&values) {
            let r = rec.eval(wi, wo);
            assert!(
                (r - *v).abs().max_element() < 1e-9 * (1.0 + v.max_element()),
                "{}: {r} vs {v}",
                prior.name()
            );
        }
    }
}

#[test]
fn a_missing_level_or_too_few_values_is_an_error() {
    let level = Uniform2x2::new(vec![0.0, 0.6]);
    let values = vec![DVec3::splat(0.1); level.measured.len()];
    assert!(matches!(
        reconstruct(&level, 2, &values),
        Err(ReconstructError::NoLevel(2))
    ));
    assert!(matches!(
        reconstruct(&level, 1, &values[1..]),
        Err(ReconstructError::TooFewValues { need: 8, got: 7, .. })
    ));
}

/// The sharp-lobe floor is the smaller share of the estimate and of what the samples resolve.
#[test]
fn the_sharp_lobe_floor_never_exceeds_a_share_of_the_estimate() {
    let level = Uniform2x2::new(vec![0.0, 0.6, 1.2]);
    let pairs: Vec<(DVec3, DVec3)> = level.measured.iter().map(|&(_, wi, wo)| (wi, wo)).collect();
    for alpha in [1e-4, 0.05, 1.0] {
        let f = prior::sharp_lobe_floor(alpha, &pairs);
        assert!(
            f.is_finite() && f >= 0.0 && f <= SHARP_FLOOR_SHARE * alpha,
            "{alpha}: {f}"
        );
    }
}

/// On mixture slices the residual reads the query lookup where the prior is all lobes, each
/// slice's own warp where it has none, and a blend in between; on uniform slices both agree.
#[test]
fn the_residual_lookup_follows_the_lobes_share() {
    use crate::brdf::fit_lobes::TwoLobes;
    use crate::brdf::warp::MixtureWarp;
    let estimate = Ggx {
        alpha: 0.05,
        diffuse: DVec3::splat(0.2),
        specular: DVec3::ONE,
    };
    let thetas = vec![0.3, 0.9];
    let slices: Vec<SliceWarp> = thetas
        .iter()
        .map(|&t| {
            let wi = from_spherical(t, 0.0);
            SliceWarp::Mixture(std::sync::Arc::new(MixtureWarp::new(wi, 0.05, &estimate, 33)))
        })
        .collect();
    let (n, m) = (4, 4);
    let mut grid = MeasurementGrid::from_slices(
        slices.clone(),
        NodeLayout::Nested,
        thetas.clone(),
        n,
        m,
        vec![DVec3::ZERO; 2 * n * m],
        vec![false; 2 * n * m],
    )
    .expect("grid");
    // A residual that varies across nodes, so the two lookups differ.
    for k in 0..2 {
        for j in 0..m {
            for i in 0..n {
                let r = 0.1 * (i as f64) - 0.05 * (j as f64) + 0.2 * k as f64;
                grid.set_node(k, i, j, Some(DVec3::new(r, 0.5 * r, -r)));
            }
        }
    }
    let lobes = |diffuse: f64, lobe: f64| TwoLobes {
        diffuse: DVec3::splat(diffuse),
        sharp_alpha: 0.05,
        sharp: DVec3::splat(lobe),
        broad_alpha: 0.3,
        broad: DVec3::splat(lobe),
        sharp_grazing: DVec3::splat(lobe),
        broad_grazing: DVec3::splat(lobe),
        coated: DVec3::ZERO,
    };
    let rec = |prior: TwoLobes| Reconstruction {
        grid: grid.clone(),
        slices: slices.clone(),
        prior: Some(FittedPrior::TwoLobes(prior)),
    };
    let (wi, wo) = (from_spherical(0.6, 0.0), from_spherical(1.2, 2.5));
    let lookup = |k: usize, wi: DVec3, wo: DVec3| match slices.get(k)? {
        SliceWarp::Mixture(w) => w.invert_from(wi, wo),
        other => other.invert(wo),
    };
    let query = grid.eval_guided(wi, wo, Some(&lookup), None);
    let own = grid.eval(wi, wo);
    assert!(
        (query - own).abs().max_element() > 1e-3,
        "the lookups must differ here: {query} {own}"
    );
    assert_eq!(
        rec(lobes(0.0, 1.0)).residual(wi, wo, None),
        query,
        "all lobes: the query lookup"
    );
    assert_eq!(
        rec(lobes(0.5, 0.0)).residual(wi, wo, None),
        own,
        "no lobe: the slice's own warp"
    );
    let mixed = lobes(0.5, 1.0);
    let s = mixed.lobe_share(wi, wo);
    assert!(s > 0.0 && s < 1.0, "{s}");
    let v = rec(mixed).residual(wi, wo, None);
    assert!((v - (s * query + (1.0 - s) * own)).abs().max_element() < 1e-12, "{v}");
    // Uniform slices: one lookup, whatever the prior.
    let uniform = Uniform2x2::new(vec![0.2, 0.8]);
    let values = vec![DVec3::splat(0.3); uniform.measured.len()];
    let r = reconstruct_with(&uniform, 1, &values, &TwoLobesPrior).expect("reconstruct");
    assert_eq!(r.residual(wi, wo, None), r.grid().eval(wi, wo));
}

/// The reconstruction guides its residual lookup by the prior (`GUIDE_WIDTH`): between nodes whose
/// priors differ it departs from the plain bilinear lookup, and at the nodes it still returns
/// each measurement.
#[test]
fn the_reconstruction_guides_its_lookup_by_the_prior() {
    let level = Uniform2x2::new(vec![0.0, 0.6, 1.2]);
    let truth = coloured_ggx(0.15);
    // A misfit the prior cannot follow: one node 3x too dark.
    let values: Vec<DVec3> = level
        .measured
        .iter()
        .enumerate()
        .map(|(d, &(_, wi, wo))| truth.eval(wi, wo) * if d == 5 { 0.3 } else { 1.0 })
        .collect();
    let rec = reconstruct_with(&level, 1, &values, &TwoLobesPrior).expect("rec");
    let prior = rec.prior().expect("fitted").clone();
    let plain = |wi: DVec3, wo: DVec3| inverse(forward(prior.eval(wi, wo)) + rec.grid().eval(wi, wo)).max(DVec3::ZERO);
    let mut departs = 0.0f64;
    for t in 1..12 {
        let (wi, wo) = (
            from_spherical(0.3, 0.0),
            from_spherical(0.1 * t as f64, 0.5 + 0.2 * t as f64),
        );
        let (g, p) = (rec.eval(wi, wo), plain(wi, wo));
        assert!(g.is_finite() && g.min_element() >= 0.0, "{g}");
        departs = departs.max(((g - p).abs() / (p + DVec3::splat(1e-3))).max_element());
    }
    assert!(
        departs > 1e-3,
        "the guided lookup never departs from bilinear: {departs}"
    );
    for (&(_, wi, wo), v) in level.measured.iter().zip(&values) {
        let r = rec.eval(wi, wo);
        assert!(
            (r - *v).abs().max_element() < 1e-9 * (1.0 + v.max_element()),
            "{r} vs {v}"
        );
    }
}
