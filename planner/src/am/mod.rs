//! The alternating-minimisation (AM) engine: one iteration, two uses.
//!
//! Every iteration (METHOD.md section 2) projects the current positions onto
//! the non-convex constraint set ([`projection`]: inter-robot and obstacle
//! spheroids, the workspace box), updates the multiplier, and solves the
//! pre-factored xi-step ([`crate::kkt::TeamKkt`]). The cost decides the use:
//! - [`Objective::Projection`], the safety filter (SF): stay close to a given
//!   sample `xi`, `c = 1/2 ||xi_bar - xi||^2`;
//! - [`Objective::Smoothness`], the from-scratch optimiser: minimise squared
//!   acceleration from a cold start ([`AmSettings::routed_start`]).
//!
//! Working in position space keeps the iteration cheap: the multiplier and
//! right-hand side only change through `P^T (e - F xi)`, which is non-zero
//! only at violated samples, and `F^T F xi` has the Laplacian structure.
//!
//! Constraints are imposed at samples `1..K`: sample 0 is the measured start,
//! which no plan can change. Every separation is inflated by the safety
//! `margin` (and the box shrunk by it) so that a plan meeting them at the
//! samples also clears the true sizes between samples; the dense
//! verification ([`AmSettings`]) checks exactly that.
//!
//! ```
//! use flowopt_planner::am::{AmSettings, Engine, Objective, Stop};
//! use flowopt_planner::problem::{Dim, Team};
//! use flowopt_planner::scenario::RandomScenario;
//!
//! let team = Team::default_for(Dim::Two, 4);
//! let problem = RandomScenario::new(team.clone()).generate(7).unwrap();
//! let engine = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser()).unwrap();
//! let outcome = engine.solve(&problem).unwrap();
//! assert_ne!(outcome.stop, Stop::IterationCap);
//! ```

mod projection;
mod settings;
mod working_point;

use std::time::Instant;

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

pub use settings::{AmSettings, RhoSchedule, Stop};
pub use working_point::{WorkingPoint, WorkingPointError};

use crate::basis::{BOUNDARY_ROWS, Basis};
use crate::kkt::{KktError, TeamKkt, WORKSPACE_WEIGHT};
use crate::linalg::{dot, gemm};
use crate::metrics::DENSE_FACTOR;
use crate::plan::JointPlan;
use crate::problem::{Problem, ProblemError, Team};
use crate::reference::{ReferenceError, SmoothReference};
use crate::route::{Blockers, Fitter, route};
pub use projection::Limits;
use projection::{Projection, SampleGrid};

/// First sample the constraints are imposed at (sample 0 is the start state).
pub const FIRST_CONSTRAINED_SAMPLE: usize = 1;

/// Iterations between two deadline checks (a clock read costs about as
/// much as a tenth of a small team's iteration).
const DEADLINE_CHECK_EVERY: usize = 4;

/// How exactly a start must meet the boundary conditions to be returned
/// without an update (normalised time units).
const BOUNDARY_EXACTNESS: f64 = 1e-9;

/// Amplitude of a restart's perturbation of the interior coefficients, in
/// robot separations.
const RESTART_AMPLITUDE: f64 = 0.5;

/// What the AM iterations minimise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Objective {
    /// The safety filter: `c = 1/2 ||xi_bar - xi||^2` for a given sample `xi`.
    Projection,
    /// The safety filter in a smoothness-weighted metric:
    /// `c = 1/2 (xi_bar - xi)^T (I + weight Q) (xi_bar - xi)` with `Q` the
    /// per-robot Gram matrix of the squared accelerations at the K samples
    /// (physical units), so repairs prefer smooth detours to sharp ones.
    /// `weight = 0` is [`Objective::Projection`].
    SmoothProjection {
        /// Weight of the smoothness of the correction against its size.
        weight: f64,
    },
    /// The from-scratch optimiser: `c = 1/2 weight * sum ||p''(t_k)||^2`
    /// (physical units).
    Smoothness {
        /// Weight of the smoothness cost against the penalty `rho`.
        weight: f64,
    },
}

impl Objective {
    /// The optimiser's objective with the default weight.
    pub fn smoothness() -> Self {
        Objective::Smoothness { weight: 1.0 }
    }

    /// The safety filter's objective for a smoothing weight: the plain
    /// projection at 0, [`Objective::SmoothProjection`] above it. Callers
    /// validate the weight (finite, 0 or more); anything else not above 0,
    /// NaN included, gives the plain projection.
    pub fn filter(smoothing: f64) -> Self {
        if smoothing > 0.0 { Objective::SmoothProjection { weight: smoothing } } else { Objective::Projection }
    }
}

/// Why the engine could not be built or run.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum EngineError {
    /// The problem failed validation.
    #[error("EngineError::Problem: {0}")]
    Problem(#[from] ProblemError),
    /// A KKT system could not be factored.
    #[error("EngineError::Kkt: {0}")]
    Kkt(#[from] KktError),
    /// The problem does not have the shape the engine was built for.
    #[error("EngineError::ShapeMismatch: engine built for {expected}, problem has {got}")]
    ShapeMismatch {
        /// What the engine expects.
        expected: String,
        /// What was given.
        got: String,
    },
    /// A sample or initial state has the wrong length.
    #[error("EngineError::BadLength: {got} values, expected {expected}")]
    BadLength {
        /// Required length.
        expected: usize,
        /// Given length.
        got: usize,
    },
}

/// Residuals of one iteration.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Residuals {
    /// `||F xi - e|| + ||G xi - h + s||` at the iterate (m).
    pub primal: f64,
    /// `||xi^{l+1} - xi^l|| + ||lambda^{l+1} - lambda^l||` of the update
    /// from it (NaN for an iterate that was not updated).
    pub fixed_point: f64,
}

/// An AM iterate: coefficients and multiplier, both `[axis][robot][coef]`.
#[derive(Debug, Clone, PartialEq)]
pub struct AmState {
    /// Coefficients `xi_bar`.
    pub xi: Vec<f64>,
    /// Multiplier `lambda`.
    pub lambda: Vec<f64>,
}

/// The result of a run.
#[derive(Debug, Clone)]
pub struct AmOutcome {
    /// Final iterate.
    pub state: AmState,
    /// xi-updates performed (all attempts together).
    pub iterations: usize,
    /// Attempts started (1 without restarts).
    pub attempts: usize,
    /// Why it stopped.
    pub stop: Stop,
    /// Primal residual of the final iterate.
    pub primal: f64,
    /// Per-iterate residuals of every attempt, in order (if recorded).
    pub history: Vec<Residuals>,
}

/// Per-penalty precomputation.
#[derive(Debug, Clone)]
struct Level {
    rho: f64,
    kkt: TeamKkt,
    /// `K11_mean - K11_diff`, `n_xi x n_xi`.
    mean_minus_diff: Vec<f64>,
    /// `rho P^T P` over the constrained samples.
    rho_gram: Vec<f64>,
}

/// The engine for one team shape, obstacle count and objective: holds the
/// basis, the sample grids and the KKT factorisations for every penalty level.
#[derive(Debug, Clone)]
pub struct Engine {
    team: Team,
    obstacles: usize,
    objective: Objective,
    settings: AmSettings,
    basis: Basis,
    n_xi: usize,
    /// The constrained samples `1..K`.
    grid: SampleGrid,
    /// The dense verification grid `1..DENSE_FACTOR K` (of `DENSE_FACTOR K`).
    dense: SampleGrid,
    levels: Vec<Level>,
    /// The smoothest curves through the boundary values (optimiser cold start).
    reference: SmoothReference,
    /// Fits routed cold starts to the basis.
    fitter: Fitter,
    /// The six boundary rows, `6 x n_xi`.
    boundary_rows: Vec<f64>,
    /// The per-robot cost Hessian `C`, `n_xi x n_xi`.
    cost: Vec<f64>,
}

/// Per-problem data the iterations read.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// Per level: `K12_diff (b_i - b_mean) + K12_mean b_mean`, `[axis][robot][n_xi]`.
    beta: Vec<Vec<f64>>,
    /// Linear cost term (the SF sample, or `C` times it for
    /// [`Objective::SmoothProjection`]), `[axis][robot][coef]`; empty for the optimiser.
    target: Vec<f64>,
    /// The cold-start coefficients (the sample for the SF).
    cold: Vec<f64>,
    /// Inflated sizes and shrunk box at the constrained samples.
    constraint: Limits,
    /// True sizes and box on the dense grid.
    verify: Limits,
    /// Boundary values `[axis][robot][6]` (normalised time).
    boundary: Vec<f64>,
}

/// The linear pieces of one iteration at one penalty level, for code that
/// re-implements the iteration (the learned initialiser's differentiable
/// unrolled safety filter). Matrices are row-major; with `[axis][robot][coef]`
/// rows, one iteration from `(xi, lambda)` with projection corrections `c`
/// (`[axis][robot][sample]`, see [`Limits`]) is
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

impl Prepared {
    /// The boundary part `beta` of the xi-step at penalty level `level`
    /// (clamped), `[axis][robot][coef]`.
    pub fn beta(&self, level: usize) -> &[f64] {
        &self.beta[level.min(self.beta.len() - 1)]
    }

    /// The cost's linear term: the SF sample, or `C` times it for
    /// [`Objective::SmoothProjection`] (empty for the optimiser), `[axis][robot][coef]`.
    pub fn target(&self) -> &[f64] {
        &self.target
    }

    /// The cold-start coefficients, `[axis][robot][coef]`: the safety
    /// filter's sample.
    pub fn cold(&self) -> &[f64] {
        &self.cold
    }

    /// The inflated sizes and shrunk box the iterations project onto.
    pub fn constraint(&self) -> &Limits {
        &self.constraint
    }
}

/// Repairs SF samples the way the optimiser's cold start avoids static
/// obstacles: a robot whose curve passes through an inflated static
/// obstacle at a constrained sample gets a curve along a route around the
/// static obstacles instead ([`crate::route`]). Each robot is routed at
/// most once, however many samples of the problem are repaired. A robot
/// whose start or goal already lies within an inflated obstacle (a measured
/// start in near-contact) is left to the filter: every curve of it would
/// count as blocked.
pub struct Rerouter<'e> {
    engine: &'e Engine,
    problem: &'e Problem,
    blockers: Blockers,
    boundary: Vec<f64>,
    /// Per robot: its start or goal is within an inflated obstacle.
    pinned: Vec<bool>,
    /// Per robot: not routed yet, or its routed curve (`None`: walled off).
    routes: Vec<Option<Option<Vec<f64>>>>,
}

impl Rerouter<'_> {
    /// Reroutes the blocked robots of `xi` (the problem's coefficients,
    /// `[axis][robot][coef]`); returns how many were rerouted.
    ///
    /// # Panics
    /// If `xi` is not of the engine's length (the problem must be of the
    /// engine's team: [`Engine::prepare`] checks it).
    pub fn apply(&mut self, xi: &mut [f64]) -> usize {
        assert_eq!(xi.len(), self.engine.coeff_len(), "coefficients of the engine's team");
        if self.blockers.is_empty() {
            return 0;
        }
        let e = self.engine;
        let (n, axes, k) = (e.team.robots, e.team.dim.axes(), e.team.samples);
        let positions = JointPlan::new(&e.team, xi.to_vec()).sampled(k, 0);
        let mut count = 0;
        for i in 0..n {
            if self.pinned[i] {
                continue;
            }
            let blocked = (FIRST_CONSTRAINED_SAMPLE..k).any(|s| {
                let mut p = Vector3::zeros();
                for a in 0..axes {
                    p[a] = positions[(a * n + i) * k + s];
                }
                self.blockers.blocks(&p)
            });
            if !blocked {
                continue;
            }
            let route =
                self.routes[i].get_or_insert_with(|| e.routed_curve(self.problem, &self.blockers, &self.boundary, i));
            if let Some(curve) = route {
                set_curve(xi, curve, n, e.n_xi, i);
                count += 1;
            }
        }
        count
    }
}

/// Writes robot `i`'s `curve` (`[axis][coef]`, `nx` per axis) into the
/// coefficients `xi` of a team of `n` (`[axis][robot][coef]`).
fn set_curve(xi: &mut [f64], curve: &[f64], n: usize, nx: usize, i: usize) {
    for (a, c) in curve.chunks_exact(nx).enumerate() {
        xi[(a * n + i) * nx..(a * n + i + 1) * nx].copy_from_slice(c);
    }
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
struct Work {
    g: Vec<f64>,
    u: Vec<f64>,
    rhs: Vec<f64>,
    next: Vec<f64>,
}

impl Engine {
    /// Builds the engine: basis, grids, Gram matrices and one factorisation
    /// pair per penalty level.
    pub fn new(team: &Team, obstacles: usize, objective: Objective, settings: AmSettings) -> Result<Self, EngineError> {
        team.validate()?;
        let basis = team.basis().map_err(ProblemError::from)?;
        let n_xi = basis.n_xi();
        let k = basis.samples();
        let grid = SampleGrid::new(team.degree, (FIRST_CONSTRAINED_SAMPLE..k).map(|s| basis.tau(s)).collect());
        let dense_count = DENSE_FACTOR * k;
        let dense = SampleGrid::new(
            team.degree,
            (1 + settings.verify_skip..dense_count).map(|s| s as f64 / (dense_count - 1) as f64).collect(),
        );
        let gram = basis.gram(FIRST_CONSTRAINED_SAMPLE);
        let boundary = basis.boundary_rows();
        let identity = (0..n_xi * n_xi).map(|i| f64::from(i % (n_xi + 1) == 0));
        let smoothness = |weight: f64| {
            let scale = weight / team.horizon.powi(4);
            basis.acceleration_gram().into_iter().map(move |v| v * scale)
        };
        let cost: Vec<f64> = match objective {
            Objective::Projection => identity.collect(),
            Objective::SmoothProjection { weight } => identity.zip(smoothness(weight)).map(|(i, q)| i + q).collect(),
            Objective::Smoothness { weight } => smoothness(weight).collect(),
        };
        let levels = settings
            .rho
            .levels()
            .into_iter()
            .map(|rho| {
                let kkt = TeamKkt::new(&cost, &gram, &boundary, team.robots, obstacles, rho)?;
                let mean_minus_diff = kkt.mean().k11().iter().zip(kkt.diff().k11()).map(|(m, d)| m - d).collect();
                Ok(Level { rho, kkt, mean_minus_diff, rho_gram: gram.iter().map(|g| rho * g).collect() })
            })
            .collect::<Result<Vec<_>, KktError>>()?;
        let reference = SmoothReference::new(team).map_err(|e| match e {
            ReferenceError::Basis(b) => EngineError::Problem(b.into()),
            ReferenceError::Kkt(k) => EngineError::Kkt(k),
        })?;
        let fitter = Fitter::new(&basis)?;
        Ok(Self {
            team: team.clone(),
            obstacles,
            objective,
            settings,
            basis,
            n_xi,
            grid,
            dense,
            levels,
            reference,
            fitter,
            boundary_rows: boundary,
            cost,
        })
    }

    /// The team this engine plans for.
    pub fn team(&self) -> &Team {
        &self.team
    }

    /// The settings it runs with.
    pub fn settings(&self) -> &AmSettings {
        &self.settings
    }

    /// Number of obstacles it was built for.
    pub fn obstacles(&self) -> usize {
        self.obstacles
    }

    /// The basis.
    pub fn basis(&self) -> &Basis {
        &self.basis
    }

    /// The penalty values of the schedule.
    pub fn rho_levels(&self) -> Vec<f64> {
        self.levels.iter().map(|l| l.rho).collect()
    }

    /// Length of a coefficient (or multiplier) vector.
    pub fn coeff_len(&self) -> usize {
        self.team.dim.axes() * self.team.robots * self.n_xi
    }

    /// The plan a coefficient vector describes.
    pub fn plan(&self, xi: Vec<f64>) -> JointPlan {
        JointPlan::new(&self.team, xi)
    }

    /// Validates `problem` against the engine and precomputes what the
    /// iterations read. `sample` is the SF sample (ignored by the optimiser).
    pub fn prepare(&self, problem: &Problem, sample: Option<&[f64]>) -> Result<Prepared, EngineError> {
        problem.validate()?;
        self.check_shape(problem)?;
        let t = &problem.team;
        let dim = t.dim.axes();
        let n = t.robots;
        let b = problem.boundary_values();
        let beta = self
            .levels
            .iter()
            .map(|level| {
                let mut out = vec![0.0; dim * n * self.n_xi];
                for a in 0..dim {
                    self.boundary_part(
                        &level.kkt,
                        &b[a * n * BOUNDARY_ROWS..(a + 1) * n * BOUNDARY_ROWS],
                        &mut out[a * n * self.n_xi..(a + 1) * n * self.n_xi],
                    );
                }
                out
            })
            .collect();
        let sample = match (self.objective, sample) {
            (Objective::Smoothness { .. }, _) => None,
            (_, Some(x)) if x.len() == self.coeff_len() => Some(x),
            (_, x) => {
                return Err(EngineError::BadLength { expected: self.coeff_len(), got: x.map_or(0, <[f64]>::len) });
            }
        };
        // The cost's linear term: `C xi` per robot and axis (`xi` itself
        // for the plain projection).
        let target = match (self.objective, sample) {
            (Objective::SmoothProjection { .. }, Some(x)) => {
                let mut linear = vec![0.0; x.len()];
                gemm(&mut linear, x, &self.cost, x.len() / self.n_xi, self.n_xi, self.n_xi, false);
                linear
            }
            (_, Some(x)) => x.to_vec(),
            (_, None) => Vec::new(),
        };
        let cold = match sample {
            Some(x) => x.to_vec(),
            None => self.smooth_start(problem, &b),
        };
        let margin = self.settings.margin;
        let shrink = [t.robot.radius, t.robot.radius, t.robot.half_height].map(|r| margin * r);
        Ok(Prepared {
            beta,
            target,
            cold,
            constraint: Limits::new(problem, &self.grid, 1.0 + margin, shrink),
            verify: Limits::new(problem, &self.dense, 1.0 + self.settings.verify_margin, [0.0; 3]),
            boundary: b,
        })
    }

    /// `K12_diff (b_i - b_mean) + K12_mean b_mean` for one axis.
    fn boundary_part(&self, kkt: &TeamKkt, b: &[f64], out: &mut [f64]) {
        let n = self.team.robots;
        let nx = self.n_xi;
        let mut b_mean = [0.0; BOUNDARY_ROWS];
        for row in b.chunks_exact(BOUNDARY_ROWS) {
            for (m, v) in b_mean.iter_mut().zip(row) {
                *m += v / n as f64;
            }
        }
        let mut mean_part = vec![0.0; nx];
        kkt.mean().apply_boundary(&b_mean, &mut mean_part);
        let mut db = [0.0; BOUNDARY_ROWS];
        for (row, o) in b.chunks_exact(BOUNDARY_ROWS).zip(out.chunks_exact_mut(nx)) {
            for c in 0..BOUNDARY_ROWS {
                db[c] = row[c] - b_mean[c];
            }
            kkt.diff().apply_boundary(&db, o);
            for (x, m) in o.iter_mut().zip(&mean_part) {
                *x += m;
            }
        }
    }

    /// The optimiser's cold start: per robot the smoothest curve meeting the
    /// boundary conditions, or, with `routed_start`, a fitted route around the
    /// static obstacles when its straight segment crosses one.
    fn smooth_start(&self, problem: &Problem, b: &[f64]) -> Vec<f64> {
        let n = self.team.robots;
        let nx = self.n_xi;
        let mut xi = vec![0.0; self.coeff_len()];
        for (row, bv) in xi.chunks_exact_mut(nx).zip(b.chunks_exact(BOUNDARY_ROWS)) {
            self.reference.curve(bv, row);
        }
        if !self.settings.routed_start {
            return xi;
        }
        let blockers = self.blockers(problem);
        if blockers.is_empty() {
            return xi;
        }
        for i in 0..n {
            let (start, goal) = (problem.starts[i].position, problem.goals[i]);
            if !blockers.segment_blocked(&start, &goal) {
                continue;
            }
            if let Some(curve) = self.routed_curve(problem, &blockers, b, i) {
                set_curve(&mut xi, &curve, n, nx, i);
            }
        }
        xi
    }

    /// Whether `problem` has the engine's team and obstacle count
    /// ([`EngineError::ShapeMismatch`] otherwise).
    fn check_shape(&self, problem: &Problem) -> Result<(), EngineError> {
        if problem.team != self.team || problem.obstacles.len() != self.obstacles {
            return Err(EngineError::ShapeMismatch {
                expected: format!("{:?} with {} obstacles", self.team, self.obstacles),
                got: format!("{:?} with {} obstacles", problem.team, problem.obstacles.len()),
            });
        }
        Ok(())
    }

    /// The static obstacles of `problem` inflated by the robot size and the
    /// safety margin, for routing.
    fn blockers(&self, problem: &Problem) -> Blockers {
        Blockers::new(&self.team, &problem.obstacles, self.settings.margin, 0.0)
    }

    /// Robot `i`'s curve along a route around `blockers` meeting its
    /// boundary values (from `b`, [`Problem::boundary_values`]), `[axis][coef]`;
    /// `None` when its goal is walled off on the routing grid.
    fn routed_curve(&self, problem: &Problem, blockers: &Blockers, b: &[f64], i: usize) -> Option<Vec<f64>> {
        let (n, nx) = (self.team.robots, self.n_xi);
        let path = route(&self.team, blockers, &problem.starts[i].position, &problem.goals[i])?;
        let mut curve = vec![0.0; self.team.dim.axes() * nx];
        for (a, q) in self.fitter.timed_samples(&path, self.team.dim.axes()).iter().enumerate() {
            let row = a * n + i;
            self.fitter.fit(q, &b[row * BOUNDARY_ROWS..(row + 1) * BOUNDARY_ROWS], &mut curve[a * nx..(a + 1) * nx]);
        }
        Some(curve)
    }

    /// A [`Rerouter`] for `problem`, which must have the engine's team and
    /// obstacle count ([`EngineError::ShapeMismatch`] otherwise).
    pub fn rerouter<'e>(&'e self, problem: &'e Problem) -> Result<Rerouter<'e>, EngineError> {
        self.check_shape(problem)?;
        let blockers = self.blockers(problem);
        let pinned = problem
            .starts
            .iter()
            .zip(&problem.goals)
            .map(|(s, g)| blockers.blocks(&s.position) || blockers.blocks(g))
            .collect();
        Ok(Rerouter {
            engine: self,
            problem,
            blockers,
            boundary: problem.boundary_values(),
            pinned,
            routes: vec![None; problem.robots()],
        })
    }

    /// The cold start with a zero multiplier: for the optimiser see
    /// [`AmSettings::routed_start`], for the SF the sample itself.
    pub fn cold_start(&self, prepared: &Prepared) -> AmState {
        AmState { xi: prepared.cold.clone(), lambda: vec![0.0; self.coeff_len()] }
    }

    /// Validates, prepares and optimises from the cold start, restarting
    /// from perturbed cold starts ([`AmSettings::restarts`]) while attempts
    /// hit their share of the iteration cap.
    pub fn solve(&self, problem: &Problem) -> Result<AmOutcome, EngineError> {
        let prepared = self.prepare(problem, None)?;
        Ok(self.solve_prepared(&prepared))
    }

    /// [`Self::solve`] for an already prepared problem.
    pub fn solve_prepared(&self, prepared: &Prepared) -> AmOutcome {
        self.solve_prepared_until(prepared, None)
    }

    /// [`Self::solve_prepared`] that also stops ([`Stop::Deadline`]) with the
    /// best iterate so far once `deadline` has passed.
    pub fn solve_prepared_until(&self, prepared: &Prepared, deadline: Option<Instant>) -> AmOutcome {
        let attempts = self.settings.restarts + 1;
        let share = self.settings.max_iterations / attempts;
        let mut iterations = 0;
        let mut history = Vec::new();
        let mut best: Option<AmOutcome> = None;
        for attempt in 0..attempts {
            let mut state = self.cold_start(prepared);
            if attempt > 0 {
                self.perturb(&mut state.xi, attempt as u64);
            }
            let cap =
                if attempt + 1 == attempts { self.settings.max_iterations - share * (attempts - 1) } else { share };
            let mut outcome = self.run_capped(prepared, state, cap, deadline);
            iterations += outcome.iterations;
            history.append(&mut outcome.history);
            let done = outcome.stop != Stop::IterationCap;
            if outcome.stop == Stop::Deadline {
                best = Some(outcome);
                break;
            }
            if best.as_ref().is_none_or(|b| done || outcome.primal < b.primal) {
                best = Some(outcome);
            }
            if done {
                break;
            }
        }
        let mut outcome = best.expect("at least one attempt runs");
        outcome.iterations = iterations;
        outcome.attempts = attempts.min(history.len().max(1)).max(1);
        outcome.history = history;
        outcome
    }

    /// Seeded uniform perturbation of the interior coefficients (those the
    /// boundary rows do not touch), so the boundary conditions still hold.
    fn perturb(&self, xi: &mut [f64], seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let amplitude = RESTART_AMPLITUDE * self.team.separation().0;
        let interior = BOUNDARY_ROWS / 2..self.n_xi - BOUNDARY_ROWS / 2;
        for row in xi.chunks_exact_mut(self.n_xi) {
            for x in &mut row[interior.clone()] {
                *x += amplitude * rng.random_range(-1.0..=1.0);
            }
        }
    }

    /// Runs the safety filter on `sample` from `init` (the sample itself and a
    /// zero multiplier when `None`).
    pub fn filter(&self, problem: &Problem, sample: &[f64], init: Option<AmState>) -> Result<AmOutcome, EngineError> {
        let prepared = self.prepare(problem, Some(sample))?;
        let state = match init {
            Some(s) if s.xi.len() == self.coeff_len() && s.lambda.len() == self.coeff_len() => s,
            Some(s) => {
                return Err(EngineError::BadLength { expected: self.coeff_len(), got: s.xi.len().min(s.lambda.len()) });
            }
            None => self.cold_start(&prepared),
        };
        Ok(self.run(&prepared, state))
    }

    /// Iterates from `state` under the stopping rules of [`AmSettings`].
    pub fn run(&self, prepared: &Prepared, state: AmState) -> AmOutcome {
        self.run_capped(prepared, state, self.settings.max_iterations, None)
    }

    /// [`Self::run`] that also stops ([`Stop::Deadline`]) once `deadline`
    /// has passed.
    pub fn run_until(&self, prepared: &Prepared, state: AmState, deadline: Instant) -> AmOutcome {
        self.run_capped(prepared, state, self.settings.max_iterations, Some(deadline))
    }

    fn run_capped(&self, prepared: &Prepared, mut state: AmState, cap: usize, deadline: Option<Instant>) -> AmOutcome {
        let dim = self.team.dim;
        let n = self.team.robots;
        let mut projection = Projection::new(dim, n, &self.grid);
        let mut work = self.work();
        let mut history = Vec::new();
        let mut iterations = 0;
        let s = &self.settings;
        loop {
            let primal = projection.run(dim, n, &self.grid, &prepared.constraint, &state.xi);
            let verifying = s.verify_every > 0;
            let due = primal <= s.tolerance || iterations % s.verify_every.max(1) == 0 || iterations >= cap;
            // Every update meets the boundary conditions; a given start
            // (an SF sample) may not, and must not be returned as it is.
            let acceptable = || iterations > 0 || self.meets_boundary(prepared, &state.xi);
            let stop = if !verifying && primal <= s.tolerance && acceptable() {
                Some(Stop::Tolerance)
            } else if verifying && primal <= s.verify_below && due && acceptable() && self.verify(prepared, &state.xi) {
                Some(Stop::Verified)
            } else if iterations >= cap {
                Some(Stop::IterationCap)
            } else if deadline.is_some_and(|d| iterations % DEADLINE_CHECK_EVERY == 0 && Instant::now() >= d) {
                Some(Stop::Deadline)
            } else {
                None
            };
            if let Some(stop) = stop {
                if s.record_history {
                    history.push(Residuals { primal, fixed_point: f64::NAN });
                }
                return AmOutcome { state, iterations, attempts: 1, stop, primal, history };
            }
            let level = s.rho.level_at(iterations, self.levels.len());
            let fixed_point = self.update(prepared, &mut state, level, &projection, &mut work);
            if s.record_history {
                history.push(Residuals { primal, fixed_point });
            }
            iterations += 1;
        }
    }

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

    /// The primal residual of `xi` (inflated sizes, constrained samples).
    pub fn primal_residual(&self, prepared: &Prepared, xi: &[f64]) -> f64 {
        let (dim, n) = (self.team.dim, self.team.robots);
        Projection::new(dim, n, &self.grid).run(dim, n, &self.grid, &prepared.constraint, xi)
    }

    /// Whether `xi` keeps the true sizes and box on the dense grid: no
    /// overlap at all, stricter than the success verdict's tolerance (the
    /// boundary conditions hold for every iterate).
    pub fn verify(&self, prepared: &Prepared, xi: &[f64]) -> bool {
        let (dim, n) = (self.team.dim, self.team.robots);
        Projection::new(dim, n, &self.dense).run(dim, n, &self.dense, &prepared.verify, xi) == 0.0
    }

    /// Whether `xi` meets the boundary conditions (to 1e-9 in normalised time).
    fn meets_boundary(&self, prepared: &Prepared, xi: &[f64]) -> bool {
        let rows = &self.boundary_rows;
        xi.chunks_exact(self.n_xi).zip(prepared.boundary.chunks_exact(BOUNDARY_ROWS)).all(|(x, b)| {
            rows.chunks_exact(self.n_xi).zip(b).all(|(row, bv)| (dot(row, x) - bv).abs() <= BOUNDARY_EXACTNESS)
        })
    }

    fn work(&self) -> Work {
        let len = self.coeff_len();
        Work { g: vec![0.0; len], u: vec![0.0; len], rhs: vec![0.0; len], next: vec![0.0; len] }
    }

    /// Multiplier update and xi-step from the corrections of `projection`;
    /// returns the fixed-point residual.
    fn update(
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
        gemm(&mut w.g, &projection.corr, &self.grid.p, rows, self.grid.count(), nx, false);
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
        for (i, r) in w.rhs.iter_mut().enumerate() {
            *r = prepared.target.get(i).copied().unwrap_or(0.0) + rho * w.g[i] + state.lambda[i];
        }
        gemm(&mut w.rhs, &w.u, &lv.rho_gram, rows, nx, nx, true);
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
        gemm(&mut w.next, &w.rhs, lv.kkt.diff().k11(), rows, nx, nx, true);
        let xi_sq: f64 = state.xi.iter().zip(&w.next).map(|(a, b)| (a - b) * (a - b)).sum();
        std::mem::swap(&mut state.xi, &mut w.next);
        xi_sq.sqrt() + lambda_sq.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::Metrics;
    use crate::problem::Dim;
    use crate::scenario::RandomScenario;

    fn optimiser(team: &Team, obstacles: usize) -> Engine {
        Engine::new(team, obstacles, Objective::smoothness(), AmSettings::optimiser()).unwrap()
    }

    #[test]
    fn the_optimiser_meets_the_boundary_conditions_from_a_moving_start() {
        let team = Team::default_for(Dim::Two, 8);
        let mut problem = RandomScenario::new(team.clone()).with_start_speed(0.4).generate(3).unwrap();
        problem.starts[2].acceleration.x = 0.3;
        let outcome = optimiser(&team, 0).solve(&problem).unwrap();
        assert_eq!(outcome.stop, Stop::Verified);
        let m = Metrics::measure(&problem, &JointPlan::new(&team, outcome.state.xi));
        assert!(m.boundary_error < 1e-9, "boundary error {}", m.boundary_error);
        assert!(m.success(team.separation().0));
        assert!(m.min_clearance() >= 0.0, "verified plans keep the true sizes");
    }

    #[test]
    fn a_passed_deadline_stops_the_optimiser_with_its_current_iterate() {
        let team = Team::default_for(Dim::Two, 16);
        let problem = RandomScenario::new(team.clone()).generate(5).unwrap();
        let engine = optimiser(&team, 0);
        let prepared = engine.prepare(&problem, None).unwrap();
        assert!(!engine.verify(&prepared, &engine.cold_start(&prepared).xi), "the straight lines collide");
        let outcome = engine.solve_prepared_until(&prepared, Some(Instant::now()));
        assert_eq!(outcome.stop, Stop::Deadline);
        assert_eq!(outcome.iterations, 0);
        assert_eq!(outcome.state.xi, engine.cold_start(&prepared).xi);
        let unhurried = engine.solve_prepared_until(&prepared, None);
        assert_eq!(unhurried.stop, Stop::Verified);
    }

    #[test]
    fn the_safety_filter_leaves_a_feasible_sample_alone() {
        let team = Team::default_for(Dim::Two, 6);
        let problem = RandomScenario::new(team.clone()).generate(4).unwrap();
        let solved = optimiser(&team, 0).solve(&problem).unwrap().state.xi;
        let sf = Engine::new(&team, 0, Objective::Projection, AmSettings::safety_filter()).unwrap();
        let prepared = sf.prepare(&problem, Some(&solved)).unwrap();
        // Verified before any iteration: returned unchanged.
        let outcome = sf.run(&prepared, sf.cold_start(&prepared));
        assert_eq!((outcome.iterations, outcome.stop), (0, Stop::Verified));
        assert_eq!(outcome.state.xi, solved);
    }

    #[test]
    fn the_safety_filter_never_returns_a_sample_that_breaks_the_boundary_conditions() {
        let team = Team::default_for(Dim::Two, 6);
        let problem = RandomScenario::new(team.clone()).generate(4).unwrap();
        let mut sample = optimiser(&team, 0).solve(&problem).unwrap().state.xi;
        sample[0] += 1e-3; // robot 0's first x coefficient: its start position
        let sf = Engine::new(&team, 0, Objective::Projection, AmSettings::safety_filter()).unwrap();
        let outcome = sf.filter(&problem, &sample, None).unwrap();
        assert_eq!(outcome.stop, Stop::Verified);
        assert!(outcome.iterations >= 1);
        let m = Metrics::measure(&problem, &JointPlan::new(&team, outcome.state.xi));
        assert!(m.boundary_error < 1e-9, "boundary error {}", m.boundary_error);
    }

    #[test]
    fn the_safety_filter_repairs_a_perturbed_plan() {
        let team = Team::default_for(Dim::Two, 16);
        let problem = RandomScenario::new(team.clone()).generate(5).unwrap();
        let solved = optimiser(&team, 0).solve(&problem).unwrap().state.xi;
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let sample: Vec<f64> = solved.iter().map(|x| x + 0.05 * rng.random_range(-1.0..=1.0)).collect();
        let sf =
            Engine::new(&team, 0, Objective::Projection, AmSettings::safety_filter().residual_study(0.01)).unwrap();
        let prepared = sf.prepare(&problem, Some(&sample)).unwrap();
        let before = sf.primal_residual(&prepared, &sample);
        let outcome = sf.run(&prepared, sf.cold_start(&prepared));
        assert_eq!(outcome.stop, Stop::Tolerance);
        assert!(outcome.primal <= 0.01 && before > 0.01, "{before} -> {}", outcome.primal);
        // Residual histories: one entry per iterate, the last not updated.
        assert_eq!(outcome.history.len(), outcome.iterations + 1);
        assert!(outcome.history.last().unwrap().fixed_point.is_nan());
    }

    /// A 16-robot instance and its smoothest straight curves, which collide.
    fn colliding_sample() -> (Team, Problem, Vec<f64>) {
        let team = Team::default_for(Dim::Two, 16);
        let problem = RandomScenario::new(team.clone()).generate(5).unwrap();
        let sample = SmoothReference::new(&team).unwrap().coefficients(&problem);
        (team, problem, sample)
    }

    #[test]
    fn the_smooth_projection_with_weight_zero_is_the_projection() {
        let (team, problem, sample) = colliding_sample();
        let run = |objective| {
            let sf = Engine::new(&team, 0, objective, AmSettings::safety_filter()).unwrap();
            sf.filter(&problem, &sample, None).unwrap()
        };
        let plain = run(Objective::Projection);
        let weighted = run(Objective::SmoothProjection { weight: 0.0 });
        assert!(plain.iterations > 0);
        assert_eq!(plain.state, weighted.state);
    }

    #[test]
    fn the_smooth_projection_repairs_with_smoother_detours() {
        let (team, problem, sample) = colliding_sample();
        let repair = |objective| {
            let sf = Engine::new(&team, 0, objective, AmSettings::safety_filter()).unwrap();
            let outcome = sf.filter(&problem, &sample, None).unwrap();
            assert_eq!(outcome.stop, Stop::Verified, "{objective:?}");
            let correction: Vec<f64> = outcome.state.xi.iter().zip(&sample).map(|(a, b)| a - b).collect();
            let plan = JointPlan::new(&team, outcome.state.xi);
            assert!(Metrics::measure(&problem, &plan).success(team.separation().0));
            (JointPlan::new(&team, correction).smoothness(team.samples), plan.smoothness(team.samples))
        };
        let (plain_correction, plain) = repair(Objective::Projection);
        let (smooth_correction, smooth) = repair(Objective::SmoothProjection { weight: 3.0 });
        assert!(smooth_correction < 0.5 * plain_correction, "{smooth_correction} vs {plain_correction}");
        assert!(smooth < plain, "{smooth} vs {plain}");
    }

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

    #[test]
    fn solving_is_deterministic_including_restarts() {
        let team = Team::default_for(Dim::Two, 16);
        let problem = RandomScenario::new(team.clone()).with_obstacles(8).generate(16).unwrap();
        let engine = optimiser(&team, 8);
        let a = engine.solve(&problem).unwrap();
        let b = engine.solve(&problem).unwrap();
        assert_eq!(a.state, b.state);
        assert_eq!((a.iterations, a.attempts, a.stop), (b.iterations, b.attempts, b.stop));
    }

    #[test]
    fn a_problem_of_another_shape_is_rejected() {
        let team = Team::default_for(Dim::Two, 4);
        let engine = optimiser(&team, 0);
        let other = RandomScenario::new(team.clone()).with_obstacles(1).generate(1).unwrap();
        assert!(matches!(engine.solve(&other), Err(EngineError::ShapeMismatch { .. })));
        let sf = Engine::new(&team, 0, Objective::Projection, AmSettings::safety_filter()).unwrap();
        let problem = RandomScenario::new(team).generate(1).unwrap();
        assert!(matches!(sf.filter(&problem, &[0.0; 3], None), Err(EngineError::BadLength { expected: 88, got: 3 })));
    }

    #[test]
    fn the_rerouter_moves_only_robots_that_cross_a_static_obstacle() {
        use crate::problem::{Obstacle, Spheroid, StartState};
        let team = Team::default_for(Dim::Two, 2);
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        let problem = Problem {
            team: team.clone(),
            starts: vec![StartState::at_rest(at(-0.8, 0.0)), StartState::at_rest(at(-0.8, 0.7))],
            goals: vec![at(0.8, 0.0), at(0.8, 0.7)],
            obstacles: vec![Obstacle {
                position: at(0.0, 0.02),
                velocity: Vector3::zeros(),
                shape: Spheroid::ball(0.2),
            }],
        };
        let engine = Engine::new(&team, 1, Objective::filter(3.0), AmSettings::safety_filter()).unwrap();
        // Straight lines (the SF routes no cold start): robot 0 crosses the
        // obstacle, robot 1 passes above it.
        let mut xi = engine.smooth_start(&problem, &problem.boundary_values());
        let before = xi.clone();
        let mut rerouter = engine.rerouter(&problem).unwrap();
        assert_eq!(rerouter.apply(&mut xi), 1);
        let nx = team.degree + 1;
        for a in 0..2 {
            let row = (a * 2 + 1) * nx..(a * 2 + 2) * nx;
            assert_eq!(xi[row.clone()], before[row], "robot 1 keeps its curve");
        }
        let m = Metrics::measure(&problem, &JointPlan::new(&team, xi.clone()));
        assert!(m.boundary_error < 1e-9, "the route keeps the boundary conditions: {}", m.boundary_error);
        assert!(m.min_obstacle_clearance > 0.0, "the route clears the obstacle: {}", m.min_obstacle_clearance);
        let once = xi.clone();
        rerouter.apply(&mut xi);
        assert_eq!(xi, once, "rerouting twice changes nothing");
    }

    #[test]
    fn the_rerouter_leaves_near_contact_robots_and_refuses_other_teams() {
        use crate::problem::{Obstacle, Spheroid, StartState};
        let team = Team::default_for(Dim::Two, 1);
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        let ball = Spheroid::ball(0.2);
        let engine = Engine::new(&team, 1, Objective::filter(3.0), AmSettings::safety_filter()).unwrap();
        // The start touches the obstacle within the safety margin (scaled
        // distance 1.02 < 1.05) and the straight line runs past it.
        let (a, _) = team.obstacle_separation(&ball);
        let problem = Problem {
            team: team.clone(),
            starts: vec![StartState::at_rest(at(-0.5, 0.0))],
            goals: vec![at(0.8, 0.0)],
            obstacles: vec![Obstacle { position: at(-0.5 - 1.02 * a, 0.0), velocity: Vector3::zeros(), shape: ball }],
        };
        let mut xi = engine.smooth_start(&problem, &problem.boundary_values());
        let before = xi.clone();
        assert_eq!(engine.rerouter(&problem).unwrap().apply(&mut xi), 0);
        assert_eq!(xi, before);
        let other = Problem { team: Team::default_for(Dim::Two, 2), ..problem };
        assert!(matches!(engine.rerouter(&other), Err(EngineError::ShapeMismatch { .. })));
    }
}
