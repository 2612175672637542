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
//!   why. The pipeline plans problems from rest only ([`FromRest`]): from
//!   motion the optimiser plans alone (unless `race_from_motion`, as in
//!   the daemon). Where the team has an acceleration limit, the optimiser makes
//!   a verified plan from motion that is over it again within it
//!   ([`WithinLimits`], unless `retry_within_limits` is off, as in the
//!   daemon). Teams too small for the optimiser's crew
//!   ([`flowopt_planner::am::CREW_MIN_ROBOTS`]) leave cores idle: there
//!   [`VARIANTS`] race beside them, one per core the settings' `threads`
//!   leaves after the learned pipeline and the optimiser;
//! - `safety-filter`: the filter's benchmark ([`PerturbedFilter`]).

use flowopt_models::ModelError;
use flowopt_models::pipeline::{LearnedPipeline, LearnedPlanner};
use flowopt_models::shipped::{Weights, WeightsRef};
use flowopt_planner::am::{AmSettings, CREW_MIN_ROBOTS, Objective, RhoSchedule};
use flowopt_planner::method::{PlanError, Planner};
use flowopt_planner::optimiser::Optimiser;
use flowopt_planner::problem::{Dim, Team};

use crate::filter_bench::PerturbedFilter;
use crate::from_rest::FromRest;
use crate::method::Method;
use crate::race::Race;
use crate::settings::PlannerSettings;
use crate::within_limits::WithinLimits;

/// The learned pipeline as `method` runs it with `settings`, for teams of
/// `dim` (the shipped weights are picked by the dimension).
pub fn learned(settings: &PlannerSettings, method: Method, dim: Dim) -> Result<LearnedPipeline, ModelError> {
    let mut pipeline = settings.learned();
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

/// A variant: its name in the race and how it changes the optimiser's
/// settings.
pub type Variant = (&'static str, fn(AmSettings) -> AmSettings);

/// Optimiser variants `auto` races beside the optimiser where cores are
/// idle, in the order they are added: the penalty doubling every 100
/// iterations instead of every 25 (50 before 2026-11-28; docs/BENCHMARKS.md,
/// "What each change does"),
/// and no veering start (the straight lines). On a 16-core host they made
/// `auto` faster with obstacles and crossings (16 robots + 8 obstacles
/// 4.13 against 7.37 ms) and no worse elsewhere beyond its noise
/// (docs/BENCHMARKS.md, "Threads").
pub const VARIANTS: [Variant; 2] = [
    ("optimiser-slow-penalty", |s| AmSettings { rho: RhoSchedule { every: 100, ..s.rho }, ..s }),
    ("optimiser-straight", |s| AmSettings { veer: false, ..s }),
];

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
            // With an acceleration limit, the optimiser makes a plan from
            // motion over it again within it.
            let optimiser = || match team.max_acceleration {
                Some(_) if settings.retry_within_limits => {
                    Box::new(WithinLimits::new(settings.optimiser())) as Box<dyn Planner>
                }
                _ => optimiser(),
            };
            let (mut racers, why): Members = match learned {
                Ok(pipeline) => {
                    // From motion the optimiser plans alone (`from_rest.rs`),
                    // unless the settings race the pipeline there too.
                    let pipeline: Box<dyn Planner> = Box::new(pipeline);
                    let learned = if settings.race_from_motion { pipeline } else { Box::new(FromRest(pipeline)) };
                    (vec![learned, optimiser()], None)
                }
                Err(why) => (vec![optimiser()], Some(why)),
            };
            racers.extend(variants(settings, team, settings.threads().saturating_sub(racers.len())));
            (racers, why)
        }
    })
}

/// The [`VARIANTS`] that race for `team` on `spare` idle cores: one per
/// core, none for a team the optimiser's crew plans (its threads have the
/// cores).
fn variants(settings: &PlannerSettings, team: &Team, spare: usize) -> Vec<Box<dyn Planner>> {
    let spare = if team.robots < CREW_MIN_ROBOTS { spare } else { 0 };
    VARIANTS
        .iter()
        .take(spare)
        .map(|(name, vary)| Box::new(Optimiser::new(vary(settings.optimiser())).named(name)) as Box<dyn Planner>)
        .collect()
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
    fn idle_cores_race_optimiser_variants_for_teams_the_crew_does_not_plan() {
        let settings = PlannerSettings::default();
        let names = |robots, spare| -> Vec<&str> {
            variants(&settings, &Team::default_for(Dim::Two, robots), spare).iter().map(|m| m.name()).collect()
        };
        assert_eq!(names(16, 0), Vec::<&str>::new());
        assert_eq!(names(16, 1), vec!["optimiser-slow-penalty"]);
        assert_eq!(names(16, 9), vec!["optimiser-slow-penalty", "optimiser-straight"]);
        assert_eq!(names(CREW_MIN_ROBOTS, 9), Vec::<&str>::new(), "the crew has the cores");
        // Each variant is the optimiser with one knob changed.
        let base = settings.optimiser();
        let slow = VARIANTS[0].1(base);
        assert_eq!((slow.rho.every, slow.veer), (100, base.veer));
        let straight = VARIANTS[1].1(base);
        assert_eq!((straight.rho, straight.veer), (base.rho, false));
    }

    #[test]
    fn auto_races_where_the_weights_plan_and_says_why_it_does_not_elsewhere() {
        // One thread: no idle cores for variants.
        let settings = PlannerSettings { threads: 1, ..PlannerSettings::default() };
        let names = |team: &Team| {
            let (members, why) = members(&settings, team).unwrap();
            (members.iter().map(|m| m.name()).collect::<Vec<_>>(), why)
        };
        assert_eq!(names(&Team::default_for(Dim::Two, 16)), (vec!["learned", "optimiser"], None));
        assert_eq!(names(&Team::default_for(Dim::Three, 16)).0, vec!["learned", "optimiser"]);
        // A team with an acceleration limit: the same two (the optimiser
        // goes on within the limit in its own lane).
        let limited = Team { max_acceleration: Some(3.0), ..Team::default_for(Dim::Two, 16) };
        assert_eq!(names(&limited).0, vec!["learned", "optimiser"]);
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
    fn auto_plans_from_motion_with_the_optimiser_alone() {
        let settings = PlannerSettings { threads: 1, ..PlannerSettings::default() };
        let team = Team::default_for(Dim::Two, 16);
        let mut auto = planner(&settings, &team).unwrap();
        for seed in 0..4 {
            let mut problem = RandomScenario::new(team.clone()).generate(seed).unwrap();
            let rest = auto.plan(&problem, &Budget::unlimited(), seed).unwrap();
            assert!(rest.verified(), "{seed}");
            problem.starts[0].velocity.x = 0.3;
            let moving = auto.plan(&problem, &Budget::unlimited(), seed).unwrap();
            assert!(moving.verified() && moving.by == "optimiser", "{seed}: by {}", moving.by);
        }
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
