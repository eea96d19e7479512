//! Where a reconstruction's environment-light FLIP comes from: the closed loop's env score
//! (`examples/sphere-sky.toml` at `ENV_SIZE`, the noise-free quadrature render of
//! `gonio-lab closed-loop`) for the product's plan (`auto`, from the photo estimate, as the
//! closed loop's `adaptive`) at each level, its mean FLIP split over the sphere's pixels by the
//! view elevation theta_o (the rim is grazing) and by the elevation of the mirror-reflected
//! direction above the world horizon (which part of the sky a pixel mirrors: ground, horizon, sky).
//! Each cell is its pixels' share of the mean FLIP (the cells of one split sum to it); `background`
//! is the pixels whose centre misses the sphere (edge pixels the sub-pixel grid partly covers, and
//! error FLIP's spatial filter spreads past the silhouette).
//!
//!     cargo run --release -p gonio-lab --example env_flip_bands -- SPEC [SPEC...]
//!
//! Used in docs/tradeoff/README.md to read fruitwood-241's level 3 -> 4 env FLIP step.

use anyhow::Context;
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::predict::Scorer;
use gonio::plan::{square_grids, PlanConfig, Planner, Strategy};
use gonio::reconstruct::reconstruct;
use gonio::render::Scene;
use gonio_lab::plan::tradeoff::closed_loop::ENV_SIZE;
use gonio_lab::plan::tradeoff::{capture_photo, photo_estimate};

/// Upper edges of the view-elevation bands (degrees).
const VIEW_EDGES: [f64; 6] = [30.0, 60.0, 70.0, 80.0, 85.0, 90.1];
/// Upper edges of the reflected direction's elevation bands (degrees above the world horizon).
const SKY_EDGES: [f64; 5] = [0.0, 10.0, 30.0, 60.0, 90.1];

fn band(edges: &[f64], x: f64) -> usize {
    edges.iter().position(|&e| x < e).unwrap_or(edges.len() - 1)
}

fn main() -> anyhow::Result<()> {
    let specs: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(!specs.is_empty(), "usage: env_flip_bands SPEC [SPEC...]");
    // The closed loop's default `--env-scene`.
    let mut env = Scene::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/sphere-sky.toml"
    )))?;
    env.camera.width = ENV_SIZE;
    env.camera.height = ENV_SIZE;
    let (camera, shape) = (env.camera.clone(), env.shape);
    let mut scorer = Scorer::new(ENV_SIZE)?.with_env(env);
    let encoder = Encoder::shipped(ModelKind::Ggx)?;
    let heads = |edges: &[f64]| edges.iter().map(|e| format!("<{e:>4.0}")).collect::<Vec<_>>().join(" ");
    for spec in &specs {
        let (estimate, _) = photo_estimate(&capture_photo(spec)?.1, &encoder)?;
        let truth = gonio::brdf::parse_material(spec)?;
        let truth_img = scorer
            .render_env(gonio::brdf::parse_material(spec)?, spec)
            .context("no environment")?;
        let config = PlanConfig {
            strategy: Strategy::Auto,
            grids: square_grids(4),
            ..PlanConfig::default()
        };
        let plan = Planner::new(gonio::instrument::default_instrument(), estimate)?.plan(&config)?;
        let values = plan.measure(truth.as_ref());
        println!(
            "== {spec}: share of the mean env FLIP by view elevation theta_o [{}] | by reflected elevation [{}]",
            heads(&VIEW_EDGES),
            heads(&SKY_EDGES)
        );
        for level in 1..=plan.levels.len() {
            let rec = reconstruct(&plan, level, &values)?;
            let img = scorer.render_env(Box::new(rec), spec).context("no environment")?;
            let (c, map) = gonio::render::metrics::compare(&truth_img, &img)?;
            let total = (map.width * map.height) as f64;
            let (mut view, mut sky, mut background) = (vec![0.0; VIEW_EDGES.len()], vec![0.0; SKY_EDGES.len()], 0.0);
            for py in 0..map.height {
                for px in 0..map.width {
                    let e = map.errors[py * map.width + px] as f64 / total;
                    let ray = camera.ray(px as f64 + 0.5, py as f64 + 0.5);
                    let Some(hit) = shape.intersect(&ray) else {
                        background += e;
                        continue;
                    };
                    let cos_o = (-ray.dir).dot(hit.normal).clamp(-1.0, 1.0);
                    view[band(&VIEW_EDGES, cos_o.acos().to_degrees())] += e;
                    let reflected = gonio::brdf::frame::reflect(-ray.dir, hit.normal);
                    sky[band(&SKY_EDGES, reflected.y.clamp(-1.0, 1.0).asin().to_degrees())] += e;
                }
            }
            let cells = |v: &[f64]| v.iter().map(|x| format!("{x:.4}")).collect::<Vec<_>>().join(" ");
            println!(
                "level {level} ({} directions): env FLIP {:.4} = view {} | reflected {} | background {background:.4}",
                plan.levels[level - 1].cumulative_directions,
                c.flip,
                cells(&view),
                cells(&sky)
            );
        }
    }
    Ok(())
}
