//! The safety filter written in candle ops, differentiable end to end, for
//! training the initialiser through `L` unrolled iterations (METHOD.md
//! section 4). It is the planner's SF iteration
//! ([`flowopt_planner::am::StepOperators`]) on a batch of problems of one
//! shape: the projection pushes every violating pair or robot-obstacle
//! offset `d` to `d max(1, 1/r)` (normalised differences, no angles) and
//! clamps positions into the box, then the multiplier and xi-steps apply
//! the same pre-factored operators, at the penalty the engine's schedule
//! gives each iteration. Tensors are `[B, axis, robot, coef]`, the
//! planner's `[axis][robot][coef]` per problem. It projects onto the fixed
//! (margin-inflated) separation: the planner's chord inflation
//! (`AmSettings::chord`) is not unrolled, so the initialiser learns the
//! filter's first iterations without it.

use candle_core::{DType, Device, Result, Tensor};
use flowopt_planner::am::{Engine, Prepared, RhoSchedule};

/// Diagonal offset that keeps a robot from interacting with itself.
const SELF_OFFSET: f64 = 1e6;

/// The operators of one penalty level.
#[derive(Debug, Clone)]
struct LevelOps {
    rho: f64,
    rho_gram: Tensor,
    k11_diff: Tensor,
    /// `(K11_mean - K11_diff)^T`.
    mean_minus_diff_t: Tensor,
}

/// The constant operators of one engine (team shape, obstacle count).
#[derive(Debug, Clone)]
pub struct UnrolledSf {
    /// One per penalty level of the engine's schedule.
    levels: Vec<LevelOps>,
    schedule: RhoSchedule,
    modes: f64,
    /// `P^T`, `[n_xi, K]`.
    pt: Tensor,
    /// `P`, `[K, n_xi]`.
    p: Tensor,
    /// The per-robot cost Hessian (the SF's metric), `[n_xi, n_xi]`.
    cost: Tensor,
    /// `1 / sep^2` per axis, `[1, D, 1, 1, 1]`.
    inv_robot: Tensor,
    /// `n x n` diagonal offset, `[1, n, n, 1]`.
    self_offset: Tensor,
    dtype: DType,
}

/// The per-problem data of a batch.
#[derive(Debug, Clone)]
pub struct SfBatch {
    /// The xi-step's boundary part per penalty level, `[B, D, n, n_xi]` each.
    pub beta: Vec<Tensor>,
    /// The cost's linear term (see `Prepared::target`), `[B, D, n, n_xi]`.
    pub target: Tensor,
    /// The samples the SF repairs, `[B, D, n, n_xi]`.
    pub sample: Tensor,
    /// Obstacle centres, `[B, D, m, K]`, and `1 / sep^2`, `[B, D, 1, m, 1]`.
    pub obstacles: Option<(Tensor, Tensor)>,
    /// Box per axis, `[1, D, 1, 1]` each.
    pub lo: Tensor,
    /// Upper corner.
    pub hi: Tensor,
}

fn matrix(values: &[f64], rows: usize, cols: usize, dtype: DType) -> Result<Tensor> {
    Tensor::from_slice(values, (rows, cols), &Device::Cpu)?.to_dtype(dtype)
}

impl UnrolledSf {
    /// The operators of `engine` (a safety filter) at every level of its
    /// penalty schedule, in `dtype`.
    pub fn new(engine: &Engine, dtype: DType) -> Result<Self> {
        let per_level: Vec<_> = (0..engine.rho_levels().len()).map(|l| engine.step_operators(l)).collect();
        let first = &per_level[0];
        let team = engine.team();
        let (dim, n) = (team.dim.axes(), team.robots);
        let nx = engine.basis().n_xi();
        let k = first.taus.len();
        let p = matrix(&first.p, k, nx, dtype)?;
        let levels = per_level
            .iter()
            .map(|ops| {
                Ok(LevelOps {
                    rho: ops.rho,
                    rho_gram: matrix(&ops.rho_gram, nx, nx, dtype)?,
                    k11_diff: matrix(&ops.k11_diff, nx, nx, dtype)?,
                    mean_minus_diff_t: matrix(&ops.mean_minus_diff, nx, nx, dtype)?.t()?.contiguous()?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let (a, b) = team.separation();
        let margin = 1.0 + engine.settings().margin;
        let sep = [a, a, b].map(|s| s * margin);
        let inv: Vec<f64> = (0..dim).map(|ax| 1.0 / (sep[ax] * sep[ax])).collect();
        let offset: Vec<f64> = (0..n * n).map(|i| if i / n == i % n { SELF_OFFSET } else { 0.0 }).collect();
        Ok(Self {
            levels,
            schedule: engine.settings().rho,
            modes: first.modes,
            pt: p.t()?.contiguous()?,
            p,
            cost: matrix(engine.cost(), nx, nx, dtype)?,
            inv_robot: Tensor::from_vec(inv, (1, dim, 1, 1, 1), &Device::Cpu)?.to_dtype(dtype)?,
            self_offset: Tensor::from_vec(offset, (1, n, n, 1), &Device::Cpu)?.to_dtype(dtype)?,
            dtype,
        })
    }

    /// The batch of prepared problems (all of this engine's shape).
    pub fn batch(&self, engine: &Engine, prepared: &[&Prepared]) -> Result<SfBatch> {
        let team = engine.team();
        let (dim, n) = (team.dim.axes(), team.robots);
        let nx = engine.basis().n_xi();
        let k = self.p.dim(0)?;
        let b = prepared.len();
        let m = engine.obstacles();
        let stack = |f: &dyn Fn(&Prepared) -> &[f64]| -> Result<Tensor> {
            let v: Vec<f64> = prepared.iter().flat_map(|p| f(p).iter().copied()).collect();
            Tensor::from_vec(v, (b, dim, n, nx), &Device::Cpu)?.to_dtype(self.dtype)
        };
        let obstacles = if m == 0 {
            None
        } else {
            let mut tracks = Vec::with_capacity(b * dim * m * k);
            let mut inv = Vec::with_capacity(b * dim * m);
            for p in prepared {
                let limits = p.constraint();
                // Limits hold [obstacle][axis][sample]; the batch wants [axis][obstacle][sample].
                for ax in 0..dim {
                    for o in 0..m {
                        tracks.extend_from_slice(&limits.tracks()[(o * dim + ax) * k..(o * dim + ax + 1) * k]);
                    }
                }
                for ax in 0..dim {
                    inv.extend(limits.obstacle_separations().iter().map(|s| 1.0 / (s[ax] * s[ax])));
                }
            }
            Some((
                Tensor::from_vec(tracks, (b, dim, m, k), &Device::Cpu)?.to_dtype(self.dtype)?,
                Tensor::from_vec(inv, (b, dim, 1, m, 1), &Device::Cpu)?.to_dtype(self.dtype)?,
            ))
        };
        let (lo, hi) = match prepared.first() {
            Some(p) => p.constraint().bounds(),
            None => ([0.0; 3], [0.0; 3]),
        };
        let corner =
            |c: [f64; 3]| Tensor::from_vec(c[..dim].to_vec(), (1, dim, 1, 1), &Device::Cpu)?.to_dtype(self.dtype);
        Ok(SfBatch {
            beta: (0..self.levels.len()).map(|l| stack(&|p| p.beta(l))).collect::<Result<_>>()?,
            target: stack(&|p| p.target())?,
            sample: stack(&|p| p.cold())?,
            obstacles,
            lo: corner(lo)?,
            hi: corner(hi)?,
        })
    }

    /// The projection's corrections `e - F xi` per robot, `[B, D, n, K]`.
    pub fn corrections(&self, xi: &Tensor, batch: &SfBatch) -> Result<Tensor> {
        let pos = xi.broadcast_matmul(&self.pt)?;
        // Pairs: d_ij = p_i - p_j, r^2 = sum_a d_a^2 / sep_a^2.
        let d = pos.unsqueeze(3)?.broadcast_sub(&pos.unsqueeze(2)?)?;
        let s = d.sqr()?.broadcast_mul(&self.inv_robot)?.sum(1)?.broadcast_add(&self.self_offset)?;
        let f = (s.sqrt()?.recip()? - 1.0)?.relu()?;
        let mut corr = d.broadcast_mul(&f.unsqueeze(1)?)?.sum(3)?;
        if let Some((tracks, inv)) = &batch.obstacles {
            let d = pos.unsqueeze(3)?.broadcast_sub(&tracks.unsqueeze(2)?)?;
            let s = d.sqr()?.broadcast_mul(inv)?.sum(1)?;
            let f = (s.sqrt()?.recip()? - 1.0)?.relu()?;
            corr = (corr + d.broadcast_mul(&f.unsqueeze(1)?)?.sum(3)?)?;
        }
        let clamped = pos.broadcast_maximum(&batch.lo)?.broadcast_minimum(&batch.hi)?;
        corr + (clamped - pos)?
    }

    /// Iteration `l` from `(xi, lambda)`, at the schedule's penalty for `l`.
    pub fn step(&self, l: usize, xi: &Tensor, lambda: &Tensor, batch: &SfBatch) -> Result<(Tensor, Tensor)> {
        let level = self.schedule.level_at(l, self.levels.len());
        let ops = &self.levels[level];
        let g = self.corrections(xi, batch)?.broadcast_matmul(&self.p)?;
        let lambda = (lambda + (&g * ops.rho)?)?;
        let u = ((xi * self.modes)?.broadcast_sub(&xi.sum_keepdim(2)?))?;
        let rhs = ((&batch.target + (&g * ops.rho)?)? + &lambda)?.add(&u.broadcast_matmul(&ops.rho_gram)?)?;
        let next = batch.beta[level]
            .add(&rhs.broadcast_matmul(&ops.k11_diff)?)?
            .broadcast_add(&rhs.mean_keepdim(2)?.broadcast_matmul(&ops.mean_minus_diff_t)?)?;
        Ok((next, lambda))
    }

    /// The SF's own distance from `xi` to the samples, per problem:
    /// `sum_(axis, robot) (xi - sample)^T C (xi - sample)` with `C` the
    /// engine's cost Hessian (the squared Euclidean distance for the plain
    /// projection), `[B]`.
    pub fn distance(&self, xi: &Tensor, batch: &SfBatch) -> Result<Tensor> {
        let d = (xi - &batch.sample)?;
        (d.broadcast_matmul(&self.cost)? * &d)?.flatten_from(1)?.sum(1)
    }

    /// Runs `iterations` steps from `(xi, lambda)`; returns the final iterate
    /// and the per-problem squared fixed-point residuals of every step
    /// (`||dxi||^2 + ||dlambda||^2`, `[iterations, B]`).
    pub fn unroll(
        &self,
        xi: &Tensor,
        lambda: &Tensor,
        batch: &SfBatch,
        iterations: usize,
    ) -> Result<(Tensor, Tensor, Tensor)> {
        let (mut xi, mut lambda) = (xi.clone(), lambda.clone());
        let mut residuals = Vec::with_capacity(iterations);
        for iteration in 0..iterations {
            let (x, l) = self.step(iteration, &xi, &lambda, batch)?;
            let r = ((&x - &xi)?.sqr()?.flatten_from(1)?.sum(1)? + (&l - &lambda)?.sqr()?.flatten_from(1)?.sum(1)?)?;
            residuals.push(r);
            (xi, lambda) = (x, l);
        }
        Ok((xi, lambda, Tensor::stack(&residuals, 0)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::am::{AmSettings, AmState, Objective};
    use flowopt_planner::problem::{Dim, Team};
    use flowopt_planner::reference::SmoothReference;
    use flowopt_planner::scenario::RandomScenario;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_unrolled_filter_equals_the_planners_filter() {
        unrolled_equals_planner(Objective::Projection);
    }

    #[test]
    fn the_unrolled_smooth_projection_equals_the_planners() {
        unrolled_equals_planner(Objective::SmoothProjection { weight: 3.0 });
    }

    fn unrolled_equals_planner(objective: Objective) {
        let team = Team::default_for(Dim::Two, 6);
        // A penalty doubling every other iteration: the 5 iterations below
        // run at three levels. The planner runs them without stopping
        // (a tolerance never met, a cap of 5), with its own choice of level.
        // The unrolled filter projects onto the fixed separation: the
        // planner's chord inflation is off for the comparison.
        let mut settings = AmSettings { chord: false, ..AmSettings::safety_filter().residual_study(-1.0) };
        settings.rho.every = 2;
        settings.max_iterations = 5;
        let engine = Engine::new(&team, 2, objective, settings).unwrap();
        assert!(engine.rho_levels().len() >= 3);
        let sf = UnrolledSf::new(&engine, DType::F64).unwrap();
        let reference = SmoothReference::new(&team).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut prepared = Vec::new();
        let mut states = Vec::new();
        for seed in 0..2 {
            let problem =
                RandomScenario::new(team.clone()).with_obstacles(2).with_start_speed(0.3).generate(seed).unwrap();
            // The straight curves plus noise collide with each other and the obstacles.
            let sample: Vec<f64> =
                reference.coefficients(&problem).iter().map(|x| x + 0.2 * rng.random_range(-1.0..=1.0)).collect();
            let p = engine.prepare(&problem, Some(&sample)).unwrap();
            let lambda: Vec<f64> = (0..sample.len()).map(|_| rng.random_range(-0.5..=0.5)).collect();
            states.push(AmState { xi: sample, lambda });
            prepared.push(p);
        }
        let refs: Vec<&Prepared> = prepared.iter().collect();
        let batch = sf.batch(&engine, &refs).unwrap();
        let shape = (2, 2, 6, 11);
        let flat = |f: &dyn Fn(&AmState) -> &Vec<f64>| states.iter().flat_map(|s| f(s).clone()).collect::<Vec<f64>>();
        let xi = Tensor::from_vec(flat(&|s| &s.xi), shape, &Device::Cpu).unwrap();
        let lambda = Tensor::from_vec(flat(&|s| &s.lambda), shape, &Device::Cpu).unwrap();
        // The batch keeps the samples apart from the cost's linear term,
        // which is the sample itself only for the plain projection.
        let values = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        assert_eq!(values(&batch.sample), flat(&|s| &s.xi));
        assert_eq!(values(&batch.target) == values(&batch.sample), objective == Objective::Projection);
        let (xi_l, lambda_l, residuals) = sf.unroll(&xi, &lambda, &batch, 5).unwrap();
        assert_eq!(residuals.dims(), &[5, 2]);
        let mut stepped = Vec::new();
        for (state, p) in states.iter().zip(&prepared) {
            let run = engine.run(p, state.clone());
            assert_eq!(run.iterations, 5);
            assert!(run.history.iter().any(|r| r.primal > 0.0), "the test must exercise the projection");
            stepped.push(run.state);
        }
        let ours_xi = xi_l.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let ours_lambda = lambda_l.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let theirs_xi: Vec<f64> = stepped.iter().flat_map(|s| s.xi.clone()).collect();
        let theirs_lambda: Vec<f64> = stepped.iter().flat_map(|s| s.lambda.clone()).collect();
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        // The SF's distance of the result from the samples, row by row in the engine's metric.
        let (samples, c, nx) = (flat(&|s| &s.xi), engine.cost(), 11);
        let expected: Vec<f64> = ours_xi
            .chunks(ours_xi.len() / 2)
            .zip(samples.chunks(samples.len() / 2))
            .map(|(x, s)| {
                let d: Vec<f64> = x.iter().zip(s).map(|(a, b)| a - b).collect();
                d.chunks(nx)
                    .map(|r| (0..nx).map(|i| (0..nx).map(|j| r[i] * c[i * nx + j] * r[j]).sum::<f64>()).sum::<f64>())
                    .sum()
            })
            .collect();
        let distance = values(&sf.distance(&xi_l, &batch).unwrap());
        assert!(close(&distance, &expected) < 1e-9 * expected[0].max(1.0), "{distance:?} vs {expected:?}");
        assert!(close(&ours_xi, &theirs_xi) < 1e-9, "xi differs by {}", close(&ours_xi, &theirs_xi));
        assert!(
            close(&ours_lambda, &theirs_lambda) < 1e-9,
            "lambda differs by {}",
            close(&ours_lambda, &theirs_lambda)
        );
    }
}
