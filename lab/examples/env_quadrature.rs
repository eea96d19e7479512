//! What the trade-off report's environment score is worth: the deterministic quadrature render
//! (`render::quadrature`, what `Scorer::render_env` now draws) against the Monte Carlo render it
//! replaced, on `examples/sphere-sky.toml` at the report's 128 px and 2 x 2 sub-pixels.
//!
//! Per material it prints FLIP between
//! * two quadrature renders (determinism: 0 when nothing is random),
//! * two Monte Carlo renders at 32 spp with seeds 1 and 2 (the old score's noise),
//! * the quadrature render and a 1,024 spp Monte Carlo render (what the fixed directions cost),
//! * the default quadrature (64 x 32 cells) and a finer one (128 x 64): how far it is from converged,
//!
//! and the wall time of one quadrature render and one 32 spp render.
//!
//!     cargo run --release -p gonio-lab --example env_quadrature [MATERIAL ...]
//!
//! Materials default to two held-out MERL fits and the three real RGL measurements (run from the
//! repository root: `../shared/data/rgl/`). Used in docs/render.md.

use anyhow::Context;
use gonio::brdf::parse_material;
use gonio::plan::predict::score;
use gonio::render::quadrature::{render_quadrature, EnvQuadrature, DEFAULT_COLS, DEFAULT_ROWS};
use gonio::render::{render_plain, Image, Scene};
use std::path::Path;
use std::time::Instant;

/// The trade-off report's environment render side.
const SIZE: usize = 128;

fn main() -> anyhow::Result<()> {
    let mut materials: Vec<String> = std::env::args().skip(1).collect();
    if materials.is_empty() {
        materials = [
            "nbrdf:tungsten-carbide",
            "nbrdf:white-fabric2",
            "rgl:../shared/data/rgl/satin_rosaline_rgb.bsdf",
            "rgl:../shared/data/rgl/cc_iris_purple_gem_rgb.bsdf",
            "rgl:../shared/data/rgl/paper_white_rgb.bsdf",
        ]
        .map(String::from)
        .to_vec();
    }
    let mut scene = Scene::load(Path::new("examples/sphere-sky.toml")).context("run from the repository root")?;
    scene.camera.width = SIZE;
    scene.camera.height = SIZE;
    let env = scene
        .environment
        .clone()
        .context("examples/sphere-sky.toml has no environment")?;
    let quad = EnvQuadrature::of(&env);
    let fine = EnvQuadrature::new(&env, 2 * DEFAULT_COLS, 2 * DEFAULT_ROWS);
    println!(
        "sphere-sky at {SIZE} px, 2 x 2 sub-pixels; quadrature {DEFAULT_COLS} x {DEFAULT_ROWS} cells ({} directions), fine {} directions",
        quad.directions.len(),
        fine.directions.len()
    );
    println!("| material | quad vs quad | MC 32 spp seed 1 vs 2 | quad vs MC 1,024 spp | quad vs fine quad | quad ms | MC 32 spp ms |");
    println!("|---|---|---|---|---|---|---|");
    for spec in &materials {
        scene.material = parse_material(spec)?;
        scene.sampler = gonio::render::brdf_sampling::BrdfSampler::for_spec(spec);
        let t0 = Instant::now();
        let a = render_quadrature(&scene, &quad);
        let quad_ms = t0.elapsed().as_secs_f64() * 1e3;
        let b = render_quadrature(&scene, &quad);
        let f = render_quadrature(&scene, &fine);
        let mc = |spp: u32, seed: u64| -> Image {
            let mut settings = scene.settings.clone();
            settings.spp = spp;
            settings.seed = seed;
            render_plain(&scene, &settings, &|| {})
        };
        let t0 = Instant::now();
        let mc1 = mc(32, 1);
        let mc_ms = t0.elapsed().as_secs_f64() * 1e3;
        let mc2 = mc(32, 2);
        let reference = mc(1024, 1);
        println!(
            "| {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.0} | {:.0} |",
            spec.rsplit('/').next().unwrap_or(spec),
            score(&a, &b)?.flip,
            score(&mc1, &mc2)?.flip,
            score(&a, &reference)?.flip,
            score(&a, &f)?.flip,
            quad_ms,
            mc_ms
        );
    }
    Ok(())
}
