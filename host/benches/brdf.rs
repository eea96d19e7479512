//! Evaluations per second for each material type, and warp sample / invert per second.
//! Each iteration processes a fixed batch of 1024 direction pairs (or u points) drawn with a fixed
//! seed, and criterion reports the throughput in elements per second.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::{DVec2, DVec3};
use gonio::brdf::analytic::{Ggx, Lambert, Ward};
use gonio::brdf::frame::from_spherical;
use gonio::brdf::grid::{MeasurementGrid, NodeLayout, THETA_I_MAX};
use gonio::brdf::merl::{Lookup, MerlTable};
use gonio::brdf::nbrdf::NeuralBrdf;
use gonio::brdf::rgl::{tabulate_ggx, RglBsdf};
use gonio::brdf::warp::{Warp, WarpKind};
use gonio::brdf::Material;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;
use std::path::Path;

const BATCH: usize = 1024;

fn pairs() -> Vec<(DVec3, DVec3)> {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let dir =
        |rng: &mut ChaCha8Rng| from_spherical(rng.random::<f64>().acos(), std::f64::consts::TAU * rng.random::<f64>());
    (0..BATCH).map(|_| (dir(&mut rng), dir(&mut rng))).collect()
}

/// `material` measured on a nested N x N grid of `warp`'s slices at K equal-angle elevations.
fn measured_grid(material: &dyn Material, warp: WarpKind, k: usize, n: usize) -> Option<MeasurementGrid> {
    let thetas: Vec<f64> = (0..k).map(|i| i as f64 / (k - 1) as f64 * THETA_I_MAX).collect();
    let slices = thetas
        .iter()
        .map(|&t| warp.for_incident(from_spherical(t, 0.0)))
        .collect();
    let cells = k * n * n;
    let mut grid = MeasurementGrid::from_slices(
        slices,
        NodeLayout::Nested,
        thetas,
        n,
        n,
        vec![DVec3::ZERO; cells],
        vec![false; cells],
    )
    .ok()?;
    for kk in 0..k {
        for j in 0..n {
            for i in 0..n {
                let v = grid.node_directions(kk, i, j).map(|(wi, wo)| material.eval(wi, wo));
                grid.set_node(kk, i, j, v);
            }
        }
    }
    Some(grid)
}

fn eval(c: &mut Criterion) {
    let ggx = Ggx {
        alpha: 0.2,
        diffuse: DVec3::splat(0.1),
        specular: DVec3::ONE,
    };
    let mut merl_tri = MerlTable::tabulate(&ggx);
    merl_tri.lookup = Lookup::Trilinear;
    let mut materials: Vec<(&str, Box<dyn Material>)> = vec![
        (
            "lambert",
            Box::new(Lambert {
                albedo: DVec3::splat(0.5),
            }),
        ),
        (
            "ward",
            Box::new(Ward {
                rho_d: DVec3::splat(0.2),
                rho_s: DVec3::splat(0.8),
                alpha: 0.2,
            }),
        ),
        ("ggx", Box::new(ggx.clone())),
        ("merl-nearest", Box::new(MerlTable::tabulate(&ggx))),
        ("merl-trilinear", Box::new(merl_tri)),
    ];
    if let Ok(n) = NeuralBrdf::bundled("alum-bronze") {
        materials.push(("nbrdf", Box::new(n)));
    }
    if let Ok(r) = RglBsdf::from_bytes(&tabulate_ggx(&ggx, 0.2, 8, 128, 64), Path::new("bench.bsdf")) {
        materials.push(("rgl", Box::new(r)));
    }
    if let Some(g) = measured_grid(&ggx, WarpKind::GgxVndf { alpha: 0.2 }, 8, 32) {
        materials.push(("grid-32x32-vndf", Box::new(g)));
    }
    let pairs = pairs();
    let mut group = c.benchmark_group("eval");
    group.throughput(Throughput::Elements(BATCH as u64));
    for (name, m) in &materials {
        group.bench_function(*name, |b| {
            b.iter(|| {
                let mut acc = DVec3::ZERO;
                for &(wi, wo) in &pairs {
                    acc += m.eval(black_box(wi), black_box(wo));
                }
                acc
            })
        });
    }
    group.finish();
}

fn warps(c: &mut Criterion) {
    let wi = from_spherical(45f64.to_radians(), 0.0);
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let us: Vec<DVec2> = (0..BATCH).map(|_| DVec2::new(rng.random(), rng.random())).collect();
    let kinds = [
        WarpKind::Cosine,
        WarpKind::Ward { alpha: 0.2 },
        WarpKind::GgxNdf { alpha: 0.2 },
        WarpKind::GgxVndf { alpha: 0.2 },
    ];
    let mut group = c.benchmark_group("warp");
    group.throughput(Throughput::Elements(BATCH as u64));
    for kind in kinds {
        let warp = kind.for_incident(wi);
        let wos: Vec<DVec3> = us.iter().filter_map(|&u| warp.sample(u)).collect();
        group.bench_with_input(BenchmarkId::new("sample", kind), &us, |b, us| {
            b.iter(|| us.iter().filter_map(|&u| warp.sample(black_box(u))).count())
        });
        // Invert the valid samples, cycled to a full batch so the throughput stays comparable.
        let wos: Vec<DVec3> = wos.iter().cycle().take(BATCH).copied().collect();
        group.bench_with_input(BenchmarkId::new("invert", kind), &wos, |b, wos| {
            b.iter(|| wos.iter().filter_map(|&w| warp.invert(black_box(w))).count())
        });
    }
    group.finish();
}

criterion_group!(benches, eval, warps);
criterion_main!(benches);
