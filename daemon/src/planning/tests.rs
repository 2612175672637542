//! The followability contract's tests: [`TeamPlanner`]'s answers to
//! snapshots built by hand (held plans, warm and cold plans, stopping
//! plans, obstacles appearing and moving, limits).

use super::*;
use crate::config::TeamConfig;
use crate::preload::PreloadError;
use flowopt_planner::am::{AmSettings, Objective};
use flowopt_planner::metrics::Metrics;
use flowopt_planner::problem::{Dim, Obstacle, Spheroid, StartState};
use flowopt_planner::scenario::RandomScenario;

fn config(robots: usize, extra: &str) -> TeamConfig {
    let text = format!(
        "name = \"t\"\ndim = 2\nrobots = {robots}\nrobot = {{ radius = 0.1 }}\n\
         workspace = {{ min = [-1.0, -1.0], max = [1.0, 1.0] }}\nmax_obstacles = 2\ndeadline_ms = 1000.0\n{extra}"
    );
    toml::from_str(&text).unwrap()
}

/// Answers `problem` measured at `origin_ns` (s 1), the deadline
/// running from `received`.
/// Answers as the daemon does when nothing can be planned in time: no
/// cold planner, and a deadline long past (a result a cold thread
/// finished meanwhile would otherwise be taken, rightly).
fn answer_late(planner: &mut TeamPlanner, problem: &Problem, origin_ns: u64) -> Answer {
    planner.cold = Race::start("test", Vec::new(), None, || {});
    let long_ago = Instant::now() - Duration::from_secs(5);
    answer(planner, problem, origin_ns, long_ago)
}

fn answer(planner: &mut TeamPlanner, problem: &Problem, origin_ns: u64, received: Instant) -> Answer {
    let deadline = received + planner.deadline();
    planner.answer(problem.clone(), origin_ns, origin_ns / 1_000_000, deadline)
}

/// Checks that the held plan starts at `problem`'s state at its origin
/// (within the follow tolerance: a plan made while the robots followed
/// the one before starts on that one) and keeps the true sizes on the
/// dense grid, and, from starts apart, the tracking buffer too: robots
/// grown by the follow tolerance (default 10 mm) do not touch.
fn assert_verified_from(planner: &TeamPlanner, problem: &Problem) {
    let held = planner.held().expect("a held plan");
    let starts: Vec<StartState> = held.plan.at(0.0).iter().map(|k| StartState::at_rest(k.position)).collect();
    let off = held.plan.deviation(0.0, &problem.starts);
    assert!(off <= planner.rules.follow_tolerance, "starts {off} m from the measured state");
    let team = Team { horizon: held.plan.horizon, ..problem.team.clone() };
    let check = Problem { team: team.clone(), starts, ..problem.clone() };
    let m = Metrics::measure(&check, &held.plan);
    assert!(m.min_robot_scaled >= 1.0 && m.workspace_excess <= 0.0, "{m:?}");
    let mut grown = team;
    grown.robot.radius += planner.rules.follow_tolerance;
    grown.robot.half_height += planner.rules.follow_tolerance;
    let buffered = Metrics::measure(&Problem { team: grown, ..check }, &held.plan);
    assert!(buffered.min_robot_scaled >= 1.0, "keeps the tracking buffer: {buffered:?}");
}

/// The first team of the shipped configuration `file` (under the
/// repository root), renamed `name` with a long deadline: preloads with
/// the learned planner racing the optimiser and plans a random problem
/// cold, verified. Returns the team's configuration.
fn shipped_team_plans_cold(file: &str, name: &str) -> TeamConfig {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let config = crate::config::DaemonConfig::load(&root.join(file)).unwrap();
    let mut team = config.teams[0].clone();
    team.name = name.into();
    team.deadline_ms = 10_000.0;
    let mut planner = TeamPlanner::preload(&team).unwrap();
    assert_eq!(planner.cold.members(), 2, "the learned pipeline races the optimiser");
    let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
    let a = answer(&mut planner, &problem, 1_000_000_000, Instant::now());
    assert_eq!((a.follow, a.why, a.warm), (Follow::New, Why::None, false));
    assert_verified_from(&planner, &problem);
    team
}

#[test]
fn the_default_config_preloads_the_shipped_weights_and_plans_cold() {
    let team = shipped_team_plans_cold("config/default.toml", "t");
    // Weights for another dimension are refused at preload.
    let mut three = team.clone();
    three.dim = Dim::Three;
    three.robot = toml::from_str("radius = 0.1").unwrap();
    three.workspace = toml::from_str("min = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]").unwrap();
    let two_d = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/weights/flow.safetensors");
    three.planner.learned.flow = flowopt_models::shipped::WeightsRef::File(two_d);
    three.planner.method = flowopt_methods::Method::Flowopt;
    assert!(matches!(TeamPlanner::preload(&three), Err(PreloadError::Planner(_))));
    // Under `auto` the optimiser plans alone.
    three.planner.method = flowopt_methods::Method::Auto;
    assert_eq!(TeamPlanner::preload(&three).unwrap().cold.members(), 1);
    // A weight file that is named but missing is an error.
    let mut missing = team.clone();
    missing.planner.learned.flow = flowopt_models::shipped::WeightsRef::File("/no/such.safetensors".into());
    let err = TeamPlanner::preload(&missing).unwrap_err().to_string();
    assert!(err.contains("/no/such.safetensors"), "{err}");
}

#[test]
fn the_3d_config_preloads_the_3d_weights_and_plans_cold() {
    shipped_team_plans_cold("config/team3d.toml", "t3");
}

#[test]
fn a_cold_plan_then_a_warm_replan_along_it_are_both_verified() {
    let mut planner = TeamPlanner::preload(&config(8, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
    let first = answer(&mut planner, &problem, 1_000_000_000, Instant::now());
    assert_eq!((first.follow, first.warm), (Follow::New, false));
    assert_verified_from(&planner, &problem);
    let plan0 = planner.held().unwrap().plan.clone();

    // The robots followed the plan for 0.4 s.
    let mut moved = problem.clone();
    for (s, k) in moved.starts.iter_mut().zip(plan0.at(0.4)) {
        s.position = k.position;
        s.velocity = k.velocity;
    }
    let second = answer(&mut planner, &moved, 1_400_000_000, Instant::now());
    assert_eq!((second.follow, second.warm), (Follow::New, true));
    assert_verified_from(&planner, &moved);
    assert!(second.iterations < 100, "warm replans stay cheap: {}", second.iterations);
    assert_eq!(planner.held().unwrap().origin_ns, 1_400_000_000);
}

#[test]
fn changed_goals_get_a_cold_plan() {
    let mut planner = TeamPlanner::preload(&config(4, "")).unwrap();
    let a = RandomScenario::new(planner.team().clone()).generate(1).unwrap();
    answer(&mut planner, &a, 1_000_000_000, Instant::now());
    let mut b = a.clone();
    b.goals.swap(0, 1);
    let replanned = answer(&mut planner, &b, 1_020_000_000, Instant::now());
    assert_eq!((replanned.follow, replanned.warm), (Follow::New, false));
    assert_verified_from(&planner, &b);
}

#[test]
fn robots_that_left_the_plan_get_no_warm_start_and_a_stopping_plan_when_nothing_verifies_in_time() {
    let mut planner = TeamPlanner::preload(&config(16, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(5).unwrap();
    answer(&mut planner, &problem, 1_000_000_000, Instant::now());
    // One second later the robots have not moved (frozen, or a restarted
    // controller), and the deadline has already passed.
    let late = answer_late(&mut planner, &problem, 2_000_000_000);
    assert_eq!((late.follow, late.why, late.warm), (Follow::Stopping, Why::NotFollowing, false));
    let held = planner.held().unwrap();
    assert_eq!((held.kind, held.origin_ns), (Kind::Stopping, 2_000_000_000));
    assert!(held.plan.deviation(held.plan.horizon, &problem.starts) < 1e-6, "robots at rest stay where they are");
    assert_verified_from(&planner, &problem);
}

#[test]
fn a_held_plan_is_reissued_while_the_robots_follow_it() {
    let mut planner = TeamPlanner::preload(&config(16, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(5).unwrap();
    answer(&mut planner, &problem, 1_000_000_000, Instant::now());
    let plan0 = planner.held().unwrap().plan.clone();
    let mut moved = problem.clone();
    for (s, k) in moved.starts.iter_mut().zip(plan0.at(0.3)) {
        s.position = k.position;
        s.velocity = k.velocity;
    }
    // New goals arrive and no plan for them verifies in time.
    moved.goals.rotate_left(1);
    let late = answer_late(&mut planner, &moved, 1_300_000_000);
    assert_eq!((late.follow, late.why), (Follow::Held, Why::DeadlineMissed));
    assert_eq!(planner.held().unwrap().origin_ns, 1_000_000_000, "unchanged, with its own origin");
}

#[test]
fn a_held_plan_to_the_same_goals_serves_without_a_cold_plan() {
    let mut planner = TeamPlanner::preload(&config(16, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(5).unwrap();
    answer(&mut planner, &problem, 1_000_000_000, Instant::now());
    let mut on_it = problem.clone();
    for (s, k) in on_it.starts.iter_mut().zip(planner.held().unwrap().plan.at(0.3)) {
        s.position = k.position;
        s.velocity = k.velocity;
    }
    // No warm replan in time: the held plan is re-issued at once, and
    // no cold plan runs for the goals it already reaches.
    let served = answer_late(&mut planner, &on_it, 1_300_000_000);
    assert_eq!(served.follow, Follow::Held);
    assert!(planner.pending.is_none(), "no cold request for the held plan's goals");
    // Robots off the plan: a cold plan is started for them.
    let mut off = on_it.clone();
    off.starts[0].position.x += 0.2;
    let off_answer = answer_late(&mut planner, &off, 1_320_000_000);
    assert_ne!(off_answer.follow, Follow::Held);
    assert!(planner.pending.is_some(), "a cold request for the robots off the plan");
}

#[test]
fn plans_keep_the_limits_stretched_from_rest() {
    let mut planner = TeamPlanner::preload(&config(4, "max_speed = 0.1\nmax_acceleration = 0.2\n")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(3).unwrap();
    let a = answer(&mut planner, &problem, 1_000_000_000, Instant::now());
    assert_eq!(a.follow, Follow::New);
    let held = planner.held().unwrap();
    let (speed, acceleration) = held.plan.peak_rates(4 * planner.team().samples);
    assert!(speed <= 0.1 && acceleration <= 0.2, "{speed} {acceleration}");
    assert!(held.plan.horizon > planner.team().horizon, "stretched: {}", held.plan.horizon);
    // To the headroom under the limits, no further.
    let room = 1.0 + crate::repair::STRETCH_HEADROOM;
    let tight = (speed * room / 0.1).max((acceleration / 0.2).sqrt() * room);
    assert!((tight - 1.0).abs() < 1e-6, "stretched to the headroom under the limits: {tight}");
    assert_verified_from(&planner, &problem);
    // From a moving start a plan cannot be stretched: one over the
    // limits is refused, never published.
    let mut moving = problem.clone();
    moving.starts[0].velocity.x = 0.05;
    moving.goals.swap(0, 1);
    let b = answer(&mut planner, &moving, 2_000_000_000, Instant::now());
    if b.follow == Follow::New {
        let (speed, acceleration) = planner.held().unwrap().plan.peak_rates(4 * planner.team().samples);
        assert!(speed <= 0.1 && acceleration <= 0.2, "{speed} {acceleration}");
    }
}

#[test]
fn cold_plans_from_motion_over_the_limits_are_refused_for_them() {
    let mut planner = TeamPlanner::preload(&config(4, "max_speed = 0.2\nmax_acceleration = 0.8\n")).unwrap();
    let mut problem = RandomScenario::new(planner.team().clone()).generate(3).unwrap();
    // Robot 0, moving slowly, to the far side of the box: no plan of 5 s
    // gets there within 0.2 m/s (and none can be stretched from motion).
    problem.starts[0].velocity.x = 0.03;
    let far = -problem.starts[0].position.normalize() * 0.85;
    problem.goals[0] = Vector3::new(far.x, far.y, 0.0);
    problem.validate().unwrap();
    let a = answer(&mut planner, &problem, 1_000_000_000, Instant::now());
    assert_ne!(a.follow, Follow::New, "{a:?}");
    assert_eq!(a.why, Why::Limits, "{a:?}");
}

/// Gives `planner` its own racers again (`config`'s), each running
/// `wait` before every request.
fn hold_racers(planner: &mut TeamPlanner, config: &TeamConfig, wait: fn()) {
    let team = planner.team().clone();
    let settings = crate::preload::cold_settings(config.planner_settings(&team));
    let (racers, _) = flowopt_methods::build::members(&settings, &team).unwrap();
    planner.cold = Race::start("t", racers, None, wait);
}

/// Returns once `gate` is open.
fn wait_for(gate: &std::sync::atomic::AtomicBool) {
    while !gate.load(std::sync::atomic::Ordering::Acquire) {
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Opens the racers of [`a_late_cold_plan_is_adopted_when_the_robots_are_still_at_its_start`].
static COLD_GATE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

#[test]
fn a_late_cold_plan_is_adopted_when_the_robots_are_still_at_its_start() {
    let config = config(16, "");
    let mut planner = TeamPlanner::preload(&config).unwrap();
    let team = planner.team().clone();
    // The same racers, held until the late answer is out: its one look
    // for a result (the deadline long past) must come before any. With
    // the preloaded race, a 16-robot cold plan of about a millisecond
    // was now and then done first, while the test thread waited for a
    // core between submitting and looking (CI, 2 cores).
    hold_racers(&mut planner, &config, || wait_for(&COLD_GATE));
    let problem = RandomScenario::new(team).generate(5).unwrap();
    let long_ago = Instant::now() - Duration::from_secs(5);
    let late = answer(&mut planner, &problem, 1_000_000_000, long_ago);
    COLD_GATE.store(true, std::sync::atomic::Ordering::Release);
    assert_eq!(late.follow, Follow::Stopping, "nothing in time: the robots rest");
    let results = planner.cold_results();
    let result = results.recv_timeout(Duration::from_secs(30)).expect("the cold plan keeps running");
    let adopted = planner.on_cold(result).expect("adopted");
    assert_eq!((adopted.follow, adopted.why), (Follow::New, Why::None));
    assert_eq!(planner.held().unwrap().kind, Kind::Goals);
    assert_verified_from(&planner, &problem);
}

/// Opens the racers of [`a_plan_made_while_the_robots_follow_the_held_one_starts_on_it`].
static ANCHOR_GATE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

#[test]
fn a_plan_made_while_the_robots_follow_the_held_one_starts_on_it() {
    let config = config(16, "");
    let mut planner = TeamPlanner::preload(&config).unwrap();
    let team = planner.team().clone();
    let problem = RandomScenario::new(team.clone()).generate(5).unwrap();
    let on_plan = on_the_plan_after(&mut planner, &problem, 0.4);
    let held = planner.held().unwrap().plan.clone();
    // The same racers, held until the late answer is out (as in
    // `a_late_cold_plan_is_adopted_when_the_robots_are_still_at_its_start`).
    hold_racers(&mut planner, &config, || wait_for(&ANCHOR_GATE));
    // New goals (back to the starts), measured 3 mm to one side of the
    // plan: within the follow tolerance (10 mm).
    let shifted = |problem: &Problem, dx: f64| {
        let mut p = problem.clone();
        p.starts.iter_mut().for_each(|s| s.position.x += dx);
        p
    };
    let mut back = shifted(&on_plan, 0.003);
    back.goals = problem.starts.iter().map(|s| s.position).collect();
    let long_ago = Instant::now() - Duration::from_secs(5);
    let late = answer(&mut planner, &back, 1_400_000_000, long_ago);
    ANCHOR_GATE.store(true, std::sync::atomic::Ordering::Release);
    assert_eq!((late.follow, late.why), (Follow::Held, Why::DeadlineMissed), "followed while the cold plan runs");
    // Then measured 3 mm to the other side of it: 6 mm from the first
    // measurement, 3 mm from the plan.
    let mut later = shifted(&on_plan, -0.003);
    later.goals = back.goals.clone();
    planner.newest = Some(World { problem: later, origin_ns: 1_400_000_000, sequence: 2 });
    let results = planner.cold_results();
    let result = results.recv_timeout(Duration::from_secs(30)).expect("the cold plan keeps running");
    let adopted = planner.on_cold(result).expect("adopted");
    assert_eq!((adopted.follow, adopted.why), (Follow::New, Why::None));
    let new = planner.held().unwrap();
    assert_eq!(new.origin_ns, 1_400_000_000, "adopted as planned, not repaired from a later state");
    for (k, h) in new.plan.at(0.0).iter().zip(held.at(0.4)) {
        assert!((k.position - h.position).norm() < 1e-6, "starts where the held plan has the robot");
        assert!((k.velocity - h.velocity).norm() < 1e-6, "at its velocity");
    }
}

#[test]
fn a_robot_knocked_off_the_plan_is_replanned_from_its_measurement_and_the_rest_from_the_plan() {
    let config = config(16, "");
    let mut planner = TeamPlanner::preload(&config).unwrap();
    let team = planner.team().clone();
    let problem = RandomScenario::new(team).generate(5).unwrap();
    let mut knocked = on_the_plan_after(&mut planner, &problem, 0.4);
    let held = planner.held().unwrap().plan.clone();
    // Every robot measured 3 mm to one side of the plan (within the 10 mm
    // follow tolerance) but robot 0, knocked 30 mm off it at 0.3 m/s
    // (within the 50 mm warm tolerance): the plan may not be followed.
    knocked.starts.iter_mut().for_each(|s| s.position.x += 0.003);
    let side = Vector3::new(0.0, 1.0, 0.0);
    knocked.starts[0].position += 0.027 * side;
    knocked.starts[0].velocity += 0.3 * side;
    let replanned = answer(&mut planner, &knocked, 1_400_000_000, Instant::now());
    assert_eq!((replanned.follow, replanned.why, replanned.warm), (Follow::New, Why::None, true));
    let new = planner.held().unwrap();
    let (k, s) = (new.plan.at(0.0), &knocked.starts[0]);
    assert!((k[0].position - s.position).norm() < 1e-9, "robot 0 starts where it was measured");
    assert!((k[0].velocity - s.velocity).norm() < 1e-9, "at its measured velocity");
    for (k, h) in k.iter().zip(held.at(0.4)).skip(1) {
        assert!((k.position - h.position).norm() < 1e-6, "the others start where the held plan has them");
        assert!((k.velocity - h.velocity).norm() < 1e-6, "at its velocity");
    }
    assert_verified_from(&planner, &knocked);
}

/// Plans `problem` from rest, then returns the problem of the robots
/// on that plan `t` seconds later (origin 1 s + t).
fn on_the_plan_after(planner: &mut TeamPlanner, problem: &Problem, t: f64) -> Problem {
    let first = answer(planner, problem, 1_000_000_000, Instant::now());
    assert_eq!(first.follow, Follow::New);
    on(problem, &planner.held().unwrap().plan, t)
}

/// `problem` with the robots where `plan` has them `t` s in, at its
/// velocities.
fn on(problem: &Problem, plan: &JointPlan, t: f64) -> Problem {
    let mut moved = problem.clone();
    for (s, k) in moved.starts.iter_mut().zip(plan.at(t)) {
        s.position = k.position;
        s.velocity = k.velocity;
    }
    moved
}

/// An obstacle of radius 0.1 at `position`, moving at `velocity`.
fn obstacle(position: Vector3<f64>, velocity: Vector3<f64>) -> Obstacle {
    Obstacle { position, velocity, shape: Spheroid::ball(0.1) }
}

/// The robot whose path ahead (from `t` on) comes closest to `target`,
/// and where it will be 2.5 s later.
fn ahead_of(planner: &TeamPlanner, t: f64) -> (usize, Vector3<f64>) {
    let plan = &planner.held().unwrap().plan;
    let (here, later) = (plan.at(t), plan.at(t + 2.5));
    let i = (0..here.len())
        .max_by(|&a, &b| {
            let d = |i: usize| (later[i].position - here[i].position).norm();
            d(a).total_cmp(&d(b))
        })
        .unwrap();
    (i, later[i].position)
}

/// Checks that what the planner holds clears `obstacles` from `origin_ns` on.
fn clears(planner: &TeamPlanner, problem: &Problem, origin_ns: u64) {
    let held = planner.held().expect("a held plan");
    let elapsed = seconds(held.origin_ns, origin_ns);
    let window = (held.plan.horizon - elapsed).max(planner.rules.check_window);
    let check = Recheck::new(&problem.team, &AmSettings::safety_filter());
    assert!(check.clear(&held.plan, elapsed, window, &problem.obstacles), "the followed plan crosses an obstacle");
}

#[test]
fn a_held_plan_an_obstacle_appeared_on_is_replaced_at_once_by_a_verified_stopping_plan() {
    let mut planner = TeamPlanner::preload(&config(8, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
    let mut moved = on_the_plan_after(&mut planner, &problem, 0.4);
    let (_, ahead) = ahead_of(&planner, 0.4);
    moved.obstacles.push(obstacle(ahead, Vector3::zeros()));
    // No time to plan around it: the held plan is not re-issued.
    let a = answer_late(&mut planner, &moved, 1_400_000_000);
    assert_eq!((a.follow, a.why), (Follow::Stopping, Why::WorldChanged));
    assert_eq!(planner.held().unwrap().kind, Kind::Stopping);
    clears(&planner, &moved, 1_400_000_000);
}

#[test]
fn a_team_on_a_stopping_plan_goes_on_from_its_motion_without_coming_to_rest() {
    // Brake, then go: an obstacle appears on the held plan and nothing
    // is planned in time, so the robots brake along a stopping plan; the
    // next snapshot, 0.1 s into it, gets a plan to the goals that starts
    // where the stopping plan has them, still moving.
    let config = config(8, "");
    let mut planner = TeamPlanner::preload(&config).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
    let mut moved = on_the_plan_after(&mut planner, &problem, 1.0);
    let (_, ahead) = ahead_of(&planner, 1.0);
    moved.obstacles.push(obstacle(ahead, Vector3::zeros()));
    let stop = answer_late(&mut planner, &moved, 2_000_000_000);
    assert_eq!(stop.follow, Follow::Stopping);
    let braking = on(&moved, &planner.held().unwrap().plan, 0.1);
    let fastest = braking.starts.iter().map(|s| s.velocity.norm()).fold(0.0, f64::max);
    assert!(fastest > 0.2, "still moving: {fastest} m/s");
    // Racers again; the request `answer_late` left with none is dropped.
    hold_racers(&mut planner, &config, || {});
    planner.pending = None;
    let go = answer(&mut planner, &braking, 2_100_000_000, Instant::now());
    assert_eq!((go.follow, go.why), (Follow::New, Why::None), "{go:?}");
    let held = planner.held().unwrap();
    assert_eq!(held.kind, Kind::Goals);
    for (k, s) in held.plan.at(0.0).iter().zip(&braking.starts) {
        assert!((k.position - s.position).norm() < 1e-6, "starts where the stopping plan has the robot");
        assert!((k.velocity - s.velocity).norm() < 1e-6, "at its velocity, not at rest");
    }
    assert_verified_from(&planner, &braking);
    clears(&planner, &braking, 2_100_000_000);
}

#[test]
fn a_moving_obstacle_whose_reported_motion_crosses_the_held_plan_is_planned_around_or_stopped_for() {
    let mut planner = TeamPlanner::preload(&config(8, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(12).unwrap();
    let moved = on_the_plan_after(&mut planner, &problem, 0.4);
    let (_, ahead) = ahead_of(&planner, 0.4);
    // It walks at 0.4 m/s and reaches that point when the robot does.
    let velocity = Vector3::new(0.4, 0.0, 0.0);
    let crossing = Problem { obstacles: vec![obstacle(ahead - velocity * 2.5, velocity)], ..moved.clone() };
    let check = Recheck::new(&crossing.team, &AmSettings::safety_filter());
    let held = planner.held().unwrap().plan.clone();
    assert!(!check.clear(&held, 0.4, 4.6, &crossing.obstacles), "the setup crosses the held plan");
    for deadline in [Instant::now() - Duration::from_secs(5), Instant::now() + Duration::from_secs(1)] {
        let mut planner = TeamPlanner::preload(&config(8, "")).unwrap();
        on_the_plan_after(&mut planner, &problem, 0.4);
        let a = planner.answer(crossing.clone(), 1_400_000_000, 1400, deadline);
        assert_ne!(a.follow, Follow::Held, "{a:?}");
        if a.follow != Follow::Nothing {
            clears(&planner, &crossing, 1_400_000_000);
        }
    }
}

#[test]
fn a_robot_a_walker_comes_through_is_stopped_beside_its_track() {
    let mut planner = TeamPlanner::preload(&config(8, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
    let horizon = planner.stops[0].engines.team().horizon;
    // A walker at 0.4 m/s reaching a robot at rest 1.2 s from now (at
    // the stopping horizon it is over where the robot would rest), its
    // way there and on for 2.5 s clear of every other robot (a robot
    // it runs into before the horizon has to be planned around it,
    // which is another test's).
    let velocity = Vector3::new(0.0, -0.4, 0.0);
    let clear_of_the_others = |i: usize| {
        let (from, to) = (problem.starts[i].position - velocity * 1.2, problem.starts[i].position + velocity * 2.5);
        problem.starts.iter().enumerate().filter(|(j, _)| *j != i).all(|(_, s)| {
            let along = ((s.position - from).dot(&(to - from)) / (to - from).norm_squared()).clamp(0.0, 1.0);
            (s.position - (from + (to - from) * along)).norm() > 0.45
        })
    };
    let i = (0..8).find(|i| clear_of_the_others(*i)).expect("a robot with a clear way to it");
    let here = problem.starts[i].position;
    let walker = Problem { obstacles: vec![obstacle(here - velocity * 1.2, velocity)], ..problem };
    walker.validate().unwrap();
    assert!((walker.obstacles[0].at(horizon) - here).norm() < 0.2, "the setup puts the walker on the robot");
    let a = planner.observe(walker.clone(), 1_000_000_000, 1, Instant::now() + Duration::from_secs(1));
    assert_eq!(a.follow, Follow::Stopping, "{a:?}");
    clears(&planner, &walker, 1_000_000_000);
    // Robot i rests beside the walker's track.
    let rest = planner.held().unwrap().plan.at(horizon)[i].position;
    assert!((rest.x - here.x).abs() > 0.2, "{rest:?} from {here:?}");
}

/// Robot 0 at top speed towards a walker's track; robot 1 at rest, out
/// of the way. Its stopping point at 1 s (0.75 m ahead) is on the
/// track the walker crosses 0.5 s later.
fn towards_a_walkers_track(planner: &TeamPlanner) -> (Problem, f64) {
    let (x0, v) = (-0.8, 1.5);
    let track = x0 + v * planner.stops[0].engines.team().horizon / 2.0;
    let mut problem = RandomScenario::new(planner.team().clone()).generate(1).unwrap();
    problem.starts = vec![
        StartState { velocity: Vector3::new(v, 0.0, 0.0), ..StartState::at_rest(Vector3::new(x0, 0.0, 0.0)) },
        StartState::at_rest(Vector3::new(-0.8, -0.8, 0.0)),
    ];
    problem.goals = vec![Vector3::new(0.8, 0.0, 0.0), Vector3::new(-0.8, -0.8, 0.0)];
    let walker = Vector3::new(0.0, -0.4, 0.0);
    problem.obstacles = vec![obstacle(Vector3::new(track, 0.6, 0.0), walker)];
    problem.validate().unwrap();
    (problem, track)
}

fn observed(planner: &mut TeamPlanner, problem: &Problem) -> Answer {
    planner.observe(problem.clone(), 1_000_000_000, 1, Instant::now() + Duration::from_secs(1))
}

/// The stopping horizon's filters (for one obstacle) rebuilt with
/// `change` made to their settings.
fn restop(planner: &mut TeamPlanner, change: impl Fn(&mut AmSettings)) {
    let engine = planner.stops[0].engines.get(1).unwrap();
    let mut settings = *engine.settings();
    change(&mut settings);
    planner.stops[0].engines = EngineSet::preloaded(engine.team(), Objective::Projection, settings, 1).unwrap();
}

fn within_the_limits(plan: &JointPlan) {
    let (speed, acceleration) = plan.peak_rates(200);
    assert!(speed <= 1.5 + 1e-9 && acceleration <= 3.0 + 1e-9, "{speed} m/s, {acceleration} m/s^2");
}

#[test]
fn a_robot_that_must_stop_short_of_a_walkers_track_is_stopped_within_the_acceleration_limit() {
    let mut planner = TeamPlanner::preload(&config(2, "")).unwrap();
    let (problem, track) = towards_a_walkers_track(&planner);
    // Its stopping point stepped back towards the start, the repair
    // without the limit stops short over it and is refused; with the
    // limit a constraint of the repair it stops short within it.
    let mut unlimited = TeamPlanner::preload(&config(2, "")).unwrap();
    unlimited.stops.truncate(1);
    restop(&mut unlimited, |s| s.limit_acceleration = false);
    assert_eq!(observed(&mut unlimited, &problem).follow, Follow::Nothing, "without the limit");
    let a = observed(&mut planner, &problem);
    assert_eq!(a.follow, Follow::Stopping, "{a:?}");
    let held = &planner.held().unwrap().plan;
    assert_eq!(held.horizon, planner.stops[0].engines.team().horizon);
    within_the_limits(held);
    assert!(held.at(held.horizon)[0].position.x < track - 0.2, "rests short of the track");
    clears(&planner, &problem, 1_000_000_000);
}

#[test]
fn a_stopping_plan_refused_at_the_stopping_horizon_is_made_over_the_longer_one() {
    let mut planner = TeamPlanner::preload(&config(2, "")).unwrap();
    let horizons: Vec<f64> = planner.stops.iter().map(|s| s.engines.team().horizon).collect();
    assert_eq!(horizons, [1.0, 2.0], "the stopping horizon and twice it");
    let (problem, _) = towards_a_walkers_track(&planner);
    // The stopping horizon's filter allowed no iteration: its plan is
    // the braking reference, which runs into the walker's track.
    restop(&mut planner, |s| s.max_iterations = 0);
    let a = observed(&mut planner, &problem);
    assert_eq!(a.follow, Follow::Stopping, "{a:?}");
    let held = &planner.held().unwrap().plan;
    assert_eq!(held.horizon, horizons[1]);
    within_the_limits(held);
    clears(&planner, &problem, 1_000_000_000);
}

#[test]
fn a_snapshot_whose_goals_cannot_be_planned_still_reports_the_world() {
    let mut planner = TeamPlanner::preload(&config(8, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
    let moved = on_the_plan_after(&mut planner, &problem, 0.4);
    // Goals unchanged, nothing new: the held plan may be followed.
    let same = planner.observe(moved.clone(), 1_400_000_000, 2, Instant::now());
    assert_eq!(same.follow, Follow::Held);
    // An obstacle appeared ahead (the same snapshot's goal is in it):
    // the held plan is no longer followed.
    let (_, ahead) = ahead_of(&planner, 0.4);
    let blocked = Problem { obstacles: vec![obstacle(ahead, Vector3::zeros())], ..moved };
    let a = planner.observe(blocked.clone(), 1_400_000_000, 3, Instant::now() + Duration::from_secs(1));
    assert_eq!((a.follow, a.why), (Follow::Stopping, Why::WorldChanged));
    clears(&planner, &blocked, 1_400_000_000);
}

#[test]
fn a_plan_is_reissued_without_a_measurement_only_while_the_newest_is_fresh() {
    let mut planner = TeamPlanner::preload(&config(4, "")).unwrap();
    let problem = RandomScenario::new(planner.team().clone()).generate(3).unwrap();
    answer(&mut planner, &problem, 1_000_000_000, Instant::now());
    let stale = planner.rules.stale_after_ns;
    assert_eq!(planner.reissue(1_000_000_000 + stale), Follow::Held);
    assert!(planner.held().is_some());
    assert_eq!(planner.reissue(1_000_000_001 + stale), Follow::Nothing);
    assert!(planner.held().is_none(), "nothing is held once nothing is followed");
    assert_eq!(planner.reissue(1_000_000_000), Follow::Nothing);
}
