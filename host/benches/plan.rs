//! Planning time against N: estimate -> ordered, timed, encoded plan (mixture warp, 8 incoming),
//! for N x N = 4 x 4 .. 16 x 16 under criterion, then one timed run per N up to 32 with the ratio to
//! the previous N and to the direction count squared (the order and bound are O(n^2) in a level's n
//! directions, so doubling N, which quadruples n, should cost ~16x at most).

use criterion::{BenchmarkId, Criterion};
use gonio::instrument::default_instrument;
use gonio::plan::{file::encode_plan, ggx_estimate, PlanConfig, Planner, Strategy};
use std::hint::black_box;
use std::time::{Duration, Instant};

fn plan_bytes(level: usize) -> (usize, Vec<u8>) {
    let planner = Planner::new(default_instrument(), ggx_estimate(0.1, 0.2)).expect("planner");
    let plan = planner
        .plan(&PlanConfig {
            strategy: Strategy::Mixture,
            max_level: level,
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
    println!("\n   N  directions  seconds  x prev N  seconds / n^2 (ns)");
    let mut prev: Option<f64> = None;
    for level in 1..=5usize {
        let t = Instant::now();
        let (n, _) = plan_bytes(level);
        let s = t.elapsed().as_secs_f64();
        println!(
            "{:>4} {:>11} {:>8.3} {:>9} {:>19.1}",
            1 << level,
            n,
            s,
            prev.map_or("-".into(), |p| format!("{:.1}", s / p)),
            s / (n * n) as f64 * 1e9
        );
        prev = Some(s);
    }
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    planning(&mut c);
    c.final_summary();
    scaling();
}
