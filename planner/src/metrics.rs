//! Plan quality and the success verdict.
//!
//! - smoothness: mean over robots of `sum_k ||p''_i(t_k)||^2` at the `K`
//!   samples (m^2/s^4);
//! - arc length: mean over robots of `sum_k ||p_i(t_{k+1}) - p_i(t_k)||` (m);
//! - clearances on a dense re-sampling ([`DENSE_FACTOR`] x K instants): the
//!   smallest scaled distance between robots and between robots and
//!   obstacles (1 = touching; a moving obstacle while its motion is
//!   predicted, [`crate::problem::Team::obstacle_prediction`]), and the
//!   matching surface gaps in metres (`(scaled - 1) x separation`, exact
//!   for discs and spheres); while a start violation is recovered from
//!   ([`crate::recovery`]), its distance is measured against its floor
//!   (the ratio, and the gap from it; none while the floor is 0) and the
//!   box it may be outside of;
//! - boundary error: worst mismatch of position, velocity and acceleration
//!   at the start and at the goal;
//! - [`Metrics::success`]: every clearance within
//!   [`FEASIBILITY_TOLERANCE`] of the true sizes, the box kept to the same
//!   tolerance, the boundary met to [`BOUNDARY_TOLERANCE`];
//! - [`Metrics::time_scale`]: the post-hoc stretch of the time axis that
//!   brings speed and acceleration within limits.

use nalgebra::Vector3;
use serde::Serialize;

use crate::plan::JointPlan;
use crate::problem::{FEASIBILITY_TOLERANCE, Problem, scaled_norm};
use crate::recovery::Recovery;

pub use crate::basis::DENSE_FACTOR;

/// Largest boundary mismatch (m, m/s, m/s^2) that counts as met.
pub const BOUNDARY_TOLERANCE: f64 = 1e-6;

/// The measured quality of a plan for a problem.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Metrics {
    /// Mean over robots of the sum of squared accelerations at the samples.
    pub smoothness: f64,
    /// Mean over robots of the sampled path length (m).
    pub arc_length: f64,
    /// Smallest robot-robot scaled distance on the dense re-sampling.
    pub min_robot_scaled: f64,
    /// Smallest robot-obstacle scaled distance (infinite without obstacles).
    pub min_obstacle_scaled: f64,
    /// Smallest robot-robot surface gap (m).
    pub min_robot_clearance: f64,
    /// Smallest robot-obstacle surface gap (m; infinite without obstacles).
    pub min_obstacle_clearance: f64,
    /// Farthest any centre leaves the workspace box (m; 0 inside).
    pub workspace_excess: f64,
    /// Worst boundary mismatch.
    pub boundary_error: f64,
    /// Largest speed on the dense re-sampling (m/s).
    pub max_speed: f64,
    /// Largest acceleration magnitude on the dense re-sampling (m/s^2).
    pub max_acceleration: f64,
}

impl Metrics {
    /// Measures `plan` against `problem`.
    pub fn measure(problem: &Problem, plan: &JointPlan) -> Self {
        let team = &problem.team;
        let dim = team.dim;
        let axes = dim.axes();
        let n = team.robots;
        let k = team.samples;
        let vec_at = |series: &[f64], samples: usize, i: usize, s: usize| -> Vector3<f64> {
            let mut v = Vector3::zeros();
            for a in 0..axes {
                v[a] = series[(a * n + i) * samples + s];
            }
            v
        };
        let pos = plan.sampled(k, 0);
        let smoothness = plan.smoothness(k);
        let mut arc_length = 0.0;
        for i in 0..n {
            for s in 0..k - 1 {
                arc_length += (vec_at(&pos, k, i, s + 1) - vec_at(&pos, k, i, s)).norm();
            }
        }
        let dense = DENSE_FACTOR * k;
        let dpos = plan.sampled(dense, 0);
        let dvel = plan.sampled(dense, 1);
        let dacc = plan.sampled(dense, 2);
        let (a, b) = team.separation();
        let mut min_robot_scaled = f64::INFINITY;
        let mut min_obstacle_scaled = f64::INFINITY;
        let mut min_obstacle_clearance = f64::INFINITY;
        let mut workspace_excess: f64 = 0.0;
        let mut max_speed: f64 = 0.0;
        let mut max_acceleration: f64 = 0.0;
        let recovery = Recovery::of(problem);
        // A distance against what holds at `t`: the separation, or a start
        // violation's floor while it is recovered from.
        let against = |scaled: f64, floor: f64| match floor {
            f if f >= 1.0 => scaled,
            f if f > 0.0 => scaled / f,
            _ => f64::INFINITY,
        };
        for s in 0..dense {
            let t = plan.horizon * s as f64 / (dense - 1) as f64;
            let p: Vec<Vector3<f64>> = (0..n).map(|i| vec_at(&dpos, dense, i, s)).collect();
            for i in 0..n {
                for j in i + 1..n {
                    let scaled = against(scaled_norm(dim, &(p[i] - p[j]), a, b), recovery.pair_floor(i, j, t));
                    min_robot_scaled = min_robot_scaled.min(scaled);
                }
                for (m, o) in
                    problem.obstacles.iter().enumerate().filter(|(_, o)| t <= team.predicted_until(&o.velocity))
                {
                    let (ao, bo) = team.obstacle_separation(&o.shape);
                    let scaled = against(scaled_norm(dim, &(p[i] - o.at(t)), ao, bo), recovery.obstacle_floor(i, m, t));
                    min_obstacle_scaled = min_obstacle_scaled.min(scaled);
                    min_obstacle_clearance = min_obstacle_clearance.min((scaled - 1.0) * ao);
                }
                for ax in 0..axes {
                    let (lo, hi) = recovery.bounds(i, ax, t, (team.workspace.min[ax], team.workspace.max[ax]));
                    let out = (lo - p[i][ax]).max(p[i][ax] - hi);
                    workspace_excess = workspace_excess.max(out);
                }
                max_speed = max_speed.max(vec_at(&dvel, dense, i, s).norm());
                max_acceleration = max_acceleration.max(vec_at(&dacc, dense, i, s).norm());
            }
        }
        let mut boundary_error: f64 = 0.0;
        let start = plan.at(0.0);
        let end = plan.at(plan.horizon);
        for i in 0..n {
            let s = &problem.starts[i];
            let errors = [
                start[i].position - s.position,
                start[i].velocity - s.velocity,
                start[i].acceleration - s.acceleration,
                end[i].position - problem.goals[i],
                end[i].velocity,
                end[i].acceleration,
            ];
            for e in errors {
                for ax in 0..axes {
                    boundary_error = boundary_error.max(e[ax].abs());
                }
            }
        }
        Self {
            smoothness,
            arc_length: arc_length / n as f64,
            min_robot_scaled,
            min_obstacle_scaled,
            min_robot_clearance: (min_robot_scaled - 1.0) * a,
            min_obstacle_clearance,
            workspace_excess,
            boundary_error,
            max_speed,
            max_acceleration,
        }
    }

    /// The smaller of the robot and obstacle clearances (m).
    pub fn min_clearance(&self) -> f64 {
        self.min_robot_clearance.min(self.min_obstacle_clearance)
    }

    /// Whether the plan is feasible: clearances and box within
    /// [`FEASIBILITY_TOLERANCE`] of the separation (`separation` is the
    /// robot's horizontal separation, used for the box), boundary met.
    pub fn success(&self, separation: f64) -> bool {
        self.min_robot_scaled >= 1.0 - FEASIBILITY_TOLERANCE
            && self.min_obstacle_scaled >= 1.0 - FEASIBILITY_TOLERANCE
            && self.workspace_excess <= FEASIBILITY_TOLERANCE * separation
            && self.boundary_error <= BOUNDARY_TOLERANCE
    }

    /// The factor `s >= 1` to stretch the horizon by (`T' = s T`) so that
    /// speed stays within `v_max` and acceleration within `a_max`: speeds
    /// scale by `1/s`, accelerations by `1/s^2`. Only exact for plans that
    /// start at rest (a stretched plan also slows its start velocity).
    pub fn time_scale(&self, v_max: f64, a_max: f64) -> f64 {
        1.0_f64.max(self.max_speed / v_max).max((self.max_acceleration / a_max).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::{Dim, Obstacle, Spheroid, StartState, Team};

    /// Two robots on straight, constant-coefficient lines: with Bernstein
    /// coefficients in arithmetic progression the motion is uniform.
    fn uniform_plan(team: &Team, from: [[f64; 2]; 2], to: [[f64; 2]; 2]) -> JointPlan {
        let nx = team.degree + 1;
        let mut coeffs = vec![0.0; 2 * 2 * nx];
        for a in 0..2 {
            for i in 0..2 {
                for c in 0..nx {
                    let s = c as f64 / (nx - 1) as f64;
                    coeffs[(a * 2 + i) * nx + c] = from[i][a] + s * (to[i][a] - from[i][a]);
                }
            }
        }
        JointPlan::new(team, coeffs)
    }

    #[test]
    fn uniform_motion_has_known_length_speed_and_no_acceleration() {
        let team = Team::default_for(Dim::Two, 2);
        let plan = uniform_plan(&team, [[-0.5, 0.5], [-0.5, -0.5]], [[0.5, 0.5], [0.5, -0.5]]);
        let problem = Problem {
            team: team.clone(),
            starts: vec![
                StartState {
                    position: Vector3::new(-0.5, 0.5, 0.0),
                    velocity: Vector3::new(0.2, 0.0, 0.0),
                    acceleration: Vector3::zeros(),
                },
                StartState {
                    position: Vector3::new(-0.5, -0.5, 0.0),
                    velocity: Vector3::new(0.2, 0.0, 0.0),
                    acceleration: Vector3::zeros(),
                },
            ],
            goals: vec![Vector3::new(0.5, 0.5, 0.0), Vector3::new(0.5, -0.5, 0.0)],
            obstacles: vec![],
        };
        let m = Metrics::measure(&problem, &plan);
        assert!((m.arc_length - 1.0).abs() < 1e-9);
        assert!(m.smoothness < 1e-18);
        assert!((m.max_speed - 0.2).abs() < 1e-9);
        // 1 m apart, separation 0.2: gap 0.8 m, scaled distance 5.
        assert!((m.min_robot_clearance - 0.8).abs() < 1e-9);
        assert!((m.min_robot_scaled - 5.0).abs() < 1e-9);
        // The goal velocity is 0.2 m/s, not rest: the boundary is missed by 0.2.
        assert!((m.boundary_error - 0.2).abs() < 1e-9);
        assert!(!m.success(0.2));
        assert!((m.time_scale(0.1, 10.0) - 2.0).abs() < 1e-9);
    }

    #[test]
    fn crossing_robots_and_obstacles_are_measured_on_the_dense_grid() {
        let team = Team::default_for(Dim::Two, 2);
        // Robot 0 moves right along y = 0.05, robot 1 left along y = -0.05:
        // they pass 0.1 m apart at t = T/2 (scaled 0.5).
        let plan = uniform_plan(&team, [[-0.5, 0.05], [0.5, -0.05]], [[0.5, 0.05], [-0.5, -0.05]]);
        let problem = Problem {
            team: team.clone(),
            starts: vec![
                StartState::at_rest(Vector3::new(-0.5, 0.05, 0.0)),
                StartState::at_rest(Vector3::new(0.5, -0.05, 0.0)),
            ],
            goals: vec![Vector3::new(0.5, 0.05, 0.0), Vector3::new(-0.5, -0.05, 0.0)],
            obstacles: vec![Obstacle {
                position: Vector3::new(0.0, 0.5, 0.0),
                velocity: Vector3::zeros(),
                shape: Spheroid::ball(0.2),
            }],
        };
        let m = Metrics::measure(&problem, &plan);
        // The dense grid has 200 instants; the midpoint is within half a step.
        assert!((m.min_robot_scaled - 0.5).abs() < 0.01, "{}", m.min_robot_scaled);
        assert!((m.min_robot_clearance + 0.1).abs() < 0.002);
        // Obstacle at (0, 0.5), inflated size 0.3: robot 0 passes 0.45 away.
        assert!((m.min_obstacle_scaled - 1.5).abs() < 0.01);
        assert!((m.min_clearance() - m.min_robot_clearance).abs() < 1e-12);
        assert!(!m.success(0.2));
    }
}
