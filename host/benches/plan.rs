//! Planning time against N: estimate -> ordered, timed, encoded and re-checked plan (mixture warp,
//! 8 incoming), for N x N = 4 x 4 .. 16 x 16 under criterion, then one timed run per N up to 32:
//! time per direction (the order is ~O(n K) with bucketed neighbour lists, so it should stay
//! roughly flat) and, for comparison, the time with the O(n^2) lower bound included.

use criterion::{BenchmarkId, Criterion};
use gonio::instrument::default_instrument;
use gonio::plan::{file::encode_plan, ggx_estimate, PlanConfig, Planner, Strategy};
use std::hint::black_box;
use std::time::{Duration, Instant};

fn plan_bytes(level: usize, bound: bool) -> (usize, Vec<u8>) {
    let planner = Planner::new(default_instrument(), ggx_estimate(0.1, 0.2)).expect("planner");
    let plan = planner
        .plan(&PlanConfig {
            strategy: Strategy::Mixture,
            grids: gonio::plan::square_grids(level),
            bound,
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
            b.iter(|| black_box(plan_bytes(l, false)))
        });
    }
    g.finish();
}

fn scaling() {
    println!("\n   N  directions  plan s  x prev N  us / direction  with bound s");
    let mut prev: Option<f64> = None;
    for level in 1..=5usize {
        let t = Instant::now();
        let (n, _) = plan_bytes(level, false);
        let s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        plan_bytes(level, true);
        let with_bound = t.elapsed().as_secs_f64();
        println!(
            "{:>4} {:>11} {:>7.3} {:>9} {:>15.1} {:>13.3}",
            1 << level,
            n,
            s,
            prev.map_or("-".into(), |p| format!("{:.1}", s / p)),
            s / n as f64 * 1e6,
            with_bound
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
