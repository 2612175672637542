//! One end-to-end test per fault of `flowopt demo --faults`: the daemon as
//! a child process, this test as the controller (or controllers), checking
//! the followability contract: every message says which trajectory to
//! follow, that trajectory starts where the robots were measured, and a bad
//! snapshot is rejected with its reason and changes nothing.

mod common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{ANSWER, Controller, STALE_AFTER_MS, Setup, exe, problem};
use flowopt_client::clock::monotonic_ns;
use flowopt_client::{Endpoint, JointTrajectory, PlanStatus, PortError, Reason, StateSnapshot};
use flowopt_planner::metrics::DENSE_FACTOR;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{FEASIBILITY_TOLERANCE, Obstacle, Problem, Spheroid, scaled_norm};
use nalgebra::Vector3;

/// Checks that `msg` carries a plan that starts (at its origin) where
/// `p`'s robots were.
fn starts_at(msg: &JointTrajectory, p: &Problem) {
    starts_within(msg, p, 1e-9);
}

/// Checks that `msg` carries a plan that starts (at its origin) within
/// `tolerance` (m) of where `p`'s robots were.
fn starts_within(msg: &JointTrajectory, p: &Problem, tolerance: f64) {
    let start = msg.sample(0.0).unwrap();
    for (k, s) in start.iter().zip(&p.starts) {
        assert!((k.position - s.position).norm() < tolerance, "{:?} vs {:?}", k.position, s.position);
    }
}

/// A plan, then one bad snapshot: the held plan comes back with `reason`,
/// unchanged, and the next valid snapshot is planned.
fn rejected_and_held(test: &str, edit: impl Fn(&mut StateSnapshot), reason: Reason) {
    let setup = Setup::new(test);
    let _daemon = setup.daemon();
    let mut c = setup.controller(&format!("faults-{test}"));
    let p = problem(4);
    let first = c.request(&p, |_| {});
    assert_eq!((first.status(), first.reason()), (Ok(PlanStatus::Ok), Ok(Reason::None)));
    let (sequence, origin) = (first.plan_sequence, first.plan_origin_ns);
    drop(first);
    let bad = c.request(&p, edit);
    assert_eq!((bad.status(), bad.reason()), (Ok(PlanStatus::Held), Ok(reason)));
    assert_eq!((bad.plan_sequence, bad.plan_origin_ns), (sequence, origin), "the held plan, unchanged");
    drop(bad);
    let followed = c.plans.to_follow().unwrap();
    assert_eq!((followed.plan_sequence, followed.origin_ns), (sequence, origin));
    let next = c.request(&p, |_| {});
    assert_eq!(
        (next.status(), next.reason()),
        (Ok(PlanStatus::Ok), Ok(Reason::None)),
        "the next valid snapshot is planned"
    );
}

#[test]
fn a_speed_glitch_is_rejected_as_implausible() {
    rejected_and_held("glitch", |s| s.robot[0].velocity = [1e6, 0.0, 0.0], Reason::Implausible);
}

#[test]
fn a_nan_state_is_rejected_as_non_finite() {
    rejected_and_held("nan", |s| s.robot[0].position[0] = f64::NAN, Reason::NonFinite);
}

#[test]
fn a_zero_timestamp_is_rejected_by_the_clock_check() {
    rejected_and_held("zero-clock", |s| s.timestamp_ns = 0, Reason::Clock);
}

#[test]
fn a_timestamp_an_hour_ahead_is_rejected_by_the_clock_check() {
    rejected_and_held("future-clock", |s| s.timestamp_ns += 3_600_000_000_000, Reason::Clock);
}

#[test]
fn a_sequence_that_does_not_increase_is_rejected() {
    rejected_and_held("sequence", |s| s.sequence = 1, Reason::Sequence);
}

#[test]
fn a_restarted_controller_with_the_same_goals_gets_a_plan_from_its_robots_state() {
    let setup = Setup::new("restart-controller");
    let _daemon = setup.daemon();
    let p = problem(6);
    let mut first = setup.controller("faults-controller-a");
    assert_eq!(first.request(&p, |_| {}).status(), Ok(PlanStatus::Ok));
    drop(first);
    // The robots did not move while the controller was down; the new one
    // starts its sequences from 1 again.
    std::thread::sleep(Duration::from_millis(500));
    let mut second = setup.controller("faults-controller-b");
    assert!(second.plans.to_follow().is_none(), "nothing to follow before an answer to its own snapshots");
    let answer = second.request(&p, |_| {});
    assert_eq!(answer.answers_sequence, 1);
    assert_eq!(answer.status(), Ok(PlanStatus::Ok), "{:?}", answer.reason());
    assert_eq!(answer.plan_origin_ns, answer.state_timestamp_ns, "made from the new controller's state");
    // A robot measured within the follow tolerance (10 mm) of the held plan
    // starts where that plan has it (it has barely moved the robots in
    // 0.5 s), the others where they were measured.
    starts_within(&answer, &p, 0.010);
}

#[test]
fn frozen_robots_are_only_given_plans_from_where_they_stand() {
    let setup = Setup::new("frozen");
    let _daemon = setup.daemon();
    let mut c = setup.controller("faults-frozen");
    let p = problem(8);
    let since = Instant::now();
    let mut answers = 0;
    while since.elapsed() < Duration::from_secs(2) {
        let answer = c.request(&p, |_| {});
        let status = answer.status().unwrap();
        assert_ne!(status, PlanStatus::NoPlan, "{:?}", answer.reason());
        // A plan made while the robots still count as following the held
        // one (the default follow tolerance, 10 mm) starts on that one.
        if matches!(status, PlanStatus::Ok | PlanStatus::Stopping) {
            starts_within(&answer, &p, 0.010);
        }
        assert!(answer.max_speed <= 1.5 && answer.max_acceleration <= 3.0, "within the default limits");
        answers += 1;
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(answers > 20);
}

#[test]
fn a_second_daemon_for_the_same_team_refuses_to_start() {
    let setup = Setup::new("second");
    let _first = setup.daemon();
    let mut c = setup.controller("faults-second");
    let p = problem(3);
    assert_eq!(c.request(&p, |_| {}).status(), Ok(PlanStatus::Ok));
    let mut second = Command::new(exe())
        .args(["serve", "--config"])
        .arg(&setup.config)
        .args(["--ipc-prefix", &setup.prefix])
        .stdin(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let since = Instant::now();
    while second.try_wait().unwrap().is_none() {
        assert!(since.elapsed() < ANSWER, "the second daemon did not refuse");
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = second.wait_with_output().unwrap();
    assert!(!out.status.success());
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(text.contains(&format!("{}/t/plan", setup.prefix)) && text.contains("\"t\""), "{text}");
    assert_eq!(c.request(&p, |_| {}).status(), Ok(PlanStatus::Ok), "the first still serves");
}

#[test]
fn a_killed_daemon_leaves_the_held_plan_and_its_successor_takes_over() {
    let setup = Setup::new("sigkill");
    let mut daemon = setup.daemon();
    let mut c = setup.controller("faults-sigkill");
    let p = problem(5);
    let plan = c.request(&p, |_| {});
    assert_eq!(plan.status(), Ok(PlanStatus::Ok));
    let origin = plan.plan_origin_ns;
    drop(plan);
    daemon.signal(libc::SIGKILL);
    daemon.0.wait().unwrap();
    // Silence changes nothing for the controller: it keeps the held plan.
    assert!(c.plans.wait(Duration::from_millis(200)).unwrap().is_none());
    assert_eq!(c.plans.to_follow().map(|f| f.origin_ns), Some(origin));
    let _successor = setup.daemon();
    let plan = c.request(&p, |s| s.timestamp_ns = monotonic_ns());
    assert!(plan.status().unwrap().followable(), "{:?}", plan.reason());
}

/// How far ahead the daemon checks followable answers against a moving
/// obstacle's reported motion: `TeamConfig::obstacle_check_s` of the
/// default `obstacle_prediction_s` (3.5 s, less 1 s).
const PREDICTION_S: f64 = 2.5;

/// Checks that `msg`, if it says to follow a trajectory, keeps clear of
/// `obstacles` (reported at `reported_ns`) from then over the rest of its
/// horizon (a moving one over the prediction window), within the success
/// tolerance: this test's own check, not the daemon's.
fn clears(msg: &JointTrajectory, p: &Problem, reported_ns: u64) {
    if !msg.status().unwrap().followable() {
        return;
    }
    let plan = msg.plan().unwrap();
    let elapsed = (reported_ns as f64 - msg.plan_origin_ns as f64) * 1e-9;
    let step = plan.horizon / (DENSE_FACTOR * p.team.samples - 1) as f64;
    let mut t = elapsed.max(0.0);
    while t <= plan.horizon {
        for (i, k) in plan.at(t).iter().enumerate() {
            for o in &p.obstacles {
                if t - elapsed > PREDICTION_S && o.velocity.norm() > 0.0 {
                    continue;
                }
                let (a, b) = p.team.obstacle_separation(&o.shape);
                let d = scaled_norm(p.team.dim, &(k.position - o.at(t - elapsed)), a, b);
                assert!(
                    d >= 1.0 - FEASIBILITY_TOLERANCE,
                    "{:?}/{:?}: robot {i} at {d:.3} of the obstacle {t:.2} s into the plan",
                    msg.status(),
                    msg.reason()
                );
            }
        }
        t += step;
    }
}

/// A first plan from rest for `p` (without obstacles), the daemon's deadline
/// too short for it: the late cold plan, adopted when it verifies; with its
/// origin.
fn first_plan(c: &mut Controller, p: &Problem) -> (JointPlan, u64) {
    let first = c.request(p, |_| {});
    let late = !matches!(first.status(), Ok(PlanStatus::Ok));
    drop(first);
    let msg = if late { c.wait_for(PlanStatus::Ok, Reason::None) } else { c.request(p, |_| {}) };
    assert_eq!(msg.status(), Ok(PlanStatus::Ok));
    (msg.plan().unwrap(), msg.plan_origin_ns)
}

/// The robots of `p` on `plan` `t` s into it, and the robot that moves the
/// most over the next `ahead` s with where it will be then.
fn on_plan(p: &Problem, plan: &JointPlan, t: f64, ahead: f64) -> (Problem, usize, Vector3<f64>) {
    let mut moved = p.clone();
    for (s, k) in moved.starts.iter_mut().zip(plan.at(t)) {
        s.position = k.position;
        s.velocity = k.velocity;
    }
    let later = plan.at(t + ahead);
    let i = (0..p.robots())
        .max_by(|&a, &b| {
            let d = |i: usize| (later[i].position - moved.starts[i].position).norm();
            d(a).total_cmp(&d(b))
        })
        .unwrap();
    (moved, i, later[i].position)
}

/// Sends `world` (the robots on the followed plan, with an obstacle the
/// plan did not know) measured now, five times over a second, and checks
/// every answer: never the old plan re-issued through the obstacle, and
/// whatever is to be followed clears it.
fn never_through(
    c: &mut Controller,
    p: &Problem,
    plan: &JointPlan,
    origin_ns: u64,
    obstacle: impl Fn(f64) -> Obstacle,
) {
    for _ in 0..5 {
        let now = monotonic_ns();
        let t = (now - origin_ns) as f64 * 1e-9;
        let (mut world, _, _) = on_plan(p, plan, t, 0.0);
        world.obstacles = vec![obstacle(t)];
        let answer = c.request(&world, |s| s.timestamp_ns = now);
        assert!(
            !(answer.status() == Ok(PlanStatus::Held) && answer.plan_origin_ns == origin_ns),
            "the plan made before the obstacle was re-issued ({:?})",
            answer.reason()
        );
        clears(&answer, &world, now);
        drop(answer);
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn an_obstacle_appearing_on_the_held_plans_path_is_never_followed_through() {
    // A 1 ms deadline: nothing around the obstacle can be planned in time.
    let setup = Setup::with_deadline("appears", 1.0);
    let _daemon = setup.daemon();
    let mut c = setup.controller("faults-appears");
    let mut p = problem(21);
    p.obstacles.clear();
    let (plan, origin) = first_plan(&mut c, &p);
    // 1.5 s ahead of the robot that moves the most, where it will be.
    let t0 = (monotonic_ns() - origin) as f64 * 1e-9;
    let (_, _, ahead) = on_plan(&p, &plan, t0, 1.5);
    let shape = Spheroid::ball(0.1);
    never_through(&mut c, &p, &plan, origin, |_| Obstacle { position: ahead, velocity: Vector3::zeros(), shape });
}

#[test]
fn a_moving_obstacle_crossing_the_held_plan_is_never_followed_through() {
    let setup = Setup::with_deadline("crossing", 1.0);
    let _daemon = setup.daemon();
    let mut c = setup.controller("faults-crossing");
    let mut p = problem(22);
    p.obstacles.clear();
    let (plan, origin) = first_plan(&mut c, &p);
    // It walks at 0.4 m/s along x and meets the robot that moves the most
    // 2 s from now, where the robot will be.
    let t0 = (monotonic_ns() - origin) as f64 * 1e-9;
    let (_, _, meet) = on_plan(&p, &plan, t0, 2.0);
    let v = Vector3::new(0.4, 0.0, 0.0);
    let shape = Spheroid::ball(0.1);
    never_through(&mut c, &p, &plan, origin, |t| Obstacle { position: meet - v * (t0 + 2.0 - t), velocity: v, shape });
}

#[test]
fn a_second_controller_is_refused_naming_the_team_and_the_first_is_still_served() {
    let setup = Setup::new("second-controller");
    let _daemon = setup.daemon();
    let mut first = setup.controller("faults-first-controller");
    let p = problem(23);
    assert_eq!(first.request(&p, |_| {}).status(), Ok(PlanStatus::Ok));
    let other = Endpoint::new("faults-second-controller").unwrap();
    let err = other.state_publisher(&setup.channel()).unwrap_err();
    assert!(matches!(err, PortError::StateTaken { .. }), "{err}");
    assert!(err.to_string().contains("team \"t\"") && err.to_string().contains("one state source"), "{err}");
    assert!(first.request(&p, |_| {}).status().unwrap().followable());
}

#[test]
fn a_crashed_controllers_successor_takes_over_at_once() {
    let setup = Setup::new("crashed-controller");
    let _daemon = setup.daemon();
    // A controller process, flying the team until it is killed.
    let mut crashed = setup.sim(60.0).stdout(Stdio::null()).spawn().unwrap();
    let watcher = Endpoint::new("faults-watcher").unwrap();
    let mut plans = watcher.plan_watcher(&setup.channel()).unwrap();
    let since = Instant::now();
    while plans.wait(Duration::from_millis(100)).unwrap().is_none() {
        assert!(since.elapsed() < ANSWER, "the simulated controller got no plan");
    }
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(crashed.id() as libc::pid_t, libc::SIGKILL) };
    crashed.wait().unwrap();
    // Its successor publishes at its first try and is answered from its state.
    let mut successor = setup.controller("faults-successor");
    let p = problem(24);
    let answer = successor.request(&p, |_| {});
    assert_eq!((answer.status(), answer.answers_sequence), (Ok(PlanStatus::Ok), 1));
    starts_at(&answer, &p);
}

#[test]
fn rejected_snapshots_reissue_the_held_plan_only_while_the_newest_accepted_one_is_fresh() {
    let setup = Setup::new("stale-rejections");
    let _daemon = setup.daemon();
    let mut c = setup.controller("faults-stale-rejections");
    let p = problem(25);
    let first = c.request(&p, |_| {});
    assert_eq!(first.status(), Ok(PlanStatus::Ok));
    let accepted_ns = first.state_timestamp_ns;
    drop(first);
    // Snapshots with a zero clock for twice stale_after_ms.
    let (mut held, mut none) = (0, 0);
    let since = Instant::now();
    while since.elapsed() < Duration::from_secs_f64(2e-3 * STALE_AFTER_MS) {
        let answer = c.request(&p, |s| s.timestamp_ns = 0);
        assert_eq!(answer.reason(), Ok(Reason::Clock));
        let age_ms = (answer.received_ns - accepted_ns) as f64 * 1e-6;
        let expected = if age_ms <= STALE_AFTER_MS { PlanStatus::Held } else { PlanStatus::NoPlan };
        assert_eq!(answer.status(), Ok(expected), "{age_ms:.1} ms after the accepted snapshot");
        if expected == PlanStatus::Held {
            held += 1
        } else {
            none += 1
        }
        drop(answer);
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(held > 0 && none > 0, "{held} held, {none} without a plan");
    // A valid snapshot is planned again.
    assert_eq!(c.request(&p, |s| s.timestamp_ns = monotonic_ns()).status(), Ok(PlanStatus::Ok));
}
