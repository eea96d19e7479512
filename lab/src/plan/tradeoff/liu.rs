//! `liu_log_err`: Liu et al. 2023's BRDF-space metric, mean over RGB and over 25,000 random valid
//! direction pairs of |log(1 + f cos) - log(1 + f_rec cos)| (`predict::log_err_over`, cos =
//! cos theta_o), beside `brdf_log_err`, which takes the fit's fixed direction set instead.
//! The pairs: wi and wo each uniform in solid angle over the upper hemisphere (cos theta uniform in
//! (0, 1], phi uniform), from ChaCha8 seeded with `SEED`: the same pairs in every run.

use glam::DVec3;
use gonio::brdf::frame::from_spherical;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub const PAIRS: usize = 25_000;
pub const SEED: u64 = 2023;

/// The fixed random pairs.
pub fn liu_pairs() -> Vec<(DVec3, DVec3)> {
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let mut dir = || {
        // 1 - u lies in (0, 1]: never exactly grazing.
        let cos: f64 = 1.0 - rng.random::<f64>();
        from_spherical(cos.acos(), std::f64::consts::TAU * rng.random::<f64>())
    };
    (0..PAIRS).map(|_| (dir(), dir())).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_are_fixed_valid_and_spread() {
        let a = liu_pairs();
        assert_eq!(a.len(), PAIRS);
        assert_eq!(a[..10], liu_pairs()[..10]);
        assert!(a.iter().all(|(i, o)| i.z > 0.0 && o.z > 0.0));
        // Uniform in solid angle: mean cos theta 1/2.
        let mean = a.iter().map(|(i, _)| i.z).sum::<f64>() / PAIRS as f64;
        assert!((mean - 0.5).abs() < 0.01, "{mean}");
    }
}
