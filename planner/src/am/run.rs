//! Running the iterations: stopping rules (tolerance, dense verification,
//! iteration cap, deadline, cancellation), the optimiser's restarts, and the
//! checks a stop is decided by.

use std::time::Instant;

use super::engine::{AmOutcome, AmState, Engine, EngineError, Residuals};
use super::prepare::Prepared;
use super::projection::{Projection, ROBOT_BLOCK, SampleGrid};
use super::settings::Stop;
use crate::crew::Crew;
use crate::problem::Problem;

/// Iterations between two budget checks (a clock read costs about as
/// much as a tenth of a small team's iteration).
const DEADLINE_CHECK_EVERY: usize = 4;

/// The fewest iterations per robot an attempt of a restarted solve gets:
/// the crowd of 256 robots, seed 26, verifies after 5,680 iterations in one
/// attempt and in none of four attempts of 2,500 (docs/BENCHMARKS.md).
pub const ATTEMPT_ITERATIONS_PER_ROBOT: usize = 25;

/// How much an attempt's lowest primal residual must fall (relative) to
/// count as progress for [`super::AmSettings::stall`]. Attempts that verify
/// fall steadily until they do; jammed ones level off within a few hundred
/// iterations (doorways and aisles of 16 robots: at 0.1-0.4 m, within 1%
/// for the rest of a 2,500-iteration attempt).
pub const STALL_PROGRESS: f64 = 0.05;

/// Teams at least this large iterate on [`super::AmSettings::threads`]
/// threads, at most one per robot block of the projection (16 robots);
/// smaller ones alone (starting the threads costs more than they save).
pub const CREW_MIN_ROBOTS: usize = 32;

/// When a run must stop before its own stopping rules: a deadline
/// ([`Stop::Deadline`]), a cancellation ([`Stop::Cancelled`]), both or
/// neither; checked every few iterations.
#[derive(Clone, Copy, Default)]
pub struct Budget<'a> {
    /// Stop once this instant has passed.
    pub deadline: Option<Instant>,
    /// Stop once this returns `true` (another thread's plan won, newer
    /// goals arrived).
    pub cancelled: Option<&'a (dyn Fn() -> bool + Sync)>,
}

impl std::fmt::Debug for Budget<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Budget")
            .field("deadline", &self.deadline)
            .field("cancellable", &self.cancelled.is_some())
            .finish()
    }
}

impl<'a> Budget<'a> {
    /// No limit but the run's own rules.
    pub fn unlimited() -> Self {
        Self::default()
    }

    /// Stop at `deadline`.
    pub fn until(deadline: Instant) -> Self {
        Self { deadline: Some(deadline), cancelled: None }
    }

    /// Also stop once `cancelled` returns `true`.
    pub fn or_cancelled(self, cancelled: &'a (dyn Fn() -> bool + Sync)) -> Self {
        Self { cancelled: Some(cancelled), ..self }
    }

    /// Why to stop now, if the budget is spent.
    pub fn spent(&self) -> Option<Stop> {
        if self.cancelled.is_some_and(|c| c()) {
            Some(Stop::Cancelled)
        } else if self.deadline.is_some_and(|d| Instant::now() >= d) {
            Some(Stop::Deadline)
        } else {
            None
        }
    }
}

impl Engine {
    /// Validates, prepares and optimises from the cold start, restarting
    /// from perturbed cold starts ([`AmSettings::restarts`]) while attempts
    /// hit their share of the iteration cap.
    pub fn solve(&self, problem: &Problem) -> Result<AmOutcome, EngineError> {
        let prepared = self.prepare(problem, None)?;
        Ok(self.solve_prepared(&prepared))
    }

    /// [`Self::solve`] for an already prepared problem.
    pub fn solve_prepared(&self, prepared: &Prepared) -> AmOutcome {
        self.solve_prepared_within(prepared, &Budget::unlimited())
    }

    /// [`Self::solve_prepared`] that also stops ([`Stop::Deadline`],
    /// [`Stop::Cancelled`]) with the current iterate once `budget` is spent.
    pub fn solve_prepared_within(&self, prepared: &Prepared, budget: &Budget<'_>) -> AmOutcome {
        let max = self.settings.max_iterations;
        let stall = self.stall_window(prepared);
        // Attempts that end on a stall go on while the cap lasts; otherwise
        // each gets its share of it.
        let attempts = if stall.is_some() { usize::MAX } else { self.attempts() };
        let share = max / attempts;
        let mut iterations = 0;
        let mut started = 0;
        let mut history = Vec::new();
        let mut best: Option<AmOutcome> = None;
        for attempt in 0..attempts {
            let state = if attempt == 0 { self.cold_start(prepared) } else { self.restart(prepared, attempt) };
            let cap = match stall {
                Some(_) => max - iterations,
                None if attempt + 1 == attempts => max - share * (attempts - 1),
                None => share,
            };
            let mut outcome = self.run_capped(prepared, state, cap, stall, budget);
            started += 1;
            iterations += outcome.iterations;
            history.append(&mut outcome.history);
            let done = outcome.stop != Stop::IterationCap;
            if matches!(outcome.stop, Stop::Deadline | Stop::Cancelled) {
                best = Some(outcome);
                break;
            }
            if best.as_ref().is_none_or(|b| done || outcome.primal < b.primal) {
                best = Some(outcome);
            }
            if done || iterations >= max {
                break;
            }
        }
        let mut outcome = best.expect("at least one attempt runs");
        outcome.iterations = iterations;
        outcome.attempts = started;
        outcome.history = history;
        outcome
    }

    /// The iterations without progress that end an attempt
    /// ([`AmSettings::stall`]), where the cold start routed robots and the
    /// settings ask for it: at least [`ATTEMPT_ITERATIONS_PER_ROBOT`] per
    /// robot. `None`: attempts run their share.
    ///
    /// [`AmSettings::stall`]: super::AmSettings::stall
    fn stall_window(&self, prepared: &Prepared) -> Option<usize> {
        (self.settings.stall > 0 && !prepared.routed.is_empty())
            .then(|| self.settings.stall.max(ATTEMPT_ITERATIONS_PER_ROBOT * self.team.robots))
    }

    /// Attempts of a restarted solve: [`AmSettings::restarts`] + 1, fewer
    /// where the iteration cap cannot give each
    /// [`ATTEMPT_ITERATIONS_PER_ROBOT`] iterations per robot (big teams fail
    /// by being cut short, not by being stuck), at least one.
    ///
    /// [`AmSettings::restarts`]: super::AmSettings::restarts
    pub fn attempts(&self) -> usize {
        let affordable = self.settings.max_iterations / (ATTEMPT_ITERATIONS_PER_ROBOT * self.team.robots.max(1));
        (self.settings.restarts + 1).min(affordable.max(1))
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
        self.run_within(prepared, state, &Budget::unlimited())
    }

    /// [`Self::run`] that also stops ([`Stop::Deadline`],
    /// [`Stop::Cancelled`]) once `budget` is spent.
    pub fn run_within(&self, prepared: &Prepared, state: AmState, budget: &Budget<'_>) -> AmOutcome {
        self.run_capped(prepared, state, self.settings.max_iterations, None, budget)
    }

    /// At most `cap` iterations, fewer once `stall` iterations pass without
    /// progress ([`STALL_PROGRESS`]; [`Stop::IterationCap`] either way).
    fn run_capped(
        &self,
        prepared: &Prepared,
        state: AmState,
        cap: usize,
        stall: Option<usize>,
        budget: &Budget<'_>,
    ) -> AmOutcome {
        // One thread per robot block at most: a step's blocks would not keep
        // more busy.
        let n = self.team.robots;
        let threads = if n < CREW_MIN_ROBOTS { 1 } else { self.settings.threads.min(n.div_ceil(ROBOT_BLOCK)).max(1) };
        Crew::with(threads, |crew| self.iterate(prepared, state, cap, stall, budget, crew))
    }

    /// The iterations of [`Self::run_capped`] on `crew`.
    fn iterate(
        &self,
        prepared: &Prepared,
        mut state: AmState,
        cap: usize,
        stall: Option<usize>,
        budget: &Budget<'_>,
        crew: &Crew<'_>,
    ) -> AmOutcome {
        let (dim, n) = (self.team.dim, self.team.robots);
        let mut projection = Projection::new(dim, n, &self.grid);
        let mut work = self.work();
        let mut verifier = None;
        let mut history = Vec::new();
        let mut iterations = 0;
        let s = &self.settings;
        // The lowest primal residual so far, and when it last fell by
        // STALL_PROGRESS.
        let (mut lowest, mut progressed) = (f64::INFINITY, 0);
        loop {
            let primal = projection.run(crew, dim, n, &self.grid, &prepared.constraint, &state.xi)
                + self.rates_step(&state.xi, &mut work);
            if primal < (1.0 - STALL_PROGRESS) * lowest {
                (lowest, progressed) = (primal, iterations);
            }
            let verifying = s.verify_every > 0;
            let due = primal <= s.tolerance || iterations % s.verify_every.max(1) == 0 || iterations >= cap;
            // Every update meets the boundary conditions; a given start
            // (an SF sample) may not, and must not be returned as it is.
            let acceptable = || iterations > 0 || self.meets_boundary(prepared, &state.xi);
            let stop = if !verifying && primal <= s.tolerance && acceptable() {
                Some(Stop::Tolerance)
            } else if verifying
                && primal <= s.verify_below
                && due
                && acceptable()
                && self.verify_with(verifier.get_or_insert_with(|| Verifier::new(self)), crew, prepared, &state.xi)
            {
                Some(Stop::Verified)
            } else if iterations >= cap || stall.is_some_and(|w| iterations - progressed > w) {
                Some(Stop::IterationCap)
            } else if iterations % DEADLINE_CHECK_EVERY == 0 {
                budget.spent()
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
            let fixed_point = self.update(crew, prepared, &mut state, level, &projection, &mut work);
            if s.record_history {
                history.push(Residuals { primal, fixed_point });
            }
            iterations += 1;
        }
    }

    /// The primal residual of `xi` (inflated sizes, constrained samples).
    pub fn primal_residual(&self, prepared: &Prepared, xi: &[f64]) -> f64 {
        let (dim, n) = (self.team.dim, self.team.robots);
        let rates = self
            .rates
            .as_ref()
            .map_or(0.0, |limits| limits.correct(dim.axes(), n, xi, &mut vec![0.0; self.coeff_len()]));
        Projection::new(dim, n, &self.grid).run(&Crew::alone(), dim, n, &self.grid, &prepared.constraint, xi) + rates
    }

    /// Whether `xi` keeps the true sizes and box on the dense grid: no
    /// overlap at all, stricter than the success verdict's tolerance (the
    /// boundary conditions hold for every iterate). The dense instants the
    /// settings' `verify_skip` leaves out of that (right after a measured
    /// start, which may be in near-contact) are held to the success
    /// verdict's tolerance instead.
    pub fn verify(&self, prepared: &Prepared, xi: &[f64]) -> bool {
        self.verify_with(&mut Verifier::new(self), &Crew::alone(), prepared, xi)
    }

    /// [`Self::verify`] with a run's verification memory.
    fn verify_with(&self, verifier: &mut Verifier, crew: &Crew<'_>, prepared: &Prepared, xi: &[f64]) -> bool {
        let (dim, n) = (self.team.dim, self.team.robots);
        let clear = |projection: &mut Projection, grid: &SampleGrid, limits| {
            grid.count() == 0 || projection.clear(crew, dim, n, grid, limits, xi)
        };
        clear(&mut verifier.start, &self.dense_start, &prepared.verify_start)
            && clear(&mut verifier.dense, &self.dense, &prepared.verify)
            && self.rates.as_ref().is_none_or(|r| r.within(dim.axes(), n, xi))
    }
}

/// A run's dense verification: the working memory of its two grids, kept
/// between calls (a 256-robot dense grid is megabytes) with the pair each
/// last failed at.
struct Verifier {
    start: Projection,
    dense: Projection,
}

impl Verifier {
    fn new(engine: &Engine) -> Self {
        let (dim, n) = (engine.team.dim, engine.team.robots);
        Self { start: Projection::new(dim, n, &engine.dense_start), dense: Projection::new(dim, n, &engine.dense) }
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::am::{AmSettings, Objective};
    use crate::metrics::Metrics;
    use crate::plan::JointPlan;
    use crate::problem::{Dim, Team};
    use crate::reference::SmoothReference;
    use crate::scenario::RandomScenario;

    #[test]
    fn big_teams_restart_less_so_that_each_attempt_gets_its_iterations_per_robot() {
        let attempts = |robots| optimiser(&Team::default_for(Dim::Two, robots), 0).attempts();
        // The default cap of 10,000 gives four attempts up to 100 robots.
        assert_eq!([attempts(16), attempts(64), attempts(100)], [4, 4, 4]);
        assert_eq!([attempts(128), attempts(256), attempts(1000)], [3, 1, 1]);
    }

    #[test]
    fn a_doorway_that_fixed_shares_leave_jammed_verifies_with_attempts_that_end_on_a_stall() {
        // Eight robots swapping rooms through one door: from the routes'
        // one timing all meet there, and every perturbed attempt of the
        // fixed shares ends at its cap; attempts that stop on a stall and
        // move the robots' passages through the door find an order.
        let (problem, _) =
            crate::scenes::Scene::new(crate::scenes::Family::Doorway, Dim::Two, 8, 100).generate().unwrap();
        let solve = |stall| {
            let settings = AmSettings { stall, ..AmSettings::optimiser() };
            Engine::new(&problem.team, problem.obstacles.len(), Objective::smoothness(), settings)
                .unwrap()
                .solve(&problem)
                .unwrap()
        };
        let shares = solve(0);
        assert_eq!((shares.stop, shares.attempts, shares.iterations), (Stop::IterationCap, 4, 10_000));
        let stalls = solve(300);
        assert_eq!(stalls.stop, Stop::Verified);
        assert!(
            stalls.attempts > 1 && stalls.iterations < 10_000,
            "{} attempts, {}",
            stalls.attempts,
            stalls.iterations
        );
    }

    #[test]
    fn without_routed_robots_attempts_keep_their_shares_whatever_the_stall() {
        // Open space routes nobody: runs that only the cap ends (no
        // verification, a tolerance never met) make the same attempts and
        // plans with the stall rule on or off.
        let team = Team::default_for(Dim::Two, 2);
        let problem = RandomScenario::new(team.clone()).generate(5).unwrap();
        let solve = |stall| {
            let settings =
                AmSettings { stall, max_iterations: 200, verify_every: 0, tolerance: -1.0, ..AmSettings::optimiser() };
            Engine::new(&team, 0, Objective::smoothness(), settings).unwrap().solve(&problem).unwrap()
        };
        let (off, on) = (solve(0), solve(300));
        assert_eq!((off.stop, off.attempts, off.iterations), (Stop::IterationCap, 4, 200));
        assert_eq!((on.attempts, on.iterations), (off.attempts, off.iterations));
        assert_eq!(on.state.xi, off.state.xi);
    }

    #[test]
    fn the_engine_runs_the_penalty_schedule_of_its_teams_size() {
        let every = |robots| optimiser(&Team::default_for(Dim::Two, robots), 0).settings().rho.every;
        assert_eq!([every(16), every(32), every(33), every(64)], [25, 25, 50, 50]);
    }

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
    fn a_passed_deadline_or_a_cancellation_stops_the_optimiser_with_its_current_iterate() {
        let team = Team::default_for(Dim::Two, 16);
        let problem = RandomScenario::new(team.clone()).generate(5).unwrap();
        let engine = optimiser(&team, 0);
        let prepared = engine.prepare(&problem, None).unwrap();
        assert!(!engine.verify(&prepared, &engine.cold_start(&prepared).xi), "the straight lines collide");
        let outcome = engine.solve_prepared_within(&prepared, &Budget::until(Instant::now()));
        assert_eq!(outcome.stop, Stop::Deadline);
        assert_eq!(outcome.iterations, 0);
        assert_eq!(outcome.state.xi, engine.cold_start(&prepared).xi);
        let unhurried = engine.solve_prepared_within(&prepared, &Budget::unlimited());
        assert_eq!(unhurried.stop, Stop::Verified);
        let cancelled = || true;
        let outcome = engine.solve_prepared_within(&prepared, &Budget::unlimited().or_cancelled(&cancelled));
        assert_eq!((outcome.stop, outcome.iterations), (Stop::Cancelled, 0));
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
    fn the_instants_right_after_the_start_are_verified_too() {
        use crate::problem::StartState;
        use nalgebra::Vector3;
        // Two robots just touching, closing at 1 m/s, then parting for
        // their goals: they overlap early on and are far apart later.
        let team = Team::default_for(Dim::Two, 2);
        let moving = |x: f64, vx: f64| StartState {
            position: Vector3::new(x, 0.0, 0.0),
            velocity: Vector3::new(vx, 0.0, 0.0),
            acceleration: Vector3::zeros(),
        };
        let problem = Problem {
            team: team.clone(),
            starts: vec![moving(-0.1, 0.5), moving(0.1, -0.5)],
            goals: vec![Vector3::new(-0.8, 0.0, 0.0), Vector3::new(0.8, 0.0, 0.0)],
            obstacles: vec![],
        };
        let xi = SmoothReference::new(&team).unwrap().coefficients(&problem);
        let m = Metrics::measure(&problem, &JointPlan::new(&team, xi.clone()));
        assert!(m.min_robot_scaled < 0.9, "they overlap: {}", m.min_robot_scaled);
        // Skipping the buffer for the first three quarters of the horizon
        // still leaves those instants held to the feasibility tolerance.
        let settings = AmSettings { verify_margin: 0.02, verify_skip: 150, ..AmSettings::safety_filter() };
        let sf = Engine::new(&team, 0, Objective::Projection, settings).unwrap();
        let prepared = sf.prepare(&problem, Some(&xi)).unwrap();
        assert!(!sf.verify(&prepared, &xi), "an overlap right after the start is not verified");
    }
}
