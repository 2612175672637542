//! Heap allocations of the optimiser's iterations, counted by this test
//! binary's global allocator: none in iterations 100 to 400 of a run,
//! alone and on a crew, with its dense verifications, for a warm
//! start (the daemon's replan) as for a cold one. What a run allocates once
//! (its working memory, the crew's threads) is listed in docs/ENGINE.md.
//!
//! One test in this binary, so that nothing else allocates meanwhile.

use std::sync::atomic::{AtomicUsize, Ordering};

use flowopt_planner::am::{AmSettings, Budget, Engine, Objective};
use flowopt_planner::problem::Dim;
use flowopt_planner::scenes::{Family, Scene};

mod counting;
use counting::ALLOCATIONS;

/// Iterations between two looks at the budget (`am::run`'s
/// `DEADLINE_CHECK_EVERY`).
const CHECK_EVERY: usize = 4;

#[test]
fn iterations_allocate_nothing_after_a_runs_start() {
    // 64 robots (a crew of two), two obstacles, one of them moving.
    let scene = Scene { obstacles: 2, obstacle_speed: 0.3, ..Scene::new(Family::Crowd, Dim::Two, 64, 7) };
    let (problem, _) = scene.generate().expect("the scene generates");
    for threads in [1, 2] {
        // Verifications every 10 iterations from the start, at twice the
        // separations (they fail: the run goes on to its cap).
        let settings = AmSettings {
            threads,
            verify_below: f64::INFINITY,
            verify_margin: 1.0,
            tolerance: -1.0,
            ..AmSettings::optimiser()
        };
        let engine = Engine::new(&problem.team, 2, Objective::smoothness(), settings).expect("the engine builds");
        let prepared = engine.prepare(&problem, None).expect("the problem is valid");
        // A warm start: the solved plan, as the daemon's replan starts from
        // the held one; and the cold start.
        let solver = Engine::new(&problem.team, 2, Objective::smoothness(), AmSettings::optimiser()).expect("builds");
        let warm = solver.solve(&problem).expect("the problem solves").state;
        for (start, name) in [(warm, "warm"), (engine.cold_start(&prepared), "cold")] {
            // The budget's cancellation is asked every few iterations: the
            // count when it is first asked after iteration 100, and at the
            // end of the run's 400.
            let mut capped = settings;
            capped.max_iterations = 400;
            let engine = Engine::new(&problem.team, 2, Objective::smoothness(), capped).expect("builds");
            let (asked, at_100) = (AtomicUsize::new(0), AtomicUsize::new(usize::MAX));
            let cancelled = || {
                if asked.fetch_add(1, Ordering::Relaxed) * CHECK_EVERY >= 100
                    && at_100.load(Ordering::Relaxed) == usize::MAX
                {
                    at_100.store(ALLOCATIONS.load(Ordering::Relaxed), Ordering::Relaxed);
                }
                false
            };
            let outcome = engine.run_within(&prepared, start, &Budget::unlimited().or_cancelled(&cancelled));
            let at_end = ALLOCATIONS.load(Ordering::Relaxed);
            assert_eq!(outcome.iterations, 400, "{name}: the run goes on to its cap");
            let during = at_end - at_100.load(Ordering::Relaxed);
            assert_eq!(during, 0, "{name} start, {threads} thread(s): {during} allocations in iterations 100 to 400");
        }
    }
}
