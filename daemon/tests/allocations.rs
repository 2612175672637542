//! Heap allocations of the daemon's warm replans (`TeamPlanner::answer`
//! along the held plan), counted by this test binary's global allocator on
//! the answering thread (a team this small iterates on the calling thread
//! alone; the braking bound's background thread and the cold planners,
//! which allocate whenever the scheduler runs them, do not count):
//! the same number for every warm answer after the first, and at most [`CEILING`] for a
//! 16-robot team. What still allocates, and why, is listed in
//! docs/ENGINE.md ("Heap allocations"); the optimiser's iterations
//! allocate nothing (`planner/tests/allocations.rs`).
//!
//! CI once counted 275 for one answer among 273s when every thread
//! counted.

use std::time::{Duration, Instant};

use flowopt_daemon::answer::Follow;
use flowopt_daemon::config::TeamConfig;
use flowopt_daemon::planning::TeamPlanner;
use flowopt_planner::scenario::RandomScenario;

#[path = "../../planner/tests/counting/mod.rs"]
mod counting;
use counting::on_this_thread;

/// The most allocations one warm answer of a 16-robot team may make (273
/// measured when this test was written; 2,546 before the Bernstein rows of
/// a plan's evaluation were written in place and the team's check stopped
/// building a basis).
const CEILING: usize = 300;

/// The team's robots: fewer than a crew needs, so that the answer runs on
/// the calling thread alone.
const ROBOTS: usize = 16;

#[test]
fn every_warm_replan_allocates_the_same_few_hundred_times() {
    let text = format!(
        "name = \"t\"\ndim = 2\nrobots = {ROBOTS}\nrobot = {{ radius = 0.1 }}\n\
                workspace = {{ min = [-1.0, -1.0], max = [1.0, 1.0] }}\nmax_obstacles = 2\ndeadline_ms = 1000.0\n\
                [planner]\nmethod = \"baseline\"\n"
    );
    const { assert!(ROBOTS < flowopt_planner::am::CREW_MIN_ROBOTS, "the team iterates on the answering thread alone") };
    let config: TeamConfig = toml::from_str(&text).expect("the test's configuration parses");
    let mut planner = TeamPlanner::preload(&config).expect("the team preloads");
    let problem = RandomScenario::new(planner.team().clone()).generate(11).expect("a problem");
    let origin = 1_000_000_000u64;
    let first = planner.answer(problem.clone(), origin, 1, Instant::now() + Duration::from_secs(1));
    assert_eq!(first.follow, Follow::New, "the cold plan");
    let mut counts = Vec::new();
    // The robots on the held plan, a snapshot every 20 ms.
    for step in 1..=20u64 {
        let held = planner.held().expect("a held plan");
        let at_ns = origin + step * 20_000_000;
        let mut moved = problem.clone();
        for (s, k) in moved.starts.iter_mut().zip(held.plan.at((at_ns - held.origin_ns) as f64 * 1e-9)) {
            s.position = k.position;
            s.velocity = k.velocity;
        }
        let before = on_this_thread();
        let answer = planner.answer(moved, at_ns, 1 + step, Instant::now() + Duration::from_secs(1));
        counts.push(on_this_thread() - before);
        assert_eq!((answer.follow, answer.warm), (Follow::New, true), "step {step}: a warm replan");
    }
    // After the first (which sets up memory kept for later answers), the
    // same every time.
    let warm = &counts[1..];
    assert!(warm.iter().all(|c| *c == warm[0]), "the same every time: {counts:?}");
    eprintln!("a warm answer allocates {} times on the answering thread", warm[0]);
    assert!(warm[0] <= CEILING, "{} allocations per warm answer, more than {CEILING}", warm[0]);
}
