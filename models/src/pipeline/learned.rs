//! The learned planner as the daemon and the command line assemble it, and
//! as a [`Planner`].

use flowopt_planner::am::{AmSettings, Budget, Engine, EngineSet, Objective};
use flowopt_planner::method::{PlanError, Planned, Planner};
use flowopt_planner::problem::{Problem, Team};

use super::model::FlowOpt;
use super::outcome::{PipelineOutcome, Query};
use super::settings::PipelineSettings;
use crate::ModelError;
use crate::shipped::Weights;

/// The learned planner as the daemon and the command line assemble it:
/// the networks (with the initialiser when its weights are given) and the
/// metric of the safety filter that repairs their samples.
#[derive(Debug, Clone)]
pub struct LearnedPlanner {
    model: FlowOpt,
    sf_objective: Objective,
}

impl LearnedPlanner {
    /// Loads the flow policy at `flow` and the initialiser at `init`;
    /// `sf_smoothing` weighs the smoothness of the filter's corrections
    /// ([`Objective::filter`]; finite, 0 or more).
    pub fn load(flow: &Weights, init: Option<&Weights>, sf_smoothing: f64) -> Result<Self, ModelError> {
        if !(sf_smoothing.is_finite() && sf_smoothing >= 0.0) {
            return Err(ModelError::Config(format!("the SF smoothing weight {sf_smoothing} is not finite and >= 0")));
        }
        Ok(Self { model: FlowOpt::load(flow, init)?, sf_objective: Objective::filter(sf_smoothing) })
    }

    /// The networks.
    pub fn model(&self) -> &FlowOpt {
        &self.model
    }

    /// The safety filter's objective.
    pub fn sf_objective(&self) -> Objective {
        self.sf_objective
    }

    /// The safety filters for `team` (whose dimension and basis the
    /// networks must plan in) with `settings`, built for every obstacle
    /// count up to `max_obstacles`.
    pub fn filters(&self, team: &Team, settings: AmSettings, max_obstacles: usize) -> Result<EngineSet, ModelError> {
        self.model.check(team)?;
        Ok(EngineSet::preloaded(team, self.sf_objective, settings, max_obstacles)?)
    }
}

/// The learned pipeline as a [`Planner`]: the loaded networks, the
/// pipeline's settings, and its safety filters (per team and obstacle
/// count, built on first use with `filter`'s settings).
#[derive(Debug)]
pub struct LearnedPipeline {
    planner: LearnedPlanner,
    settings: PipelineSettings,
    filter: AmSettings,
    filters: Vec<EngineSet>,
}

impl LearnedPipeline {
    /// The pipeline of `planner` run with `settings`, its safety filter
    /// with `filter`.
    pub fn new(planner: LearnedPlanner, settings: PipelineSettings, filter: AmSettings) -> Self {
        Self { planner, settings, filter, filters: Vec::new() }
    }

    /// The loaded networks.
    pub fn planner(&self) -> &LearnedPlanner {
        &self.planner
    }

    /// Its settings.
    pub fn settings(&self) -> &PipelineSettings {
        &self.settings
    }

    /// The safety filter for `team` with `obstacles` obstacles, built on
    /// first use; the networks must plan in the team's dimension and basis.
    pub fn filter(&mut self, team: &Team, obstacles: usize) -> Result<&Engine, ModelError> {
        safety_filter(&self.planner, &mut self.filters, self.filter, team, obstacles)
    }

    /// Plans `queries` (one team shape and obstacle count) together, with
    /// everything the pipeline found ([`FlowOpt::plan_batch`]).
    pub fn plan_batch(
        &mut self,
        queries: &[Query<'_>],
        budget: &Budget<'_>,
        seed: u64,
    ) -> Result<Vec<PipelineOutcome>, ModelError> {
        let Some(first) = queries.first() else { return Ok(Vec::new()) };
        let (team, obstacles) = (&first.enforced.team, first.enforced.obstacles.len());
        let sf = safety_filter(&self.planner, &mut self.filters, self.filter, team, obstacles)?;
        self.planner.model().plan_batch(queries, sf, &self.settings, seed, budget)
    }
}

impl Planner for LearnedPipeline {
    fn name(&self) -> &'static str {
        "learned"
    }

    fn ready(&mut self, team: &Team, obstacles: usize) -> Result<(), PlanError> {
        self.filter(team, obstacles).map_err(unavailable)?;
        Ok(())
    }

    fn plan(&mut self, problem: &Problem, budget: &Budget<'_>, seed: u64) -> Result<Planned, PlanError> {
        let _span = tracing::info_span!("learned").entered();
        let started = std::time::Instant::now();
        let obstacles = problem.obstacles.len();
        let sf = safety_filter(&self.planner, &mut self.filters, self.filter, &problem.team, obstacles)
            .map_err(unavailable)?;
        let out = self.planner.model().plan(problem, sf, &self.settings, seed, budget).map_err(failed)?;
        let chosen = out.refined.get(out.chosen).ok_or_else(|| PlanError::Failed("no candidate".into()))?;
        Ok(Planned {
            plan: sf.plan(chosen.outcome.state.xi.clone()),
            stop: chosen.outcome.stop,
            primal: chosen.outcome.primal,
            iterations: out.refined.iter().map(|r| r.outcome.iterations).sum(),
            run_iterations: chosen.outcome.iterations,
            candidates: out.refined.len(),
            stages: out.stages,
            wall: started.elapsed(),
            by: "learned",
            start: Some(Box::new((chosen.prepared.clone(), chosen.start.clone()))),
        })
    }
}

/// The safety filter of `planner` for `team` with `obstacles` obstacles,
/// from `filters` (built on first use with `settings`); the networks must
/// plan in the team's dimension and basis.
fn safety_filter<'f>(
    planner: &LearnedPlanner,
    filters: &'f mut Vec<EngineSet>,
    settings: AmSettings,
    team: &Team,
    obstacles: usize,
) -> Result<&'f Engine, ModelError> {
    planner.model().check(team)?;
    let set = EngineSet::find_or_add(filters, team, planner.sf_objective(), settings);
    Ok(set.engine(obstacles)?)
}

/// A team the networks cannot plan for.
fn unavailable(e: ModelError) -> PlanError {
    PlanError::Unavailable(e.to_string())
}

/// The pipeline failed.
fn failed(e: ModelError) -> PlanError {
    PlanError::Failed(e.to_string())
}
