//! A robot's plan as the polynomial pieces a Crazyflie flies (Crazyswarm's
//! `uploadTrajectory`: per piece a duration and 8 coefficients per axis,
//! x, y, z and yaw, of `sum_k c_k t^k` with `t` the seconds since the
//! piece began).
//!
//! Each piece is the degree-7 Hermite interpolant of the plan over its
//! interval: position, velocity, acceleration and jerk match the plan at
//! both ends, so consecutive pieces join with continuous position,
//! velocity, acceleration and jerk. [`Pieces::max_error`] measures how far
//! they are from the plan on a dense grid; with the default piece length
//! ([`DEFAULT_PIECE_S`]) a 5 s, degree-10 plan is followed within
//! micrometres (tested).

use flowopt_planner::basis::bernstein_row;
use flowopt_planner::plan::JointPlan;
use nalgebra::{Matrix4, Vector4};
use thiserror::Error;

/// Seconds per piece by default: 10 pieces for a 5 s plan (a Crazyflie's
/// trajectory memory holds about 30).
pub const DEFAULT_PIECE_S: f64 = 0.5;

/// Coefficients per axis of a piece.
pub const COEFFICIENTS: usize = 8;

/// One piece: its duration and, per axis (x, y, z, yaw), the coefficients
/// of ascending powers of the seconds since it began.
#[derive(Debug, Clone, PartialEq)]
pub struct Piece {
    /// Seconds.
    pub duration: f64,
    /// x, y, z, yaw (yaw 0: the plans do not turn the robots).
    pub axes: [[f64; COEFFICIENTS]; 4],
}

/// One robot's plan as pieces.
#[derive(Debug, Clone, PartialEq)]
pub struct Pieces {
    /// In flight order.
    pub pieces: Vec<Piece>,
}

/// Why a plan cannot be converted.
#[derive(Debug, Error, PartialEq)]
pub enum PiecesError {
    /// The robot is not in the plan.
    #[error("the plan has {robots} robots; there is no robot {robot}")]
    NoRobot {
        /// The robot asked for.
        robot: usize,
        /// The plan's robots.
        robots: usize,
    },
    /// The piece length is not a positive number.
    #[error("the piece length {0} s is not positive")]
    PieceLength(f64),
}

impl Pieces {
    /// Robot `robot` of `plan` in pieces of at most `piece_s` seconds
    /// (equal lengths, as few as that allows).
    pub fn of(plan: &JointPlan, robot: usize, piece_s: f64) -> Result<Self, PiecesError> {
        if robot >= plan.robots {
            return Err(PiecesError::NoRobot { robot, robots: plan.robots });
        }
        if !(piece_s.is_finite() && piece_s > 0.0) {
            return Err(PiecesError::PieceLength(piece_s));
        }
        let count = (plan.horizon / piece_s).ceil().max(1.0) as usize;
        let d = plan.horizon / count as f64;
        let pieces = (0..count)
            .map(|k| {
                let (t0, t1) = (k as f64 * d, (k + 1) as f64 * d);
                let mut axes = [[0.0; COEFFICIENTS]; 4];
                for (axis, out) in axes.iter_mut().enumerate().take(plan.dim.axes()) {
                    *out = hermite(&derivatives(plan, axis, robot, t0), &derivatives(plan, axis, robot, t1), d);
                }
                Piece { duration: d, axes }
            })
            .collect();
        Ok(Self { pieces })
    }

    /// The position (x, y, z) the pieces give `t` seconds after the first
    /// began (clamped to the pieces).
    pub fn position(&self, t: f64) -> [f64; 3] {
        let mut start = 0.0;
        for (k, piece) in self.pieces.iter().enumerate() {
            if t < start + piece.duration || k + 1 == self.pieces.len() {
                let s = (t - start).clamp(0.0, piece.duration);
                return [0, 1, 2].map(|a| piece.axes[a].iter().rev().fold(0.0, |acc, c| acc * s + c));
            }
            start += piece.duration;
        }
        [0.0; 3]
    }

    /// The largest distance (m) between the pieces and robot `robot` of
    /// `plan` on `samples` instants over the plan.
    pub fn max_error(&self, plan: &JointPlan, robot: usize, samples: usize) -> f64 {
        (0..samples)
            .map(|i| {
                let t = plan.horizon * i as f64 / (samples.max(2) - 1) as f64;
                let p = plan.at(t)[robot].position;
                let q = self.position(t);
                ((p.x - q[0]).powi(2) + (p.y - q[1]).powi(2) + (p.z - q[2]).powi(2)).sqrt()
            })
            .fold(0.0, f64::max)
    }

    /// The pieces as Crazyswarm's CSV: a header, then per piece
    /// `duration,x^0..x^7,y^0..y^7,z^0..z^7,yaw^0..yaw^7`.
    pub fn csv(&self) -> String {
        let mut out = String::from("Duration");
        for axis in ["x", "y", "z", "yaw"] {
            for k in 0..COEFFICIENTS {
                out.push_str(&format!(",{axis}^{k}"));
            }
        }
        out.push('\n');
        for piece in &self.pieces {
            out.push_str(&format!("{}", piece.duration));
            for c in piece.axes.iter().flatten() {
                out.push_str(&format!(",{c}"));
            }
            out.push('\n');
        }
        out
    }
}

/// Position, velocity, acceleration and jerk of `axis` of `robot` at `t`.
fn derivatives(plan: &JointPlan, axis: usize, robot: usize, t: f64) -> [f64; 4] {
    let coefficients = plan.coefficients(axis, robot);
    let tau = (t / plan.horizon).clamp(0.0, 1.0);
    [0, 1, 2, 3].map(|order| {
        let row = bernstein_row(plan.degree, order, tau);
        let value: f64 = row.iter().zip(coefficients).map(|(b, c)| b * c).sum();
        value / plan.horizon.powi(order as i32)
    })
}

/// The degree-7 polynomial over `[0, d]` with position, velocity,
/// acceleration and jerk `a` at 0 and `b` at `d`: ascending coefficients.
fn hermite(a: &[f64; 4], b: &[f64; 4], d: f64) -> [f64; COEFFICIENTS] {
    let mut c = [a[0], a[1], a[2] / 2.0, a[3] / 6.0, 0.0, 0.0, 0.0, 0.0];
    // What the first four leave at d, per derivative, and each of the last
    // four's contribution there.
    let falling = |k: usize, order: usize| (0..order).map(|i| (k - i) as f64).product::<f64>();
    let mut matrix = Matrix4::zeros();
    let mut rhs = Vector4::zeros();
    for order in 0..4 {
        let known: f64 = (order..4).map(|k| falling(k, order) * c[k] * d.powi((k - order) as i32)).sum();
        rhs[order] = b[order] - known;
        for (j, k) in (4..8).enumerate() {
            matrix[(order, j)] = falling(k, order) * d.powi((k - order) as i32);
        }
    }
    if let Some(solution) = matrix.lu().solve(&rhs) {
        for j in 0..4 {
            c[4 + j] = solution[j];
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::{Dim, Team};
    use flowopt_planner::scenario::RandomScenario;

    fn plan(dim: Dim, seed: u64) -> JointPlan {
        // A smooth plan of the team's degree: the reference curves of a
        // random problem (boundary conditions met, moving starts).
        let team = Team::default_for(dim, 4);
        let problem = RandomScenario::new(team.clone()).with_start_speed(0.5).generate(seed).unwrap();
        let reference = flowopt_planner::reference::SmoothReference::new(&team).unwrap();
        JointPlan::new(&team, reference.coefficients(&problem))
    }

    #[test]
    fn pieces_follow_the_plan_within_micrometres_and_join_smoothly() {
        for (dim, seed) in [(Dim::Two, 1), (Dim::Three, 2)] {
            let plan = plan(dim, seed);
            for robot in 0..plan.robots {
                let pieces = Pieces::of(&plan, robot, DEFAULT_PIECE_S).unwrap();
                assert_eq!(pieces.pieces.len(), 10);
                let error = pieces.max_error(&plan, robot, 2001);
                assert!(error < 1e-6, "robot {robot}: {error} m");
                // Position and velocity continuous across every join.
                for w in pieces.pieces.windows(2) {
                    let (p, q) = (&w[0], &w[1]);
                    for axis in 0..3 {
                        let end: f64 =
                            p.axes[axis].iter().enumerate().map(|(k, c)| c * p.duration.powi(k as i32)).sum();
                        let slope: f64 = p.axes[axis]
                            .iter()
                            .enumerate()
                            .skip(1)
                            .map(|(k, c)| k as f64 * c * p.duration.powi(k as i32 - 1))
                            .sum();
                        assert!((end - q.axes[axis][0]).abs() < 1e-9 && (slope - q.axes[axis][1]).abs() < 1e-9);
                    }
                }
            }
        }
    }

    #[test]
    fn longer_pieces_are_coarser_and_bad_requests_are_errors() {
        let plan = plan(Dim::Two, 3);
        let fine = Pieces::of(&plan, 0, 0.5).unwrap().max_error(&plan, 0, 2001);
        let coarse = Pieces::of(&plan, 0, 5.0).unwrap().max_error(&plan, 0, 2001);
        assert!(coarse > fine, "{coarse} vs {fine}");
        assert_eq!(Pieces::of(&plan, 9, 0.5), Err(PiecesError::NoRobot { robot: 9, robots: 4 }));
        assert_eq!(Pieces::of(&plan, 0, 0.0), Err(PiecesError::PieceLength(0.0)));
        let csv = Pieces::of(&plan, 0, 0.5).unwrap().csv();
        assert_eq!(csv.lines().count(), 11);
        assert_eq!(csv.lines().next().unwrap().split(',').count(), 33);
    }
}
