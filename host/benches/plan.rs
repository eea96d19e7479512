//! Planning time against N: estimate -> ordered, timed, encoded and re-checked plan (mixture warp,
//! 8 incoming), for N x N = 4 x 4 .. 16 x 16 under criterion, then one timed run per N up to 32:
//! time per direction (the order is ~O(n K) with bucketed neighbour lists and don't-look bits, so
//! it should stay roughly flat; the lower bound comes free with the neighbour lists), then the
//! issue's figure: capture photo (`examples/sample.png`) -> estimate -> encoded, checked plan at N = 32.

use criterion::{BenchmarkId, Criterion};
use gonio::instrument::default_instrument;
use gonio::plan::{file::encode_plan, ggx_estimate, PlanConfig, Planner, Strategy};
use std::hint::black_box;
use std::time::{Duration, Instant};

fn plan_bytes(level: usize) -> (usize, Vec<u8>) {
    plan_bytes_for(ggx_estimate(0.1, 0.2), level)
}

fn plan_bytes_for(estimate: gonio::plan::Estimate, level: usize) -> (usize, Vec<u8>) {
    let planner = Planner::new(default_instrument(), estimate).expect("planner");
    let plan = planner
        .plan(&PlanConfig {
            strategy: Strategy::Mixture,
            grids: gonio::plan::square_grids(level),
            ..PlanConfig::default()
        })
        .expect("plan");
    let bytes = encode_plan(&plan.wire()).expect("encode");
    plan.check_encoded(&default_instrument(), &bytes).expect("check");
    (plan.directions.len(), bytes)
}

fn planning(c: &mut Criterion) {
    let mut g = c.benchmark_group("plan");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    for level in [2usize, 3, 4] {
        g.bench_with_input(BenchmarkId::from_parameter(1 << level), &level, |b, &l| {
            b.iter(|| black_box(plan_bytes(l)))
        });
    }
    g.finish();
}

fn scaling() {
    println!("\n   N  directions  plan s  x prev N  us / direction");
    let mut prev: Option<f64> = None;
    for level in 1..=5usize {
        let t = Instant::now();
        let (n, _) = plan_bytes(level);
        let s = t.elapsed().as_secs_f64();
        println!(
            "{:>4} {:>11} {:>7.3} {:>9} {:>15.1}",
            1 << level,
            n,
            s,
            prev.map_or("-".into(), |p| format!("{:.1}", s / p)),
            s / n as f64 * 1e6,
        );
        prev = Some(s);
    }
    let photo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/sample.png");
    for run in 1..=3 {
        let t = Instant::now();
        let estimate = gonio::encoder::photo::estimate_from_photo(&photo, gonio::encoder::ModelKind::Ggx)
            .expect("examples/sample.png")
            .estimate;
        let e = t.elapsed().as_secs_f64();
        let (n, bytes) = plan_bytes_for(estimate, 5);
        let total = t.elapsed().as_secs_f64();
        println!(
            "photo -> encoded plan at N = 32, run {run}: {total:.3} s ({n} directions, {} B; estimate incl. model load {e:.3} s)",
            bytes.len()
        );
    }
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    planning(&mut c);
    c.final_summary();
    scaling();
}
