//! Render timings: a 256 x 256 point-light render (goal <= 50 ms on 2 cores for analytic materials),
//! environment-map throughput in samples per second (goal: 256 x 256 at 64 spp <= 2 s), how both
//! scale with resolution and spp, and the cost of an empty `[effects]` table against the plain
//! render. After criterion's groups, `main` prints the ratios measured in the same run.

use criterion::{BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use gonio::render::effects::EffectsConfig;
use gonio::render::envmap::EnvMap;
use gonio::render::scene::{DeltaLight, Scene};
use gonio::render::sky::{sky, SkyParams};
use gonio::render::{render, render_plain};
use std::hint::black_box;
use std::time::{Duration, Instant};

const SPEC: &str = "ggx:alpha=0.2,diffuse=0.15/0.08/0.04";

fn scene(size: usize, env: Option<EnvMap>, spp: u32) -> Scene {
    let lights = if env.is_none() {
        vec![DeltaLight::Point {
            position: DVec3::new(2.0, 2.0, 5.0),
            intensity: 30.0,
        }]
    } else {
        Vec::new()
    };
    let mut s = Scene::orthographic_sphere(SPEC, size).expect("valid spec");
    s.lights = lights;
    s.environment = env;
    s.settings.spp = spp;
    s
}

fn sky_env() -> EnvMap {
    EnvMap::new(sky(&SkyParams::default()), 1.0).expect("valid sky")
}

fn point_light(c: &mut Criterion) {
    let mut g = c.benchmark_group("point_light");
    for size in [64usize, 128, 256] {
        let s = scene(size, None, 1);
        g.throughput(Throughput::Elements((size * size) as u64));
        g.bench_with_input(BenchmarkId::new("ggx_2x2_subpixels", size), &s, |b, s| {
            b.iter(|| black_box(render(s).expect("renders")))
        });
    }
    g.finish();
}

fn environment(c: &mut Criterion) {
    let mut g = c.benchmark_group("environment");
    g.sample_size(10);
    let env = sky_env();
    for (size, spp) in [(64usize, 16u32), (64, 64), (128, 64), (256, 64)] {
        let s = scene(size, Some(env.clone()), spp);
        g.throughput(Throughput::Elements((size * size) as u64 * spp as u64));
        g.bench_with_input(BenchmarkId::new(format!("{size}px"), spp), &s, |b, s| {
            b.iter(|| black_box(render(s).expect("renders")))
        });
    }
    g.finish();
}

fn effects(c: &mut Criterion) {
    let mut g = c.benchmark_group("effects");
    let plain = scene(256, None, 1);
    let mut empty = scene(256, None, 1);
    empty.effects = Some(EffectsConfig::default());
    g.bench_function("plain", |b| {
        b.iter(|| black_box(render_plain(&plain, &plain.settings, &|| {})))
    });
    g.bench_function("empty_effects_table", |b| {
        b.iter(|| black_box(render(&empty).expect("renders")))
    });
    g.finish();
}

/// Median wall time of `runs` calls.
fn median(runs: usize, mut f: impl FnMut()) -> Duration {
    let mut t: Vec<Duration> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed()
        })
        .collect();
    t.sort();
    t[runs / 2]
}

fn ratios() {
    let env = sky_env();
    let point = median(15, || {
        black_box(render(&scene(256, None, 1)).expect("renders"));
    });
    let point128 = median(15, || {
        black_box(render(&scene(128, None, 1)).expect("renders"));
    });
    println!(
        "point light 256x256: {:.1} ms; 256x256 / 128x128 time = {:.2} (pixels: 4.00)",
        point.as_secs_f64() * 1e3,
        point.as_secs_f64() / point128.as_secs_f64()
    );
    let s16 = scene(64, Some(env.clone()), 16);
    let s64 = scene(64, Some(env.clone()), 64);
    let t16 = median(5, || drop(black_box(render(&s16))));
    let t64 = median(5, || drop(black_box(render(&s64))));
    let big = scene(256, Some(env), 64);
    let tbig = median(3, || drop(black_box(render(&big))));
    println!(
        "environment 256x256 @ 64 spp: {:.3} s = {:.2} M samples/s; 64 spp / 16 spp time = {:.2} (spp: 4.00)",
        tbig.as_secs_f64(),
        (256.0 * 256.0 * 64.0) / tbig.as_secs_f64() / 1e6,
        t64.as_secs_f64() / t16.as_secs_f64()
    );
    let plain = scene(256, None, 1);
    let mut empty = scene(256, None, 1);
    empty.effects = Some(EffectsConfig::default());
    let tp = median(21, || {
        black_box(render_plain(&plain, &plain.settings, &|| {}));
    });
    let te = median(21, || {
        black_box(render(&empty).expect("renders"));
    });
    println!(
        "empty [effects] / plain render time = {:.3} (expected ~1.00)",
        te.as_secs_f64() / tp.as_secs_f64()
    );
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    point_light(&mut c);
    environment(&mut c);
    effects(&mut c);
    c.final_summary();
    ratios();
}
