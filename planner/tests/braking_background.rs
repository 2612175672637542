//! The braking bound solved in the background (its own process: the mode
//! is process-wide): a caller never waits for the linear program, reads
//! the physical bound until the speed is solved, and the plan's bound once
//! it is.

use std::time::{Duration, Instant};

use flowopt_planner::braking::{least_excursion, solve_in_background};

#[test]
fn a_speed_not_solved_yet_reads_the_physical_bound_then_the_plans() {
    solve_in_background(|| {});
    // A shape no other test here uses: nothing solved for it yet.
    let excursion = || least_excursion(10, 50, 5.0, 2.5, 0.0, 1.0);
    let physical = 1.0 / (2.0 * 2.5);
    assert_eq!(excursion(), physical, "nothing solved yet: the physical bound");
    let given_up = Instant::now() + Duration::from_secs(120);
    let mut latest = excursion();
    while latest <= physical && Instant::now() < given_up {
        std::thread::sleep(Duration::from_millis(5));
        latest = excursion();
    }
    assert!(latest > physical * 1.05, "the plan's bound once solved: {latest} against {physical}");
    // A slower speed not asked for reads what is solved below it (nothing:
    // the physical bound), a faster one at least the solved one.
    assert_eq!(least_excursion(10, 50, 5.0, 2.5, 0.0, 0.5), 0.25 / 5.0);
    assert!(least_excursion(10, 50, 5.0, 2.5, 0.0, 1.2) >= latest);
}
