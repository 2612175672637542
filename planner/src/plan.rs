//! A joint plan: Bernstein coefficients for every robot and axis over a
//! horizon, and its evaluation at any time.

use nalgebra::Vector3;

use crate::basis::{BOUNDARY_ROWS, bernstein_row_into};
use crate::problem::{Dim, Problem, StartState, Team};
use crate::route::Fitter;

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

impl Kinematics {
    /// How far (m) the robot measured in `measured` is from this state:
    /// the distance between the positions, the measure a robot follows a
    /// plan by ([`JointPlan::deviation`]).
    pub fn deviation(&self, measured: &StartState) -> f64 {
        (self.position - measured.position).norm()
    }
}

impl From<Kinematics> for StartState {
    /// A plan's state at an instant as the start of another plan.
    fn from(k: Kinematics) -> Self {
        StartState { position: k.position, velocity: k.velocity, acceleration: k.acceleration }
    }
}

/// The Bernstein rows of position, velocity and acceleration at one
/// instant of a plan: evaluates any robot's coefficients there.
#[derive(Debug, Clone)]
pub struct InstantRows {
    /// Position's, velocity's and acceleration's rows, one after the other.
    rows: Vec<f64>,
    /// Time-derivative scales `1, 1/T, 1/T^2`.
    scale: [f64; 3],
}

impl InstantRows {
    /// The rows of `degree` at `t` seconds into a plan over `horizon`
    /// (clamped to `[0, horizon]`).
    pub fn new(degree: usize, horizon: f64, t: f64) -> Self {
        let tau = (t / horizon).clamp(0.0, 1.0);
        let mut rows = vec![0.0; 3 * (degree + 1)];
        for (order, row) in rows.chunks_exact_mut(degree + 1).enumerate() {
            bernstein_row_into(degree, order, tau, row);
        }
        Self { rows, scale: [1.0, 1.0 / horizon, 1.0 / (horizon * horizon)] }
    }

    /// The kinematics of one robot whose coefficients along axis `a` are
    /// `coefficients(a)`, for `axes` axes.
    pub fn kinematics<'c>(&self, axes: usize, coefficients: impl Fn(usize) -> &'c [f64]) -> Kinematics {
        let mut v = [Vector3::zeros(); 3];
        let nx = self.rows.len() / 3;
        for a in 0..axes {
            let c = coefficients(a);
            for (order, row) in self.rows.chunks_exact(nx).enumerate() {
                v[order][a] = row.iter().zip(c).map(|(b, x)| b * x).sum::<f64>() * self.scale[order];
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

    /// The largest distance (m) between any robot's measured position in
    /// `starts` and where this plan has it `t` seconds after its origin:
    /// how far the robots are from following it.
    pub fn deviation(&self, t: f64, starts: &[StartState]) -> f64 {
        self.at(t).iter().zip(starts).map(|(k, s)| k.deviation(s)).fold(0.0, f64::max)
    }

    /// The largest speed (m/s) and acceleration (m/s^2) of any robot at
    /// `samples` evenly spaced instants.
    pub fn peak_rates(&self, samples: usize) -> (f64, f64) {
        let peak = |order: usize| {
            let series = self.sampled(samples, order);
            let n = self.robots;
            (0..n * samples)
                .map(|j| {
                    let (i, s) = (j / samples, j % samples);
                    (0..self.dim.axes()).map(|a| series[(a * n + i) * samples + s].powi(2)).sum::<f64>().sqrt()
                })
                .fold(0.0, f64::max)
        };
        (peak(1), peak(2))
    }

    /// The same paths over a horizon `factor` times as long: speeds divide
    /// by `factor`, accelerations by its square (the paper's post-hoc time
    /// scaling; the start velocity and acceleration scale too).
    pub fn stretched(&self, factor: f64) -> JointPlan {
        JointPlan { horizon: self.horizon * factor, ..self.clone() }
    }

    /// This plan as a warm start `dt` seconds after its origin, for
    /// `problem` (the same team, measured then): the positions from `dt` on
    /// (held at the goal past the end) sampled at the `K` instants of a new
    /// horizon and fitted to the basis (`fitter`, of this plan's basis)
    /// under `problem`'s boundary conditions. The start accelerations, which
    /// a snapshot does not measure, are taken from this plan at `dt` and
    /// written into `problem`. Returns the coefficients, `[axis][robot][coef]`.
    pub fn shifted(&self, dt: f64, problem: &mut Problem, fitter: &Fitter) -> Vec<f64> {
        let team = &problem.team;
        let (axes, n, nx, k) = (team.dim.axes(), team.robots, team.degree + 1, team.samples);
        for (s, kin) in problem.starts.iter_mut().zip(self.at(dt)) {
            s.acceleration = kin.acceleration;
        }
        let mut series = vec![vec![0.0; k]; axes * n];
        for s in 0..k {
            let t = dt + team.horizon * s as f64 / (k - 1) as f64;
            for (i, kin) in self.at(t).iter().enumerate() {
                for a in 0..axes {
                    series[a * n + i][s] = kin.position[a];
                }
            }
        }
        let mut xi = vec![0.0; axes * n * nx];
        for (row, b) in problem.boundary_values().chunks_exact(BOUNDARY_ROWS).enumerate() {
            fitter.fit(&series[row], b, &mut xi[row * nx..(row + 1) * nx]);
        }
        xi
    }

    /// The `order`-th time derivative (physical units) of every robot at
    /// `samples` evenly spaced instants over `[0, T]`, `[axis][robot][sample]`.
    pub fn sampled(&self, samples: usize, order: usize) -> Vec<f64> {
        let nx = self.degree + 1;
        let scale = self.horizon.powi(-(order as i32));
        let mut rows = vec![0.0; samples * nx];
        for (s, row) in rows.chunks_exact_mut(nx).enumerate() {
            bernstein_row_into(self.degree, order, s as f64 / (samples - 1) as f64, row);
        }
        let mut out = vec![0.0; self.dim.axes() * self.robots * samples];
        for (series, c) in out.chunks_exact_mut(samples).zip(self.coeffs.chunks_exact(nx)) {
            for (o, row) in series.iter_mut().zip(rows.chunks_exact(nx)) {
                *o = row.iter().zip(c).map(|(b, x)| b * x).sum::<f64>() * scale;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::metrics::Metrics;
    use crate::reference::SmoothReference;

    #[test]
    fn a_shifted_plan_starts_where_the_robots_are_and_follows_the_rest_of_the_old_one() {
        let team = Team::default_for(Dim::Two, 2);
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        let problem = Problem {
            team: team.clone(),
            starts: vec![StartState::at_rest(at(-0.6, 0.2)), StartState::at_rest(at(0.5, -0.4))],
            goals: vec![at(0.6, -0.1), at(-0.3, 0.7)],
            obstacles: vec![],
        };
        let plan = JointPlan::new(&team, SmoothReference::new(&team).unwrap().coefficients(&problem));
        let dt = 0.8;
        let mut later = problem.clone();
        for (s, k) in later.starts.iter_mut().zip(plan.at(dt)) {
            *s = StartState { position: k.position, velocity: k.velocity, acceleration: Vector3::zeros() };
        }
        let fitter = Fitter::new(&team.basis().unwrap()).unwrap();
        let shifted = JointPlan::new(&team, plan.shifted(dt, &mut later, &fitter));
        // The start acceleration was taken from the old plan ...
        for (s, k) in later.starts.iter().zip(plan.at(dt)) {
            assert_eq!(s.acceleration, k.acceleration);
        }
        // ... so the fit meets every boundary condition of the new problem,
        let m = Metrics::measure(&later, &shifted);
        assert!(m.boundary_error < 1e-9, "boundary error {}", m.boundary_error);
        // and stays on the old plan's path (held at the goal after its end).
        for t in [0.5, 1.5, 3.0, 4.5] {
            for (new, old) in shifted.at(t).iter().zip(plan.at(t + dt)) {
                assert!((new.position - old.position).norm() < 0.01, "t = {t}: {new:?} vs {old:?}");
            }
        }
    }

    #[test]
    fn deviation_peak_rates_and_stretching_agree_with_the_metrics() {
        let team = Team::default_for(Dim::Two, 2);
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        let problem = Problem {
            team: team.clone(),
            starts: vec![StartState::at_rest(at(-0.6, 0.2)), StartState::at_rest(at(0.5, -0.4))],
            goals: vec![at(0.6, -0.1), at(-0.3, 0.7)],
            obstacles: vec![],
        };
        let plan = JointPlan::new(&team, SmoothReference::new(&team).unwrap().coefficients(&problem));
        assert!(plan.deviation(0.0, &problem.starts) < 1e-12);
        let mut moved = problem.starts.clone();
        moved[1].position.x += 0.03;
        assert!((plan.deviation(0.0, &moved) - 0.03).abs() < 1e-12);
        let m = Metrics::measure(&problem, &plan);
        let (speed, acceleration) = plan.peak_rates(4 * team.samples);
        assert!((speed - m.max_speed).abs() < 1e-12 && (acceleration - m.max_acceleration).abs() < 1e-12);
        let slow = plan.stretched(2.0);
        let (s2, a2) = slow.peak_rates(4 * team.samples);
        assert!((s2 - speed / 2.0).abs() < 1e-12 && (a2 - acceleration / 4.0).abs() < 1e-12);
        assert_eq!(slow.at(2.0 * 1.3)[1].position, plan.at(1.3)[1].position);
    }
}
