//! `auto`'s learned member plans problems from rest only: from motion the
//! optimiser plans alone, unless the settings race the pipeline there too
//! (`PlannerSettings::race_from_motion`, which the daemon turns on).
//!
//! On two cores the race slows the optimiser (each member on a core of
//! its own still cost it 20-115% of its time per plan, with the same
//! iterations), and from motion the learned pipeline wins too few races to
//! pay for that: on the 450 cold starts from motion of docs/BENCHMARKS.md
//! (16 robots at 0.3-1.0 m/s, seeds 900, 2000, 3000), alternating in one
//! run, the optimiser alone planned the same 291 of 298 within the limit
//! at medians of 1.13-2.77 ms against the race's 1.54-4.44 ms
//! (docs/experiments/2026-11-29-small-programs.md). `--method flowopt`
//! (the pipeline alone) still plans from motion.

use flowopt_planner::am::Budget;
use flowopt_planner::method::{PlanError, Planned, Planner};
use flowopt_planner::problem::{Problem, Team};

/// A planner that declines problems whose robots are not all at rest
/// ([`Problem::at_rest`]) at once, with [`PlanError::Unavailable`].
pub struct FromRest(pub Box<dyn Planner>);

impl Planner for FromRest {
    fn name(&self) -> &'static str {
        self.0.name()
    }

    fn plan(&mut self, problem: &Problem, budget: &Budget<'_>, seed: u64) -> Result<Planned, PlanError> {
        if !problem.at_rest() {
            return Err(PlanError::Unavailable(format!("{} races plans from rest only", self.0.name())));
        }
        self.0.plan(problem, budget, seed)
    }

    fn ready(&mut self, team: &Team, obstacles: usize) -> Result<(), PlanError> {
        self.0.ready(team, obstacles)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::am::AmSettings;
    use flowopt_planner::optimiser::Optimiser;
    use flowopt_planner::problem::Dim;
    use flowopt_planner::scenario::RandomScenario;

    #[test]
    fn a_problem_from_motion_is_declined_at_once_and_one_from_rest_planned() {
        let team = Team::default_for(Dim::Two, 4);
        let rest = RandomScenario::new(team).generate(3).unwrap();
        let mut planner = FromRest(Box::new(Optimiser::new(AmSettings::optimiser())));
        let planned = planner.plan(&rest, &Budget::unlimited(), 0).unwrap();
        assert!(planned.verified() && planned.by == "optimiser");
        let mut moving = rest.clone();
        moving.starts[2].velocity.x = 0.1;
        assert!(matches!(planner.plan(&moving, &Budget::unlimited(), 0), Err(PlanError::Unavailable(_))));
        // At rest within the tolerance still counts as rest.
        moving.starts[2].velocity.x = 0.01;
        assert!(planner.plan(&moving, &Budget::unlimited(), 0).is_ok());
    }
}
