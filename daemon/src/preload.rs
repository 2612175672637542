//! Building a team's planner: every engine a snapshot can need (the warm
//! start's and the stopping plans' safety filters for every obstacle
//! count, the cold planners' engines), the checks of held plans, and the
//! cold planners' race, so that no snapshot waits for a factorisation.

use std::time::Duration;

use flowopt_methods::build::members;
use flowopt_methods::settings::{PlannerSettings, buffered, tracking_buffer};
use flowopt_methods::{PlanError, Planner, Race};
use flowopt_planner::am::{AmSettings, EngineError, EngineSet, Objective, Recheck};
use flowopt_planner::problem::Team;
use flowopt_planner::reference::{ReferenceError, SmoothReference};
use flowopt_planner::route::Fitter;
use flowopt_planner::stopping::stopping_team;
use thiserror::Error;
use tracing::info;

use crate::config::{ConfigError, TeamConfig};
use crate::planning::{Rules, TeamPlanner};
use crate::stops::Stops;

/// Iteration cap of the warm-start safety filter (about 10 ms for 16
/// robots); it also gets at most half the deadline, leaving the rest to a
/// cold plan when it does not verify.
const WARM_ITERATIONS: usize = 2000;

/// Why a team's planner cannot be built.
#[derive(Debug, Error)]
pub enum PreloadError {
    /// The team's configuration is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// An engine cannot be built for it.
    #[error("cannot build the engines: {0}")]
    Engine(#[from] EngineError),
    /// A cold planner cannot be built (weights named but missing, or not
    /// for this team).
    #[error("cannot build the cold planners: {0}")]
    Planner(#[from] PlanError),
}

/// The worker's and the cold race's shares of `threads`: the worker's
/// half rounded up, the rest to the cold race, one each at least.
fn split_threads(threads: usize) -> (usize, usize) {
    let worker = threads.div_ceil(2).max(1);
    (worker, threads.saturating_sub(worker).max(1))
}

/// The daemon's cold planners' settings from a team's: a cold plan from
/// motion over the acceleration limit is refused and the next snapshot's
/// request starts from where the robots are then (planning the stale
/// request again within the limit held the optimiser's lane for up to its
/// iteration cap: 16-robot lab, seeds 0-3, a walker contact at 1.000 of
/// the separation in one run, main none;
/// docs/experiments/2026-11-28-plans-from-motion-within-the-limit.md);
/// and the learned pipeline races cold plans from motion too (without it
/// the 16-robot lab day reached fewer goals: seed 0, 1.78 and 2.59 goals
/// per robot-minute against 2.66-2.72;
/// docs/experiments/2026-11-29-small-programs.md).
pub(crate) fn cold_settings(settings: PlannerSettings) -> PlannerSettings {
    PlannerSettings { retry_within_limits: false, race_from_motion: true, ..settings }
}

impl TeamPlanner {
    /// Builds every engine (basis, sample grids, KKT factorisations) the
    /// team can need, so that no snapshot waits for one, and starts the
    /// cold planners' race ([`flowopt_methods::build::members`] of the
    /// team's `[team.planner]` settings, with the tracking buffer).
    pub fn preload(config: &TeamConfig) -> Result<Self, PreloadError> {
        // The braking certificate's linear programs run beside the worker,
        // never inside an answer.
        flowopt_planner::braking::solve_in_background(crate::realtime::idle_priority);
        let team = config.team()?;
        let settings = config.planner_settings(&team);
        let buffer = tracking_buffer(&team, config.follow_tolerance_m);
        let max = config.max_obstacles;
        // Warm replans and stopping plans of big teams run while a cold
        // plan may run too: the two crews share the settings' threads (the
        // same plans on any count), so that spinning members never outnumber
        // the cores the controllers also need.
        let (threads, cold_threads) = split_threads(settings.threads());
        let settings = PlannerSettings { threads: cold_threads, ..cold_settings(settings) };
        let filter_settings =
            buffered(AmSettings { max_iterations: WARM_ITERATIONS, threads, ..AmSettings::safety_filter() }, buffer);
        let filters = EngineSet::preloaded(&team, Objective::Projection, filter_settings, max)?;
        // Warm replans that come out over the limits go on in filters that
        // hold them (along a chain of repairs plans crept past the speed
        // limit: at 128 robots 262-335 answers a minute re-issued the held
        // plan in four runs of five;
        // docs/experiments/2026-11-29-speed-limit-in-warm-replans.md). The
        // limits' rows slow every iteration (they hold each step near the
        // last along them), so only those.
        let limited_settings = AmSettings { limit_speed: true, limit_acceleration: true, ..filter_settings };
        let limited_filters = EngineSet::preloaded(&team, Objective::Projection, limited_settings, max)?;
        // Stopping plans, the last resort before none, are verified at the
        // true sizes: robots a jam has left within the buffer of each other
        // are then still held apart under control instead of braking on
        // their own (and drifting) with no plan at all. They keep the
        // acceleration limit as they are made: repaired without it, most
        // refused ones were over it, and the team was left with no plan
        // (16-robot lab, seeds 0-11: `NoPlan` 49 and contacts in 4 runs
        // without it, 6 and none with it, one at 0.992 of the separation
        // on a stopping plan in two more runs;
        // docs/experiments/2026-11-28-acceleration-limit-in-stopping-plans.md).
        let stop_settings = AmSettings {
            verify_margin: 0.0,
            threads,
            limit_acceleration: true,
            ..buffered(AmSettings::safety_filter(), buffer)
        };
        let stops = config
            .stop_horizons()
            .into_iter()
            .map(|horizon| {
                let stop_team = stopping_team(&team, horizon);
                let engines = EngineSet::preloaded(&stop_team, Objective::Projection, stop_settings, max)?;
                let reference = SmoothReference::new(&stop_team).map_err(|e| match e {
                    ReferenceError::Basis(b) => EngineError::Problem(b.into()),
                    ReferenceError::Kkt(k) => EngineError::Kkt(k),
                })?;
                Ok(Stops { engines, reference })
            })
            .collect::<Result<Vec<_>, EngineError>>()?;
        // The check of held stopping plans (each on its own horizon's grid).
        let stop_team = stopping_team(&team, config.stop_horizon());
        let basis = team.basis().map_err(|e| EngineError::Problem(e.into()))?;
        let fitter = Fitter::new(&basis).map_err(EngineError::Kkt)?;
        let (racers, alone) = members(&settings, &team)?;
        if let Some(why) = alone {
            info!(team = config.name, "cold plans by the optimiser alone: {why}");
        }
        let names: Vec<&str> = racers.iter().map(|r| r.name()).collect();
        info!(team = config.name, "cold planners: {}", names.join(", "));
        let budget = Duration::from_secs_f64(config.cold_budget_ms * 1e-3);
        let mut cold = Race::start(&config.name, racers, Some(budget), crate::realtime::lower_lane_priority);
        for obstacles in 0..=max {
            cold.ready(&team, obstacles)?;
        }
        // Followable answers are checked against newer snapshots over a
        // shorter prediction than plans are made with.
        let check_window = config.obstacle_check_s();
        let checked = |t: &Team| Team { obstacle_prediction: Some(check_window), ..t.clone() };
        Ok(TeamPlanner {
            recheck_goals: Recheck::new(&checked(&team), &filter_settings),
            recheck_stops: Recheck::new(&checked(&stop_team), &stop_settings),
            team,
            rules: Rules {
                deadline: Duration::from_secs_f64(config.deadline_ms * 1e-3),
                follow_tolerance: config.follow_tolerance_m,
                warm_tolerance: config.warm_tolerance_m,
                stale_after_ns: (config.stale_after_ms * 1e6) as u64,
                check_window,
            },
            filters,
            limited_filters,
            stops,
            fitter,
            cold,
            held: None,
            newest: None,
            pending: None,
            fresh: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::split_threads;

    #[test]
    fn the_worker_and_the_cold_race_share_the_threads() {
        assert_eq!(split_threads(1), (1, 1), "one each at least");
        assert_eq!(split_threads(2), (1, 1));
        assert_eq!(split_threads(3), (2, 1));
        assert_eq!(split_threads(15), (8, 7));
    }
}
