//! Reachability and precision survey of an instrument: how many random direction pairs it can
//! reach (and why not the others), how exactly FK(IK(w)) returns w in f64 and in the firmware's
//! f32, and how often the host (f64) and the firmware (f32) compute different integer step targets.
//!
//! Both precisions start from the same f32 angles (what travels on the wire), so the comparison
//! isolates the arithmetic, not the quantisation of the plan. `gonio instrument survey` prints it.

use gonio_shared::kinematics::{Kinematics, Pose, Unreachable};
use gonio_shared::vec3::Vec3;
use gonio_shared::{InstrumentConfig, AXES};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use std::fmt;

/// The outcome counts and precision figures of a survey.
#[derive(Clone, Debug, Default)]
pub struct Survey {
    pub pairs: usize,
    /// Outcome of the f64 inverse kinematics, by reason name ("reachable" for success).
    pub outcomes: BTreeMap<String, usize>,
    /// Pairs where f64 and f32 disagree on reachability (a boundary case in one precision only).
    pub outcome_disagreements: usize,
    /// Over pairs reachable in both: axis step targets equal / off by one / off by more.
    pub step_targets_equal: usize,
    pub step_targets_off_by_one: usize,
    pub step_targets_off_by_more: usize,
    /// Largest FK(IK(w)) angle error over reachable pairs, radians.
    pub max_fk_error_f64: f64,
    pub max_fk_error_f32: f64,
}

fn reason_name(r: &Result<Pose<f64>, Unreachable>) -> String {
    match r {
        Ok(_) => "reachable".into(),
        Err(Unreachable::BelowHorizon { .. }) => "below horizon".into(),
        Err(Unreachable::Blocked) => "blocked cone".into(),
        Err(Unreachable::Limit(a)) => format!("{} limit", a.name()),
        Err(Unreachable::NotFinite) => "not finite".into(),
    }
}

/// A direction uniform in solid angle over the hemisphere with theta <= `max_theta`, as f32 angles.
fn random_direction(rng: &mut ChaCha8Rng, max_theta: f64) -> (f32, f32) {
    let cos_min = max_theta.cos();
    let z: f64 = rng.random_range(cos_min..=1.0);
    let phi: f64 = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
    (z.acos() as f32, phi as f32)
}

/// Survey `pairs` random pairs with theta up to 89.9 degrees, each solved from the rest pose.
pub fn survey(
    cfg: &InstrumentConfig<f64>,
    pairs: usize,
    seed: u64,
) -> Result<Survey, gonio_shared::instrument::ConfigError> {
    let k64 = Kinematics::new(*cfg)?;
    let k32 = Kinematics::new(cfg.cast::<f32>())?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let max_theta = 89.9f64.to_radians();
    let mut s = Survey {
        pairs,
        ..Survey::default()
    };
    for _ in 0..pairs {
        let (ti, pi) = random_direction(&mut rng, max_theta);
        let (to, po) = random_direction(&mut rng, max_theta);
        let rest64 = k64.rest_pose();
        let rest32 = k32.rest_pose();
        let r64 = k64.inverse_angles(ti as f64, pi as f64, to as f64, po as f64, &rest64);
        let r32 = k32.inverse_angles(ti, pi, to, po, &rest32);
        *s.outcomes.entry(reason_name(&r64)).or_default() += 1;
        match (r64, r32) {
            (Ok(p64), Ok(p32)) => {
                let wi = Vec3::from_spherical(ti as f64, pi as f64);
                let wo = Vec3::from_spherical(to as f64, po as f64);
                let (fi, fo) = k64.forward(&p64);
                s.max_fk_error_f64 = s.max_fk_error_f64.max(fk_error(cfg.isotropic, wi, wo, fi, fo));
                let (fi32, fo32) = k32.forward(&p32);
                let widen = |v: Vec3<f32>| Vec3::new(v.x as f64, v.y as f64, v.z as f64);
                let err32 = fk_error(cfg.isotropic, wi, wo, widen(fi32), widen(fo32));
                s.max_fk_error_f32 = s.max_fk_error_f32.max(err32);
                match (k64.to_steps(&p64), k32.to_steps(&p32)) {
                    (Ok(a), Ok(b)) => {
                        let worst = AXES
                            .iter()
                            .map(|x| (a[x.index()] - b[x.index()]).unsigned_abs())
                            .max()
                            .unwrap_or(0);
                        match worst {
                            0 => s.step_targets_equal += 1,
                            1 => s.step_targets_off_by_one += 1,
                            _ => s.step_targets_off_by_more += 1,
                        }
                    }
                    _ => s.outcome_disagreements += 1,
                }
            }
            (Err(_), Err(_)) => {}
            _ => s.outcome_disagreements += 1,
        }
    }
    Ok(s)
}

/// FK error: exact vectors for an anisotropic instrument; theta_i, theta_o and the angle between
/// wi and wo (the isotropic invariants) when the azimuth stage does not move.
fn fk_error(isotropic: bool, wi: Vec3<f64>, wo: Vec3<f64>, fi: Vec3<f64>, fo: Vec3<f64>) -> f64 {
    if isotropic {
        let th = |v: Vec3<f64>| v.to_spherical().0;
        (th(wi) - th(fi))
            .abs()
            .max((th(wo) - th(fo)).abs())
            .max((wi.angle_to(wo) - fi.angle_to(fo)).abs())
    } else {
        wi.angle_to(fi).max(wo.angle_to(fo))
    }
}

impl Survey {
    pub fn reachable(&self) -> usize {
        self.outcomes.get("reachable").copied().unwrap_or(0)
    }
    pub fn compared(&self) -> usize {
        self.step_targets_equal + self.step_targets_off_by_one + self.step_targets_off_by_more
    }
}

impl fmt::Display for Survey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let pct = |n: usize, of: usize| if of == 0 { 0.0 } else { 100.0 * n as f64 / of as f64 };
        writeln!(
            f,
            "pairs surveyed (uniform solid angle, theta <= 89.9 deg): {}",
            self.pairs
        )?;
        for (name, n) in &self.outcomes {
            writeln!(f, "  {name:<16} {n:>8}  {:6.2} %", pct(*n, self.pairs))?;
        }
        let c = self.compared();
        writeln!(
            f,
            "f64 (host) vs f32 (firmware) step targets, over {c} pairs reachable in both:"
        )?;
        writeln!(
            f,
            "  equal            {:>8}  {:6.3} %",
            self.step_targets_equal,
            pct(self.step_targets_equal, c)
        )?;
        writeln!(
            f,
            "  off by one step  {:>8}  {:6.3} %",
            self.step_targets_off_by_one,
            pct(self.step_targets_off_by_one, c)
        )?;
        writeln!(
            f,
            "  off by more      {:>8}  {:6.3} %",
            self.step_targets_off_by_more,
            pct(self.step_targets_off_by_more, c)
        )?;
        writeln!(f, "  reachability disagrees: {}", self.outcome_disagreements)?;
        writeln!(
            f,
            "max FK(IK(w)) error: f64 {:.3e} rad, f32 {:.3e} rad",
            self.max_fk_error_f64, self.max_fk_error_f32
        )
    }
}
