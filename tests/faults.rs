//! One end-to-end test per fault of `flowopt demo --faults`: the daemon as
//! a child process, this test as the controller (or controllers), checking
//! the followability contract: every message says which trajectory to
//! follow, that trajectory starts where the robots were measured, and a bad
//! snapshot is rejected with its reason and changes nothing.

mod common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{ANSWER, Setup, exe, problem};
use flowopt_client::clock::monotonic_ns;
use flowopt_client::{JointTrajectory, PlanStatus, Reason, StateSnapshot};
use flowopt_planner::problem::Problem;

/// Checks that `msg` carries a plan that starts (at its origin) where
/// `p`'s robots were.
fn starts_at(msg: &JointTrajectory, p: &Problem) {
    let start = msg.sample(0.0).unwrap();
    for (k, s) in start.iter().zip(&p.starts) {
        assert!((k.position - s.position).norm() < 1e-9, "{:?} vs {:?}", k.position, s.position);
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
    assert_eq!(first.status(), Ok(PlanStatus::Ok));
    let (sequence, origin) = (first.plan_sequence, first.plan_origin_ns);
    drop(first);
    let bad = c.request(&p, edit);
    assert_eq!((bad.status(), bad.reason()), (Ok(PlanStatus::Held), Ok(reason)));
    assert_eq!((bad.plan_sequence, bad.plan_origin_ns), (sequence, origin), "the held plan, unchanged");
    drop(bad);
    let followed = c.plans.to_follow().unwrap();
    assert_eq!((followed.plan_sequence, followed.origin_ns), (sequence, origin));
    let next = c.request(&p, |_| {});
    assert_eq!(next.status(), Ok(PlanStatus::Ok), "the next valid snapshot is planned");
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
    starts_at(&answer, &p);
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
        if matches!(status, PlanStatus::Ok | PlanStatus::Stopping) {
            starts_at(&answer, &p);
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
