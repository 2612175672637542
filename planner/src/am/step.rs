//! One iteration: the projection's corrections, the multiplier update and
//! the pre-factored xi-step; [`Stepper`] runs it alone (the unit the
//! per-iteration benchmarks time) and [`StepOperators`] exposes its linear
//! pieces to code that re-implements it.

use super::engine::{AmState, Engine, Residuals};
use super::prepare::Prepared;
use super::projection::Projection;
use crate::kkt::WORKSPACE_WEIGHT;
use crate::linalg::{Accum, dot, gemm};

/// The linear pieces of one iteration at one penalty level, for code that
/// re-implements the iteration (the learned initialiser's differentiable
/// unrolled safety filter). Matrices are row-major; with `[axis][robot][coef]`
/// rows, one iteration from `(xi, lambda)` with projection corrections `c`
/// (`[axis][robot][sample]`, see [`super::Limits`]) is
/// `g = c P`, `lambda += rho g`, `u_i = modes xi_i - sum_j xi_j`,
/// `r = target + rho g + lambda + u gram_rho`,
/// `xi_i = beta_i + r_i k11_diff + mean_r mean_minus_diff^T`.
#[derive(Debug, Clone)]
pub struct StepOperators {
    /// The penalty.
    pub rho: f64,
    /// `n + m + w`: robots, obstacles and the workspace weight.
    pub modes: f64,
    /// Normalised times of the constrained samples.
    pub taus: Vec<f64>,
    /// `P` at the constrained samples, `count x n_xi`.
    pub p: Vec<f64>,
    /// `rho P^T P`, `n_xi x n_xi`.
    pub rho_gram: Vec<f64>,
    /// `K11` of the difference-mode system, `n_xi x n_xi`.
    pub k11_diff: Vec<f64>,
    /// `K11_mean - K11_diff`, `n_xi x n_xi`.
    pub mean_minus_diff: Vec<f64>,
}

/// Runs single AM iterations with buffers allocated once: the unit the
/// per-iteration benchmarks time.
pub struct Stepper<'e> {
    engine: &'e Engine,
    projection: Projection,
    work: Work,
}

impl Stepper<'_> {
    /// One iteration from `state` at penalty level `level` (clamped to the
    /// schedule); returns the residuals of the iterate it started from.
    pub fn step(&mut self, prepared: &Prepared, state: &mut AmState, level: usize) -> Residuals {
        let e = self.engine;
        let (dim, n) = (e.team.dim, e.team.robots);
        let primal = self.projection.run(dim, n, &e.grid, &prepared.constraint, &state.xi);
        let level = level.min(e.levels.len() - 1);
        let fixed_point = e.update(prepared, state, level, &self.projection, &mut self.work);
        Residuals { primal, fixed_point }
    }
}

/// Buffers of the xi-step, each `[axis][robot][coef]`.
pub(super) struct Work {
    g: Vec<f64>,
    u: Vec<f64>,
    rhs: Vec<f64>,
    next: Vec<f64>,
}

impl Engine {
    /// The per-robot cost Hessian `C` (`n_xi x n_xi`, row-major): the
    /// identity for [`Objective::Projection`], `I + weight Q` for
    /// [`Objective::SmoothProjection`], the SF's metric.
    pub fn cost(&self) -> &[f64] {
        &self.cost
    }

    /// The linear pieces of an iteration at penalty level `level` (clamped
    /// to the schedule).
    pub fn step_operators(&self, level: usize) -> StepOperators {
        let lv = &self.levels[level.min(self.levels.len() - 1)];
        StepOperators {
            rho: lv.rho,
            modes: self.team.robots as f64 + self.obstacles as f64 + WORKSPACE_WEIGHT,
            taus: self.grid.taus.clone(),
            p: self.grid.p.clone(),
            rho_gram: lv.rho_gram.clone(),
            k11_diff: lv.kkt.diff().k11().to_vec(),
            mean_minus_diff: lv.mean_minus_diff.clone(),
        }
    }

    /// A reusable single-iteration driver (buffers allocated once).
    pub fn stepper(&self) -> Stepper<'_> {
        Stepper {
            engine: self,
            projection: Projection::new(self.team.dim, self.team.robots, &self.grid),
            work: self.work(),
        }
    }

    /// Fresh buffers for the xi-step.
    pub(super) fn work(&self) -> Work {
        let len = self.coeff_len();
        Work { g: vec![0.0; len], u: vec![0.0; len], rhs: vec![0.0; len], next: vec![0.0; len] }
    }

    /// Multiplier update and xi-step from the corrections of `projection`;
    /// returns the fixed-point residual.
    pub(super) fn update(
        &self,
        prepared: &Prepared,
        state: &mut AmState,
        level: usize,
        projection: &Projection,
        w: &mut Work,
    ) -> f64 {
        let dim = self.team.dim.axes();
        let n = self.team.robots;
        let nx = self.n_xi;
        let rows = dim * n;
        let lv = &self.levels[level];
        let rho = lv.rho;
        // g = P^T (e - F xi): the corrections mapped back to coefficients.
        projection.coefficients(&self.grid, rows, &mut w.g);
        // lambda <- lambda - rho F^T r1 - rho G^T r2 = lambda + rho g
        let mut lambda_sq = 0.0;
        for (l, g) in state.lambda.iter_mut().zip(&w.g) {
            let d = rho * g;
            *l += d;
            lambda_sq += d * d;
        }
        // rhs = c_lin + rho g + lambda + rho P^T P u, with
        // u_i = (n + m + w) xi_i - sum_j xi_j (the structured F^T F + G^T G).
        let modes = n as f64 + self.obstacles as f64 + WORKSPACE_WEIGHT;
        for ax in 0..dim {
            let axis = ax * n * nx..(ax + 1) * n * nx;
            let mut sum = vec![0.0; nx];
            for row in state.xi[axis.clone()].chunks_exact(nx) {
                for (m, v) in sum.iter_mut().zip(row) {
                    *m += v;
                }
            }
            for (u, x) in w.u[axis.clone()].chunks_exact_mut(nx).zip(state.xi[axis.clone()].chunks_exact(nx)) {
                for c in 0..nx {
                    u[c] = modes * x[c] - sum[c];
                }
            }
        }
        // Two loops rather than a bounds check per element: the empty
        // target's masked loads cost the optimiser 7% of an iteration at
        // 256 robots on these hosts.
        let moves = w.rhs.iter_mut().zip(&w.g).zip(&state.lambda);
        if prepared.target.is_empty() {
            moves.for_each(|((r, g), l)| *r = rho * g + l);
        } else {
            moves.zip(&prepared.target).for_each(|(((r, g), l), t)| *r = t + rho * g + l);
        }
        gemm(&mut w.rhs, &w.u, &lv.rho_gram, rows, nx, nx, Accum::Add);
        // xi_i = K11_diff rhs_i + (K11_mean - K11_diff) rhs_mean + beta_i (K11 symmetric).
        w.next.copy_from_slice(&prepared.beta[level]);
        for ax in 0..dim {
            let axis = ax * n * nx..(ax + 1) * n * nx;
            let mut mean = vec![0.0; nx];
            for row in w.rhs[axis.clone()].chunks_exact(nx) {
                for (m, v) in mean.iter_mut().zip(row) {
                    *m += v / n as f64;
                }
            }
            let shift: Vec<f64> = lv.mean_minus_diff.chunks_exact(nx).map(|row| dot(row, &mean)).collect();
            for row in w.next[axis].chunks_exact_mut(nx) {
                for (x, s) in row.iter_mut().zip(&shift) {
                    *x += s;
                }
            }
        }
        gemm(&mut w.next, &w.rhs, lv.kkt.diff().k11(), rows, nx, nx, Accum::Add);
        let xi_sq: f64 = state.xi.iter().zip(&w.next).map(|(a, b)| (a - b) * (a - b)).sum();
        std::mem::swap(&mut state.xi, &mut w.next);
        xi_sq.sqrt() + lambda_sq.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use crate::am::{AmSettings, Engine, Objective};
    use crate::problem::{Dim, Team};
    use crate::scenario::RandomScenario;

    #[test]
    fn stepping_equals_running_one_iteration() {
        let team = Team::default_for(Dim::Three, 5);
        let problem = RandomScenario::new(team.clone()).with_obstacles(2).generate(8).unwrap();
        // A negative tolerance never stops the run before the cap.
        let mut settings = AmSettings::optimiser().residual_study(-1.0);
        settings.max_iterations = 1;
        let engine = Engine::new(&team, 2, Objective::smoothness(), settings).unwrap();
        let prepared = engine.prepare(&problem, None).unwrap();
        let run = engine.run(&prepared, engine.cold_start(&prepared));
        let mut state = engine.cold_start(&prepared);
        let residuals = engine.stepper().step(&prepared, &mut state, 0);
        assert_eq!(state, run.state);
        assert_eq!(residuals, run.history[0]);
    }
}
