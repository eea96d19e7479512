//! Fit Lambert plus a coated diffuse plus two GGX lobes with a bounded Fresnel rise to sampled
//! values: the log(1 + f cos) loss, the roughness pair on a log grid (docs/planner.md, "The two-lobe fit").

use super::analytic::ggx_specular;
use super::frame::luminance;
use super::log_nnls::solve_capped;
use super::Material;
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

const ALPHA_MIN: f64 = 2e-3;
const ALPHA_MAX: f64 = 1.0;
/// Grid steps over [ALPHA_MIN, ALPHA_MAX] (log spaced) for each lobe's roughness.
const ALPHA_STEPS: usize = 20;
/// The broad lobe is at least this many times rougher than the sharp one.
const MIN_RATIO: f64 = 2.5;
/// Smallest normal-incidence reflectance a lobe's Fresnel rise may imply: kg <= ks / F0_MIN (water's F0).
pub const F0_MIN: f64 = 0.02;

/// `DiffuseBound::BelowDarkest` reads only samples with both directions above 80 deg (cos theta).
const CAP_MIN_COS: f64 = 0.17364817766693041; // cos 80 deg

/// Lambert plus a coated diffuse term plus two GGX lobes (Smith masking; `analytic::ggx_specular`),
/// each lobe with a Schlick Fresnel rise from its normal-incidence colour ks to its grazing colour kg.
#[derive(Clone, Debug, PartialEq)]
pub struct TwoLobes {
    pub diffuse: DVec3,
    pub sharp_alpha: f64,
    pub sharp: DVec3,
    pub broad_alpha: f64,
    pub broad: DVec3,
    /// Each lobe's colour at grazing: a lobe is ks (1 - x) + kg x times its GGX factor, with the
    /// Schlick weight x = (1 - wi.h)^5, so kg = ks is a lobe without Fresnel rise. A fit keeps
    /// ks <= kg <= ks / `F0_MIN`.
    pub sharp_grazing: DVec3,
    pub broad_grazing: DVec3,
    /// A second diffuse term, `coated_diffuse_shape` times kc / pi: the diffuse under a clear
    /// coat, which darkens toward grazing as the coat reflects more of the light (zero: none).
    pub coated: DVec3,
}

/// The grazing falloff of a diffuse base under a smooth coat, (1 - (1 - cos theta / 2)^5) per
/// direction (Ashikhmin and Shirley 2000), normalised to 1 at normal incidence, 0 at the horizon.
pub fn coated_diffuse_shape(wi: DVec3, wo: DVec3) -> f64 {
    // 1 - (1/2)^5 at normal incidence; cos is clamped to [0, 1], so the shape is in [0, 1].
    const NORMAL: f64 = 1.0 - 1.0 / 32.0;
    let f = |c: f64| (1.0 - (1.0 - 0.5 * c.clamp(0.0, 1.0)).powi(5)) / NORMAL;
    f(wi.z) * f(wo.z)
}

/// Schlick's Fresnel weight (1 - wi.h)^5 of the pair; 0 without a half vector.
pub fn schlick_weight(wi: DVec3, wo: DVec3) -> f64 {
    match crate::brdf::frame::half_vector(wi, wo) {
        Some(h) => (1.0 - wi.dot(h).clamp(0.0, 1.0)).powi(5),
        None => 0.0,
    }
}

impl TwoLobes {
    /// A readable one-line description (not a material spec: no parser reads it).
    pub fn describe(&self) -> String {
        let c = |v: DVec3| format!("{:.3}/{:.3}/{:.3}", v.x, v.y, v.z);
        format!(
            "lambert {} + coated diffuse {} + ggx(alpha {:.4}) {} grazing {} + ggx(alpha {:.4}) {} grazing {}",
            c(self.diffuse),
            c(self.coated),
            self.sharp_alpha,
            c(self.sharp),
            c(self.sharp_grazing),
            self.broad_alpha,
            c(self.broad),
            c(self.broad_grazing)
        )
    }
}

impl Material for TwoLobes {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let (sharp, broad) = self.lobes(wi, wo);
        self.diffuse * FRAC_1_PI + self.coated * (FRAC_1_PI * coated_diffuse_shape(wi, wo)) + sharp + broad
    }
}

impl TwoLobes {
    /// The sharp and the broad GGX lobe alone (both centred on the mirror direction: they move with wi).
    fn lobes(&self, wi: DVec3, wo: DVec3) -> (DVec3, DVec3) {
        let x = schlick_weight(wi, wo);
        // ks + (kg - ks) x, not ks (1 - x) + kg x: a lobe without rise (kg = ks) then evaluates to
        // exactly ks, bit for bit as before the rise existed (the encoder's two-lobe dataset).
        (
            (self.sharp + (self.sharp_grazing - self.sharp) * x) * ggx_specular(wi, wo, self.sharp_alpha),
            (self.broad + (self.broad_grazing - self.broad) * x) * ggx_specular(wi, wo, self.broad_alpha),
        )
    }

    /// The share of f's luminance at (wi, wo) made of the two GGX lobes (they move with wi); 1 where
    /// f is 0 (nothing to split).
    pub fn lobe_share(&self, wi: DVec3, wo: DVec3) -> f64 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 1.0;
        }
        let (sharp, broad) = self.lobes(wi, wo);
        let (l, total) = (luminance(sharp + broad), luminance(self.eval(wi, wo)));
        // Guard: a black or non-finite total has no share to split.
        if total > 0.0 && l.is_finite() && total.is_finite() {
            (l / total).clamp(0.0, 1.0)
        } else {
            1.0
        }
    }
}

/// The fitted lobes and the weighted RMS of the log residuals.
#[derive(Clone, Debug)]
pub struct TwoLobeFit {
    pub model: TwoLobes,
    pub rms_log_error: f64,
}

/// Fit `TwoLobes` to `values[i]` = f(pairs[i]) with weights (as `fit::fit_samples`), the sharp lobe
/// no sharper than `min_alpha`, which the caller knows its data resolve. Panics if the lengths differ.
pub fn fit_two_lobes(pairs: &[(DVec3, DVec3)], values: &[DVec3], weights: &[f64], min_alpha: f64) -> TwoLobeFit {
    fit_two_lobes_with(pairs, values, weights, min_alpha, LobeFresnel::Bounded)
}

/// Whether the fitted lobes may rise toward grazing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LobeFresnel {
    /// One colour per lobe at every angle (kg = ks).
    None,
    /// A Schlick rise with ks <= kg <= ks / `F0_MIN` (the default).
    Bounded,
}

/// How high the fitted Lambert term may go.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DiffuseBound {
    /// Any non-negative albedo.
    Free,
    /// Per channel, kd / pi at most the darkest sample's value within 80 deg of the normal (a trial).
    BelowDarkest,
}

/// `fit_two_lobes` with the choice of Fresnel rise (and the diffuse left free).
pub fn fit_two_lobes_with(
    pairs: &[(DVec3, DVec3)],
    values: &[DVec3],
    weights: &[f64],
    min_alpha: f64,
    fresnel: LobeFresnel,
) -> TwoLobeFit {
    fit_two_lobes_bounded(pairs, values, weights, min_alpha, fresnel, DiffuseBound::Free)
}

/// `fit_two_lobes_with` with a bound on the Lambert term.
pub fn fit_two_lobes_bounded(
    pairs: &[(DVec3, DVec3)],
    values: &[DVec3],
    weights: &[f64],
    min_alpha: f64,
    fresnel: LobeFresnel,
    bound: DiffuseBound,
) -> TwoLobeFit {
    assert_eq!(pairs.len(), values.len(), "one value per direction pair");
    assert_eq!(pairs.len(), weights.len(), "one weight per direction pair");
    let kept = Kept::of(pairs, values, weights);
    let cap = kept.diffuse_caps(bound);
    let cols = Columns::of(&kept, fresnel);
    let mut best: Option<(f64, usize, usize, [[f64; 6]; 3])> = None;
    // Guard: a non-finite floor is no floor; one above the grid leaves only the roughest pair.
    let min_alpha = if min_alpha.is_finite() {
        min_alpha.min(ALPHA_MAX / MIN_RATIO)
    } else {
        0.0
    };
    let alphas = &cols.alphas;
    for s in 0..alphas.len() {
        // The grid point at or just below the floor stays, so the floor is never skipped over.
        if alphas.get(s + 1).is_some_and(|&next| next <= min_alpha) {
            continue;
        }
        for b in s + 1..alphas.len() {
            if alphas[b] < MIN_RATIO * alphas[s] {
                continue;
            }
            let (coeffs, loss) = cols.fit_pair(&kept, &cap, s, b, fresnel);
            if best.is_none_or(|(l, ..)| loss < l) {
                best = Some((loss, s, b, coeffs));
            }
        }
    }
    let total_w: f64 = kept.w.iter().sum::<f64>().max(f64::MIN_POSITIVE);
    match best {
        Some((loss, s, b, x)) => TwoLobeFit {
            model: model_of(&x, alphas[s], alphas[b]),
            rms_log_error: (loss / (3.0 * total_w)).sqrt(),
        },
        // No usable sample: a black material.
        None => TwoLobeFit {
            model: model_of(&[[0.0; 6]; 3], ALPHA_MIN, ALPHA_MAX),
            rms_log_error: 0.0,
        },
    }
}

/// The model of coefficients `x[c]` = [kd, ks_sharp, kg_sharp, ks_broad, kg_broad, kc] per channel.
fn model_of(x: &[[f64; 6]; 3], sharp_alpha: f64, broad_alpha: f64) -> TwoLobes {
    let col = |p: usize| DVec3::new(x[0][p], x[1][p], x[2][p]);
    TwoLobes {
        diffuse: col(0),
        sharp_alpha,
        sharp: col(1),
        broad_alpha,
        broad: col(3),
        sharp_grazing: col(2),
        broad_grazing: col(4),
        coated: col(5),
    }
}

/// The samples that carry weight (guards as in `fit::fit_samples`), with their log targets.
struct Kept {
    pairs: Vec<(DVec3, DVec3)>,
    cos_o: Vec<f64>,
    w: Vec<f64>,
    /// log(1 + f cos theta_o) per channel.
    target: [Vec<f64>; 3],
}

impl Kept {
    fn of(pairs: &[(DVec3, DVec3)], values: &[DVec3], weights: &[f64]) -> Self {
        let mut kept = Kept {
            pairs: Vec::new(),
            cos_o: Vec::new(),
            w: Vec::new(),
            target: [Vec::new(), Vec::new(), Vec::new()],
        };
        for (i, &(wi, wo)) in pairs.iter().enumerate() {
            let wt = if weights[i].is_finite() {
                weights[i].max(0.0)
            } else {
                0.0
            };
            let v = values[i];
            if !(wo.z > 0.0 && wi.z > 0.0) || wt == 0.0 || !v.is_finite() {
                continue;
            }
            kept.cos_o.push(wo.z);
            kept.w.push(wt);
            kept.pairs.push((wi, wo));
            for c in 0..3 {
                kept.target[c].push((v[c].max(0.0) * wo.z).ln_1p());
            }
        }
        kept
    }

    /// The Lambert cap per channel (albedo units: kd / pi <= min f); infinite when free or when no
    /// kept sample is above the grazing band. Guard: values were clamped at 0, so a finite cap is >= 0.
    fn diffuse_caps(&self, bound: DiffuseBound) -> [f64; 3] {
        std::array::from_fn(|c| match bound {
            DiffuseBound::Free => f64::INFINITY,
            DiffuseBound::BelowDarkest => self.target[c]
                .iter()
                .zip(&self.pairs)
                .filter(|(_, (wi, wo))| wi.z.min(wo.z) >= CAP_MIN_COS)
                .map(|(t, (_, wo))| t.exp_m1() / wo.z * std::f64::consts::PI)
                .fold(f64::INFINITY, f64::min),
        })
    }
}

/// The model's columns (each term's value times cos theta_o) at every kept sample.
struct Columns {
    /// The candidate roughnesses, log spaced over [ALPHA_MIN, ALPHA_MAX].
    alphas: Vec<f64>,
    /// Each roughness's GGX factor.
    basis: Vec<Vec<f64>>,
    /// Each roughness's Fresnel-rising column (empty when the rise is off).
    rising: Vec<Vec<f64>>,
    diffuse: Vec<f64>,
    coated: Vec<f64>,
}

impl Columns {
    fn of(kept: &Kept, fresnel: LobeFresnel) -> Self {
        let alphas: Vec<f64> = (0..=ALPHA_STEPS)
            .map(|i| (ALPHA_MIN.ln() + (ALPHA_MAX / ALPHA_MIN).ln() * i as f64 / ALPHA_STEPS as f64).exp())
            .collect();
        let basis: Vec<Vec<f64>> = alphas
            .iter()
            .map(|&a| {
                kept.pairs
                    .iter()
                    .zip(&kept.cos_o)
                    .map(|(&(wi, wo), c)| ggx_specular(wi, wo, a) * c)
                    .collect()
            })
            .collect();
        let diffuse: Vec<f64> = kept.cos_o.iter().map(|c| c * FRAC_1_PI).collect();
        let coated: Vec<f64> = kept
            .pairs
            .iter()
            .zip(&kept.cos_o)
            .map(|(&(wi, wo), c)| c * FRAC_1_PI * coated_diffuse_shape(wi, wo))
            .collect();
        // Each lobe enters as two columns, S and S (1 + (1/F0_MIN - 1) x) (x the Schlick weight):
        // non-negative (c0, c1) span exactly the lobes with ks <= kg <= ks / F0_MIN.
        let rise = 1.0 / F0_MIN - 1.0;
        let fresnel_cols: Vec<f64> = kept
            .pairs
            .iter()
            .map(|&(wi, wo)| 1.0 + rise * schlick_weight(wi, wo))
            .collect();
        let rising: Vec<Vec<f64>> = match fresnel {
            LobeFresnel::Bounded => basis
                .iter()
                .map(|b| b.iter().zip(&fresnel_cols).map(|(v, f)| v * f).collect())
                .collect(),
            LobeFresnel::None => Vec::new(),
        };
        Self {
            alphas,
            basis,
            rising,
            diffuse,
            coated,
        }
    }

    /// Per channel the best coefficients [kd, ks_sharp, kg_sharp, ks_broad, kg_broad, kc] for the
    /// roughness pair (s, b), and the summed loss.
    fn fit_pair(&self, kept: &Kept, cap: &[f64; 3], s: usize, b: usize, fresnel: LobeFresnel) -> ([[f64; 6]; 3], f64) {
        let to_colours = |c0: f64, c1: f64| -> (f64, f64) { (c0 + c1, c0 + c1 / F0_MIN) };
        let mut coeffs = [[0.0; 6]; 3];
        let mut loss = 0.0;
        for c in 0..3 {
            let (x, l) = match fresnel {
                LobeFresnel::Bounded => {
                    let cols = [
                        &self.diffuse[..],
                        &self.basis[s][..],
                        &self.rising[s][..],
                        &self.basis[b][..],
                        &self.rising[b][..],
                        &self.coated[..],
                    ];
                    let (x, l) = solve_capped(&cols, &kept.target[c], &kept.w, cap[c]);
                    let (ks, kg) = to_colours(x[1], x[2]);
                    let (bs, bg) = to_colours(x[3], x[4]);
                    ([x[0], ks, kg, bs, bg, x[5]], l)
                }
                LobeFresnel::None => {
                    let cols = [
                        &self.diffuse[..],
                        &self.basis[s][..],
                        &self.basis[b][..],
                        &self.coated[..],
                    ];
                    let (x, l) = solve_capped(&cols, &kept.target[c], &kept.w, cap[c]);
                    ([x[0], x[1], x[1], x[2], x[2], x[3]], l)
                }
            };
            coeffs[c] = x;
            loss += l;
        }
        (coeffs, loss)
    }
}

/// Samples closer than this to the mirror direction of their wi (half-vector angle, radians)
/// measure a lobe's height, not its width: `resolvable_alpha` looks past them.
const AT_PEAK_TAN: f64 = 1e-3;

/// The roughness a sample set resolves: the median over incident directions of tan theta_h of the
/// sample nearest the mirror direction (past `AT_PEAK_TAN`); 0 when none has an off-peak sample.
/// Pairs below the horizon or not finite are ignored.
pub fn resolvable_alpha(pairs: &[(DVec3, DVec3)]) -> f64 {
    let mut nearest: Vec<(DVec3, f64)> = Vec::new();
    for &(wi, wo) in pairs {
        if !(wi.z > 0.0 && wo.z > 0.0 && wi.is_finite() && wo.is_finite()) {
            continue;
        }
        let Some(h) = crate::brdf::frame::half_vector(wi, wo) else {
            continue;
        };
        let tan = (1.0 - h.z * h.z).max(0.0).sqrt() / h.z;
        if !(tan >= AT_PEAK_TAN) {
            continue;
        }
        match nearest.iter_mut().find(|(w, _)| (*w - wi).length_squared() < 1e-18) {
            Some((_, t)) => *t = t.min(tan),
            None => nearest.push((wi, tan)),
        }
    }
    let mut t: Vec<f64> = nearest.into_iter().map(|(_, t)| t).collect();
    if t.is_empty() {
        return 0.0;
    }
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::fit::fit_directions;

    /// The lobes' share is 0 without lobes, 1 without anything else, 1 where f is black or the
    /// pair is below the horizon, and grows toward the mirror direction; it is finite at grazing.
    #[test]
    fn the_lobe_share_at_its_extremes() {
        use crate::brdf::frame::from_spherical;
        let model = |diffuse: f64, lobe: f64| TwoLobes {
            diffuse: DVec3::splat(diffuse),
            sharp_alpha: 0.02,
            sharp: DVec3::splat(lobe),
            broad_alpha: 0.2,
            broad: DVec3::splat(lobe),
            sharp_grazing: DVec3::splat(lobe),
            broad_grazing: DVec3::splat(lobe),
            coated: DVec3::ZERO,
        };
        let wi = from_spherical(0.5, 0.0);
        let mirror = from_spherical(0.5, std::f64::consts::PI);
        let back = from_spherical(1.5, 0.0);
        assert_eq!(model(0.5, 0.0).lobe_share(wi, mirror), 0.0);
        assert_eq!(model(0.0, 1.0).lobe_share(wi, back), 1.0);
        assert_eq!(model(0.0, 0.0).lobe_share(wi, mirror), 1.0, "black: nothing to split");
        assert_eq!(model(0.5, 1.0).lobe_share(wi, -mirror), 1.0, "below the horizon");
        let mixed = model(0.5, 1.0);
        let (peak, far) = (mixed.lobe_share(wi, mirror), mixed.lobe_share(wi, back));
        assert!(peak > 0.99 && far < peak && far >= 0.0, "{peak} {far}");
        let edge = std::f64::consts::FRAC_PI_2 - 1e-4;
        let grazing = mixed.lobe_share(from_spherical(edge, 0.0), from_spherical(edge, 3.0));
        assert!((0.0..=1.0).contains(&grazing), "{grazing}");
    }

    /// Samples of a two-lobe material come back as its two lobes; a one-lobe material comes back
    /// with the other lobe (nearly) empty.
    #[test]
    fn recovers_two_lobes_and_leaves_a_missing_one_empty() {
        let truth = two_lobe_truth();
        let fit = fit_unfloored(&truth);
        let m = &fit.model;
        assert_same_roughness(m, &truth);
        for (got, want) in [
            (m.diffuse, truth.diffuse),
            (m.sharp, truth.sharp),
            (m.broad, truth.broad),
        ] {
            assert!((got - want).abs().max_element() < 1e-4, "{}", m.describe());
        }
        assert!(fit.rms_log_error < 1e-6, "{}", fit.rms_log_error);

        // A single lobe: the fit explains it with one lobe and leaves the other near zero.
        let one = crate::brdf::analytic::Ggx {
            alpha: alpha_grid(10),
            diffuse: DVec3::splat(0.2),
            specular: DVec3::splat(0.6),
        };
        let fit = fit_unfloored(&one);
        assert!(
            fit.rms_log_error < 1e-6,
            "{} {}",
            fit.rms_log_error,
            fit.model.describe()
        );
    }

    /// The coated diffuse shape at its extremes: 1 at normal incidence both ways, 0 with either
    /// direction at (or, clamped, below) the horizon, within [0, 1] and falling with either angle.
    /// A material whose diffuse darkens that way comes back as the coated term, not as Lambert.
    #[test]
    fn a_coated_diffuse_base_is_recovered_as_one() {
        use crate::brdf::frame::from_spherical;
        let z = DVec3::Z;
        assert!((coated_diffuse_shape(z, z) - 1.0).abs() < 1e-15);
        let horizon = from_spherical(std::f64::consts::FRAC_PI_2, 0.3);
        assert_eq!(coated_diffuse_shape(z, horizon), 0.0);
        assert_eq!(coated_diffuse_shape(DVec3::new(1.0, 0.0, -0.1).normalize(), z), 0.0);
        let mut last = 1.0;
        for deg in [10.0, 30.0, 60.0, 80.0, 89.0, 90.0] {
            let v = coated_diffuse_shape(z, from_spherical(f64::to_radians(deg), 0.0));
            assert!((0.0..=last).contains(&v), "{deg}: {v}");
            last = v;
        }
        let truth = TwoLobes {
            diffuse: DVec3::ZERO,
            sharp_alpha: alpha_grid(5),
            sharp: DVec3::splat(0.3),
            broad_alpha: alpha_grid(15),
            broad: DVec3::splat(0.1),
            sharp_grazing: DVec3::splat(0.3),
            broad_grazing: DVec3::splat(0.1),
            coated: DVec3::new(0.6, 0.4, 0.2),
        };
        let m = fit_unfloored(&truth).model;
        assert_same_roughness(&m, &truth);
        assert!((m.coated - truth.coated).abs().max_element() < 1e-3, "{}", m.describe());
        assert!(m.diffuse.max_element() < 1e-3, "{}", m.describe());
    }

    /// A Fresnel rise inside the bound comes back exactly; one beyond it is fitted at the bound,
    /// never above (every fitted lobe keeps ks <= kg <= ks / F0_MIN).
    #[test]
    fn fresnel_rise_is_recovered_inside_its_bound_and_capped_beyond_it() {
        let lobes = |sharp_rise: f64| TwoLobes {
            diffuse: DVec3::splat(0.1),
            sharp_alpha: alpha_grid(5),
            sharp: DVec3::new(0.2, 0.3, 0.4),
            broad_alpha: alpha_grid(15),
            broad: DVec3::splat(0.2),
            sharp_grazing: DVec3::new(0.2, 0.3, 0.4) * sharp_rise,
            broad_grazing: DVec3::splat(0.2 * 3.0),
            coated: DVec3::ZERO,
        };
        let truth = lobes(10.0);
        let fit = fit_unfloored(&truth);
        let m = &fit.model;
        assert_same_roughness(m, &truth);
        for (got, want) in [
            (m.sharp, truth.sharp),
            (m.sharp_grazing, truth.sharp_grazing),
            (m.broad, truth.broad),
            (m.broad_grazing, truth.broad_grazing),
        ] {
            assert!(
                (got - want).abs().max_element() < 1e-3 * want.max_element(),
                "{}",
                m.describe()
            );
        }
        // A rise of 200x is beyond the bound (1 / F0_MIN = 50x): the fit stays inside it.
        let fit = fit_unfloored(&lobes(200.0));
        let m = &fit.model;
        for (ks, kg) in [(m.sharp, m.sharp_grazing), (m.broad, m.broad_grazing)] {
            for c in 0..3 {
                assert!(
                    kg[c] >= ks[c] * (1.0 - 1e-9) && kg[c] <= ks[c] / F0_MIN * (1.0 + 1e-9),
                    "{}",
                    m.describe()
                );
            }
        }
    }

    /// The floor holds: samples of a sharp lobe fitted with a floor above its alpha get a sharp
    /// lobe at the floor's grid point, never below.
    #[test]
    fn the_sharp_lobe_respects_its_floor() {
        let truth = TwoLobes {
            diffuse: DVec3::splat(0.1),
            sharp_alpha: alpha_grid(2),
            sharp: DVec3::splat(0.3),
            broad_alpha: alpha_grid(15),
            broad: DVec3::splat(0.4),
            sharp_grazing: DVec3::splat(0.3),
            broad_grazing: DVec3::splat(0.4),
            coated: DVec3::ZERO,
        };
        let pairs = fit_directions();
        let values: Vec<DVec3> = pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        let floor = alpha_grid(6) * 1.01;
        let fit = fit_two_lobes(&pairs, &values, &vec![1.0; pairs.len()], floor);
        assert!(fit.model.sharp_alpha >= alpha_grid(6), "{}", fit.model.describe());
        assert!(
            fit.rms_log_error > 1e-3,
            "a floored fit cannot be exact: {}",
            fit.rms_log_error
        );
    }

    #[test]
    fn degenerate_inputs_give_a_finite_black_or_valid_fit() {
        let wi = crate::brdf::frame::from_spherical(0.3, 0.0);
        let wo = crate::brdf::frame::from_spherical(0.5, 2.0);
        // No samples at all.
        let fit = fit_two_lobes(&[], &[], &[], 0.0);
        assert_eq!(fit.model.diffuse, DVec3::ZERO);
        // Only unusable samples: below the horizon, NaN, weight 0.
        let fit = fit_two_lobes(
            &[(wi, DVec3::new(0.0, 0.6, -0.8)), (wi, wo), (wi, wo)],
            &[DVec3::ONE, DVec3::splat(f64::NAN), DVec3::ONE],
            &[1.0, 1.0, 0.0],
            0.0,
        );
        assert_eq!(fit.model.diffuse, DVec3::ZERO);
        assert!(fit.rms_log_error.is_finite());
        // One usable sample: finite, non-negative colours.
        let fit = fit_two_lobes(&[(wi, wo)], &[DVec3::splat(0.3)], &[1.0], f64::NAN);
        let m = &fit.model;
        for v in [m.diffuse, m.sharp, m.broad] {
            assert!(v.is_finite() && v.min_element() >= 0.0, "{}", m.describe());
        }
    }

    /// The resolvable roughness is the median over incident directions of the nearest off-peak
    /// sample's tan theta_h: samples at the mirror direction, below the horizon or not finite do not
    /// count, and a set with no off-peak sample resolves everything (0).
    #[test]
    fn resolvable_alpha_reads_the_nearest_off_peak_sample() {
        use crate::brdf::frame::from_spherical;
        let deg = |d: f64| d.to_radians();
        // wi at theta_i, and wo at the mirror direction tilted by 2 t in the plane of incidence:
        // the half vector is then t off the normal.
        let at = |ti: f64, t: f64| {
            (
                from_spherical(deg(ti), 0.0),
                from_spherical(deg(ti) + 2.0 * t, std::f64::consts::PI),
            )
        };
        let slice = |ti: f64, ts: &[f64]| -> Vec<(DVec3, DVec3)> { ts.iter().map(|&t| at(ti, t)).collect() };
        let mut pairs = Vec::new();
        // Three incident directions, nearest off-peak samples at 0.02, 0.05 and 0.2 rad (plus a
        // sample exactly at each peak and one farther out): median 0.05.
        pairs.extend(slice(10.0, &[0.0, 0.02, 0.3]));
        pairs.extend(slice(30.0, &[0.0, 0.05, 0.1]));
        pairs.extend(slice(50.0, &[0.0, 0.2, 0.25]));
        // Unusable pairs change nothing.
        pairs.push((from_spherical(deg(30.0), 0.0), DVec3::new(0.0, 0.6, -0.8)));
        pairs.push((from_spherical(deg(30.0), 0.0), DVec3::splat(f64::NAN)));
        let r = resolvable_alpha(&pairs);
        assert!((r - 0.05f64.tan()).abs() < 1e-9, "{r}");
        // Only peak samples (theta_i 0 and 45 deg, normal and mirror): nothing resolves the width.
        assert_eq!(resolvable_alpha(&[at(0.0, 0.0), at(45.0, 0.0)]), 0.0);
        assert_eq!(resolvable_alpha(&[]), 0.0);
        // Grazing and normal incidence stay finite.
        let r = resolvable_alpha(&[at(0.0, 0.1), at(89.0, -0.01)]);
        assert!(r.is_finite() && r > 0.0, "{r}");
    }

    /// A material of the family never contradicts the Lambert bound (its Lambert term is under every
    /// sample), so the bounded fit recovers it as the free one does; when the bound binds, the
    /// Lambert term sits on it and the other terms are refitted around it (loss no lower than free).
    #[test]
    fn the_diffuse_bound_changes_nothing_it_need_not_and_holds_where_it_binds() {
        let truth = two_lobe_truth();
        let pairs = fit_directions();
        let values: Vec<DVec3> = pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        let w = vec![1.0; pairs.len()];
        let fit = |bound| fit_two_lobes_bounded(&pairs, &values, &w, 0.0, LobeFresnel::Bounded, bound);
        let (free, capped) = (fit(DiffuseBound::Free), fit(DiffuseBound::BelowDarkest));
        assert_eq!(free.model, capped.model);
        assert!(
            (capped.model.diffuse - truth.diffuse).abs().max_element() < 1e-4,
            "{}",
            capped.model.describe()
        );

        // Darken the samples of one direction far from every mirror direction: only a lower
        // Lambert term can follow it, so the bound binds there, at that sample's value.
        let mut dark = values.clone();
        let (idx, _) = pairs
            .iter()
            .enumerate()
            .find(|(_, (wi, wo))| wi.z > 0.9 && wo.z > 0.5 && wi.dot(*wo) < 0.6)
            .expect("an off-peak pair");
        dark[idx] = values[idx] * 0.2;
        let fit = |bound| fit_two_lobes_bounded(&pairs, &dark, &w, 0.0, LobeFresnel::Bounded, bound);
        let (free, capped) = (fit(DiffuseBound::Free), fit(DiffuseBound::BelowDarkest));
        let cap = dark[idx] * std::f64::consts::PI;
        assert!(
            free.model.diffuse.cmpgt(cap).all(),
            "{} vs {cap}",
            free.model.describe()
        );
        assert!(
            (capped.model.diffuse - cap).abs().max_element() < 1e-12,
            "{} vs {cap}",
            capped.model.describe()
        );
        assert!(capped.rms_log_error >= free.rms_log_error - 1e-12);
    }

    /// Lambert plus a sharp and a broad lobe, both on the roughness grid, with distinct colours.
    fn two_lobe_truth() -> TwoLobes {
        TwoLobes {
            diffuse: DVec3::new(0.05, 0.1, 0.2),
            sharp_alpha: alpha_grid(4),
            sharp: DVec3::splat(0.3),
            broad_alpha: alpha_grid(14),
            broad: DVec3::new(0.5, 0.2, 0.1),
            sharp_grazing: DVec3::splat(0.3),
            broad_grazing: DVec3::new(0.5, 0.2, 0.1),
            coated: DVec3::ZERO,
        }
    }

    /// `fit_two_lobes` of `truth` sampled on the documented direction set, equal weights, no floor.
    fn fit_unfloored(truth: &dyn Material) -> TwoLobeFit {
        let pairs = fit_directions();
        let values: Vec<DVec3> = pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        fit_two_lobes(&pairs, &values, &vec![1.0; pairs.len()], 0.0)
    }

    fn assert_same_roughness(m: &TwoLobes, truth: &TwoLobes) {
        assert_eq!(
            (m.sharp_alpha, m.broad_alpha),
            (truth.sharp_alpha, truth.broad_alpha),
            "{}",
            m.describe()
        );
    }

    fn alpha_grid(i: usize) -> f64 {
        (ALPHA_MIN.ln() + (ALPHA_MAX / ALPHA_MIN).ln() * i as f64 / ALPHA_STEPS as f64).exp()
    }
}
