//! Stopping problems: every robot brought to rest along its motion.
//!
//! From a measured state `(p, v)` each robot's stopping point is
//! `p + v T_s / 2` (where a constant deceleration over `T_s` brings it to
//! rest), kept inside the workspace; the problem keeps the obstacles and
//! plans over the stopping horizon `T_s`. Planned and verified like any
//! other problem, it gives robots that left their plan a way to rest
//! that is checked against each other and the obstacles.
//!
//! A stopping point that an obstacle is predicted to cover while the robot
//! rests there (from `T_s` to the end of the obstacle's prediction,
//! [`Team::predicted_until`]: a walker coming through) is moved out of
//! the obstacle's track, sideways to it, and stopping points that overlap
//! are moved apart, each to [`REST_CLEARANCE`] (scaled): the robot steps
//! aside instead of the team having no stopping plan at all.

use nalgebra::Vector3;

use crate::problem::{Dim, Obstacle, Problem, Team, scaled_norm};

/// The scaled distance a moved stopping point is given from an
/// obstacle's track and from another stopping point: room for the
/// constraints' margin around a plan's end.
pub const REST_CLEARANCE: f64 = 1.1;

/// Rounds of moving stopping points (each can move another back into
/// something; most scenes need one).
const REST_ROUNDS: usize = 8;

/// The team `team` with the stopping horizon `horizon` (s).
pub fn stopping_team(team: &Team, horizon: f64) -> Team {
    Team { horizon, ..team.clone() }
}

/// The problem of bringing every robot of `problem` to rest over
/// `horizon` seconds along its motion, each stopping point kept `inset`
/// metres inside the workspace and moved out of obstacles' tracks and
/// apart from the others (the module's doc). Not validated: stopping
/// points may still overlap (a crowd against a wall), which
/// [`Problem::validate`] then reports.
pub fn stopping_problem(problem: &Problem, horizon: f64, inset: f64) -> Problem {
    let team = stopping_team(&problem.team, horizon);
    let inside = |g: &mut Vector3<f64>| {
        for a in 0..team.dim.axes() {
            let (lo, hi) = (team.workspace.min[a] + inset, team.workspace.max[a] - inset);
            g[a] = if lo <= hi { g[a].clamp(lo, hi) } else { (lo + hi) / 2.0 };
        }
    };
    let mut goals: Vec<Vector3<f64>> = problem
        .starts
        .iter()
        .map(|s| {
            let mut g = s.position + s.velocity * (horizon / 2.0);
            inside(&mut g);
            g
        })
        .collect();
    for _ in 0..REST_ROUNDS {
        let mut moved = false;
        for g in goals.iter_mut() {
            for o in &problem.obstacles {
                moved |= step_aside(&team, o, g, &inside);
            }
        }
        moved |= spread(&team, &mut goals);
        goals.iter_mut().for_each(inside);
        if !moved {
            break;
        }
    }
    Problem { team, starts: problem.starts.clone(), goals, obstacles: problem.obstacles.clone() }
}

/// Moves the stopping point `g` of `team` (its horizon the stopping
/// horizon) to [`REST_CLEARANCE`] from obstacle `o`'s track while the
/// robot rests there, if it is closer, and `inside` the box: to the other
/// side of the track where the box leaves more room there; whether it
/// moved.
fn step_aside(team: &Team, o: &Obstacle, g: &mut Vector3<f64>, inside: &impl Fn(&mut Vector3<f64>)) -> bool {
    let until = team.predicted_until(&o.velocity);
    if team.horizon > until {
        return false;
    }
    // The track from the horizon to the prediction's end (the obstacle
    // itself where it is static).
    let from = o.at(team.horizon);
    let along = if until.is_finite() { o.velocity * (until - team.horizon) } else { Vector3::zeros() };
    let share =
        if along.norm_squared() > 0.0 { ((*g - from).dot(&along) / along.norm_squared()).clamp(0.0, 1.0) } else { 0.0 };
    let closest = from + along * share;
    let (a, b) = team.obstacle_separation(&o.shape);
    let mut aside = *g;
    if !moved_to_clearance(team.dim, &mut aside, closest, a, b, along) {
        return false;
    }
    let mut kept = aside;
    inside(&mut kept);
    if kept != aside {
        let mut other = 2.0 * closest - aside;
        inside(&mut other);
        let room = |p: &Vector3<f64>| scaled_norm(team.dim, &(p - closest), a, b);
        if room(&other) > room(&kept) {
            kept = other;
        }
    }
    *g = kept;
    true
}

/// Moves stopping points closer than the separation apart, each pair's
/// two by half; whether any moved.
fn spread(team: &Team, goals: &mut [Vector3<f64>]) -> bool {
    let (a, b) = team.separation();
    let mut moved = false;
    for i in 0..goals.len() {
        for j in i + 1..goals.len() {
            if scaled_norm(team.dim, &(goals[i] - goals[j]), a, b) >= 1.0 {
                continue;
            }
            let middle = (goals[i] + goals[j]) / 2.0;
            // Each to half the clearance from the middle.
            let (mut gi, mut gj) = (goals[i], goals[j]);
            let across = Vector3::new(1.0, 0.0, 0.0);
            moved_to_clearance(team.dim, &mut gi, middle, a / 2.0, b / 2.0, across);
            moved_to_clearance(team.dim, &mut gj, middle, a / 2.0, b / 2.0, -across);
            (goals[i], goals[j]) = (gi, gj);
            moved = true;
        }
    }
    moved
}

/// Moves `g` away from `from` to [`REST_CLEARANCE`] times the separation
/// `(a, b)` if it is closer (across `track`, a direction it lies along,
/// when it is at `from`); whether it moved.
fn moved_to_clearance(dim: Dim, g: &mut Vector3<f64>, from: Vector3<f64>, a: f64, b: f64, track: Vector3<f64>) -> bool {
    let d = *g - from;
    let scaled = scaled_norm(dim, &d, a, b);
    if scaled >= REST_CLEARANCE {
        return false;
    }
    let d = if scaled > 1e-9 {
        d
    } else {
        // On the point itself: across the track in the plane.
        let across = Vector3::new(-track.y, track.x, 0.0);
        if across.norm() > 0.0 { across } else { Vector3::new(1.0, 0.0, 0.0) }
    };
    *g = from + d * (REST_CLEARANCE / scaled_norm(dim, &d, a, b));
    true
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::metrics::Metrics;
    use crate::plan::JointPlan;
    use crate::problem::{Dim, StartState};
    use crate::reference::SmoothReference;

    #[test]
    fn robots_stop_ahead_along_their_motion_inside_the_box_and_at_rest() {
        let team = Team::default_for(Dim::Two, 2);
        let moving = |x: f64, vx: f64| StartState {
            position: Vector3::new(x, 0.0, 0.0),
            velocity: Vector3::new(vx, 0.0, 0.0),
            acceleration: Vector3::zeros(),
        };
        let problem = Problem {
            team: team.clone(),
            starts: vec![moving(-0.5, 0.4), moving(0.9, 1.0)],
            goals: vec![Vector3::zeros(), Vector3::new(0.5, 0.5, 0.0)],
            obstacles: vec![],
        };
        let stop = stopping_problem(&problem, 1.0, 0.05);
        assert_eq!(stop.team.horizon, 1.0);
        assert!((stop.goals[0].x - -0.3).abs() < 1e-12, "half the distance a constant speed would cover");
        assert!((stop.goals[1].x - 0.95).abs() < 1e-12, "kept inside the box");
        stop.validate().unwrap();
        let plan = JointPlan::new(&stop.team, SmoothReference::new(&stop.team).unwrap().coefficients(&stop));
        let m = Metrics::measure(&stop, &plan);
        assert!(m.boundary_error < 1e-9, "from the measured state to rest: {}", m.boundary_error);
    }

    /// Robot 0 at rest at the origin, robot 1 far from it, and a walker
    /// (radius 0.1 m) 0.6 m to the left coming through robot 0 at 0.4 m/s,
    /// predicted for 3.5 s.
    fn walker_through() -> Problem {
        let team = Team { obstacle_prediction: Some(3.5), ..Team::default_for(Dim::Two, 2) };
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        Problem {
            team,
            starts: vec![StartState::at_rest(at(0.0, 0.0)), StartState::at_rest(at(0.7, 0.7))],
            goals: vec![at(0.5, 0.5), at(-0.5, -0.5)],
            obstacles: vec![Obstacle {
                position: at(-0.6, 0.01),
                velocity: at(0.4, 0.0),
                shape: crate::problem::Spheroid::ball(0.1),
            }],
        }
    }

    #[test]
    fn a_robot_a_walker_comes_through_steps_aside_and_the_others_stay() {
        let problem = walker_through();
        let stop = stopping_problem(&problem, 1.0, 0.005);
        // Where it stood the walker is at 1.5 s: it rests beside the track,
        // across it (on the side it stood, below), clear of the whole track.
        let g = stop.goals[0];
        assert!(g.x.abs() < 1e-9 && g.y < 0.0, "{g:?}");
        let (a, _) = stop.team.obstacle_separation(&problem.obstacles[0].shape);
        assert!((g.y - 0.01 + REST_CLEARANCE * a).abs() < 1e-9, "{g:?}");
        assert_eq!(stop.goals[1], problem.starts[1].position);
        stop.validate().unwrap();
        // Without the move it was refused: the walker is on the stopping
        // point at the stopping horizon.
        let mut unmoved = stop.clone();
        unmoved.goals[0] = Vector3::zeros();
        unmoved.team.horizon = 1.5;
        assert!(matches!(unmoved.validate(), Err(crate::problem::ProblemError::GoalInObstacle { robot: 0, .. })));
    }

    #[test]
    fn a_robot_against_a_side_steps_aside_to_the_side_with_room() {
        // The same robot 2 cm from the right side, the walker coming down
        // through it: it rests left of the track.
        let mut problem = walker_through();
        problem.starts[0].position.x = 0.98;
        problem.obstacles[0].position = Vector3::new(0.97, 0.6, 0.0);
        problem.obstacles[0].velocity = Vector3::new(0.0, -0.4, 0.0);
        let stop = stopping_problem(&problem, 1.0, 0.005);
        let (a, _) = stop.team.obstacle_separation(&problem.obstacles[0].shape);
        assert!((stop.goals[0].x - (0.97 - REST_CLEARANCE * a)).abs() < 1e-9, "{:?}", stop.goals[0]);
        stop.validate().unwrap();
    }

    #[test]
    fn the_stopping_plan_around_a_walker_verifies() {
        use crate::am::{AmSettings, Engine, Objective, Stop};
        let stop = stopping_problem(&walker_through(), 1.0, 0.005);
        let engine = Engine::new(&stop.team, 1, Objective::Projection, AmSettings::safety_filter()).unwrap();
        let sample = SmoothReference::new(&stop.team).unwrap().coefficients(&stop);
        let prepared = engine.prepare(&stop, Some(&sample)).unwrap();
        let outcome = engine.run_within(&prepared, engine.cold_start(&prepared), &crate::am::Budget::unlimited());
        assert_eq!(outcome.stop, Stop::Verified);
    }

    #[test]
    fn overlapping_stopping_points_move_apart() {
        let team = Team::default_for(Dim::Two, 3);
        let moving = |x: f64, vx: f64| StartState {
            velocity: Vector3::new(vx, 0.0, 0.0),
            ..StartState::at_rest(Vector3::new(x, 0.0, 0.0))
        };
        // Robots 0 and 1 closing head on at 0.4 m/s each: over a 1 s
        // stopping horizon their stopping points are 0.1 m apart, half the
        // separation.
        let problem = Problem {
            team,
            starts: vec![moving(-0.25, 0.4), moving(0.25, -0.4), StartState::at_rest(Vector3::new(0.0, 0.8, 0.0))],
            goals: vec![Vector3::zeros(); 3],
            obstacles: vec![],
        };
        let stop = stopping_problem(&problem, 1.0, 0.005);
        let (a, b) = stop.team.separation();
        let d = scaled_norm(Dim::Two, &(stop.goals[0] - stop.goals[1]), a, b);
        assert!((d - REST_CLEARANCE).abs() < 1e-9, "{d}");
        assert!(stop.goals[0].x < stop.goals[1].x, "each on its own side");
        assert_eq!(stop.goals[2], problem.starts[2].position, "robot 2, clear, stays");
        stop.validate().unwrap();
    }
}
