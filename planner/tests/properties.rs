//! Properties of plans the engine declares feasible.

use flowopt_planner::am::{AmSettings, Engine, Objective, Stop};
use flowopt_planner::metrics::Metrics;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Dim, FEASIBILITY_TOLERANCE, Team, scaled_norm};
use flowopt_planner::scenario::RandomScenario;
use nalgebra::Vector3;
use proptest::prelude::*;

/// Instants of the independent check: ten times the optimiser's samples.
const CHECK_SAMPLES: usize = 500;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// A plan the optimiser verified has no collision, no obstacle contact and
    /// no box excursion beyond the tolerance on an independent re-sampling
    /// ten times denser than the constraints, and the success verdict agrees.
    #[test]
    fn verified_plans_have_no_collisions_on_a_much_denser_resampling(
        robots in 2usize..10,
        three_d in any::<bool>(),
        obstacles in 0usize..4,
        moving in any::<bool>(),
        start_speed in 0.0f64..0.4,
        seed in 0u64..1_000_000,
    ) {
        let dim = if three_d { Dim::Three } else { Dim::Two };
        let team = Team::default_for(dim, robots);
        let problem = RandomScenario::new(team.clone())
            .with_obstacles(obstacles)
            .with_obstacle_speed(if moving { 0.2 } else { 0.0 })
            .with_start_speed(start_speed)
            .generate(seed)
            .expect("instance");
        let engine = Engine::new(&team, obstacles, Objective::smoothness(), AmSettings::optimiser()).expect("engine");
        let outcome = engine.solve(&problem).expect("solve");
        prop_assume!(outcome.stop == Stop::Verified);
        let plan = JointPlan::new(&team, outcome.state.xi);
        prop_assert!(Metrics::measure(&problem, &plan).success(team.separation().0));
        let positions = plan.sampled(CHECK_SAMPLES, 0);
        let at = |i: usize, s: usize| {
            let mut p = Vector3::zeros();
            for a in 0..dim.axes() {
                p[a] = positions[(a * robots + i) * CHECK_SAMPLES + s];
            }
            p
        };
        let (a, b) = team.separation();
        let floor = 1.0 - FEASIBILITY_TOLERANCE;
        for s in 0..CHECK_SAMPLES {
            let t = team.horizon * s as f64 / (CHECK_SAMPLES - 1) as f64;
            for i in 0..robots {
                for j in i + 1..robots {
                    prop_assert!(scaled_norm(dim, &(at(i, s) - at(j, s)), a, b) >= floor, "robots {i} {j} at t={t}");
                }
                for o in &problem.obstacles {
                    let (ao, bo) = team.obstacle_separation(&o.shape);
                    prop_assert!(scaled_norm(dim, &(at(i, s) - o.at(t)), ao, bo) >= floor, "robot {i} in an obstacle at t={t}");
                }
                for ax in 0..dim.axes() {
                    let slack = FEASIBILITY_TOLERANCE * a;
                    prop_assert!(at(i, s)[ax] >= team.workspace.min[ax] - slack && at(i, s)[ax] <= team.workspace.max[ax] + slack);
                }
            }
        }
    }
}
