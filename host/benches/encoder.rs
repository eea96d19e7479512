//! Encoder timings on one core (tract runs single-threaded; preprocessing has no rayon): the
//! network alone on its 64 x 64 input, and a whole estimate from a 128 x 128 photo (crop, resample,
//! normalise, network), goal <= 2 ms; plus the load time of the shipped models (parse, optimise,
//! plan). After criterion's groups, `main` prints the shares measured in the same run.

use criterion::Criterion;
use gonio::encoder::capture::render_capture;
use gonio::encoder::infer::{shipped, Encoder};
use gonio::encoder::photo::estimate_from_image;
use gonio::encoder::{preprocess, resample_square, ModelKind};
use gonio::render::Image;
use std::hint::black_box;
use std::time::{Duration, Instant};

fn photo128() -> Image {
    // A 64 x 64 capture render upsampled to the 128 x 128 photo of the goal.
    let small = render_capture("ggx:alpha=0.1,diffuse=0.2/0.1/0.05", 1.0).expect("render");
    let mut big = Image::new(128, 128);
    for y in 0..128 {
        for x in 0..128 {
            big.pixels[y * 128 + x] = small.get(x / 2, y / 2);
        }
    }
    big
}

fn benches(c: &mut Criterion) {
    let photo = photo128();
    let input = preprocess(&photo).expect("preprocess");
    for kind in [ModelKind::Ward, ModelKind::Ggx] {
        let enc = Encoder::shipped(kind).expect("shipped model");
        let mut g = c.benchmark_group(format!("encoder_{}", kind.name()));
        g.bench_function("network_64x64", |b| {
            b.iter(|| enc.estimate(black_box(&input)).expect("run"))
        });
        g.bench_function("estimate_from_128x128_photo", |b| {
            b.iter(|| enc.estimate(&preprocess(black_box(&photo)).expect("pre")).expect("run"))
        });
        g.sample_size(10);
        g.bench_function("load_model", |b| {
            b.iter(|| Encoder::from_bytes(black_box(shipped(kind))).expect("load"))
        });
        g.finish();
    }
    // The planner's whole photo step: GGX network + the diffuse/specular split fitted against two
    // capture renders (encoder::photo).
    let ggx = Encoder::shipped(ModelKind::Ggx).expect("shipped model");
    let mut g = c.benchmark_group("photo_estimate");
    g.sample_size(10);
    g.bench_function("ggx_with_ratio_fit_128x128", |b| {
        b.iter(|| estimate_from_image(black_box(&photo), &ggx, None).expect("estimate"))
    });
    g.finish();
    c.bench_function("preprocess_128x128", |b| {
        b.iter(|| preprocess(black_box(&photo)).expect("pre"))
    });
    c.bench_function("resample_128_to_64", |b| {
        b.iter(|| resample_square(black_box(&photo), 64))
    });
}

/// Mean time of `f` over `n` runs after one warm-up.
fn mean(n: u32, mut f: impl FnMut()) -> Duration {
    f();
    let t = Instant::now();
    for _ in 0..n {
        f();
    }
    t.elapsed() / n
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    benches(&mut c);
    c.final_summary();
    let photo = photo128();
    let input = preprocess(&photo).expect("preprocess");
    println!("\nsummary (same run, one core):");
    for kind in [ModelKind::Ward, ModelKind::Ggx] {
        let enc = Encoder::shipped(kind).expect("model");
        let net = mean(200, || {
            enc.estimate(&input).expect("run");
        });
        let pre = mean(200, || {
            preprocess(&photo).expect("pre");
        });
        let load = mean(5, || {
            Encoder::from_bytes(shipped(kind)).expect("load");
        });
        println!(
            "  {:<4} network {:>7.3} ms + preprocessing {:>6.3} ms = estimate {:>7.3} ms per 128x128 photo \
             (goal <= 2 ms: {}); preprocessing is {:.0}% of it; model load {:.1} ms",
            kind.name(),
            net.as_secs_f64() * 1e3,
            pre.as_secs_f64() * 1e3,
            (net + pre).as_secs_f64() * 1e3,
            if net + pre <= Duration::from_millis(2) {
                "met"
            } else {
                "NOT met"
            },
            100.0 * pre.as_secs_f64() / (net + pre).as_secs_f64(),
            load.as_secs_f64() * 1e3
        );
    }
    let ggx = Encoder::shipped(ModelKind::Ggx).expect("model");
    let photo_step = mean(10, || {
        estimate_from_image(&photo, &ggx, None).expect("estimate");
    });
    println!(
        "  photo -> planner estimate (ggx network + diffuse/specular fit): {:.1} ms",
        photo_step.as_secs_f64() * 1e3
    );
}
