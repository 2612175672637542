//! The planners a method runs for a team, and the policy of who races:
//!
//! - `baseline`: the optimiser;
//! - `flowopt`: the learned pipeline with the SF initialiser (the settings'
//!   `learned.init`, else the shipped one) on the settings' threads;
//! - `flow-no-init`: the pipeline without the initialiser;
//! - `auto`: the learned pipeline (on one core, with the initialiser only
//!   where `learned.init` names one) and the optimiser race, where the
//!   team has at most `race_max_robots` robots and the weights plan in its
//!   dimension and basis; else the optimiser alone, and [`members`] says
//!   why;
//! - `safety-filter`: the filter's benchmark ([`PerturbedFilter`]).

use flowopt_models::ModelError;
use flowopt_models::pipeline::{LearnedPipeline, LearnedPlanner};
use flowopt_models::shipped::{Weights, WeightsRef};
use flowopt_planner::am::Objective;
use flowopt_planner::method::{PlanError, Planner};
use flowopt_planner::optimiser::Optimiser;
use flowopt_planner::problem::{Dim, Team};

use crate::filter_bench::PerturbedFilter;
use crate::method::Method;
use crate::race::Race;
use crate::settings::PlannerSettings;

/// The learned pipeline as `method` runs it with `settings`, for teams of
/// `dim` (the shipped weights are picked by the dimension).
pub fn learned(settings: &PlannerSettings, method: Method, dim: Dim) -> Result<LearnedPipeline, ModelError> {
    let mut pipeline = settings.learned.clone();
    let init = match method {
        Method::Flowopt => Some(pipeline.init.clone().unwrap_or(WeightsRef::Shipped)),
        Method::FlowNoInit => None,
        _ => pipeline.init.clone(),
    };
    pipeline.use_init = init.is_some();
    if method == Method::Auto {
        // Racing the optimiser, the pipeline keeps to one core.
        pipeline.threads = 1;
        pipeline.obstacle_threads = 1;
    }
    let flow = pipeline.flow.resolve(dim, Weights::shipped_flow);
    let init = init.map(|i| i.resolve(dim, Weights::shipped_init));
    let planner = LearnedPlanner::load(&flow, init.as_ref(), pipeline.sf_smoothing)?;
    Ok(LearnedPipeline::new(planner, pipeline, settings.filter))
}

/// The learned pipeline for `team`: an error where its weights cannot be
/// loaded (a file named but missing is never planned around), `Ok(Err(why))`
/// where they do not plan in the team's dimension or basis.
fn learned_for(
    settings: &PlannerSettings,
    method: Method,
    team: &Team,
) -> Result<Result<LearnedPipeline, String>, PlanError> {
    let pipeline = learned(settings, method, team.dim).map_err(|e| PlanError::Unavailable(e.to_string()))?;
    Ok(pipeline.planner().model().check(team).map(|()| pipeline).map_err(|e| e.to_string()))
}

/// The planners a method runs for a team (racing where there are several),
/// and, where `auto` plans with the optimiser alone, why.
pub type Members = (Vec<Box<dyn Planner>>, Option<String>);

/// The planners `settings.method` runs for `team` (racing where there are
/// several), and, where `auto` plans with the optimiser alone, why.
pub fn members(settings: &PlannerSettings, team: &Team) -> Result<Members, PlanError> {
    let optimiser = || Box::new(Optimiser::new(settings.optimiser())) as Box<dyn Planner>;
    let method = settings.method;
    Ok(match method {
        Method::Baseline => (vec![optimiser()], None),
        Method::SafetyFilter => {
            let objective = Objective::filter(settings.learned.sf_smoothing);
            (vec![Box::new(PerturbedFilter::new(settings.optimiser(), settings.filter, objective))], None)
        }
        Method::Flowopt | Method::FlowNoInit => {
            let pipeline = learned_for(settings, method, team)?.map_err(PlanError::Unavailable)?;
            (vec![Box::new(pipeline)], None)
        }
        Method::Auto => {
            let learned = if team.robots > settings.race_max_robots {
                Err(format!("the learned pipeline races teams of up to {} robots", settings.race_max_robots))
            } else {
                learned_for(settings, method, team)?
            };
            match learned {
                Ok(pipeline) => (vec![Box::new(pipeline), optimiser()], None),
                Err(why) => (vec![optimiser()], Some(why)),
            }
        }
    })
}

/// The planner of `settings.method` for `team`: the race of its members, or
/// its one member. Where `auto` plans with the optimiser alone, the reason
/// is logged.
pub fn planner(settings: &PlannerSettings, team: &Team) -> Result<Box<dyn Planner>, PlanError> {
    let (mut members, alone) = members(settings, team)?;
    if let Some(why) = alone {
        tracing::info!("auto: the optimiser plans alone: {why}");
    }
    Ok(match members.len() {
        1 => members.remove(0),
        _ => Box::new(Race::start(settings.method.name(), members, None, || {})),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::am::Budget;
    use flowopt_planner::scenario::RandomScenario;

    #[test]
    fn auto_races_where_the_weights_plan_and_says_why_it_does_not_elsewhere() {
        let settings = PlannerSettings::default();
        let names = |team: &Team| {
            let (members, why) = members(&settings, team).unwrap();
            (members.iter().map(|m| m.name()).collect::<Vec<_>>(), why)
        };
        assert_eq!(names(&Team::default_for(Dim::Two, 16)), (vec!["learned", "optimiser"], None));
        assert_eq!(names(&Team::default_for(Dim::Three, 16)).0, vec!["learned", "optimiser"]);
        let (big, why) = names(&Team::default_for(Dim::Two, 64));
        assert_eq!(big, vec!["optimiser"]);
        assert!(why.unwrap().contains("up to 32 robots"));
        let wide = Team { degree: 12, ..Team::default_for(Dim::Two, 8) };
        let (alone, why) = names(&wide);
        assert_eq!(alone, vec!["optimiser"]);
        assert!(why.unwrap().contains("coefficients"), "the weights do not plan in this basis");
        // Weights named but missing are an error, never planned around.
        let mut missing = settings.clone();
        missing.set("learned.flow=/no/such/flow.safetensors").unwrap();
        let err = members(&missing, &Team::default_for(Dim::Two, 16)).err().expect("an error").to_string();
        assert!(err.contains("/no/such/flow.safetensors"), "{err}");
    }

    #[test]
    fn every_method_plans_a_small_team() {
        let team = Team::default_for(Dim::Two, 4);
        let problem = RandomScenario::new(team.clone()).generate(2).unwrap();
        for method in Method::ALL {
            let settings = PlannerSettings { method, ..PlannerSettings::default() };
            let mut planner = planner(&settings, &team).unwrap();
            planner.ready(&team, 0).unwrap();
            let planned = planner.plan(&problem, &Budget::unlimited(), 5).unwrap();
            assert!(planned.verified(), "{method}");
        }
    }
}
