//! Per-iteration cost of the AM engine and the structured vs dense KKT solve.
//!
//! `cargo bench -p flowopt-planner --bench engine`

use std::hint::black_box;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use flowopt_planner::am::{AmSettings, Engine, Objective};
use flowopt_planner::basis::{BOUNDARY_ROWS, Basis};
use flowopt_planner::kkt::{DenseTeamKkt, TeamKkt};
use flowopt_planner::problem::{Dim, Team};
use flowopt_planner::scenario::RandomScenario;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A feasible plan for a seeded 16-robot 2D instance, perturbed by noise of
/// 10% of the separation on every coefficient: the SF's working point.
fn sf_setup(robots: usize, dim: Dim) -> (Engine, flowopt_planner::am::Prepared, Vec<f64>) {
    let team = Team::default_for(dim, robots);
    let problem = RandomScenario::new(team.clone()).generate(11).expect("instance");
    let optimiser = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser()).expect("engine");
    let solution = optimiser.solve(&problem).expect("solve").state.xi;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let noise = 0.1 * team.separation().0;
    let sample: Vec<f64> = solution.iter().map(|x| x + noise * rng.random_range(-1.0..=1.0)).collect();
    let sf = Engine::new(&team, 0, Objective::Projection, AmSettings::safety_filter()).expect("sf");
    let prepared = sf.prepare(&problem, Some(&sample)).expect("prepare");
    (sf, prepared, sample)
}

fn iterations(c: &mut Criterion) {
    for (robots, dim, name) in [
        (16, Dim::Two, "sf_iteration/16_robots_2d"),
        (32, Dim::Two, "sf_iteration/32_robots_2d"),
        (16, Dim::Three, "sf_iteration/16_robots_3d"),
    ] {
        let (sf, prepared, _) = sf_setup(robots, dim);
        let mut stepper = sf.stepper();
        let start = sf.cold_start(&prepared);
        // Every timed iteration starts from the perturbed sample itself, the
        // iterate with the most violations, not from a converging state.
        c.bench_function(name, |b| {
            b.iter_batched_ref(
                || start.clone(),
                |state| black_box(stepper.step(&prepared, state, 0)),
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

criterion_group!(benches, iterations, kkt);
criterion_main!(benches);
