//! The safety filter's benchmark as a planner: the optimiser plans the
//! problem (untimed), its plan is perturbed by uniform noise of 10% of the
//! separation on every coefficient (seeded), and the safety filter repairs
//! it (timed).

use std::time::Instant;

use flowopt_planner::am::{AmSettings, AmState, Budget, EngineSet, Objective};
use flowopt_planner::method::{PlanError, Planned, Planner, Stages};
use flowopt_planner::optimiser::Optimiser;
use flowopt_planner::problem::{Problem, Team};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Relative size of the perturbation (of the robots' separation).
const NOISE: f64 = 0.1;

/// The optimiser's plan, perturbed and repaired by the safety filter.
#[derive(Debug)]
pub struct PerturbedFilter {
    optimiser: Optimiser,
    objective: Objective,
    filter: AmSettings,
    filters: Vec<EngineSet>,
}

impl PerturbedFilter {
    /// The optimiser with `optimiser`'s settings, the filter with
    /// `filter`'s and the `objective` (its metric).
    pub fn new(optimiser: AmSettings, filter: AmSettings, objective: Objective) -> Self {
        Self { optimiser: Optimiser::new(optimiser), objective, filter, filters: Vec::new() }
    }

    fn set(&mut self, team: &Team) -> &mut EngineSet {
        EngineSet::find_or_add(&mut self.filters, team, self.objective, self.filter)
    }
}

impl Planner for PerturbedFilter {
    fn name(&self) -> &'static str {
        "safety-filter"
    }

    fn ready(&mut self, team: &Team, obstacles: usize) -> Result<(), PlanError> {
        self.optimiser.ready(team, obstacles)?;
        self.set(team).engine(obstacles)?;
        Ok(())
    }

    fn plan(&mut self, problem: &Problem, budget: &Budget<'_>, seed: u64) -> Result<Planned, PlanError> {
        let solved = self.optimiser.plan(problem, &Budget::unlimited(), seed)?;
        let noise = NOISE * problem.team.separation().0;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let sample: Vec<f64> = solved.plan.coeffs.iter().map(|x| x + noise * rng.random_range(-1.0..=1.0)).collect();
        let engine = self.set(&problem.team).engine(problem.obstacles.len())?;
        let started = Instant::now();
        let prepared = engine.prepare(problem, Some(&sample))?;
        let state = AmState { lambda: vec![0.0; sample.len()], xi: sample };
        let outcome = engine.run_within(&prepared, state.clone(), budget);
        Ok(Planned {
            plan: engine.plan(outcome.state.xi),
            stop: outcome.stop,
            primal: outcome.primal,
            iterations: outcome.iterations,
            run_iterations: outcome.iterations,
            candidates: 1,
            stages: Stages { filter: started.elapsed(), ..Stages::default() },
            wall: started.elapsed(),
            by: "safety-filter",
            start: Some(Box::new((prepared, state))),
        })
    }
}
