//! The repairs the policy makes plans with: the safety filter on a sample
//! shifted to the newest state ([`TeamPlanner::refine`]: a warm start, or a
//! cold plan the robots left; run on by a filter that holds the limits where
//! it came out over them), a stopping plan from the newest state
//! ([`TeamPlanner::stopping`]), and the speed and acceleration limits every
//! plan keeps ([`TeamPlanner::within_limits`]).

use std::time::Instant;

use flowopt_planner::am::{AmSettings, AmState, Budget, Stop};
use flowopt_planner::metrics::DENSE_FACTOR;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::Problem;
use flowopt_planner::stopping::{stepped_aside, stopping_problem};
use tracing::{debug, info_span};

use crate::answer::{Answer, Why};
use crate::held::{Candidate, World};
use crate::planning::TeamPlanner;
use crate::stops::Stops;

/// A plan's peak speed (m/s) and acceleration (m/s^2), and the factor a
/// stretch in time takes to bring them within the limits (1 or less:
/// within them).
#[derive(Debug, Clone, Copy)]
struct Peaks {
    speed: f64,
    acceleration: f64,
    factor: f64,
}

/// How far under the limits a plan stretched in time to keep them is
/// brought (a share of each): room for the warm replans along it, which
/// the safety filter repairs without the limits (those that come out over
/// them are run on by one that holds them: [`TeamPlanner::refine`]).
/// Stretched to the limits themselves, the 128-robot team's plans from
/// rest came back from their warm replans 0.04-0.26% over the speed limit,
/// and 270 of 1,484 answers in 30 s re-issued the held plan for `Limits`
/// (docs/experiments/2026-11-29-stretched-plans-with-headroom.md).
pub const STRETCH_HEADROOM: f64 = 0.02;

impl TeamPlanner {
    /// The safety filter on `sample` shifted by `dt` for `world`: a
    /// verified candidate within the limits, `None` if it did not verify,
    /// or why it cannot be published.
    pub(crate) fn refine(
        &self,
        sample: &JointPlan,
        dt: f64,
        world: &World,
        until: Instant,
        answer: &mut Answer,
    ) -> Result<Option<Candidate>, Why> {
        let t = Instant::now();
        let mut start = world.problem.clone();
        let xi = {
            let _span = info_span!("warm_start").entered();
            sample.shifted(dt.max(0.0), &mut start, &self.fitter)
        };
        answer.stages.warm_start += t.elapsed();
        let t = Instant::now();
        let _span = info_span!("filter").entered();
        let outcome = self.filters.get(start.obstacles.len()).and_then(|engine| {
            let prepared = engine.prepare(&start, Some(&xi)).ok()?;
            Some((engine, engine.run_within(&prepared, engine.cold_start(&prepared), &Budget::until(until))))
        });
        answer.stages.filter += t.elapsed();
        let Some((engine, outcome)) = outcome else { return Ok(None) };
        answer.iterations += outcome.iterations;
        answer.candidates = 1;
        if outcome.stop != Stop::Verified {
            debug!(stop = ?outcome.stop, iterations = outcome.iterations, primal = outcome.primal, "a repair not verified");
            return Ok(None);
        }
        let plan = engine.plan(outcome.state.xi);
        let peaks = self.peaks(&plan);
        let (plan, primal) = if peaks.factor > 1.0 && !start.stretchable() {
            let state = AmState { xi: plan.coeffs, lambda: outcome.state.lambda };
            self.repaired_within_limits(&start, &xi, state, until, answer)?
        } else {
            (self.kept_within(plan, peaks, &start)?, outcome.primal)
        };
        let (origin_ns, sequence) = (world.origin_ns, world.sequence);
        Ok(Some(Candidate { plan, problem: start, origin_ns, sequence, primal }))
    }

    /// A warm replan of `problem` (`state`, from the sample `xi`), verified
    /// but over the limits, run on by the filter that holds them until
    /// `until`: the plan and its primal residual, or [`Why::Limits`].
    fn repaired_within_limits(
        &self,
        problem: &Problem,
        xi: &[f64],
        state: AmState,
        until: Instant,
        answer: &mut Answer,
    ) -> Result<(JointPlan, f64), Why> {
        let t = Instant::now();
        let _span = info_span!("within_limits").entered();
        let engine = self.limited_filters.get(problem.obstacles.len()).ok_or(Why::Limits)?;
        let prepared = engine.prepare(problem, Some(xi)).map_err(|_| Why::Limits)?;
        let outcome = engine.run_within(&prepared, state, &Budget::until(until));
        answer.stages.filter += t.elapsed();
        answer.iterations += outcome.iterations;
        if outcome.stop != Stop::Verified {
            debug!(stop = ?outcome.stop, iterations = outcome.iterations, "a plan over the limits not repaired");
            return Err(Why::Limits);
        }
        debug!(iterations = outcome.iterations, "a plan over the limits repaired within them");
        Ok((self.within_limits(engine.plan(outcome.state.xi), problem)?, outcome.primal))
    }

    /// `plan` if it keeps the team's speed and acceleration limits; else
    /// stretched in time where the problem allows it
    /// ([`Problem::stretchable`]), [`STRETCH_HEADROOM`] under them; else
    /// [`Why::Limits`].
    pub(crate) fn within_limits(&self, plan: JointPlan, problem: &Problem) -> Result<JointPlan, Why> {
        let peaks = self.peaks(&plan);
        self.kept_within(plan, peaks, problem)
    }

    /// `plan`'s peak speed and acceleration against the team's limits (its
    /// configuration's, which the team carries; one it lacks limits
    /// nothing).
    fn peaks(&self, plan: &JointPlan) -> Peaks {
        let (speed, acceleration) = plan.peak_rates(DENSE_FACTOR * self.team.samples);
        let over = |rate: f64, limit: Option<f64>| limit.map_or(0.0, |l| rate / l);
        let factor = over(speed, self.team.max_speed).max(over(acceleration, self.team.max_acceleration).sqrt());
        Peaks { speed, acceleration, factor }
    }

    /// [`Self::within_limits`] for `plan` with its `peaks`.
    fn kept_within(&self, plan: JointPlan, peaks: Peaks, problem: &Problem) -> Result<JointPlan, Why> {
        let Peaks { speed, acceleration, factor } = peaks;
        if factor <= 1.0 {
            return Ok(plan);
        }
        if problem.stretchable() && factor.is_finite() {
            Ok(plan.stretched(factor * (1.0 + STRETCH_HEADROOM)))
        } else {
            debug!(speed, acceleration, "a plan over the limits");
            Err(Why::Limits)
        }
    }

    /// A verified stopping plan from `world`'s state against its
    /// obstacles, within the limits, made by `until`: at the stopping
    /// horizon, else at the longer one ([`crate::config::TeamConfig::stop_horizons`]).
    pub(crate) fn stopping(&self, world: &World, until: Instant, answer: &mut Answer) -> Option<Candidate> {
        let count = self.stops.len();
        self.stops.iter().enumerate().find_map(|(h, stops)| {
            // Each horizon an equal share of the time left, so that one
            // that runs out of it leaves the next its share.
            let share = until.saturating_duration_since(Instant::now()) / (count - h) as u32;
            self.stopping_at(stops, world, (Instant::now() + share).min(until), answer)
        })
    }

    /// [`Self::stopping`] at the horizon of `stops`.
    fn stopping_at(&self, stops: &Stops, world: &World, until: Instant, answer: &mut Answer) -> Option<Candidate> {
        let _span = info_span!("stopping", horizon = stops.engines.team().horizon).entered();
        let t = Instant::now();
        let inset = self.team.robot.radius * AmSettings::safety_filter().margin;
        let plain = stopping_problem(&world.problem, stops.engines.team().horizon, inset);
        let engine = stops.engines.get(plain.obstacles.len())?;
        // Stopping points stepped aside from obstacles' tracks and from each
        // other; the plain ones where a move made the problem invalid (a
        // point pushed into another obstacle). Validated by `prepare`; why
        // there is none is worth a line (before the step: 397 in 40 s of
        // the 64-robot lab, docs/experiments/2026-11-27-stopping-beside-walkers.md).
        let aside = Some(stepped_aside(&plain, inset)).filter(|a| a.goals != plain.goals);
        let (stop, prepared) = aside.into_iter().chain([plain]).find_map(|stop| {
            let sample = stops.reference.coefficients(&stop);
            match engine.prepare(&stop, Some(&sample)) {
                Ok(prepared) => Some((stop, prepared)),
                Err(e) => {
                    debug!("no stopping plan: {e}");
                    None
                }
            }
        })?;
        let outcome = engine.run_within(&prepared, engine.cold_start(&prepared), &Budget::until(until));
        answer.stages.filter += t.elapsed();
        answer.iterations += outcome.iterations;
        if outcome.stop != Stop::Verified {
            debug!(stop = ?outcome.stop, iterations = outcome.iterations, "no stopping plan");
            return None;
        }
        let Ok(plan) = self.within_limits(engine.plan(outcome.state.xi), &stop) else {
            debug!(iterations = outcome.iterations, "the stopping plan is over the limits");
            return None;
        };
        debug!(iterations = outcome.iterations, "a stopping plan");
        let (origin_ns, sequence) = (world.origin_ns, world.sequence);
        Some(Candidate { plan, problem: stop, origin_ns, sequence, primal: outcome.primal })
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use flowopt_planner::am::{Engine, Objective};
    use flowopt_planner::scenario::RandomScenario;

    use super::*;
    use crate::answer::Follow;
    use crate::config::TeamConfig;
    use crate::held::World;

    fn preload(max_speed: f64) -> TeamPlanner {
        let text = format!(
            "name = \"t\"\ndim = 2\nrobots = 4\nrobot = {{ radius = 0.1 }}\n\
             workspace = {{ min = [-1.0, -1.0], max = [1.0, 1.0] }}\nmax_obstacles = 0\n\
             max_speed = {max_speed}\nmax_acceleration = 100.0\n"
        );
        TeamPlanner::preload(&toml::from_str::<TeamConfig>(&text).unwrap()).unwrap()
    }

    #[test]
    fn a_warm_replan_over_the_speed_limit_is_run_on_within_it() {
        // Robots in motion, and the optimiser's plan from there: not
        // stretchable, and over a limit 3% under its top speed.
        let team = preload(1.5).team().clone();
        let problem = RandomScenario::new(team.clone()).with_start_speed(0.1).generate(5).unwrap();
        let optimiser = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser()).unwrap();
        let free = optimiser.solve(&problem).unwrap().state.xi;
        let samples = DENSE_FACTOR * team.samples;
        let limit = 0.97 * JointPlan::new(&team, free.clone()).peak_rates(samples).0;
        assert!(limit > 0.15, "well over the starts' speeds: {limit}");
        let planner = preload(limit);
        let problem = Problem { team: planner.team().clone(), ..problem };
        let sample = JointPlan::new(planner.team(), free.clone());
        // The filter alone leaves the plan (verified) as it is: over the limit.
        let engine = planner.filters.get(0).unwrap();
        let prepared = engine.prepare(&problem, Some(&free)).unwrap();
        let outcome = engine.run(&prepared, engine.cold_start(&prepared));
        assert_eq!(outcome.stop, Stop::Verified);
        assert!(JointPlan::new(planner.team(), outcome.state.xi).peak_rates(samples).0 > limit);
        // The warm replan goes on within it.
        let world = World { problem, origin_ns: 1, sequence: 1 };
        let mut answer = Answer::new(Follow::Nothing, Why::None);
        let until = Instant::now() + Duration::from_secs(10);
        let candidate = planner.refine(&sample, 0.0, &world, until, &mut answer).unwrap().expect("verified");
        let (speed, acceleration) = candidate.plan.peak_rates(samples);
        assert!(speed <= limit && acceleration <= 100.0, "{speed} over {limit}");
        assert_eq!(candidate.plan.horizon, planner.team().horizon, "not stretched");
    }
}
