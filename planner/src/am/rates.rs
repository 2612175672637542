//! The speed and acceleration limits as constraints of the iteration (the
//! paper's remark that velocity and acceleration bounds fit the problem's
//! structure): each robot's velocity ([`super::AmSettings::limit_speed`])
//! and acceleration ([`super::AmSettings::limit_acceleration`]) at every
//! constrained instant are kept inside the balls of the team's `max_speed` and
//! `max_acceleration`, slightly shrunk ([`SPEED_MARGIN`],
//! [`ACCELERATION_MARGIN`]), and the dense verification checks the limits
//! themselves.
//!
//! In the iteration each is one more affine map of the coefficients, per
//! robot and axis, `D xi` (the derivative of its order at the constrained
//! instants, scaled to metres by `T^r / (N (N - 1) ... (N - r + 1))`): the
//! projection moves every rate outside its ball radially onto it (axes
//! couple only there, as for the pairs), the corrections `c` enter the
//! multiplier and the right-hand side as `w D^T c`, and `rho w D^T D` joins
//! the cost Hessian of both KKT systems (it is the same for every robot, so
//! the mean/difference split is unchanged). Inside the ball the rows still
//! hold each step near the last along `D` (no correction, the same Hessian):
//! the iterations slow, so engines that rarely meet a limit are better
//! without it.
//!
//! Without them a plan is checked against the limits after the fact: a plan
//! from rest is stretched in time, one from motion is refused. In a 16-robot
//! lab run most stopping plans the daemon refused were over the acceleration
//! limit (3.6 to 40 m/s^2 against 3), and the team was left with no plan.

use crate::basis::{bernstein_row, gram_of};
use crate::linalg::dot;
use crate::problem::Team;

/// The acceleration limit is imposed at the constrained instants at this
/// fraction of `max_acceleration`, so that the dense verification at the
/// limit itself passes between them.
const ACCELERATION_MARGIN: f64 = 0.97;

/// The speed limit's fraction, as [`ACCELERATION_MARGIN`]: above the share
/// plans stretched in time keep under the limit
/// (`flowopt_daemon::repair::STRETCH_HEADROOM`, 2%), so that the limit
/// leaves those as they are. Between two instants a speed overshoots less
/// than an acceleration (one derivative fewer); the 128-robot team's
/// repairs at it verified within the limit in 10 of 13 cases, the other 3
/// running out of time (docs/experiments/2026-11-29-speed-limit-in-warm-replans.md).
const SPEED_MARGIN: f64 = 0.99;

/// Weight `w` of the acceleration rows against the position rows. Stopping
/// plans of 16 random robots starting at 1.2 m/s over 1 s (200 seeds of
/// the scenes of the test below, 67 valid stopping problems), verified
/// within 3 m/s^2: 14 without the limit; with it, at a weight of 1 / 10 /
/// 30 / 100 / 300 / 1,000 / 10,000, 46 / 48 / 50 / 50 / 50 / 48 / 45, in
/// 254 / 184 / 165 / 162 / 169 / 184 / 230 iterations on average (without
/// it 21); at 0.9 of the limit instead of [`ACCELERATION_MARGIN`], 47 at 1
/// and 46 at 100. The speed rows weigh the same.
const WEIGHT: f64 = 100.0;

/// The rows of one limit: `D` of one derivative order at the constrained
/// instants and at the dense verification's, and the limit in those units.
#[derive(Debug, Clone)]
struct Rate {
    /// `D`, `count x n_xi`, row-major, at the constrained instants.
    d: Vec<f64>,
    /// `D` at the dense instants, `dense x n_xi`.
    dense: Vec<f64>,
    /// The radius imposed at the constrained instants (scaled).
    bound: f64,
    /// The limit itself (scaled), checked at the dense instants.
    limit: f64,
}

/// The limits an engine keeps in its iteration (at least one).
#[derive(Debug, Clone)]
pub(crate) struct RateLimits {
    n_xi: usize,
    rates: Vec<Rate>,
}

impl Rate {
    /// The rows of the `order`-th derivative for `team`, the limit `max`
    /// imposed at `margin` of it at `taus` and checked at `dense_taus`.
    fn new(team: &Team, order: usize, max: f64, margin: f64, taus: &[f64], dense_taus: &[f64]) -> Self {
        // The factor the normalised derivative is scaled by: one over the
        // largest factor the derivative brings, `N (N - 1) ...`, so that the
        // rows weigh about as much as the position rows.
        let scale = 1.0 / (0..order).map(|i| team.degree.saturating_sub(i).max(1) as f64).product::<f64>();
        let rows = |taus: &[f64]| -> Vec<f64> {
            taus.iter().flat_map(|&t| bernstein_row(team.degree, order, t)).map(|v| v * scale).collect()
        };
        // D xi = T^r (rate) scale, so the limit in those units:
        let limit = max * team.horizon.powi(order as i32) * scale;
        Self { d: rows(taus), dense: rows(dense_taus), bound: margin * limit, limit }
    }

    /// Adds this limit's corrections of `xi`, `w D^T c`, into `out`;
    /// returns `||c||^2`.
    fn correct(&self, nx: usize, axes: usize, n: usize, xi: &[f64], out: &mut [f64]) -> f64 {
        let count = self.d.len() / nx;
        let mut sq = 0.0;
        let mut v = [0.0; 3];
        for i in 0..n {
            let coefs = |a: usize| &xi[(a * n + i) * nx..(a * n + i + 1) * nx];
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
        sq
    }

    /// Whether every robot of `xi` keeps the limit at the dense instants.
    fn within(&self, nx: usize, axes: usize, n: usize, xi: &[f64]) -> bool {
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

impl RateLimits {
    /// The limits asked of `team` (those it has: `max_speed` where `speed`,
    /// `max_acceleration` where `acceleration`) at the constrained instants
    /// `taus` and the dense instants `dense_taus` (normalised time); `None`
    /// if none.
    pub(crate) fn new(
        team: &Team,
        (speed, acceleration): (bool, bool),
        taus: &[f64],
        dense_taus: &[f64],
    ) -> Option<Self> {
        let valid = |max: Option<f64>| max.filter(|m| m.is_finite() && *m > 0.0);
        let speed = valid(team.max_speed).filter(|_| speed).map(|m| (1, m, SPEED_MARGIN));
        let acceleration = valid(team.max_acceleration).filter(|_| acceleration).map(|m| (2, m, ACCELERATION_MARGIN));
        let rates: Vec<Rate> = speed
            .into_iter()
            .chain(acceleration)
            .map(|(order, max, margin)| Rate::new(team, order, max, margin, taus, dense_taus))
            .collect();
        (!rates.is_empty()).then_some(Self { n_xi: team.degree + 1, rates })
    }

    /// `w D^T D` summed over the limits (`n_xi x n_xi`, row-major): what
    /// joins the cost Hessian per unit of penalty.
    pub(crate) fn gram(&self) -> Vec<f64> {
        let mut sum = vec![0.0; self.n_xi * self.n_xi];
        for rate in &self.rates {
            for (s, g) in sum.iter_mut().zip(gram_of(&rate.d, self.n_xi, 0)) {
                *s += WEIGHT * g;
            }
        }
        sum
    }

    /// The corrections of `xi` (`[axis][robot][coef]`, `axes` axes, `n`
    /// robots) onto the balls, mapped to coefficients, `w D^T c`, written
    /// into `out` (the same layout); returns the residual `sqrt(w) ||c||`.
    pub(crate) fn correct(&self, axes: usize, n: usize, xi: &[f64], out: &mut [f64]) -> f64 {
        out.fill(0.0);
        let sq: f64 = self.rates.iter().map(|rate| rate.correct(self.n_xi, axes, n, xi, out)).sum();
        (WEIGHT * sq).sqrt()
    }

    /// Whether every robot of `xi` keeps the limits at the dense instants.
    pub(crate) fn within(&self, axes: usize, n: usize, xi: &[f64]) -> bool {
        self.rates.iter().all(|rate| rate.within(self.n_xi, axes, n, xi))
    }
}

#[cfg(test)]
mod tests {
    use crate::am::{AmSettings, Engine, Objective, Stop};
    use crate::metrics::DENSE_FACTOR;
    use crate::plan::JointPlan;
    use crate::problem::{Dim, Problem, Team};
    use crate::scenario::RandomScenario;

    /// 8 robots starting at `speed` m/s (`None`: at rest), and the
    /// optimiser's plan without a limit.
    fn planned(seed: u64, speed: Option<f64>) -> (Problem, Vec<f64>) {
        let team = Team::default_for(Dim::Two, 8);
        let scenario = RandomScenario::new(team.clone());
        let problem = speed.map_or(scenario.clone(), |s| scenario.with_start_speed(s)).generate(seed).unwrap();
        let free = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser()).unwrap();
        let outcome = free.solve(&problem).unwrap();
        assert_eq!(outcome.stop, Stop::Verified);
        (problem, outcome.state.xi)
    }

    fn moving(seed: u64) -> (Problem, Vec<f64>) {
        planned(seed, Some(1.0))
    }

    fn resting(seed: u64) -> (Problem, Vec<f64>) {
        planned(seed, None)
    }

    /// The peak speed and acceleration of `xi`.
    fn peaks(team: &Team, xi: &[f64]) -> (f64, f64) {
        JointPlan::new(team, xi.to_vec()).peak_rates(DENSE_FACTOR * team.samples)
    }

    fn peak_acceleration(team: &Team, xi: &[f64]) -> f64 {
        peaks(team, xi).1
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

    fn peak_speed(team: &Team, xi: &[f64]) -> f64 {
        peaks(team, xi).0
    }

    /// `problem` of a team with `max_speed`, and its engines without and
    /// with the limit.
    fn speed_limited(
        problem: &Problem,
        max_speed: f64,
        objective: Objective,
        settings: AmSettings,
    ) -> (Problem, [Engine; 2]) {
        let team = Team { max_speed: Some(max_speed), ..problem.team.clone() };
        let engines = [false, true]
            .map(|limit_speed| Engine::new(&team, 0, objective, AmSettings { limit_speed, ..settings }).unwrap());
        (Problem { team, ..problem.clone() }, engines)
    }

    #[test]
    fn plans_keep_a_speed_limit_their_unlimited_plans_exceed() {
        for seed in [0, 3] {
            let (problem, free) = resting(seed);
            let limit = 0.9 * peak_speed(&problem.team, &free);
            let (problem, engines) = speed_limited(&problem, limit, Objective::smoothness(), AmSettings::optimiser());
            let outcome = engines[1].solve(&problem).unwrap();
            assert_eq!(outcome.stop, Stop::Verified, "seed {seed}");
            let peak = peak_speed(&problem.team, &outcome.state.xi);
            assert!(peak <= limit * (1.0 + 1e-9), "seed {seed}: {peak} over {limit}");
            // Without the setting the plan is the unlimited one.
            assert_eq!(engines[0].solve(&problem).unwrap().state.xi, free, "seed {seed}");
        }
    }

    #[test]
    fn the_safety_filter_repairs_a_sample_over_the_speed_limit() {
        // The daemon's case: a warm sample a little over the limit, repaired
        // by the safety filter within it; the filter without the limit
        // leaves it over.
        let (problem, free) = resting(0);
        let limit = 0.97 * peak_speed(&problem.team, &free);
        let (problem, engines) = speed_limited(&problem, limit, Objective::Projection, AmSettings::safety_filter());
        let peaks = engines.map(|engine| {
            let prepared = engine.prepare(&problem, Some(&free)).unwrap();
            let outcome = engine.run(&prepared, engine.cold_start(&prepared));
            assert_eq!(outcome.stop, Stop::Verified);
            peak_speed(&problem.team, &outcome.state.xi)
        });
        assert!(peaks[0] > limit, "without the limit: {} under {limit}", peaks[0]);
        assert!(peaks[1] <= limit * (1.0 + 1e-9), "with it: {} over {limit}", peaks[1]);
    }
}
