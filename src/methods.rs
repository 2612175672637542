//! The planning methods the CLI can run and time on one instance.

use std::collections::HashMap;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::ValueEnum;
use flowopt_planner::am::{AmSettings, Engine, Objective, Stop};
use flowopt_planner::metrics::Metrics;
use flowopt_planner::problem::{Problem, Team};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// A planning method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The from-scratch AM optimiser (smoothness cost, cold start).
    Baseline,
    /// The safety filter projecting the baseline's solution perturbed by
    /// uniform noise of 10% of the separation on every coefficient (timed:
    /// the SF alone).
    SafetyFilter,
}

/// Overrides of the engine settings from the command line.
#[derive(Debug, Clone, Copy, Default)]
pub struct Overrides {
    /// Iteration cap.
    pub max_iterations: Option<usize>,
    /// Primal tolerance; setting it turns the dense verification off (the
    /// paper's stopping rule).
    pub tolerance: Option<f64>,
    /// Start from the smoothest curves, without routing around obstacles.
    pub straight_start: bool,
    /// Restarts of the optimiser.
    pub restarts: Option<usize>,
}

impl Overrides {
    fn apply(&self, mut s: AmSettings) -> AmSettings {
        if let Some(cap) = self.max_iterations {
            s.max_iterations = cap;
        }
        if let Some(tol) = self.tolerance {
            s.tolerance = tol;
            s.verify_every = 0;
        }
        if self.straight_start {
            s.routed_start = false;
        }
        if let Some(r) = self.restarts {
            s.restarts = r;
        }
        s
    }
}

/// What one planning run produced and cost.
#[derive(Debug, Clone, Serialize)]
pub struct Record {
    /// Every constraint holds on the dense re-sampling (see `Metrics::success`).
    pub success: bool,
    /// AM iterations (of the timed stage).
    pub iterations: usize,
    /// Wall time of the timed stage (ms).
    pub time_ms: f64,
    /// Mean over robots of the sum of squared accelerations.
    pub smoothness: f64,
    /// Mean path length (m).
    pub arc_length: f64,
    /// Smallest robot-robot or robot-obstacle surface gap (m).
    pub min_clearance: f64,
    /// Primal residual of the returned plan (m).
    pub primal_residual: f64,
    /// Why the AM stopped.
    pub stop: Stop,
}

/// Engines built once per (team, obstacle count, objective) and reused:
/// construction (factorisations) is a start-up cost, not a per-plan one.
pub struct Planner {
    overrides: Overrides,
    engines: HashMap<(String, usize, bool), Engine>,
}

impl Planner {
    /// A planner applying `overrides` to the default settings.
    pub fn new(overrides: Overrides) -> Self {
        Self { overrides, engines: HashMap::new() }
    }

    fn engine(&mut self, team: &Team, obstacles: usize, filter: bool) -> Result<&Engine> {
        let key = (format!("{team:?}"), obstacles, filter);
        if !self.engines.contains_key(&key) {
            let (objective, settings) = if filter {
                (Objective::Projection, AmSettings::safety_filter())
            } else {
                (Objective::smoothness(), AmSettings::optimiser())
            };
            let engine = Engine::new(team, obstacles, objective, self.overrides.apply(settings))
                .context("building the AM engine")?;
            self.engines.insert(key.clone(), engine);
        }
        Ok(&self.engines[&key])
    }

    /// Plans `problem` with `method`, timing the method's own stage.
    pub fn run(&mut self, method: Method, problem: &Problem, seed: u64) -> Result<Record> {
        let obstacles = problem.obstacles.len();
        let optimiser = self.engine(&problem.team, obstacles, false)?;
        let start = Instant::now();
        let solved = optimiser.solve(problem).context("optimising")?;
        let optimise_ms = start.elapsed().as_secs_f64() * 1e3;
        let outcome = match method {
            Method::Baseline => (solved, optimise_ms),
            Method::SafetyFilter => {
                let noise = 0.1 * problem.team.separation().0;
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                let sample: Vec<f64> =
                    solved.state.xi.iter().map(|x| x + noise * rng.random_range(-1.0..=1.0)).collect();
                let filter = self.engine(&problem.team, obstacles, true)?;
                let start = Instant::now();
                let filtered = filter.filter(problem, &sample, None).context("filtering")?;
                (filtered, start.elapsed().as_secs_f64() * 1e3)
            }
        };
        let (outcome, time_ms) = outcome;
        let plan = flowopt_planner::plan::JointPlan::new(&problem.team, outcome.state.xi.clone());
        let metrics = Metrics::measure(problem, &plan);
        Ok(Record {
            success: metrics.success(problem.team.separation().0),
            iterations: outcome.iterations,
            time_ms,
            smoothness: metrics.smoothness,
            arc_length: metrics.arc_length,
            min_clearance: metrics.min_clearance(),
            primal_residual: outcome.primal,
            stop: outcome.stop,
        })
    }
}
