//! A joint plan: Bernstein coefficients for every robot and axis over a
//! horizon, and its evaluation at any time.

use nalgebra::Vector3;

use crate::basis::bernstein_row;
use crate::problem::{Dim, Team};

/// Position, velocity and acceleration of one robot at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kinematics {
    /// Position (m).
    pub position: Vector3<f64>,
    /// Velocity (m/s).
    pub velocity: Vector3<f64>,
    /// Acceleration (m/s^2).
    pub acceleration: Vector3<f64>,
}

/// The Bernstein rows of position, velocity and acceleration at one
/// instant of a plan: evaluates any robot's coefficients there.
#[derive(Debug, Clone)]
pub struct InstantRows {
    rows: [Vec<f64>; 3],
    /// Time-derivative scales `1, 1/T, 1/T^2`.
    scale: [f64; 3],
}

impl InstantRows {
    /// The rows of `degree` at `t` seconds into a plan over `horizon`
    /// (clamped to `[0, horizon]`).
    pub fn new(degree: usize, horizon: f64, t: f64) -> Self {
        let tau = (t / horizon).clamp(0.0, 1.0);
        Self {
            rows: [0, 1, 2].map(|order| bernstein_row(degree, order, tau)),
            scale: [1.0, 1.0 / horizon, 1.0 / (horizon * horizon)],
        }
    }

    /// The kinematics of one robot whose coefficients along axis `a` are
    /// `coefficients(a)`, for `axes` axes.
    pub fn kinematics<'c>(&self, axes: usize, coefficients: impl Fn(usize) -> &'c [f64]) -> Kinematics {
        let mut v = [Vector3::zeros(); 3];
        for a in 0..axes {
            let c = coefficients(a);
            for order in 0..3 {
                v[order][a] = self.rows[order].iter().zip(c).map(|(b, x)| b * x).sum::<f64>() * self.scale[order];
            }
        }
        Kinematics { position: v[0], velocity: v[1], acceleration: v[2] }
    }
}

/// The trajectories of a whole team.
#[derive(Debug, Clone, PartialEq)]
pub struct JointPlan {
    /// Workspace dimension.
    pub dim: Dim,
    /// Number of robots.
    pub robots: usize,
    /// Bernstein degree.
    pub degree: usize,
    /// Horizon T (s).
    pub horizon: f64,
    /// Coefficients, `[axis][robot][coef]`.
    pub coeffs: Vec<f64>,
}

impl JointPlan {
    /// Wraps coefficients laid out `[axis][robot][coef]` for `team`.
    pub fn new(team: &Team, coeffs: Vec<f64>) -> Self {
        debug_assert_eq!(coeffs.len(), team.dim.axes() * team.robots * (team.degree + 1));
        Self { dim: team.dim, robots: team.robots, degree: team.degree, horizon: team.horizon, coeffs }
    }

    /// Coefficients of one robot along one axis.
    pub fn coefficients(&self, axis: usize, robot: usize) -> &[f64] {
        let nx = self.degree + 1;
        let start = (axis * self.robots + robot) * nx;
        &self.coeffs[start..start + nx]
    }

    /// Every robot's kinematics at `t` seconds (clamped to `[0, T]`).
    pub fn at(&self, t: f64) -> Vec<Kinematics> {
        let rows = InstantRows::new(self.degree, self.horizon, t);
        (0..self.robots).map(|i| rows.kinematics(self.dim.axes(), |a| self.coefficients(a, i))).collect()
    }

    /// Smoothness: the mean over robots of the sum over `samples` evenly
    /// spaced instants of the squared acceleration (m^2/s^4).
    pub fn smoothness(&self, samples: usize) -> f64 {
        self.sampled(samples, 2).iter().map(|a| a * a).sum::<f64>() / self.robots as f64
    }

    /// The `order`-th time derivative (physical units) of every robot at
    /// `samples` evenly spaced instants over `[0, T]`, `[axis][robot][sample]`.
    pub fn sampled(&self, samples: usize, order: usize) -> Vec<f64> {
        let nx = self.degree + 1;
        let scale = self.horizon.powi(-(order as i32));
        let rows: Vec<Vec<f64>> =
            (0..samples).map(|s| bernstein_row(self.degree, order, s as f64 / (samples - 1) as f64)).collect();
        let mut out = vec![0.0; self.dim.axes() * self.robots * samples];
        for (series, c) in out.chunks_exact_mut(samples).zip(self.coeffs.chunks_exact(nx)) {
            for (o, row) in series.iter_mut().zip(&rows) {
                *o = row.iter().zip(c).map(|(b, x)| b * x).sum::<f64>() * scale;
            }
        }
        out
    }
}
