//! Where each obstacle lies against each robot's reference curve: the
//! pair rows a flow policy with [`crate::flow::FlowConfig::pairs`] reads.
//!
//! Whether a robot must leave its straight curve, and to which side, is a
//! question of where the obstacles lie along that curve. A policy that
//! reads only absolute obstacle rows through cross-attention does not
//! learn it: even for one robot among eight obstacles its samples detour
//! about as often where the straight curve is clear as where it is blocked
//! (docs/LEARNED.md, "Teaching the policy obstacles"). The pair rows hand
//! it that geometry, once per problem.

use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::Problem;
use nalgebra::Vector3;

/// Instants along the horizon at which the curves are compared (the
/// closest approach is then found on the segments between them).
const INSTANTS: usize = 50;

/// Largest distance (scaled) a pair row tells apart; farther obstacles read
/// as this far.
const FAR: f64 = 4.0;

/// Values per pair row for `dim` axes.
pub fn pair_width(dim: usize) -> usize {
    3 + 2 * dim
}

/// The pair rows of `problem` along the curves `xi` (`[axis][robot][coef]`,
/// the reference in use), `[robot][obstacle][pair_width]`, in scaled units
/// (the obstacle's separation from a robot is 1 on every axis): where the
/// obstacle comes closest to the robot, on the segments between
/// [`INSTANTS`] instants of the relative motion, the distance (at most
/// [`FAR`]), how deep the curve runs into it (`max(0, 1 - distance)`), the
/// fraction of the horizon, the obstacle's offset from the robot (its norm
/// at most [`FAR`]) and the unit direction of the relative motion there.
pub fn pair_rows(problem: &Problem, xi: &[f64]) -> Vec<f32> {
    let team = &problem.team;
    let (n, axes) = (team.robots, team.dim.axes());
    let positions = JointPlan::new(team, xi.to_vec()).sampled(INSTANTS, 0);
    let mut rows = Vec::with_capacity(n * problem.obstacles.len() * pair_width(axes));
    for i in 0..n {
        for o in &problem.obstacles {
            let (a, b) = team.obstacle_separation(&o.shape);
            let relative: Vec<Vector3<f64>> = (0..INSTANTS)
                .map(|s| {
                    let t = team.horizon * s as f64 / (INSTANTS - 1) as f64;
                    let d = o.at(t);
                    let mut r = Vector3::zeros();
                    for axis in 0..axes {
                        let scale = if axis == 2 { b } else { a };
                        r[axis] = (d[axis] - positions[(axis * n + i) * INSTANTS + s]) / scale;
                    }
                    r
                })
                .collect();
            let (mut distance, mut at, mut offset, mut direction) =
                (f64::INFINITY, 0.0, Vector3::zeros(), Vector3::zeros());
            for (s, w) in relative.windows(2).enumerate() {
                let step = w[1] - w[0];
                let length = step.norm();
                let u = if length > 1e-12 { (-w[0].dot(&step) / (length * length)).clamp(0.0, 1.0) } else { 0.0 };
                let closest = w[0] + step * u;
                if closest.norm() < distance {
                    distance = closest.norm();
                    at = (s as f64 + u) / (INSTANTS - 1) as f64;
                    offset = closest;
                    direction = if length > 1e-12 { step / length } else { Vector3::zeros() };
                }
            }
            if distance > FAR {
                offset *= FAR / distance;
            }
            rows.extend([distance.min(FAR), (1.0 - distance).max(0.0), at].map(|v| v as f32));
            rows.extend((0..axes).map(|axis| offset[axis] as f32));
            rows.extend((0..axes).map(|axis| direction[axis] as f32));
        }
    }
    rows
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coding::Coding;
    use flowopt_planner::problem::{Dim, Obstacle, Spheroid, StartState, Team};

    /// One robot crossing the box along x, one obstacle on its way and one
    /// beside it: the rows say which blocks it, where, and on which side.
    #[test]
    fn a_row_says_where_an_obstacle_blocks_a_curve_and_on_which_side() {
        let team = Team::default_for(Dim::Two, 1);
        let obstacle = |x: f64, y: f64| Obstacle {
            position: Vector3::new(x, y, 0.0),
            velocity: Vector3::zeros(),
            shape: Spheroid::ball(0.1),
        };
        let problem = Problem {
            team: team.clone(),
            starts: vec![StartState::at_rest(Vector3::new(-0.8, 0.0, 0.0))],
            goals: vec![Vector3::new(0.8, 0.0, 0.0)],
            obstacles: vec![obstacle(0.0, 0.05), obstacle(0.4, -0.5)],
        };
        let coding = Coding::new(&team).unwrap();
        let rows = pair_rows(&problem, &coding.reference(&problem));
        let width = pair_width(2);
        assert_eq!(rows.len(), 2 * width);
        let (blocking, beside) = (&rows[..width], &rows[width..]);
        // Separation 0.2: 0.05 m off the path is 0.25 scaled, halfway along.
        assert!((blocking[0] - 0.25).abs() < 1e-3, "{blocking:?}");
        assert!((blocking[1] - 0.75).abs() < 1e-3);
        assert!((blocking[2] - 0.5).abs() < 1e-3);
        assert!(blocking[3].abs() < 1e-3 && (blocking[4] - 0.25).abs() < 1e-3, "on the left");
        // Relative motion: the obstacle moves towards -x seen from the robot.
        assert!((blocking[5] + 1.0).abs() < 1e-3 && blocking[6].abs() < 1e-3);
        assert!((beside[0] - 2.5).abs() < 1e-2 && beside[1] == 0.0 && beside[4] < -2.4, "{beside:?}");
    }
}
