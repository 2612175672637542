//! How problems and plans are presented to the networks.
//!
//! - A plan is coded as its deviation from the smoothest curves through the
//!   boundary values ([`SmoothReference`]), at the interior coefficients only
//!   (the boundary conditions fix the others): one token per robot of
//!   `dim x interior` values, axis-major. Every decoded plan meets the
//!   boundary conditions exactly.
//! - A robot's condition row is its start position, goal and start velocity;
//!   an obstacle's row is its position, velocity, radius and half-height.

use flowopt_planner::problem::{Problem, Team};
use flowopt_planner::reference::{ReferenceError, SmoothReference};

/// The coding of one team shape.
#[derive(Debug, Clone)]
pub struct Coding {
    dim: usize,
    robots: usize,
    reference: SmoothReference,
}

impl Coding {
    /// The coding of `team`.
    pub fn new(team: &Team) -> Result<Self, ReferenceError> {
        Ok(Self { dim: team.dim.axes(), robots: team.robots, reference: SmoothReference::new(team)? })
    }

    /// Values per plan token (`dim x interior`).
    pub fn token_width(&self) -> usize {
        token_width(self.dim, self.reference.n_xi())
    }

    /// The smoothest curves of `problem`, `[axis][robot][coef]`.
    pub fn reference(&self, problem: &Problem) -> Vec<f64> {
        self.reference.coefficients(problem)
    }

    /// The tokens (`[robot][axis][interior]`) of plan `xi` against the
    /// reference `reference` (both `[axis][robot][coef]`).
    pub fn encode(&self, reference: &[f64], xi: &[f64]) -> Vec<f32> {
        let nx = self.reference.n_xi();
        let interior = self.reference.interior();
        let mut out = Vec::with_capacity(self.robots * self.token_width());
        for i in 0..self.robots {
            for a in 0..self.dim {
                let row = (a * self.robots + i) * nx;
                out.extend(interior.clone().map(|c| (xi[row + c] - reference[row + c]) as f32));
            }
        }
        out
    }

    /// The plan (`[axis][robot][coef]`) that `tokens` code against `reference`.
    pub fn decode(&self, reference: &[f64], tokens: &[f32]) -> Vec<f64> {
        let nx = self.reference.n_xi();
        let interior = self.reference.interior();
        let width = interior.len();
        let mut xi = reference.to_vec();
        for i in 0..self.robots {
            for a in 0..self.dim {
                let row = (a * self.robots + i) * nx;
                let token = &tokens[(i * self.dim + a) * width..(i * self.dim + a + 1) * width];
                for (c, v) in interior.clone().zip(token) {
                    xi[row + c] += f64::from(*v);
                }
            }
        }
        xi
    }
}

/// Values per plan token for `dim` axes and `n_xi` coefficients.
pub fn token_width(dim: usize, n_xi: usize) -> usize {
    dim * (n_xi - flowopt_planner::basis::BOUNDARY_ROWS)
}

/// Values per robot condition row.
pub fn robot_width(dim: usize) -> usize {
    3 * dim
}

/// Values per obstacle row.
pub fn obstacle_width(dim: usize) -> usize {
    2 * dim + 2
}

/// The condition rows of `problem`: robots `[robot][start, goal, velocity]`
/// and obstacles `[obstacle][position, velocity, radius, half-height]`.
pub fn conditions(problem: &Problem) -> (Vec<f32>, Vec<f32>) {
    let dim = problem.team.dim.axes();
    let mut robots = Vec::with_capacity(problem.robots() * robot_width(dim));
    for (s, g) in problem.starts.iter().zip(&problem.goals) {
        for v in [&s.position, g, &s.velocity] {
            robots.extend((0..dim).map(|a| v[a] as f32));
        }
    }
    let mut obstacles = Vec::with_capacity(problem.obstacles.len() * obstacle_width(dim));
    for o in &problem.obstacles {
        for v in [&o.position, &o.velocity] {
            obstacles.extend((0..dim).map(|a| v[a] as f32));
        }
        obstacles.extend([o.shape.radius as f32, o.shape.half_height as f32]);
    }
    (robots, obstacles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::Dim;
    use flowopt_planner::scenario::RandomScenario;

    #[test]
    fn decoding_inverts_encoding_on_the_interior_and_keeps_the_boundary() {
        let team = Team::default_for(Dim::Two, 3);
        let problem = RandomScenario::new(team.clone()).with_start_speed(0.3).generate(1).unwrap();
        let coding = Coding::new(&team).unwrap();
        let reference = coding.reference(&problem);
        let mut xi = reference.clone();
        for (k, x) in xi.iter_mut().enumerate() {
            if (3..8).contains(&(k % 11)) {
                *x += 0.01 * k as f64;
            }
        }
        let tokens = coding.encode(&reference, &xi);
        assert_eq!(tokens.len(), 3 * coding.token_width());
        // Robot 1, y axis: token block 1 * 2 + 1 = 3; coefficient row (axis 1, robot 1) = 4.
        assert!((tokens[3 * 5] - (0.01 * (4 * 11 + 3) as f32)).abs() < 1e-6);
        let back = coding.decode(&reference, &tokens);
        for (a, b) in back.iter().zip(&xi) {
            assert!((a - b).abs() < 1e-6);
        }
    }
}
