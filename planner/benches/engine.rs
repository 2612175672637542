//! Per-iteration cost of the AM engine and the structured vs dense KKT solve.
//!
//! `cargo bench -p flowopt-planner --bench engine`

use std::hint::black_box;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use flowopt_planner::basis::{BOUNDARY_ROWS, Basis};
use flowopt_planner::kkt::{DenseTeamKkt, TeamKkt};
use flowopt_planner::problem::Dim;
use flowopt_planner::working_point::WorkingPoint;

fn iterations(c: &mut Criterion) {
    for (robots, dim, name) in [
        (16, Dim::Two, "sf_iteration/16_robots_2d"),
        (32, Dim::Two, "sf_iteration/32_robots_2d"),
        (16, Dim::Three, "sf_iteration/16_robots_3d"),
    ] {
        let point = WorkingPoint::new(robots, dim).expect("working point");
        let mut stepper = point.filter.stepper();
        c.bench_function(name, |b| {
            b.iter_batched_ref(
                || point.start.clone(),
                |state| black_box(stepper.step(&point.prepared, state, 0)),
                BatchSize::SmallInput,
            )
        });
    }
}

fn kkt(c: &mut Criterion) {
    let basis = Basis::new(10, 50).expect("basis");
    let n_xi = basis.n_xi();
    let identity: Vec<f64> = (0..n_xi * n_xi).map(|i| f64::from(i % (n_xi + 1) == 0)).collect();
    let gram = basis.gram(1);
    let boundary = basis.boundary_rows();
    for robots in [16, 32] {
        let rhs: Vec<f64> = (0..robots * n_xi).map(|i| (i as f64 * 0.37).sin()).collect();
        let b: Vec<f64> = (0..robots * BOUNDARY_ROWS).map(|i| (i as f64 * 0.11).cos()).collect();
        let mut out = vec![0.0; robots * n_xi];
        let fast = TeamKkt::new(&identity, &gram, &boundary, robots, 0, 5.0).expect("kkt");
        c.bench_function(&format!("kkt_solve/structured/{robots}_robots"), |bench| {
            bench.iter(|| fast.solve_axis(black_box(&rhs), black_box(&b), &mut out))
        });
        let dense = DenseTeamKkt::new(&identity, &gram, &boundary, robots, 0, 5.0);
        c.bench_function(&format!("kkt_solve/dense/{robots}_robots"), |bench| {
            bench.iter(|| dense.solve_axis(black_box(&rhs), black_box(&b), &mut out))
        });
        c.bench_function(&format!("kkt_factor/structured/{robots}_robots"), |bench| {
            bench.iter(|| TeamKkt::new(&identity, &gram, &boundary, black_box(robots), 0, 5.0))
        });
        c.bench_function(&format!("kkt_factor/dense/{robots}_robots"), |bench| {
            bench.iter(|| DenseTeamKkt::new(&identity, &gram, &boundary, black_box(robots), 0, 5.0))
        });
    }
}

/// Big teams at constant density, from colliding straight curves: the
/// broad phase against every pair.
fn scale(c: &mut Criterion) {
    for robots in [64, 128, 256] {
        for (broad, name) in [(true, "broad_phase"), (false, "all_pairs")] {
            let point = WorkingPoint::crowd(robots, Dim::Two, broad).expect("working point");
            let mut stepper = point.filter.stepper();
            c.bench_function(&format!("sf_iteration_crowd/{robots}_robots_2d/{name}"), |b| {
                b.iter_batched_ref(
                    || point.start.clone(),
                    |state| black_box(stepper.step(&point.prepared, state, 0)),
                    BatchSize::SmallInput,
                )
            });
        }
    }
}

criterion_group!(benches, iterations, kkt, scale);
criterion_main!(benches);
