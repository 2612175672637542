//! Stopping problems: every robot brought to rest along its motion.
//!
//! From a measured state `(p, v)` each robot's stopping point is
//! `p + v T_s / 2` (where a constant deceleration over `T_s` brings it to
//! rest), kept inside the workspace; the problem keeps the obstacles and
//! plans over the stopping horizon `T_s`. Planned and verified like any
//! other problem, it gives robots that left their plan a way to rest
//! that is checked against each other and the obstacles.

use crate::problem::{Problem, Team};

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
    let axes = team.dim.axes();
    let goals = problem
        .starts
        .iter()
        .map(|s| {
            let mut g = s.position + s.velocity * (horizon / 2.0);
            for a in 0..axes {
                let (lo, hi) = (team.workspace.min[a] + inset, team.workspace.max[a] - inset);
                g[a] = if lo <= hi { g[a].clamp(lo, hi) } else { (lo + hi) / 2.0 };
            }
            g
        })
        .collect();
    Problem { team, starts: problem.starts.clone(), goals, obstacles: problem.obstacles.clone() }
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
}
