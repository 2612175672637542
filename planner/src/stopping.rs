//! Stopping problems: every robot brought to rest along its motion.
//!
//! From a measured state `(p, v)` each robot's stopping point is
//! `p + v T_s / 2` (where a constant deceleration over `T_s` brings it to
//! rest), kept inside the workspace; the problem keeps the obstacles and
//! plans over the stopping horizon `T_s`. Planned and verified like any
//! other problem, it gives robots that left their plan a way to rest
//! that is checked against each other and the obstacles.
//!
//! [`stepped_aside`]: a stopping point that a moving obstacle is predicted
//! to cover while the robot rests there (from `T_s` to the end of the
//! obstacle's prediction, [`Team::predicted_until`]: a walker coming
//! through) is moved out of the obstacle's track, sideways to it, on the
//! side it lies; one within a static obstacle is moved out of it towards
//! the robot's start (it stops short); stopping points that
//! overlap are moved apart; each to [`REST_CLEARANCE`] (scaled): the robot
//! steps aside instead of the team having no stopping plan at all.

use nalgebra::Vector3;

use crate::problem::{Dim, Obstacle, Problem, Team, scaled, scaled_norm};

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
/// metres inside the workspace. Not validated: stopping points may
/// overlap, which [`Problem::validate`] then reports.
pub fn stopping_problem(problem: &Problem, horizon: f64, inset: f64) -> Problem {
    let team = stopping_team(&problem.team, horizon);
    let goals = problem
        .starts
        .iter()
        .map(|s| {
            let mut g = s.position + s.velocity * (horizon / 2.0);
            inside(&team, inset, &mut g);
            g
        })
        .collect();
    Problem { team, starts: problem.starts.clone(), goals, obstacles: problem.obstacles.clone() }
}

/// The stopping problem `stop` ([`stopping_problem`], its points `inset`
/// metres inside the workspace) with its points moved out of obstacles'
/// tracks and apart (the module's doc). A move can land a point in
/// another obstacle: where this one is invalid and `stop` is not, plan
/// `stop`.
pub fn stepped_aside(stop: &Problem, inset: f64) -> Problem {
    let team = &stop.team;
    let mut goals = stop.goals.clone();
    for _ in 0..REST_ROUNDS {
        let mut moved = false;
        for (g, s) in goals.iter_mut().zip(&stop.starts) {
            for o in &stop.obstacles {
                moved |= step_aside(team, inset, o, s.position, g);
            }
        }
        moved |= spread(team, &mut goals);
        goals.iter_mut().for_each(|g| inside(team, inset, g));
        if !moved {
            break;
        }
    }
    Problem { goals, ..stop.clone() }
}

/// `g` kept `inset` metres inside `team`'s workspace.
fn inside(team: &Team, inset: f64, g: &mut Vector3<f64>) {
    for a in 0..team.dim.axes() {
        let (lo, hi) = (team.workspace.min[a] + inset, team.workspace.max[a] - inset);
        g[a] = if lo <= hi { g[a].clamp(lo, hi) } else { (lo + hi) / 2.0 };
    }
}

/// Moves the stopping point `g` of the robot starting at `start` (the
/// team's horizon the stopping horizon) to [`REST_CLEARANCE`] from
/// obstacle `o`'s track while the robot rests there (the obstacle itself
/// where it is static), if it is closer: on the side of the track it
/// lies (towards the start from a static obstacle), or the other where
/// the box (`inset` inside it) leaves less than the separation there;
/// whether it moved.
fn step_aside(team: &Team, inset: f64, o: &Obstacle, start: Vector3<f64>, g: &mut Vector3<f64>) -> bool {
    let until = team.predicted_until(&o.velocity);
    if team.horizon > until {
        return false;
    }
    let (a, b) = team.obstacle_separation(&o.shape);
    let scale = |v: &Vector3<f64>| scaled(team.dim, v, a, b);
    let room = |p: &Vector3<f64>, c: &Vector3<f64>| scale(&(p - c)).norm();
    // The point of the track from the horizon to the prediction's end
    // nearest to `g`, in the scaled metric the separation is measured in.
    let from = o.at(team.horizon);
    let along = if until.is_finite() { o.velocity * (until - team.horizon) } else { Vector3::zeros() };
    let (sa, sd) = (scale(&along), scale(&(*g - from)));
    let share = if sa.norm_squared() > 0.0 { (sd.dot(&sa) / sa.norm_squared()).clamp(0.0, 1.0) } else { 0.0 };
    let closest = from + along * share;
    if room(g, &closest) >= REST_CLEARANCE * (1.0 - 1e-9) {
        return false;
    }
    // Which way: from a track, on the side the point lies (a robot
    // crossing it rests beyond it, braking no harder); from a static
    // obstacle (or from the track itself), towards the start; else away,
    // or across the track.
    let (d, back) = (*g - closest, start - closest);
    let epsilon = 1e-9;
    let moving = along.norm() > 0.0;
    let across = Vector3::new(-along.y, along.x, 0.0);
    let dir = if moving && scale(&d).norm() > epsilon {
        d
    } else if scale(&back).norm() > epsilon {
        back
    } else if scale(&d).norm() > epsilon {
        d
    } else if across.norm() > 0.0 {
        across
    } else {
        Vector3::new(1.0, 0.0, 0.0)
    };
    let placed = |dir: Vector3<f64>| {
        let mut p = at_clearance(team.dim, closest, dir, a, b);
        inside(team, inset, &mut p);
        p
    };
    let mut kept = placed(dir);
    if room(&kept, &closest) < 1.0 {
        let other = placed(-dir);
        if room(&other, &closest) > room(&kept, &closest) {
            kept = other;
        }
    }
    let moved = kept != *g;
    *g = kept;
    moved
}

/// Moves stopping points closer than the separation apart, each pair's
/// two by half, to [`REST_CLEARANCE`]; whether any moved. (Points at 1
/// to 1.1 separations from each other are left: robots at rest close
/// together, a team stopped in a jam, keep where they are; an obstacle's
/// track is a prediction and gets the whole clearance.)
fn spread(team: &Team, goals: &mut [Vector3<f64>]) -> bool {
    let (a, b) = team.separation();
    let mut moved = false;
    for i in 0..goals.len() {
        for j in i + 1..goals.len() {
            let d = goals[i] - goals[j];
            let apart = scaled_norm(team.dim, &d, a, b);
            if apart >= 1.0 {
                continue;
            }
            // Each to half the clearance from the middle (on one point,
            // across the first axis).
            let middle = (goals[i] + goals[j]) / 2.0;
            let dir = if apart > 1e-9 { d } else { Vector3::new(0.0, 1.0, 0.0) };
            goals[i] = at_clearance(team.dim, middle, dir, a / 2.0, b / 2.0);
            goals[j] = 2.0 * middle - goals[i];
            moved = true;
        }
    }
    moved
}

/// The point [`REST_CLEARANCE`] times the separation `(a, b)` from
/// `from` along `dir` (not zero in `dim`'s axes).
fn at_clearance(dim: Dim, from: Vector3<f64>, dir: Vector3<f64>, a: f64, b: f64) -> Vector3<f64> {
    from + dir * (REST_CLEARANCE / scaled_norm(dim, &dir, a, b))
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
    /// (radius 0.1 m) 0.4 m to the left coming through robot 0 at 0.4 m/s,
    /// predicted for 3.5 s: at a 1 s stopping horizon it is over robot 0.
    fn walker_through() -> Problem {
        let team = Team { obstacle_prediction: Some(3.5), ..Team::default_for(Dim::Two, 2) };
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        Problem {
            team,
            starts: vec![StartState::at_rest(at(0.0, 0.0)), StartState::at_rest(at(0.7, 0.7))],
            goals: vec![at(0.5, 0.5), at(-0.5, -0.5)],
            obstacles: vec![Obstacle {
                position: at(-0.4, 0.01),
                velocity: at(0.4, 0.0),
                shape: crate::problem::Spheroid::ball(0.1),
            }],
        }
    }

    /// The stopping problem of `problem` over 1 s, and stepped aside.
    fn both(problem: &Problem) -> (Problem, Problem) {
        let plain = stopping_problem(problem, 1.0, 0.005);
        let aside = stepped_aside(&plain, 0.005);
        (plain, aside)
    }

    #[test]
    fn a_robot_a_walker_comes_through_steps_aside_and_the_others_stay() {
        let problem = walker_through();
        let (plain, stop) = both(&problem);
        // Where it would rest the walker is at the horizon: refused.
        assert!(matches!(plain.validate(), Err(crate::problem::ProblemError::GoalInObstacle { robot: 0, .. })));
        // Stepped aside, it rests beside the track, on the side it stands
        // (below), clear of the whole track.
        let g = stop.goals[0];
        assert!(g.x.abs() < 1e-9 && g.y < 0.0, "{g:?}");
        let (a, _) = stop.team.obstacle_separation(&problem.obstacles[0].shape);
        assert!((g.y - 0.01 + REST_CLEARANCE * a).abs() < 1e-9, "{g:?}");
        assert_eq!(stop.goals[1], problem.starts[1].position);
        stop.validate().unwrap();
    }

    #[test]
    fn a_robot_against_a_side_steps_aside_to_the_side_with_room() {
        // The same robot 2 cm from the right side, the walker coming down
        // through it: it rests left of the track.
        let mut problem = walker_through();
        problem.starts[0].position.x = 0.98;
        problem.obstacles[0].position = Vector3::new(0.97, 0.4, 0.0);
        problem.obstacles[0].velocity = Vector3::new(0.0, -0.4, 0.0);
        let (plain, stop) = both(&problem);
        assert!(plain.validate().is_err());
        let (a, _) = stop.team.obstacle_separation(&problem.obstacles[0].shape);
        assert!((stop.goals[0].x - (0.97 - REST_CLEARANCE * a)).abs() < 1e-9, "{:?}", stop.goals[0]);
        stop.validate().unwrap();
    }

    #[test]
    fn a_robot_heading_into_a_pillar_stops_short_of_it() {
        // 1 m/s towards a pillar 0.5 m ahead: it would rest on its centre.
        let mut problem = walker_through();
        problem.starts[0] =
            StartState { velocity: Vector3::new(1.0, 0.0, 0.0), ..StartState::at_rest(Vector3::new(-0.5, 0.0, 0.0)) };
        problem.obstacles[0] = Obstacle { velocity: Vector3::zeros(), ..problem.obstacles[0] };
        problem.obstacles[0].position = Vector3::new(0.0, 0.01, 0.0);
        let (plain, stop) = both(&problem);
        assert!(plain.validate().is_err());
        let (a, _) = stop.team.obstacle_separation(&problem.obstacles[0].shape);
        let g = stop.goals[0];
        assert!(g.x < 0.0 && ((g - problem.obstacles[0].position).norm() - REST_CLEARANCE * a).abs() < 1e-9, "{g:?}");
        stop.validate().unwrap();
    }

    #[test]
    fn the_stopping_plan_around_a_walker_verifies() {
        use crate::am::{AmSettings, Engine, Objective, Stop};
        let (plain, stop) = both(&walker_through());
        let engine = Engine::new(&stop.team, 1, Objective::Projection, AmSettings::safety_filter()).unwrap();
        let sample = SmoothReference::new(&stop.team).unwrap().coefficients(&stop);
        assert!(engine.prepare(&plain, Some(&sample)).is_err(), "no stopping plan without the step");
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
        let (plain, stop) = both(&problem);
        assert!(plain.validate().is_err());
        let (a, b) = stop.team.separation();
        let d = scaled_norm(Dim::Two, &(stop.goals[0] - stop.goals[1]), a, b);
        assert!((d - REST_CLEARANCE).abs() < 1e-9, "{d}");
        assert!(stop.goals[0].x < stop.goals[1].x, "each on its own side");
        assert_eq!(stop.goals[2], problem.starts[2].position, "robot 2, clear, stays");
        stop.validate().unwrap();
    }
}
