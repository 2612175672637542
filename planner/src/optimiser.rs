//! The from-scratch optimiser as a [`Planner`]: the AM engine with the
//! smoothness cost from its cold start ([`crate::am`]), one engine per
//! (team, obstacle count), built on first use and kept.
//!
//! ```
//! use flowopt_planner::am::{AmSettings, Budget};
//! use flowopt_planner::method::Planner;
//! use flowopt_planner::optimiser::Optimiser;
//! use flowopt_planner::problem::{Dim, Team};
//! use flowopt_planner::scenario::RandomScenario;
//!
//! let problem = RandomScenario::new(Team::default_for(Dim::Two, 8)).generate(3).unwrap();
//! let mut optimiser = Optimiser::new(AmSettings::optimiser());
//! let planned = optimiser.plan(&problem, &Budget::unlimited(), 0).unwrap();
//! assert!(planned.verified());
//! ```

use std::time::Instant;

use crate::am::{AmSettings, Budget, EngineSet, Objective};
use crate::method::{PlanError, Planned, Planner, Stages};
use crate::problem::{Problem, Team};

/// The from-scratch optimiser.
#[derive(Debug, Clone)]
pub struct Optimiser {
    settings: AmSettings,
    /// Its name in a race ([`Planner::name`]).
    name: &'static str,
    /// Engines per team, per obstacle count.
    sets: Vec<EngineSet>,
}

impl Optimiser {
    /// An optimiser with `settings` (defaults: [`AmSettings::optimiser`]).
    pub fn new(settings: AmSettings) -> Self {
        Self { settings, name: "optimiser", sets: Vec::new() }
    }

    /// The same, named `name` in a race (a variant beside the optimiser).
    pub fn named(self, name: &'static str) -> Self {
        Self { name, ..self }
    }

    /// With the engines for `team` and every obstacle count up to
    /// `max_obstacles` built now.
    pub fn preloaded(settings: AmSettings, team: &Team, max_obstacles: usize) -> Result<Self, PlanError> {
        let set = EngineSet::preloaded(team, Objective::smoothness(), settings, max_obstacles)?;
        Ok(Self { sets: vec![set], ..Self::new(settings) })
    }

    /// The settings.
    pub fn settings(&self) -> &AmSettings {
        &self.settings
    }

    fn set(&mut self, team: &Team) -> &mut EngineSet {
        EngineSet::find_or_add(&mut self.sets, team, Objective::smoothness(), self.settings)
    }
}

impl Planner for Optimiser {
    fn name(&self) -> &'static str {
        self.name
    }

    fn ready(&mut self, team: &Team, obstacles: usize) -> Result<(), PlanError> {
        self.set(team).engine(obstacles)?;
        Ok(())
    }

    fn plan(&mut self, problem: &Problem, budget: &Budget<'_>, _seed: u64) -> Result<Planned, PlanError> {
        let _span = tracing::info_span!("optimise").entered();
        let started = Instant::now();
        let engine = self.set(&problem.team).engine(problem.obstacles.len())?;
        let prepared = engine.prepare(problem, None)?;
        let outcome = engine.solve_prepared_within(&prepared, budget);
        Ok(Planned {
            plan: engine.plan(outcome.state.xi),
            stop: outcome.stop,
            primal: outcome.primal,
            iterations: outcome.iterations,
            run_iterations: outcome.iterations,
            candidates: 1,
            stages: Stages { optimise: started.elapsed(), ..Stages::default() },
            wall: started.elapsed(),
            by: self.name,
            start: None,
        })
    }
}
