//! The acceleration limit as a constraint of the iteration (the paper's
//! remark that velocity and acceleration bounds fit the problem's
//! structure): each robot's acceleration at every constrained instant is
//! kept inside the ball of the team's `max_acceleration`, slightly shrunk
//! ([`MARGIN`]), and the dense verification checks the limit itself.
//!
//! In the iteration it is one more affine map of the coefficients, per
//! robot and axis, `D xi` (the second derivative at the constrained
//! instants, scaled to metres by `T^2 / (N (N - 1))`): the projection moves
//! every acceleration outside the ball radially onto it (axes couple only
//! there, as for the pairs), the corrections `c` enter the multiplier and
//! the right-hand side as `w D^T c`, and `rho w D^T D` joins the cost
//! Hessian of both KKT systems (it is the same for every robot, so the
//! mean/difference split is unchanged).
//!
//! Without it a plan is checked against the limit after the fact: a plan
//! from rest is stretched in time, one from motion is refused. In a 16-robot
//! lab run most stopping plans the daemon refused were over the limit
//! (3.6 to 40 m/s^2 against 3), and the team was left with no plan.

use crate::basis::{bernstein_row, gram_of};
use crate::linalg::dot;
use crate::problem::Team;

/// The limit is imposed at the constrained instants at this fraction of
/// `max_acceleration`, so that the dense verification at the limit itself
/// passes between them.
const MARGIN: f64 = 0.97;

/// Weight `w` of the acceleration rows against the position rows. Stopping
/// plans of 16 random robots starting at 1.2 m/s over 1 s (200 seeds of
/// the scenes of the test below, 67 valid stopping problems), verified
/// within 3 m/s^2: 14 without the limit; with it, at a weight of 1 / 10 /
/// 30 / 100 / 300 / 1,000 / 10,000, 46 / 48 / 50 / 50 / 50 / 48 / 45, in
/// 254 / 184 / 165 / 162 / 169 / 184 / 230 iterations on average (without
/// it 21); at 0.9 of the limit instead of [`MARGIN`], 47 at 1 and 46 at 100.
const WEIGHT: f64 = 100.0;

/// The acceleration rows of one engine: `D` at its constrained instants
/// and at the dense verification's, and the limit in those units.
#[derive(Debug, Clone)]
pub(crate) struct AccelerationLimit {
    n_xi: usize,
    /// `D`, `count x n_xi`, row-major, at the constrained instants.
    d: Vec<f64>,
    /// `D` at the dense instants, `dense x n_xi`.
    dense: Vec<f64>,
    /// The radius imposed at the constrained instants (scaled).
    bound: f64,
    /// The limit itself (scaled), checked at the dense instants.
    limit: f64,
}

impl AccelerationLimit {
    /// The rows for `team` (with its `max_acceleration`; `None` without
    /// one) at the constrained instants `taus` and the dense instants
    /// `dense_taus` (normalised time).
    pub(crate) fn new(team: &Team, taus: &[f64], dense_taus: &[f64]) -> Option<Self> {
        let max = team.max_acceleration.filter(|a| a.is_finite() && *a > 0.0)?;
        let rows = |taus: &[f64]| -> Vec<f64> {
            let scale = Self::scale(team.degree);
            taus.iter().flat_map(|&t| bernstein_row(team.degree, 2, t)).map(|v| v * scale).collect()
        };
        // D xi = T^2 a scale, so the limit in those units:
        let limit = max * team.horizon * team.horizon * Self::scale(team.degree);
        Some(Self { n_xi: team.degree + 1, d: rows(taus), dense: rows(dense_taus), bound: MARGIN * limit, limit })
    }

    /// The factor the normalised second derivative is scaled by: one over
    /// `N (N - 1)`, the largest factor the derivative brings, so that the
    /// rows weigh about as much as the position rows.
    fn scale(degree: usize) -> f64 {
        1.0 / (degree * degree.saturating_sub(1)).max(1) as f64
    }

    /// `w D^T D` (`n_xi x n_xi`, row-major): what joins the cost Hessian
    /// per unit of penalty.
    pub(crate) fn gram(&self) -> Vec<f64> {
        let mut g = gram_of(&self.d, self.n_xi, 0);
        g.iter_mut().for_each(|v| *v *= WEIGHT);
        g
    }

    /// The corrections of `xi` (`[axis][robot][coef]`, `axes` axes, `n`
    /// robots) onto the ball, mapped to coefficients, `w D^T c`, written
    /// into `out` (the same layout); returns the residual `sqrt(w) ||c||`.
    pub(crate) fn correct(&self, axes: usize, n: usize, xi: &[f64], out: &mut [f64]) -> f64 {
        let nx = self.n_xi;
        let count = self.d.len() / nx;
        let mut sq = 0.0;
        let mut v = [0.0; 3];
        for i in 0..n {
            let coefs = |a: usize| &xi[(a * n + i) * nx..(a * n + i + 1) * nx];
            for a in 0..axes {
                out[(a * n + i) * nx..(a * n + i + 1) * nx].fill(0.0);
            }
            for k in 0..count {
                let row = &self.d[k * nx..(k + 1) * nx];
                for (a, v) in v.iter_mut().enumerate().take(axes) {
                    *v = dot(row, coefs(a));
                }
                let norm = v[..axes].iter().map(|x| x * x).sum::<f64>().sqrt();
                if norm <= self.bound {
                    continue;
                }
                let shrink = self.bound / norm - 1.0;
                for a in 0..axes {
                    let c = v[a] * shrink;
                    sq += c * c;
                    for (o, r) in out[(a * n + i) * nx..(a * n + i + 1) * nx].iter_mut().zip(row) {
                        *o += WEIGHT * c * r;
                    }
                }
            }
        }
        (WEIGHT * sq).sqrt()
    }

    /// Whether every robot of `xi` keeps the limit at the dense instants.
    pub(crate) fn within(&self, axes: usize, n: usize, xi: &[f64]) -> bool {
        let nx = self.n_xi;
        let limit_sq = self.limit * self.limit * (1.0 + 1e-9);
        (0..n).all(|i| {
            self.dense.chunks_exact(nx).all(|row| {
                let sq: f64 =
                    (0..axes).map(|a| dot(row, &xi[(a * n + i) * nx..(a * n + i + 1) * nx])).map(|v| v * v).sum();
                sq <= limit_sq
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::am::{AmSettings, Engine, Objective, Stop};
    use crate::metrics::DENSE_FACTOR;
    use crate::plan::JointPlan;
    use crate::problem::{Dim, Problem, Team};
    use crate::scenario::RandomScenario;

    /// 8 robots starting at 1 m/s, and the optimiser's plan without a limit.
    fn moving(seed: u64) -> (Problem, Vec<f64>) {
        let team = Team::default_for(Dim::Two, 8);
        let problem = RandomScenario::new(team.clone()).with_start_speed(1.0).generate(seed).unwrap();
        let free = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser()).unwrap();
        let outcome = free.solve(&problem).unwrap();
        assert_eq!(outcome.stop, Stop::Verified);
        (problem, outcome.state.xi)
    }

    fn peak_acceleration(team: &Team, xi: &[f64]) -> f64 {
        JointPlan::new(team, xi.to_vec()).peak_rates(DENSE_FACTOR * team.samples).1
    }

    fn limited(problem: &Problem, max_acceleration: Option<f64>, limit: bool) -> (Problem, Engine) {
        let team = Team { max_acceleration, ..problem.team.clone() };
        let settings = AmSettings { limit_acceleration: limit, ..AmSettings::optimiser() };
        let engine = Engine::new(&team, 0, Objective::smoothness(), settings).unwrap();
        (Problem { team, ..problem.clone() }, engine)
    }

    #[test]
    fn plans_keep_a_limit_their_unlimited_plans_exceed() {
        for seed in [0, 3] {
            let (problem, free) = moving(seed);
            let limit = 0.8 * peak_acceleration(&problem.team, &free);
            let (problem, engine) = limited(&problem, Some(limit), true);
            let outcome = engine.solve(&problem).unwrap();
            assert_eq!(outcome.stop, Stop::Verified, "seed {seed}");
            let peak = peak_acceleration(&problem.team, &outcome.state.xi);
            assert!(peak <= limit * (1.0 + 1e-9), "seed {seed}: {peak} over {limit}");
        }
    }

    #[test]
    fn the_verification_refuses_a_plan_over_the_limit() {
        let (problem, free) = moving(0);
        let limit = 0.8 * peak_acceleration(&problem.team, &free);
        let (with, engine) = limited(&problem, Some(limit), true);
        assert!(!engine.verify(&engine.prepare(&with, None).unwrap(), &free));
        let (without, engine) = limited(&problem, Some(limit), false);
        assert!(engine.verify(&engine.prepare(&without, None).unwrap(), &free));
    }

    #[test]
    fn without_the_setting_or_a_team_limit_plans_are_unchanged() {
        let (problem, free) = moving(3);
        let under = 0.8 * peak_acceleration(&problem.team, &free);
        for (max, limit) in [(None, true), (Some(under), false)] {
            let (problem, engine) = limited(&problem, max, limit);
            assert_eq!(engine.solve(&problem).unwrap().state.xi, free);
        }
    }

    #[test]
    fn stopping_plans_keep_the_limit_more_often_with_it() {
        use crate::reference::SmoothReference;
        use crate::stopping::{stepped_aside, stopping_problem};
        let team = Team { max_acceleration: Some(3.0), ..Team::default_for(Dim::Two, 16) };
        let mut kept = [0, 0];
        for seed in 0..60 {
            let Ok(problem) = RandomScenario::new(team.clone()).with_start_speed(1.2).generate(seed) else { continue };
            let stop = stepped_aside(&stopping_problem(&problem, 1.0, 0.005), 0.005);
            if stop.validate().is_err() {
                continue;
            }
            let sample = SmoothReference::new(&stop.team).unwrap().coefficients(&stop);
            for (kept, limit) in kept.iter_mut().zip([false, true]) {
                let settings = AmSettings { limit_acceleration: limit, ..AmSettings::safety_filter() };
                let engine = Engine::new(&stop.team, 0, Objective::Projection, settings).unwrap();
                let prepared = engine.prepare(&stop, Some(&sample)).unwrap();
                let outcome = engine.run(&prepared, engine.cold_start(&prepared));
                let within = peak_acceleration(&stop.team, &outcome.state.xi) <= 3.0 * (1.0 + 1e-9);
                if outcome.stop == Stop::Verified {
                    assert!(within || !limit, "seed {seed}: a verified plan over the limit");
                    *kept += usize::from(within);
                }
            }
        }
        assert!(kept[1] >= kept[0] + 5, "within the limit: {} without it, {} with it", kept[0], kept[1]);
    }
}
