//! Chi-square goodness-of-fit harness for warps, after Mitsuba 3's `chi2.py`. The domain (the upper
//! hemisphere, or a spherical cap around an axis for narrow lobes) is cut into cells equal in solid
//! angle (uniform in cos theta and phi about the domain's axis), the pdf is integrated over each cell
//! by adaptive Gauss-Legendre quadrature (not read at the midpoint), samples that are invalid or fall
//! outside the domain form one more cell whose expected count is N (1 - integral of the pdf over the
//! domain), cells expecting fewer than 5 samples are pooled, and the p-value is compared with a
//! Sidak-corrected threshold. The tables are printed only when a test fails.

use glam::{DVec2, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;
use std::fmt::Write;

/// Where the cells are.
#[derive(Clone, Copy, Debug)]
pub enum Domain {
    /// The upper hemisphere about +z.
    Hemisphere,
    /// The cap of angular `radius` about the unit `axis`, clipped by the pdf itself (0 below the
    /// horizon). Resolves lobes too narrow for hemisphere cells.
    Cap { axis: DVec3, radius: f64 },
}

impl Domain {
    /// Orthonormal frame (t1, t2, axis) and the range of cos theta about the axis.
    fn frame(&self) -> ([DVec3; 3], f64) {
        match *self {
            Domain::Hemisphere => ([DVec3::X, DVec3::Y, DVec3::Z], 0.0),
            Domain::Cap { axis, radius } => {
                let n = axis.normalize();
                let t1 = n.any_orthonormal_vector();
                ([t1, n.cross(t1), n], radius.cos())
            }
        }
    }
}

pub struct Chi2Config {
    pub res_z: usize,
    pub res_phi: usize,
    pub samples: usize,
    pub seed: u64,
    /// Family-wise significance level, split over `test_count` tests by Sidak's correction.
    pub significance: f64,
    pub test_count: usize,
}

pub struct Chi2Outcome {
    pub p_value: f64,
    pub dof: usize,
    pub statistic: f64,
    /// Integral of the pdf over the domain (sum of the cell integrals).
    pub pdf_integral: f64,
    /// Fraction of samples invalid or outside the domain.
    pub outside_fraction: f64,
    /// Empty unless the test failed: the observed and expected tables.
    pub report: String,
}

impl Chi2Outcome {
    pub fn passed(&self) -> bool {
        self.report.is_empty()
    }
}

const GL_NODES: [f64; 5] = [
    -0.906_179_845_938_664,
    -0.538_469_310_105_683_1,
    0.0,
    0.538_469_310_105_683_1,
    0.906_179_845_938_664,
];
const GL_WEIGHTS: [f64; 5] = [
    0.236_926_885_056_189_1,
    0.478_628_670_499_366_5,
    0.568_888_888_888_888_9,
    0.478_628_670_499_366_5,
    0.236_926_885_056_189_1,
];
const MAX_DEPTH: u32 = 12;

fn direction(frame: &[DVec3; 3], z: f64, phi: f64) -> DVec3 {
    let r = (1.0 - z * z).max(0.0).sqrt();
    frame[0] * (r * phi.cos()) + frame[1] * (r * phi.sin()) + frame[2] * z
}

/// 5x5 Gauss-Legendre rule over a (z, phi) rectangle about the frame's axis; dA = dz dphi is
/// exactly solid angle.
fn gauss(pdf: &dyn Fn(DVec3) -> f64, z: (f64, f64), p: (f64, f64)) -> f64 {
    let (hz, hp) = (0.5 * (z.1 - z.0), 0.5 * (p.1 - p.0));
    let (cz, cp) = (0.5 * (z.1 + z.0), 0.5 * (p.1 + p.0));
    let mut sum = 0.0;
    for (xi, wi) in GL_NODES.iter().zip(GL_WEIGHTS) {
        for (xj, wj) in GL_NODES.iter().zip(GL_WEIGHTS) {
            sum += wi * wj * pdf(DVec3::new(cz + hz * xi, cp + hp * xj, 0.0));
        }
    }
    sum * hz * hp
}

/// Integral over a rectangle: split in four until the four halves agree with the whole.
fn integrate(pdf: &dyn Fn(DVec3) -> f64, z: (f64, f64), p: (f64, f64), whole: f64, depth: u32) -> f64 {
    let (zm, pm) = (0.5 * (z.0 + z.1), 0.5 * (p.0 + p.1));
    let quads = [
        ((z.0, zm), (p.0, pm)),
        ((zm, z.1), (p.0, pm)),
        ((z.0, zm), (pm, p.1)),
        ((zm, z.1), (pm, p.1)),
    ];
    let parts = quads.map(|(qz, qp)| gauss(pdf, qz, qp));
    let sum: f64 = parts.iter().sum();
    if depth >= MAX_DEPTH || (sum - whole).abs() <= 1e-11_f64.max(1e-8 * sum.abs()) {
        return sum;
    }
    quads
        .iter()
        .zip(parts)
        .map(|(&(qz, qp), part)| integrate(pdf, qz, qp, part, depth + 1))
        .sum()
}

/// Regularised upper incomplete gamma Q(a, x) (Numerical Recipes: series below a + 1, Lentz
/// continued fraction above).
fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let ln_front = -x + a * x.ln() - ln_gamma(a);
    if x < a + 1.0 {
        let (mut term, mut sum, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - sum * ln_front.exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        ln_front.exp() * h
    }
}

/// ln Gamma(x) for x > 0 (Lanczos, g = 7, n = 9).
fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Run the test for one (sample, pdf) pair.
pub fn chi2_test(
    name: &str,
    sample: &dyn Fn(DVec2) -> Option<DVec3>,
    pdf: &dyn Fn(DVec3) -> f64,
    domain: &Domain,
    cfg: &Chi2Config,
) -> Chi2Outcome {
    let (nz, np) = (cfg.res_z, cfg.res_phi);
    let cells = nz * np;
    let (frame, z0) = domain.frame();
    // The quadrature passes (z, phi) about the axis packed in a vector; unpack to a direction here.
    let local_pdf = |zp: DVec3| pdf(direction(&frame, zp.x, zp.y));
    let z_edge = |iz: usize| z0 + (1.0 - z0) * iz as f64 / nz as f64;
    let cell_of = |w: DVec3| -> Option<usize> {
        let w = w.normalize();
        let local = DVec3::new(w.dot(frame[0]), w.dot(frame[1]), w.dot(frame[2]));
        if local.z < z0 {
            return None;
        }
        let iz = (((local.z - z0) / (1.0 - z0) * nz as f64) as usize).min(nz - 1);
        let phi = local.y.atan2(local.x).rem_euclid(2.0 * PI);
        let ip = ((phi / (2.0 * PI) * np as f64) as usize).min(np - 1);
        Some(iz * np + ip)
    };
    // Observed: the last slot counts invalid samples.
    let mut observed = vec![0.0_f64; cells + 1];
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    for _ in 0..cfg.samples {
        let u = DVec2::new(rng.random::<f64>(), rng.random::<f64>());
        match sample(u) {
            Some(w) if w.z > 0.0 && w.is_finite() => observed[cell_of(w).unwrap_or(cells)] += 1.0,
            _ => observed[cells] += 1.0,
        }
    }
    let n = cfg.samples as f64;
    let mut expected = vec![0.0_f64; cells + 1];
    for iz in 0..nz {
        for ip in 0..np {
            let z = (z_edge(iz), z_edge(iz + 1));
            let p = (2.0 * PI * ip as f64 / np as f64, 2.0 * PI * (ip + 1) as f64 / np as f64);
            let whole = gauss(&local_pdf, z, p);
            expected[iz * np + ip] = integrate(&local_pdf, z, p, whole, 0);
        }
    }
    let pdf_integral: f64 = expected[..cells].iter().sum();
    for e in &mut expected[..cells] {
        *e *= n;
    }
    expected[cells] = (n * (1.0 - pdf_integral)).max(0.0);

    // Pool the cells with low expected counts, smallest first (Mitsuba's rule).
    let mut order: Vec<usize> = (0..=cells).collect();
    order.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let (mut pool_obs, mut pool_exp, mut stat, mut dof) = (0.0, 0.0, 0.0, 0usize);
    let mut impossible = Vec::new();
    for &i in &order {
        if expected[i] == 0.0 && observed[i] > 0.0 {
            impossible.push(i);
        }
        if expected[i] < 5.0 || (pool_exp > 0.0 && pool_exp < 5.0) {
            pool_obs += observed[i];
            pool_exp += expected[i];
        } else {
            stat += (observed[i] - expected[i]).powi(2) / expected[i];
            dof += 1;
        }
    }
    if pool_exp > 0.0 {
        stat += (pool_obs - pool_exp).powi(2) / pool_exp;
        dof += 1;
    }
    let dof = dof.saturating_sub(1);
    let p_value = if dof == 0 {
        0.0
    } else {
        gamma_q(dof as f64 / 2.0, stat / 2.0)
    };
    let threshold = 1.0 - (1.0 - cfg.significance).powf(1.0 / cfg.test_count as f64);
    let mut report = String::new();
    if p_value < threshold || !impossible.is_empty() || dof == 0 {
        let _ = writeln!(
            report,
            "chi2 FAILED for {name}: statistic {stat:.2}, dof {dof}, p {p_value:.3e} < {threshold:.3e}"
        );
        let _ = writeln!(report, "  cells with samples but expected 0: {}", impossible.len());
        let _ = writeln!(
            report,
            "  invalid or outside: observed {} expected {:.1}; pdf integral {pdf_integral:.6}",
            observed[cells], expected[cells]
        );
        let _ = writeln!(
            report,
            "  per z-row (cos theta about the axis, from {z0:.4} to 1): observed / expected"
        );
        for iz in 0..nz {
            let row = iz * np..(iz + 1) * np;
            let (o, e): (f64, f64) = (observed[row.clone()].iter().sum(), expected[row].iter().sum());
            let _ = writeln!(report, "  z {:>3}: {o:>10.0} / {e:>12.1}", iz);
        }
        let mut worst: Vec<usize> = (0..cells).collect();
        worst.sort_by(|&a, &b| {
            let r = |i: usize| (observed[i] - expected[i]).powi(2) / expected[i].max(1e-300);
            r(b).total_cmp(&r(a))
        });
        let _ = writeln!(report, "  worst cells (iz, iphi): observed / expected");
        for &i in worst.iter().take(10) {
            let _ = writeln!(
                report,
                "  ({:>3}, {:>3}): {:>8.0} / {:>10.2}",
                i / np,
                i % np,
                observed[i],
                expected[i]
            );
        }
    }
    Chi2Outcome {
        p_value,
        dof,
        statistic: stat,
        pdf_integral,
        outside_fraction: observed[cells] / n,
        report,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gamma_q_matches_known_chi2_tail_values() {
        // P(chi2_dof > x): dof 2, x 2 -> e^-1; dof 10, x 18.307 -> 0.05; dof 100, x 124.342 -> 0.05.
        assert!((gamma_q(1.0, 1.0) - (-1.0_f64).exp()).abs() < 1e-12);
        assert!((gamma_q(5.0, 18.307 / 2.0) - 0.05).abs() < 1e-4);
        assert!((gamma_q(50.0, 124.342 / 2.0) - 0.05).abs() < 1e-4);
    }

    /// The harness must reject a sampler that does not follow its pdf.
    #[test]
    fn harness_rejects_a_wrong_pdf() {
        let cfg = Chi2Config {
            res_z: 16,
            res_phi: 32,
            samples: 50_000,
            seed: 7,
            significance: 0.01,
            test_count: 1,
        };
        // Uniform hemisphere sampler checked against the cosine pdf.
        let frame = [DVec3::X, DVec3::Y, DVec3::Z];
        let sample = |u: DVec2| Some(direction(&frame, u.x, 2.0 * PI * u.y));
        let cosine = |w: DVec3| w.z.max(0.0) / PI;
        let uniform = |w: DVec3| if w.z > 0.0 { 0.5 / PI } else { 0.0 };
        let hemi = Domain::Hemisphere;
        assert!(!chi2_test("uniform vs cosine", &sample, &cosine, &hemi, &cfg).passed());
        let ok = chi2_test("uniform vs uniform", &sample, &uniform, &hemi, &cfg);
        assert!(ok.passed(), "{}", ok.report);
        assert!((ok.pdf_integral - 1.0).abs() < 1e-12);
        // In a cap of 60 deg about a tilted axis, the uniform pdf integrates to the cap's share of
        // the hemisphere that lies above the horizon, and the test still passes.
        let cap = Domain::Cap {
            axis: DVec3::new(0.5, 0.0, 1.0),
            radius: 1.0,
        };
        let in_cap = chi2_test("uniform in a cap", &sample, &uniform, &cap, &cfg);
        assert!(in_cap.passed(), "{}", in_cap.report);
        assert!(
            in_cap.pdf_integral > 0.2 && in_cap.pdf_integral < 0.5,
            "{}",
            in_cap.pdf_integral
        );
        assert!((in_cap.pdf_integral + in_cap.outside_fraction - 1.0).abs() < 0.01);
        assert!(!chi2_test("uniform vs cosine in a cap", &sample, &cosine, &cap, &cfg).passed());
    }
}
