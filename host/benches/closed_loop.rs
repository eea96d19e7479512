//! Host time between levels of the closed loop (issue goal: <= 1 s at 2,000 measured directions):
//! reconstruct from every direction so far, render it, estimate the error and its interval
//! (`closed_loop::Assessor::assess`), at the 16 x 16 x 8 level (1,928 directions) after the 8 x 8
//! level, against the reconstruction alone measured in the same run (the baseline).

use criterion::Criterion;
use gonio::instrument::default_instrument;
use gonio::plan::closed_loop::Assessor;
use gonio::plan::{ggx_estimate, square_grids, PlanConfig, Planner, Strategy};
use std::hint::black_box;
use std::time::{Duration, Instant};

fn main() {
    let estimate = ggx_estimate(0.1, 0.2);
    let plan = Planner::new(default_instrument(), estimate.clone())
        .expect("planner")
        .plan(&PlanConfig {
            strategy: Strategy::Mixture,
            grids: square_grids(4),
            ..PlanConfig::default()
        })
        .expect("plan");
    let truth = gonio::brdf::parse_material("ggx:alpha=0.08,diffuse=0.3/0.2/0.1").expect("truth");
    let values = plan.measure(truth.as_ref());
    let (l3, l4) = (&plan.levels[2], &plan.levels[3]);
    let mut c = Criterion::default().configure_from_args();
    let mut g = c.benchmark_group("closed_loop");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.bench_function("reconstruct 1928", |b| {
        b.iter(|| black_box(gonio::reconstruct::reconstruct(&plan, 4, &values).expect("reconstruct")))
    });
    g.bench_function("between levels 1928", |b| {
        b.iter_batched(
            || {
                let mut a = Assessor::new(None).expect("assessor");
                a.assess(&plan, l3, &values).expect("level 3");
                a
            },
            |mut a| black_box(a.assess(&plan, l4, &values).expect("level 4")),
            criterion::BatchSize::LargeInput,
        )
    });
    g.finish();
    c.final_summary();
    // One plain timed run of each, and their ratio (absolute times on 2 cores are noisy).
    let t = Instant::now();
    gonio::reconstruct::reconstruct(&plan, 4, &values).expect("reconstruct");
    let rec = t.elapsed().as_secs_f64();
    let mut a = Assessor::new(None).expect("assessor");
    a.assess(&plan, l3, &values).expect("level 3");
    let t = Instant::now();
    a.assess(&plan, l4, &values).expect("level 4");
    let between = t.elapsed().as_secs_f64();
    println!(
        "host time between levels at {} directions: {between:.3} s (reconstruction alone {rec:.3} s, ratio {:.2}); goal <= 1 s",
        l4.cumulative_directions,
        between / rec.max(1e-9)
    );
}
