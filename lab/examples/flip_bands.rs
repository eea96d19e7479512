//! Where a reconstruction's point-light FLIP comes from: the trade-off report's point-light render
//! (`examples/sphere-point.toml` at 128 px, the `point` columns of `gonio-lab tradeoff`) split into bands
//! of the half-vector angle theta_h of each sphere pixel, for the `auto` plan (from the photo
//! estimate, as `gonio-lab tradeoff`'s `adaptive`) and the uniform grid at one level. First the mean
//! FLIP's split by the pixel's theta_i and theta_o (both grazing at the rim, theta_i grazing at the
//! terminator); then per theta_h band the band's share of the mean FLIP (the shares sum to the mean), the mean luminance of the truth
//! and of the reconstruction, and their ratio per channel; then the profile of f cos theta_i along the plane of the light and the
//! camera (truth, each reconstruction, and its fitted prior without the residual grid).
//!
//!     cargo run --release -p gonio-lab --example flip_bands [LEVEL] [--maps DIR] [MATERIAL ...]
//!
//! LEVEL 1 is the 2x2 level (default); materials default to two held-out metallic paints. With
//! `--maps DIR` the FLIP maps and the renders (sRGB) are written there as PNGs. Used in
//! docs/tradeoff/README.md to locate the 2x2 point-light FLIP loss (the shoulder, theta_h 4-15 deg).

use anyhow::{bail, Context};
use glam::DVec3;
use gonio::brdf::frame::luminance;
use gonio::brdf::{parse_material, Material};
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::predict::Scorer;
use gonio::plan::{PlanConfig, Planner, Strategy};
use gonio::render::scene::{DeltaLight, Scene};
use gonio_lab::plan::tradeoff::{capture_photo, photo_estimate};

/// Band edges in theta_h (degrees); the last band holds pixels facing away from the half vector.
const EDGES: [f64; 11] = [0.0, 2.0, 4.0, 7.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 180.0];
/// Upper edges of the theta_i and theta_o bands (degrees) of the second table: 78.75 is the 8x8
/// uniform grid's last ring; the last band holds pixels the light does not reach.
const ANGLE_EDGES: [f64; 7] = [30.0, 60.0, 70.0, 78.75, 84.0, 90.0, 181.0];
/// Side of the point-light render, as `gonio-lab tradeoff`'s default `--size`.
const SIZE: usize = 128;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let level: usize = args
        .next()
        .map(|a| a.parse())
        .transpose()
        .context("LEVEL")?
        .unwrap_or(1);
    let mut materials: Vec<String> = Vec::new();
    let mut maps: Option<std::path::PathBuf> = None;
    while let Some(a) = args.next() {
        if a == "--maps" {
            maps = Some(args.next().context("--maps needs a folder")?.into());
        } else {
            materials.push(a);
        }
    }
    if let Some(dir) = &maps {
        std::fs::create_dir_all(dir)?;
    }
    if materials.is_empty() {
        materials = vec!["nbrdf:red-metallic-paint".into(), "nbrdf:blue-metallic-paint2".into()];
    }
    // The scorer renders this scene (the same file, built in); its one point light gives each
    // pixel's light direction.
    let scene = Scene::from_toml(
        include_str!("../../examples/sphere-point.toml"),
        std::path::Path::new("examples/sphere-point.toml"),
    )?;
    let Some(DeltaLight::Point { position, .. }) = scene.lights.first().cloned() else {
        bail!("examples/sphere-point.toml: expected one point light");
    };
    let encoder = Encoder::shipped(ModelKind::Ggx)?;
    let instrument = gonio::instrument::default_instrument();
    let mut scorer = Scorer::new(SIZE)?;
    for spec in &materials {
        let truth = parse_material(spec)?;
        let (estimate, _) = photo_estimate(&capture_photo(spec)?.1, &encoder)?;
        println!("== {spec} (photo estimate {})", estimate.model.to_spec());
        let truth_img = scorer.render(parse_material(spec)?);
        if let Some(dir) = &maps {
            truth_img.write(&dir.join(format!("{}-truth.png", gonio_lab::plan::tradeoff::file_stem(spec))))?;
        }
        let mut profiles: Vec<(String, Box<dyn Material>)> = Vec::new();
        for strategy in [Strategy::Auto, Strategy::Uniform] {
            let config = PlanConfig {
                strategy,
                ..PlanConfig::default()
            };
            let plan = Planner::new(instrument, estimate.clone())?.plan(&config)?;
            let rec = gonio::reconstruct::reconstruct(&plan, level, &plan.measure(truth.as_ref()))?;
            let summary = plan.level(level).context("no such level")?;
            let img = scorer.render(Box::new(rec.clone()));
            let (c, map) = gonio::render::metrics::compare(&truth_img, &img)?;
            let prior = rec.prior().cloned();
            if let Some(dir) = &maps {
                let stem = format!("{}-{}-{level}", gonio_lab::plan::tradeoff::file_stem(spec), plan.warp);
                map.write_png(&dir.join(format!("{stem}-flip.png")))?;
                img.write(&dir.join(format!("{stem}.png")))?;
            }
            println!(
                "{} {}x{} ({} directions): mean FLIP {:.4}; prior {}",
                plan.warp,
                summary.n,
                summary.m,
                summary.cumulative_directions,
                c.flip,
                prior.as_ref().map(|p| p.describe()).unwrap_or_else(|| "none".into())
            );
            let bands = EDGES.len() - 1;
            let (mut share, mut count) = (vec![0.0; bands], vec![0usize; bands]);
            let (mut sum_t, mut sum_r) = (vec![DVec3::ZERO; bands], vec![DVec3::ZERO; bands]);
            let total = (map.width * map.height) as f64;
            let mut outside = 0.0;
            let mut by_angles = [[0.0f64; ANGLE_EDGES.len()]; ANGLE_EDGES.len()];
            for py in 0..map.height {
                for px in 0..map.width {
                    let idx = py * map.width + px;
                    let e = map.errors[idx] as f64;
                    // The orthographic camera spans x, y in [-1, 1], row 0 at +y (the scene file).
                    let x = (px as f64 + 0.5) / map.width as f64 * 2.0 - 1.0;
                    let y = 1.0 - (py as f64 + 0.5) / map.height as f64 * 2.0;
                    let r2 = x * x + y * y;
                    if r2 >= 1.0 {
                        outside += e;
                        continue;
                    }
                    let n = DVec3::new(x, y, (1.0 - r2).sqrt());
                    let h = ((position - n).normalize() + DVec3::Z).normalize();
                    let theta_h = n.dot(h).clamp(-1.0, 1.0).acos().to_degrees();
                    let b = EDGES[1..].iter().position(|&edge| theta_h < edge).unwrap_or(bands - 1);
                    share[b] += e / total;
                    let band = |theta: f64| {
                        ANGLE_EDGES
                            .iter()
                            .position(|&edge| theta < edge)
                            .unwrap_or(ANGLE_EDGES.len() - 1)
                    };
                    let theta_i = n.dot((position - n).normalize()).clamp(-1.0, 1.0).acos().to_degrees();
                    let theta_o = n.z.clamp(-1.0, 1.0).acos().to_degrees();
                    by_angles[band(theta_i)][band(theta_o)] += e / total;
                    count[b] += 1;
                    sum_t[b] += truth_img.pixels[idx];
                    sum_r[b] += img.pixels[idx];
                }
            }
            // The bands and the background partition the image, so the shares sum to the mean.
            let sum = share.iter().sum::<f64>() + outside / total;
            if (sum - c.flip).abs() > 1e-9 {
                bail!("band shares sum to {sum}, the mean FLIP is {}", c.flip);
            }
            println!("  FLIP share by theta_i (rows) x theta_o (columns), upper edges (deg) {ANGLE_EDGES:?}");
            for (edge, row) in ANGLE_EDGES.iter().zip(&by_angles) {
                let cells: Vec<String> = row.iter().map(|v| format!("{v:8.5}")).collect();
                println!("  {edge:>7} {}", cells.join(" "));
            }
            println!("  theta_h (deg)  pixels  FLIP share  truth lum  rec lum  rec/truth R G B");
            for b in 0..bands {
                if count[b] == 0 {
                    continue;
                }
                let k = count[b] as f64;
                // A channel the truth leaves black has no ratio.
                let ratio = |r: f64, t: f64| {
                    if t > 0.0 {
                        format!("{:.2}", r / t)
                    } else {
                        "-".to_string()
                    }
                };
                println!(
                    "  {:>5}-{:<6} {:>7}  {:>10.5}  {:>9.4}  {:>7.4}  {} {} {}",
                    EDGES[b],
                    EDGES[b + 1],
                    count[b],
                    share[b],
                    luminance(sum_t[b]) / k,
                    luminance(sum_r[b]) / k,
                    ratio(sum_r[b].x, sum_t[b].x),
                    ratio(sum_r[b].y, sum_t[b].y),
                    ratio(sum_r[b].z, sum_t[b].z)
                );
            }
            println!("  background: FLIP share {:.5}", outside / total);
            let name = plan.warp.to_string();
            profiles.push((name.clone(), Box::new(rec)));
            if let Some(p) = prior {
                profiles.push((format!("{name} prior"), Box::new(p)));
            }
        }
        // In the plane of the light and the camera: the normal at angle a from the view axis toward
        // the light, theta_h = |a - a_h| with a_h the half vector's angle (for a distant light).
        let l = position.normalize();
        let axis = DVec3::new(l.x, l.y, 0.0).normalize();
        let a_h = (0.5 * l.z.clamp(-1.0, 1.0).acos()).to_degrees();
        // The plane's normal, and the tangent frame (s, t, n) of each in-plane surface normal n.
        let t = DVec3::Z.cross(axis).normalize();
        print!("  luminance of f cos theta_i in the plane of incidence\n  theta_h      truth");
        for (name, _) in &profiles {
            print!(" {name:>16}");
        }
        println!();
        for dh in [
            -45.0f64, -30.0, -15.0, -10.0, -6.0, -3.0, -1.0, 0.0, 1.0, 3.0, 6.0, 10.0, 15.0, 30.0, 45.0,
        ] {
            let a = (a_h + dh).to_radians();
            let n = axis * a.sin() + DVec3::Z * a.cos();
            let s = t.cross(n);
            let local = |d: DVec3| DVec3::new(d.dot(s), d.dot(t), d.dot(n));
            let (wi, wo) = (local(l), local(DVec3::Z));
            if wi.z <= 0.0 || wo.z <= 0.0 {
                continue;
            }
            print!("  {dh:>7.1} {:>10.5}", luminance(truth.eval(wi, wo)) * wi.z);
            for (_, m) in &profiles {
                print!(" {:>16.5}", luminance(m.eval(wi, wo)) * wi.z);
            }
            println!();
        }
    }
    Ok(())
}
