//! Checks of the `nielsen2015` peer (`plan::nielsen`), with figures for docs/nielsen2015.md:
//!
//! 1. The ridge weight by 5-fold cross-validation over the 75 training materials (never the
//!    held-out fifteen, never rgl): per fold, a basis from the other 60, directions selected for it
//!    (reachable on the default instrument), and each left-out material reconstructed from its
//!    values there; the score is `liu_log_err` against the material itself. Printed per ridge and
//!    count; `nielsen::RIDGE` is the best mean over the counts.
//! 2. Reconstruction time of one material from the full training basis at each count (median of
//!    5 runs): the goal is <= 50 ms.
//!
//!     cargo run --release -p gonio-lab --example nielsen_check [--skip-cv]
//!
//! The basis and the selections are cached as in `gonio-lab tradeoff` (`$GONIO_LAB_CACHE`, else
//! `target/gonio-lab-cache`); the cross-validation builds its own five bases (a few minutes).

use glam::DVec3;
use gonio::brdf::nbrdf::NeuralBrdf;
use gonio::brdf::Material;
use gonio::plan::predict::log_err_over;
use gonio_lab::plan::nielsen::basis::{tabulate, Basis};
use gonio_lab::plan::nielsen::{select, training_basis, training_names, Design, RIDGE};
use gonio_shared::kinematics::Kinematics;
use rand::{Rng, SeedableRng};
use std::time::Instant;

const RIDGES: [f64; 8] = [0.0003, 0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0];
const CV_COUNTS: [usize; 3] = [24, 104, 456];
const FOLDS: usize = 5;
/// Pairs of the cross-validation's score (a fifth of `liu_log_err`'s, other seed: fast, fixed).
const CV_PAIRS: usize = 5_000;

fn main() -> anyhow::Result<()> {
    let skip_cv = std::env::args().any(|a| a == "--skip-cv");
    let kin = Kinematics::new(gonio::instrument::default_instrument()).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    if !skip_cv {
        cross_validate(&kin)?;
    }
    let basis = training_basis().map_err(anyhow::Error::msg)?;
    println!(
        "training basis: {} components from {} materials",
        basis.k(),
        training_names().len()
    );
    let candidates = select::reachable_bins(&basis, &kin);
    println!(
        "reachable bins: {} of {} above the horizon",
        candidates.len(),
        basis.valid.iter().filter(|v| **v).count()
    );
    let truth = NeuralBrdf::bundled("tungsten-carbide")?;
    println!("| directions | condition number (first min(n, K) components) | fit ms (median of 5) |\n|---|---|---|");
    for n in [5usize, 10, 20, 24, 40, 104, 456, 1928] {
        let set = select::select(&basis, &candidates, n);
        let k = n.min(basis.k());
        let cond = select::condition(&basis, &set, k);
        let design = Design::new(&basis, set, RIDGE).map_err(anyhow::Error::msg)?;
        let values: Vec<DVec3> = design.pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        let mut times: Vec<f64> = (0..5)
            .map(|_| {
                let t0 = Instant::now();
                std::hint::black_box(design.fit(&basis, &values));
                t0.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        times.sort_by(f64::total_cmp);
        println!("| {n} | {cond:.1} | {:.1} |", times[2]);
    }
    Ok(())
}

fn cross_validate(kin: &Kinematics<f64>) -> anyhow::Result<()> {
    let names = training_names();
    let materials: Vec<Box<dyn Material>> = names
        .iter()
        .map(|n| NeuralBrdf::bundled(n).map(|m| Box::new(m) as Box<dyn Material>))
        .collect::<Result<_, _>>()?;
    let t0 = Instant::now();
    let obs = tabulate(&materials);
    println!(
        "tabulated {} training materials in {:.1} s",
        materials.len(),
        t0.elapsed().as_secs_f64()
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut dir = || {
        let cos: f64 = 1.0 - rng.random::<f64>();
        gonio::brdf::frame::from_spherical(cos.acos(), std::f64::consts::TAU * rng.random::<f64>())
    };
    let pairs: Vec<(DVec3, DVec3)> = (0..CV_PAIRS).map(|_| (dir(), dir())).collect();
    // score[ridge][count] summed over left-out materials.
    let mut score = vec![vec![0.0f64; CV_COUNTS.len()]; RIDGES.len()];
    for fold in 0..FOLDS {
        let train: Vec<Vec<f64>> = (0..materials.len())
            .filter(|m| m % FOLDS != fold)
            .flat_map(|m| obs[3 * m..3 * m + 3].to_vec())
            .collect();
        let basis = Basis::from_observations(&train);
        let candidates = select::reachable_bins(&basis, kin);
        for (ci, &n) in CV_COUNTS.iter().enumerate() {
            let set = select::select(&basis, &candidates, n);
            for (ri, &ridge) in RIDGES.iter().enumerate() {
                let design = Design::new(&basis, set.clone(), ridge).map_err(anyhow::Error::msg)?;
                for m in (0..materials.len()).filter(|m| m % FOLDS == fold) {
                    let values: Vec<DVec3> = design.pairs.iter().map(|&(wi, wo)| materials[m].eval(wi, wo)).collect();
                    let rec = design.fit(&basis, &values);
                    score[ri][ci] += log_err_over(&pairs, materials[m].as_ref(), &rec);
                }
            }
        }
        println!(
            "fold {} of {FOLDS} done ({:.0} s)",
            fold + 1,
            t0.elapsed().as_secs_f64()
        );
    }
    println!(
        "\ncross-validated liu_log_err ({CV_PAIRS} pairs, seed 7), mean over the {} training materials:\n",
        materials.len()
    );
    println!(
        "| ridge |{} mean |\n|---|{}---|",
        CV_COUNTS.iter().map(|n| format!(" {n} dirs |")).collect::<String>(),
        "---|".repeat(CV_COUNTS.len())
    );
    let mut best = (f64::INFINITY, 0.0);
    for (ri, &ridge) in RIDGES.iter().enumerate() {
        let per: Vec<f64> = score[ri].iter().map(|s| s / materials.len() as f64).collect();
        let mean = per.iter().sum::<f64>() / per.len() as f64;
        if mean < best.0 {
            best = (mean, ridge);
        }
        println!(
            "| {ridge} |{} {mean:.5} |",
            per.iter().map(|v| format!(" {v:.5} |")).collect::<String>()
        );
    }
    println!("\nbest ridge {} (nielsen::RIDGE = {RIDGE})\n", best.1);
    Ok(())
}
