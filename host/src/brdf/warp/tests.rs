//! The warp stability suite: round trips, extremes, pdf normalisation and chi-square fits, for every
//! warp at alpha in {0.01, 0.05, 0.2, 0.5, 1} and theta_i in {0, 30, 60, 85} degrees.

use super::*;
use crate::brdf::chi2::{chi2_test, Chi2Config, Domain};
use crate::brdf::frame::{from_spherical, ONE_MINUS_EPSILON};
use crate::brdf::roughness::MIRROR_ALPHA;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

const ALPHAS: [f64; 5] = [0.01, 0.05, 0.2, 0.5, 1.0];
const THETAS_DEG: [f64; 4] = [0.0, 30.0, 60.0, 85.0];

fn kinds(alpha: f64) -> [WarpKind; 3] {
    [
        WarpKind::Ward { alpha },
        WarpKind::GgxNdf { alpha },
        WarpKind::GgxVndf { alpha },
    ]
}

/// Every (warp, alpha, theta_i) of the suite, the cosine warp once per theta_i.
fn suite() -> Vec<(WarpKind, f64)> {
    let mut all = Vec::new();
    for t in THETAS_DEG {
        all.push((WarpKind::Cosine, t));
        for a in ALPHAS {
            for k in kinds(a) {
                all.push((k, t));
            }
        }
    }
    all
}

/// How well u.y (the azimuth) is defined at u: it degenerates where the sampled normal (or
/// direction) reaches the pole, u.x -> 0 for the disk-like warps, u.x -> 1 for Ward's.
fn azimuth_radius(kind: WarpKind, u: DVec2) -> f64 {
    match kind {
        WarpKind::Ward { .. } => (-u.x.ln()).sqrt().min(1.0),
        _ => u.x.sqrt(),
    }
}

fn circular_distance(a: f64, b: f64) -> f64 {
    let d = (a - b).abs();
    d.min(1.0 - d)
}

/// invert(sample(u)) = u on a 33 x 33 grid that includes 0 and 1 - eps, and sample(invert(w)) = w on
/// random directions. Tolerance: 1e-9 on u.x and on u.y times the azimuth radius (the azimuth of a
/// normal at the pole carries no information), 1e-9 on directions. Pairs with |wi + wo| < 1e-6 are
/// skipped for the u check (and counted): there the half vector, which invert recovers from that
/// sum, has lost ~eps / |wi + wo| of its precision to cancellation; this happens only at grazing wi.
#[test]
fn round_trips() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let grid: Vec<f64> = (0..33)
        .map(|i| if i == 32 { ONE_MINUS_EPSILON } else { i as f64 / 32.0 })
        .collect();
    let (mut checked, mut ill_conditioned) = (0usize, 0usize);
    for t in THETAS_DEG.iter().chain(&[89.9, 90.0]) {
        let wi = from_spherical(t.to_radians(), 0.0);
        for a in ALPHAS {
            for kind in kinds(a).into_iter().chain([WarpKind::Cosine]) {
                let warp = kind.for_incident(wi);
                for &u1 in &grid {
                    for &u2 in &grid {
                        let u = DVec2::new(u1, u2);
                        let Some(w) = warp.sample(u) else { continue };
                        if kind != WarpKind::Cosine && (wi + w).length() < 1e-6 {
                            ill_conditioned += 1;
                            continue;
                        }
                        let back = warp
                            .invert(w)
                            .unwrap_or_else(|| panic!("{kind} theta {t}: invert(sample({u})) is None"));
                        let e1 = (back.x - u.x).abs();
                        let e2 = circular_distance(back.y, u.y) * azimuth_radius(kind, u);
                        assert!(e1 < 1e-9 && e2 < 1e-9, "{kind} theta {t}: u {u} -> {w} -> {back}");
                        checked += 1;
                    }
                }
                for _ in 0..200 {
                    let w = from_spherical(rng.random::<f64>().acos(), 2.0 * PI * rng.random::<f64>());
                    let Some(u) = warp.invert(w) else { continue };
                    let again = warp
                        .sample(u)
                        .unwrap_or_else(|| panic!("{kind} theta {t}: sample(invert({w})) is None"));
                    assert!((again - w).length() < 1e-9, "{kind} theta {t}: {w} -> {u} -> {again}");
                    checked += 1;
                }
            }
        }
    }
    println!("round trips checked: {checked}, skipped as ill-conditioned: {ill_conditioned}");
    assert!(checked > 100_000, "only {checked} round trips were valid");
    assert!(
        ill_conditioned < checked / 100,
        "{ill_conditioned} ill-conditioned pairs"
    );
}

/// Extremes: alpha in {0, 1e-6, 1e-4, just below and above MIRROR_ALPHA, 1}, theta_i and theta_o in
/// {0, 89.9, 90} degrees, u at the corners and edges of the square: everything finite, pdf >= 0,
/// and below the threshold the deterministic mirror (same direction for every u, pdf 0, no inverse).
#[test]
fn extremes_are_finite_and_switch_to_the_mirror() {
    let angles = [0.0_f64, 89.9, 90.0].map(f64::to_radians);
    let edge = [0.0, 0.5, ONE_MINUS_EPSILON, 1.0, -1.0, f64::NAN];
    let alphas = [0.0, 1e-6, 1e-4, 0.999 * MIRROR_ALPHA, 1.001 * MIRROR_ALPHA, 1.0];
    for alpha in alphas {
        let mirror = alpha < MIRROR_ALPHA;
        for &ti in &angles {
            let wi = from_spherical(ti, 0.0);
            for kind in kinds(alpha) {
                let warp = kind.for_incident(wi);
                assert_eq!(warp.is_delta(), mirror, "{kind}");
                let first = warp.sample(DVec2::ZERO);
                for &u1 in &edge {
                    for &u2 in &edge {
                        let s = warp.sample(DVec2::new(u1, u2));
                        if let Some(w) = s {
                            assert!(w.is_finite() && w.z > 0.0, "{kind} ti {ti}: sample {w}");
                            let back = warp.invert(w);
                            if let Some(u) = back {
                                assert!(u.is_finite() && u.min_element() >= 0.0 && u.max_element() < 1.0);
                            }
                        }
                        if mirror {
                            assert_eq!(s, first, "{kind}: the mirror limit must not depend on u");
                        }
                    }
                }
                for &to in &angles {
                    for phi in [0.0, 0.5 * PI, PI] {
                        let wo = from_spherical(to, phi);
                        let p = warp.pdf(wo);
                        assert!(p.is_finite() && p >= 0.0, "{kind} ti {ti} to {to}: pdf {p}");
                        if mirror {
                            assert_eq!(p, 0.0);
                            assert_eq!(warp.invert(wo), None);
                        } else if let Some(u) = warp.invert(wo) {
                            assert!(u.is_finite() && u.min_element() >= 0.0 && u.max_element() < 1.0);
                        }
                    }
                }
            }
        }
    }
    // The mirror direction itself, where it exists.
    let wi = from_spherical(0.4, 0.3);
    let m = WarpKind::GgxVndf { alpha: 0.0 }
        .for_incident(wi)
        .sample(DVec2::splat(0.3));
    assert_eq!(m, Some(DVec3::new(-wi.x, -wi.y, wi.z)));
}

/// Probability that `sample` is invalid, by adaptive subdivision of the u-square: a cell whose
/// corners and centre agree (from depth 4 on) is taken as wholly valid or invalid; cells on the
/// boundary are split down to 2^-11 and then counted by the fraction of their five points.
fn invalid_probability(warp: &SliceWarp) -> f64 {
    fn cell(warp: &SliceWarp, x0: f64, y0: f64, size: f64, depth: u32) -> f64 {
        let pts = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)];
        let bad = pts
            .iter()
            .filter(|(a, b)| warp.sample(DVec2::new(x0 + a * size, y0 + b * size)).is_none())
            .count();
        if depth >= 4 && (bad == 0 || bad == pts.len()) {
            return if bad == 0 { 0.0 } else { size * size };
        }
        if depth >= 11 {
            return size * size * bad as f64 / pts.len() as f64;
        }
        let h = 0.5 * size;
        cell(warp, x0, y0, h, depth + 1)
            + cell(warp, x0 + h, y0, h, depth + 1)
            + cell(warp, x0, y0 + h, h, depth + 1)
            + cell(warp, x0 + h, y0 + h, h, depth + 1)
    }
    cell(warp, 0.0, 0.0, 1.0, 0)
}

/// The chi-square suite, which also checks that the pdf integrates to 1: the integral of the pdf over
/// the hemisphere plus the probability of an invalid sample is 1 within 2e-3 (quadrature of the pdf
/// to ~1e-8 per cell; the invalid area to ~2^-11 times the length of its boundary).
/// Lobes with alpha <= 0.05 fill only a few hemisphere cells, so they are tested a second time on a
/// cap of radius 8 alpha about the mirror direction, where the same 24 x 48 cells resolve them.
#[test]
fn chi_square_and_normalisation() {
    let cases = suite();
    let narrow = |kind: WarpKind| match kind {
        WarpKind::Cosine | WarpKind::Uniform => None,
        WarpKind::Ward { alpha } | WarpKind::GgxNdf { alpha } | WarpKind::GgxVndf { alpha } => {
            (alpha <= 0.05).then_some(8.0 * alpha)
        }
    };
    let test_count = cases.len() + cases.iter().filter(|(k, _)| narrow(*k).is_some()).count();
    let cfg = |seed: u64| Chi2Config {
        res_z: 24,
        res_phi: 48,
        samples: 100_000,
        seed,
        significance: 0.01,
        test_count,
    };
    let mut failures = Vec::new();
    let mut table = String::from(
        "warp                     theta_i    chi2   dof   p-value   pdf-int   invalid(mc)  invalid(area)\n",
    );
    let mut cap_table = String::from(
        "cap of 8 alpha about the mirror direction:\nwarp                     theta_i    chi2   dof   p-value   pdf-cap   outside(mc)\n",
    );
    for (i, &(kind, t)) in cases.iter().enumerate() {
        let wi = from_spherical(t.to_radians(), 0.0);
        let warp = kind.for_incident(wi);
        let sample = |u: DVec2| warp.sample(u);
        let pdf = |w: DVec3| warp.pdf(w);
        let name = format!("{kind} theta_i {t}");
        let out = chi2_test(&name, &sample, &pdf, &Domain::Hemisphere, &cfg(1000 + i as u64));
        let p_invalid = invalid_probability(&warp);
        table += &format!(
            "{:<24} {:>7} {:>7.1} {:>5} {:>9.3} {:>9.5} {:>12.5} {:>14.5}\n",
            kind.to_string(),
            t,
            out.statistic,
            out.dof,
            out.p_value,
            out.pdf_integral,
            out.outside_fraction,
            p_invalid
        );
        if !out.passed() {
            failures.push(out.report.clone());
        }
        if (out.pdf_integral + p_invalid - 1.0).abs() > 2e-3 {
            failures.push(format!(
                "{name}: pdf integral {} + invalid {p_invalid} != 1",
                out.pdf_integral
            ));
        }
        if let Some(radius) = narrow(kind) {
            let cap = Domain::Cap {
                axis: DVec3::new(-wi.x, -wi.y, wi.z),
                radius,
            };
            let c = chi2_test(&format!("{name} cap"), &sample, &pdf, &cap, &cfg(5000 + i as u64));
            cap_table += &format!(
                "{:<24} {:>7} {:>7.1} {:>5} {:>9.3} {:>9.5} {:>12.5}\n",
                kind.to_string(),
                t,
                c.statistic,
                c.dof,
                c.p_value,
                c.pdf_integral,
                c.outside_fraction
            );
            if !c.passed() {
                failures.push(c.report.clone());
            }
        }
    }
    let threshold = 1.0 - 0.99_f64.powf(1.0 / test_count as f64);
    table += &cap_table;
    println!(
        "{table}Sidak-corrected per-test threshold: p < {threshold:.2e} fails ({test_count} tests, family-wise 0.01)"
    );
    assert!(
        failures.is_empty(),
        "{} failures:\n{}\n{table}",
        failures.len(),
        failures.join("\n")
    );
}
