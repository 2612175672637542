//! Checking a plan already made against obstacles reported after it: the
//! rest of a held plan against the newest snapshot's obstacles (static, or
//! moving at their reported velocities from the snapshot's time on).
//!
//! The check is the engine's dense verification for the obstacles: the
//! same instants per second of plan (`DENSE_FACTOR x K` over its horizon),
//! the same buffer (`verify_margin`) and chord inflation, the first
//! `verify_skip` instants after the snapshot held to the feasibility
//! tolerance only (the robots are measured there, possibly in near-contact).
//! Robot pairs and the box do not depend on the obstacles and are not
//! checked again. Past its end a plan holds its robots at rest at its final
//! positions, and the check goes on there for as long as it is asked to.
//!
//! ```
//! use flowopt_planner::am::{AmSettings, Recheck};
//! use flowopt_planner::plan::JointPlan;
//! use flowopt_planner::problem::{Dim, Obstacle, Spheroid, Team};
//! use flowopt_planner::reference::SmoothReference;
//! use flowopt_planner::scenario::RandomScenario;
//! use nalgebra::Vector3;
//!
//! let team = Team::default_for(Dim::Two, 2);
//! let problem = RandomScenario::new(team.clone()).generate(3).unwrap();
//! let plan = JointPlan::new(&team, SmoothReference::new(&team).unwrap().coefficients(&problem));
//! let recheck = Recheck::new(&team, &AmSettings::safety_filter());
//! // A ball dropped on robot 0's position 1 s into the plan.
//! let on_it = Obstacle { position: plan.at(1.0)[0].position, velocity: Vector3::zeros(), shape: Spheroid::ball(0.1) };
//! assert!(recheck.clear(&plan, 1.0, 2.0, &[]));
//! assert!(!recheck.clear(&plan, 1.0, 2.0, &[on_it]));
//! ```

use super::projection::{Limits, Projection, SampleGrid};
use super::settings::AmSettings;
use crate::metrics::DENSE_FACTOR;
use crate::plan::JointPlan;
use crate::problem::{FEASIBILITY_TOLERANCE, Obstacle, Problem, StartState, Team};

/// The obstacle check of plans of one team after the fact.
#[derive(Debug, Clone)]
pub struct Recheck {
    team: Team,
    /// Dense instants per horizon (the engine's dense grid).
    dense: usize,
    /// Instants after the snapshot held to the feasibility tolerance only.
    skip: usize,
    /// Relative buffer beyond the true sizes.
    margin: f64,
    chord: bool,
}

impl Recheck {
    /// Checks for plans of `team` verified with `settings` (its
    /// `verify_margin`, `verify_skip` and `chord`).
    pub fn new(team: &Team, settings: &AmSettings) -> Self {
        Self {
            team: team.clone(),
            dense: DENSE_FACTOR * team.samples,
            skip: settings.verify_skip,
            margin: settings.verify_margin,
            chord: settings.chord,
        }
    }

    /// Whether `plan`, from `elapsed` s after its origin and for `window`
    /// s on, keeps every robot clear of `obstacles`, which were reported at
    /// that instant (their positions then, their velocities from then on).
    /// The instants checked are that one and those of the plan's own dense
    /// grid after it (continued at the same spacing past its end).
    pub fn clear(&self, plan: &JointPlan, elapsed: f64, window: f64, obstacles: &[Obstacle]) -> bool {
        if obstacles.is_empty() {
            return true;
        }
        if !(elapsed.is_finite() && window.is_finite() && window >= 0.0) {
            return false;
        }
        let step = plan.horizon / (self.dense - 1) as f64;
        let first = (elapsed / step).floor() as i64 + 1;
        let last = ((elapsed + window) / step).ceil() as i64;
        // Seconds after the report.
        let times: Vec<f64> = std::iter::once(0.0).chain((first..=last).map(|j| j as f64 * step - elapsed)).collect();
        let tau = |t: &f64| ((elapsed + t) / plan.horizon).clamp(0.0, 1.0);
        let split = self.skip.min(times.len());
        let problem = Problem {
            team: Team { robots: plan.robots, ..self.team.clone() },
            starts: vec![StartState::at_rest(Default::default()); plan.robots],
            goals: Vec::new(),
            obstacles: obstacles.to_vec(),
        };
        let parts = [(&times[..split], 1.0 - FEASIBILITY_TOLERANCE), (&times[split..], 1.0 + self.margin)];
        parts.into_iter().filter(|(t, _)| !t.is_empty()).all(|(t, scale)| {
            let grid = SampleGrid::new(plan.degree, t.iter().map(tau).collect());
            let limits = Limits::at_times(&problem, t, scale, [0.0; 3]).with_rules(self.chord, false);
            Projection::new(plan.dim, plan.robots, &grid).obstacles_clear(
                plan.dim,
                plan.robots,
                &grid,
                &limits,
                &plan.coeffs,
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::am::{Engine, Objective};
    use crate::problem::{Dim, Spheroid};
    use crate::scenario::RandomScenario;

    fn ball(x: f64, y: f64, vx: f64, vy: f64) -> Obstacle {
        Obstacle { position: Vector3::new(x, y, 0.0), velocity: Vector3::new(vx, vy, 0.0), shape: Spheroid::ball(0.1) }
    }

    /// One robot from (-0.8, 0) to (0.8, 0) over 5 s.
    fn crossing() -> (Team, JointPlan) {
        let team = Team::default_for(Dim::Two, 1);
        let problem = Problem {
            team: team.clone(),
            starts: vec![StartState::at_rest(Vector3::new(-0.8, 0.0, 0.0))],
            goals: vec![Vector3::new(0.8, 0.0, 0.0)],
            obstacles: vec![],
        };
        let engine = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser()).unwrap();
        let plan = engine.plan(engine.solve(&problem).unwrap().state.xi);
        (team, plan)
    }

    #[test]
    fn an_obstacle_ahead_on_the_path_fails_and_one_behind_the_robot_does_not() {
        let (team, plan) = crossing();
        let check = Recheck::new(&team, &AmSettings::safety_filter());
        let here = plan.at(2.5)[0].position.x;
        assert!(!check.clear(&plan, 2.5, 2.5, &[ball(here + 0.3, 0.0, 0.0, 0.0)]), "ahead, on the path");
        assert!(check.clear(&plan, 2.5, 2.5, &[ball(here - 0.3, 0.0, 0.0, 0.0)]), "behind: already passed");
        assert!(check.clear(&plan, 2.5, 2.5, &[ball(here + 0.3, 0.5, 0.0, 0.0)]), "beside the path");
        // Past the plan's end the robot rests at its goal, checked for as long as asked.
        assert!(!check.clear(&plan, 6.0, 1.0, &[ball(0.8, 0.5, 0.0, -0.5)]), "walks onto the goal within 1 s");
        assert!(check.clear(&plan, 6.0, 0.5, &[ball(0.8, 0.5, 0.0, -0.5)]), "not within 0.5 s");
    }

    #[test]
    fn a_moving_obstacle_is_checked_along_its_reported_motion() {
        let (team, plan) = crossing();
        let check = Recheck::new(&team, &AmSettings::safety_filter());
        // The robot is at x = 0 at t = 2.5 s; from t = 1 s an obstacle at
        // (0, 0.75) walks down at 0.5 m/s: it crosses y = 0 at t = 2.5 s.
        assert!(!check.clear(&plan, 1.0, 4.0, &[ball(0.0, 0.75, 0.0, -0.5)]));
        // Walking up instead, it never meets the robot.
        assert!(check.clear(&plan, 1.0, 4.0, &[ball(0.0, 0.75, 0.0, 0.5)]));
    }

    #[test]
    fn a_moving_obstacle_is_kept_clear_of_only_while_its_motion_is_predicted() {
        let (team, plan) = crossing();
        // From t = 1 s it walks down and crosses the robot's path 1.5 s later.
        let walker = [ball(0.0, 0.75, 0.0, -0.5)];
        let within = |prediction: Option<f64>| {
            let team = Team { obstacle_prediction: prediction, ..team.clone() };
            Recheck::new(&team, &AmSettings::safety_filter()).clear(&plan, 1.0, 4.0, &walker)
        };
        assert!(!within(None), "predicted over the whole plan");
        assert!(!within(Some(2.0)), "predicted for 2 s: the meeting 1.5 s ahead");
        assert!(within(Some(1.0)), "predicted for 1 s: the meeting is beyond it");
        // A static obstacle is kept clear of over the whole plan.
        let team = Team { obstacle_prediction: Some(1.0), ..team };
        let check = Recheck::new(&team, &AmSettings::safety_filter());
        assert!(!check.clear(&plan, 1.0, 4.0, &[ball(0.5, 0.0, 0.0, 0.0)]));
    }

    #[test]
    fn the_buffer_is_the_verification_margin_and_the_first_instants_the_tolerance() {
        let (team, plan) = crossing();
        let p = plan.at(2.5)[0].position;
        // True sizes touch at 0.2 m; a 5% buffer asks for 0.21.
        let near = [ball(p.x, p.y + 0.205, 0.0, 0.0)];
        let plain = Recheck::new(&team, &AmSettings::safety_filter());
        let buffered = Recheck::new(&team, &AmSettings { verify_margin: 0.05, ..AmSettings::safety_filter() });
        assert!(plain.clear(&plan, 2.5, 0.0, &near));
        assert!(!buffered.clear(&plan, 2.5, 0.0, &near));
        // Within the skipped instants only the tolerance (0.198 m) applies.
        let skipping = AmSettings { verify_margin: 0.05, verify_skip: 4, ..AmSettings::safety_filter() };
        assert!(Recheck::new(&team, &skipping).clear(&plan, 2.5, 0.0, &near));
    }

    #[test]
    fn plans_the_engine_verified_with_an_obstacle_clear_it() {
        let team = Team::default_for(Dim::Two, 8);
        let problem = RandomScenario::new(team.clone()).with_obstacles(3).generate(4).unwrap();
        let settings = AmSettings { verify_margin: 0.03, ..AmSettings::optimiser() };
        let engine = Engine::new(&team, 3, Objective::smoothness(), settings).unwrap();
        let outcome = engine.solve(&problem).unwrap();
        assert_eq!(outcome.stop, crate::am::Stop::Verified);
        let plan = engine.plan(outcome.state.xi);
        let check = Recheck::new(&team, &settings);
        assert!(check.clear(&plan, 0.0, team.horizon, &problem.obstacles));
        // The same obstacles reported 1 s in, where they then are.
        let later: Vec<Obstacle> = problem.obstacles.iter().map(|o| Obstacle { position: o.at(1.0), ..*o }).collect();
        assert!(check.clear(&plan, 1.0, team.horizon - 1.0, &later));
    }
}
