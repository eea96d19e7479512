//! Cost of the `nielsen2015` peer (issue 28's goal: one material's reconstruction <= 50 ms):
//! the ridge fit of one material at each direction count, the direction selection, and the basis
//! built cold (one material's table, and the PCA of all the training tables) or read from the cache.
//!
//!     GONIO_LAB_CACHE=... cargo bench -p gonio-lab --bench nielsen
//!
//! The first run builds the training basis and caches it (`nielsen::cache_dir`).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use glam::DVec3;
use gonio::brdf::nbrdf::NeuralBrdf;
use gonio::brdf::Material;
use gonio_lab::plan::nielsen::basis::{tabulate, Basis};
use gonio_lab::plan::nielsen::{select, training_basis, training_names, Design, RIDGE};
use gonio_shared::kinematics::Kinematics;
use std::hint::black_box;

/// The uniform grid's cumulative counts at 2x2 .. 16x16 (8 incoming elevations).
const COUNTS: [usize; 4] = [24, 104, 456, 1928];

fn peer(c: &mut Criterion) {
    let basis = training_basis().expect("training basis");
    let kin = Kinematics::new(gonio::instrument::default_instrument()).expect("instrument");
    let candidates = select::reachable_bins(&basis, &kin);
    let truth = NeuralBrdf::bundled("tungsten-carbide").expect("bundled material");

    let mut fit = c.benchmark_group("nielsen_fit");
    fit.sample_size(20);
    for n in COUNTS {
        let design = Design::new(&basis, select::select(&basis, &candidates, n), RIDGE).expect("design");
        let values: Vec<DVec3> = design.pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
        fit.bench_with_input(BenchmarkId::from_parameter(n), &values, |b, v| {
            b.iter(|| black_box(design.fit(&basis, v)))
        });
    }
    fit.finish();

    let mut sel = c.benchmark_group("nielsen_select");
    sel.sample_size(10);
    for n in [24, 456] {
        sel.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter(|| black_box(select::select(&basis, &candidates, n)))
        });
    }
    sel.finish();

    // Cold: every training material is tabulated (one shown here), then the PCA of all the tables.
    let names = training_names();
    let materials: Vec<Box<dyn Material>> = names
        .iter()
        .map(|n| Box::new(NeuralBrdf::bundled(n).expect("bundled material")) as Box<dyn Material>)
        .collect();
    let obs = tabulate(&materials);
    let mut cold = c.benchmark_group("nielsen_basis");
    cold.sample_size(10);
    cold.bench_function("tabulate_one_material", |b| {
        b.iter(|| black_box(tabulate(&materials[..1])))
    });
    cold.bench_function(format!("pca_of_{}_materials", names.len()), |b| {
        b.iter(|| black_box(Basis::from_observations(&obs)))
    });
    cold.bench_function("read_cached", |b| {
        b.iter(|| black_box(training_basis().expect("cached basis")))
    });
    cold.finish();
}

criterion_group!(benches, peer);
criterion_main!(benches);
