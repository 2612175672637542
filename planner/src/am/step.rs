//! One iteration: the projection's corrections, the multiplier update and
//! the pre-factored xi-step; [`Stepper`] runs it alone (the unit the
//! per-iteration benchmarks time) and [`StepOperators`] exposes its linear
//! pieces to code that re-implements it.

use super::engine::{AmState, Engine, Residuals};
use super::prepare::Prepared;
use super::projection::{Projection, ROBOT_BLOCK, block_robots};
use crate::crew::{Crew, Disjoint};
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
        let crew = Crew::alone();
        let primal = self.projection.run(&crew, dim, n, &e.grid, &prepared.constraint, &state.xi)
            + e.rates_step(&state.xi, &mut self.work);
        let level = level.min(e.levels.len() - 1);
        let fixed_point = e.update(&crew, prepared, state, level, &self.projection, &mut self.work);
        Residuals { primal, fixed_point }
    }
}

/// Buffers of the xi-step: `[axis][robot][coef]` (`u`, `rhs`, `next`),
/// `[axis][coef]` (`sum`, `shared`, `mean`, `shift`), per robot block
/// (`block_sq`; `block_sums`: `[block][xi, rhs][axis][coef]`).
pub(super) struct Work {
    u: Vec<f64>,
    rhs: Vec<f64>,
    next: Vec<f64>,
    sum: Vec<f64>,
    shared: Vec<f64>,
    mean: Vec<f64>,
    shift: Vec<f64>,
    block_sq: Vec<f64>,
    block_sums: Vec<f64>,
    /// The rate limits' corrections mapped to coefficients,
    /// `[axis][robot][coef]` (empty without them).
    rates: Vec<f64>,
}

impl Engine {
    /// The per-robot cost Hessian `C` (`n_xi x n_xi`, row-major): the
    /// identity for [`Objective::Projection`], `I + weight Q` for
    /// [`Objective::SmoothProjection`], the SF's metric.
    pub fn cost(&self) -> &[f64] {
        &self.cost
    }

    /// The linear pieces of an iteration at penalty level `level` (clamped
    /// to the schedule), of an engine without rate limits
    /// ([`super::AmSettings::limit_speed`],
    /// [`super::AmSettings::limit_acceleration`]) only: with them, `K11`
    /// (and the prepared boundary part) include `rho w D^T D` while the
    /// limits' multiplier and right-hand-side terms are not among these.
    pub fn step_operators(&self, level: usize) -> StepOperators {
        debug_assert!(self.rates.is_none(), "the unrolled iteration has no rate rows");
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
        let axes = self.team.dim.axes() * self.n_xi;
        let blocks = self.team.robots.div_ceil(ROBOT_BLOCK);
        Work {
            u: vec![0.0; len],
            rhs: vec![0.0; len],
            next: vec![0.0; len],
            sum: vec![0.0; axes],
            shared: vec![0.0; axes],
            mean: vec![0.0; axes],
            shift: vec![0.0; axes],
            block_sq: vec![0.0; blocks],
            block_sums: vec![0.0; blocks * 2 * axes],
            rates: if self.rates.is_some() { vec![0.0; len] } else { Vec::new() },
        }
    }

    /// The rate limits' corrections of `xi` into `w` (nothing without
    /// them): their residual, added to the primal one.
    pub(super) fn rates_step(&self, xi: &[f64], w: &mut Work) -> f64 {
        self.rates
            .as_ref()
            .map_or(0.0, |limits| limits.correct(self.team.dim.axes(), self.team.robots, xi, &mut w.rates))
    }

    /// Multiplier update and xi-step from the corrections of `projection`
    /// on `crew`, per robot block (the same numbers for every crew size);
    /// returns the fixed-point residual.
    ///
    /// The sums over the team (of `xi`, for the structured `F^T F + G^T G`,
    /// and of the right-hand sides, for their mean) are taken per robot
    /// block inside the parallel steps and added block after block in
    /// between, so that nothing runs over the whole team on one thread:
    /// `r_i = a_i - (sum_j xi_j) rho P^T P` with `a_i` the right-hand side
    /// of `u_i = modes xi_i` alone.
    pub(super) fn update(
        &self,
        crew: &Crew<'_>,
        prepared: &Prepared,
        state: &mut AmState,
        level: usize,
        projection: &Projection,
        w: &mut Work,
    ) -> f64 {
        let dim = self.team.dim.axes();
        let n = self.team.robots;
        let nx = self.n_xi;
        let lv = &self.levels[level];
        let rho = lv.rho;
        let nb = n.div_ceil(ROBOT_BLOCK);
        let modes = n as f64 + self.obstacles as f64 + WORKSPACE_WEIGHT;
        let width = dim * nx;
        // g = P^T (e - F xi): the corrections mapped back to coefficients;
        // lambda <- lambda - rho F^T r1 - rho G^T r2 = lambda + rho g;
        // a_i = c_lin + rho g + lambda + rho P^T P modes xi_i, and per block
        // the sums of xi_i and a_i.
        let g = projection.mapped();
        let target = &prepared.target;
        let xi = &state.xi;
        {
            let Work { u, rhs, block_sq, block_sums, rates, .. } = &mut *w;
            let rates = &*rates;
            let (lambda, u, rhs, block_sq, block_sums) = (
                Disjoint::new(&mut state.lambda),
                Disjoint::new(u),
                Disjoint::new(rhs),
                Disjoint::new(block_sq),
                Disjoint::new(block_sums),
            );
            crew.each(nb, &|_, b| {
                let robots = block_robots(b, n);
                let mut lambda_sq = 0.0;
                // SAFETY: each block's sums belong to one part.
                let sums = unsafe { block_sums.range(b * 2 * width..(b + 1) * 2 * width) };
                let (xi_sums, rhs_sums) = sums.split_at_mut(width);
                for ax in 0..dim {
                    let rows = (ax * n + robots.start) * nx..(ax * n + robots.end) * nx;
                    // SAFETY: each block's rows belong to one part.
                    let (lambda, u, rhs) =
                        unsafe { (lambda.range(rows.clone()), u.range(rows.clone()), rhs.range(rows.clone())) };
                    if rates.is_empty() {
                        for (l, g) in lambda.iter_mut().zip(&g[rows.clone()]) {
                            let d = rho * g;
                            *l += d;
                            lambda_sq += d * d;
                        }
                    } else {
                        // The rate rows' corrections, `w D^T c`, enter
                        // like the positions' (the multiplier here, the
                        // right-hand side below).
                        let moves = g[rows.clone()].iter().zip(&rates[rows.clone()]);
                        for (l, (g, c)) in lambda.iter_mut().zip(moves) {
                            let (d, e) = (rho * g, rho * c);
                            *l += d;
                            *l += e;
                            lambda_sq += (d + e) * (d + e);
                        }
                    }
                    let xi_sum = &mut xi_sums[ax * nx..(ax + 1) * nx];
                    xi_sum.fill(0.0);
                    for (u, x) in u.chunks_exact_mut(nx).zip(xi[rows.clone()].chunks_exact(nx)) {
                        for c in 0..nx {
                            u[c] = modes * x[c];
                            xi_sum[c] += x[c];
                        }
                    }
                    // Two loops rather than a bounds check per element:
                    // the empty target's masked loads cost the optimiser
                    // 7% of an iteration at 256 robots on these hosts.
                    let moves = rhs.iter_mut().zip(&g[rows.clone()]).zip(&*lambda);
                    if target.is_empty() {
                        moves.for_each(|((r, g), l)| *r = rho * g + l);
                    } else {
                        moves.zip(&target[rows.clone()]).for_each(|(((r, g), l), t)| *r = t + rho * g + l);
                    }
                    gemm(rhs, u, &lv.rho_gram, robots.len(), nx, nx, Accum::Add);
                    if !rates.is_empty() {
                        // rho w D^T e = rho w D^T D xi + rho w D^T c.
                        for (r, c) in rhs.iter_mut().zip(&rates[rows.clone()]) {
                            *r += rho * c;
                        }
                        gemm(rhs, &xi[rows], &lv.rho_rates, robots.len(), nx, nx, Accum::Add);
                    }
                    let rhs_sum = &mut rhs_sums[ax * nx..(ax + 1) * nx];
                    rhs_sum.fill(0.0);
                    for row in rhs.chunks_exact(nx) {
                        for (s, v) in rhs_sum.iter_mut().zip(row) {
                            *s += v;
                        }
                    }
                }
                // SAFETY: as above.
                unsafe { *block_sq.at(b) = lambda_sq };
            });
        }
        let lambda_sq: f64 = w.block_sq.iter().sum();
        // The team's sums, block after block: `s = sum_j xi_j` (in `sum`),
        // then the shared term `s rho P^T P` (in `shared`) and the
        // right-hand sides' mean `mean_j a_j - s rho P^T P` (in `mean`).
        w.sum.fill(0.0);
        w.mean.fill(0.0);
        for sums in w.block_sums[..nb * 2 * width].chunks_exact(2 * width) {
            let (xi_sums, rhs_sums) = sums.split_at(width);
            for (s, v) in w.sum.iter_mut().zip(xi_sums) {
                *s += v;
            }
            for (m, v) in w.mean.iter_mut().zip(rhs_sums) {
                *m += v;
            }
        }
        for ax in 0..dim {
            let axis = ax * nx..(ax + 1) * nx;
            gemm(&mut w.shared[axis.clone()], &w.sum[axis.clone()], &lv.rho_gram, 1, nx, nx, Accum::Replace);
            for (m, s) in w.mean[axis.clone()].iter_mut().zip(&w.shared[axis.clone()]) {
                *m = *m / n as f64 - s;
            }
        }
        // xi_i = K11_diff r_i + (K11_mean - K11_diff) r_mean + beta_i (K11 symmetric).
        for (shift, mean) in w.shift.chunks_exact_mut(nx).zip(w.mean.chunks_exact(nx)) {
            for (s, row) in shift.iter_mut().zip(lv.mean_minus_diff.chunks_exact(nx)) {
                *s = dot(row, mean);
            }
        }
        {
            let Work { rhs, next, shift, shared, block_sq, .. } = &mut *w;
            let (shift, shared, beta) = (&*shift, &*shared, &prepared.beta[level]);
            let (rhs, next, block_sq) = (Disjoint::new(rhs), Disjoint::new(next), Disjoint::new(block_sq));
            crew.each(nb, &|_, b| {
                let robots = block_robots(b, n);
                let mut xi_sq = 0.0;
                for ax in 0..dim {
                    let rows = (ax * n + robots.start) * nx..(ax * n + robots.end) * nx;
                    // SAFETY: each block's rows belong to one part.
                    let (rhs, next) = unsafe { (rhs.range(rows.clone()), next.range(rows.clone())) };
                    let (shift, shared) = (&shift[ax * nx..(ax + 1) * nx], &shared[ax * nx..(ax + 1) * nx]);
                    for row in rhs.chunks_exact_mut(nx) {
                        for (r, s) in row.iter_mut().zip(shared) {
                            *r -= s;
                        }
                    }
                    next.copy_from_slice(&beta[rows.clone()]);
                    for row in next.chunks_exact_mut(nx) {
                        for (x, s) in row.iter_mut().zip(shift) {
                            *x += s;
                        }
                    }
                    gemm(next, rhs, lv.kkt.diff().k11(), robots.len(), nx, nx, Accum::Add);
                    xi_sq += xi[rows].iter().zip(&*next).map(|(a, b)| (a - b) * (a - b)).sum::<f64>();
                }
                // SAFETY: as above.
                unsafe { *block_sq.at(b) = xi_sq };
            });
        }
        let xi_sq: f64 = w.block_sq.iter().sum();
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
