//! One team's planner and the followability contract: every accepted
//! snapshot gets an answer that says which trajectory the controllers are
//! to follow from now on, and that trajectory is always one this planner
//! verified from a state consistent with the measured one, or there is
//! none. It knows nothing of the wire: the daemon's worker converts
//! snapshots into problems and writes the replies.
//!
//! - **Held plan.** The last verified plan published, with its own time
//!   origin. A late or failed computation never replaces it: it is
//!   re-issued ([`Follow::Held`]) while the robots are within
//!   `follow_tolerance_m` of it.
//! - **Warm start**, only from a plan the robots are on: when the goals and
//!   obstacles are unchanged and the measured state is within
//!   `warm_tolerance_m` of the held plan at the snapshot's time, the held
//!   plan shifted in time ([`JointPlan::shifted`]) is the safety filter's
//!   sample; a verified result is the new plan.
//! - **Cold plan** otherwise, or when the warm start does not verify in
//!   time: the cold planner's methods race on their own threads
//!   ([`crate::cold`]) within the same deadline. One that misses it keeps
//!   running; its plan is adopted as soon as it verifies if the newest
//!   state is still at its start, else it becomes the sample of the next
//!   warm start.
//! - **Fallback** when nothing verified by the deadline: the held plan if
//!   the robots follow it; else a verified stopping plan (every robot
//!   brought to rest along its motion, [`flowopt_planner::stopping`];
//!   verified at the true sizes, without the tracking buffer); else
//!   nothing ([`Follow::Nothing`]).
//! - **Limits.** A plan exceeding the team's speed or acceleration limits
//!   is stretched in time when the robots start at rest (the paper's
//!   post-hoc time scaling) and refused otherwise ([`Why::Limits`]).

use std::time::{Duration, Instant};

use flowopt_models::pipeline::{LearnedPlanner, PipelineSettings};
use flowopt_planner::am::{AmSettings, Budget, EngineError, EngineSet, Objective, Stop};
use flowopt_planner::metrics::DENSE_FACTOR;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Problem, Team};
use flowopt_planner::reference::{ReferenceError, SmoothReference};
use flowopt_planner::route::Fitter;
use flowopt_planner::stopping::{stopping_problem, stopping_team};
use nalgebra::Vector3;
use thiserror::Error;
use tracing::{debug, info_span};

use crate::cold::{ColdPlanner, ColdResult, Method};
use crate::config::{ConfigError, TeamConfig};

/// Why a team's planner cannot be built.
#[derive(Debug, Error)]
pub enum PreloadError {
    /// The team's configuration is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// An engine cannot be built for it.
    #[error("cannot build the engines: {0}")]
    Engine(#[from] EngineError),
    /// The learned planner's weights cannot be loaded or do not fit the team.
    #[error("cannot load the learned planner: {0}")]
    Model(#[from] flowopt_models::ModelError),
}

/// Iteration cap of the warm-start safety filter (about 10 ms for 16
/// robots); it also gets at most half the deadline, leaving the rest to a
/// cold plan when it does not verify.
const WARM_ITERATIONS: usize = 2000;

/// Constraint inflation (relative to the separation) kept beyond the
/// tracking buffer, so that plans converge to the buffered verification
/// (the engines' default 5% inflation over their 0% verification).
const CONSTRAINT_HEADROOM: f64 = 0.03;

/// The relative buffer every plan keeps beyond the robots' separation on the
/// dense verification grid: twice `follow_tolerance` over the smallest
/// separation. Two robots that each follow their plan within the tolerance
/// (the condition for re-issuing a held plan) then cannot touch. Within the
/// first constraint interval after the (measured, possibly near-contact)
/// start the buffer is not required.
pub fn tracking_buffer(team: &Team, follow_tolerance: f64) -> f64 {
    let (a, b) = team.separation();
    2.0 * follow_tolerance / a.min(b)
}

/// Start speed (m/s) below which a robot counts as at rest, so that a plan
/// may be stretched in time without changing its start.
const AT_REST: f64 = 0.02;

/// Time kept before the deadline to publish a fallback answer.
const PUBLISH_MARGIN: Duration = Duration::from_millis(1);

/// Goals closer than this (m) count as unchanged.
const SAME_GOAL: f64 = 1e-9;

/// What the controllers are to follow after an answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Follow {
    /// A new verified plan (now the held plan).
    New,
    /// The held plan, re-issued unchanged.
    Held,
    /// A new verified stopping plan (now the held plan).
    Stopping,
    /// Nothing: there is no verified trajectory.
    Nothing,
}

/// Why an answer is not a new plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Why {
    /// It is one.
    None,
    /// No plan verified within the deadline.
    DeadlineMissed,
    /// The planners' plans did not verify.
    NotVerified,
    /// The robots had left the held plan.
    NotFollowing,
    /// The verified plan exceeds the speed or acceleration limits.
    Limits,
}

/// What kind of plan is held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A plan to the goals.
    Goals,
    /// A plan bringing the robots to rest.
    Stopping,
}

/// Time spent in each planning stage (zero for a stage not run).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stages {
    /// Shifting the previous plan to the new start and fitting it.
    pub warm_start: Duration,
    /// Sampling candidates from the flow policy.
    pub sample: Duration,
    /// Ranking the candidates.
    pub rank: Duration,
    /// The initialisation network.
    pub init: Duration,
    /// The safety filter (warm start, learned candidates, stopping plan).
    pub filter: Duration,
    /// The from-scratch optimiser.
    pub optimise: Duration,
    /// Choosing among refined candidates.
    pub select: Duration,
}

/// The last verified plan published: what the controllers follow.
#[derive(Debug, Clone)]
pub struct Held {
    /// The plan.
    pub plan: JointPlan,
    /// Its time origin (ns, the clock of the snapshots).
    pub origin_ns: u64,
    /// The snapshot it was made from.
    pub sequence: u64,
    /// To the goals, or to rest.
    pub kind: Kind,
    /// Its primal residual (m).
    pub primal: f64,
    /// Its smoothness.
    pub smoothness: f64,
    /// Its largest speed (m/s).
    pub max_speed: f64,
    /// Its largest acceleration (m/s^2).
    pub max_acceleration: f64,
    goals: Vec<Vector3<f64>>,
    obstacles: usize,
}

impl Held {
    /// How far (m) the robots of `problem`, measured at `origin_ns`, are from
    /// this plan.
    fn deviation(&self, problem: &Problem, origin_ns: u64) -> f64 {
        self.plan.deviation(seconds(self.origin_ns, origin_ns), &problem.starts)
    }
}

/// Seconds from `from_ns` to `to_ns` (negative if earlier).
fn seconds(from_ns: u64, to_ns: u64) -> f64 {
    (to_ns as i128 - from_ns as i128) as f64 * 1e-9
}

/// Whether `a` and `b` have the same goals and obstacle count.
fn same_task(goals: &[Vector3<f64>], obstacles: usize, problem: &Problem) -> bool {
    obstacles == problem.obstacles.len()
        && goals.len() == problem.goals.len()
        && goals.iter().zip(&problem.goals).all(|(a, b)| (a - b).norm() <= SAME_GOAL)
}

/// What one snapshot (or a late cold plan) produced.
#[derive(Debug, Clone, PartialEq)]
pub struct Answer {
    /// What to follow: for `New`, `Held` and `Stopping`, [`TeamPlanner::held`].
    pub follow: Follow,
    /// Why it is not a new plan.
    pub why: Why,
    /// Iterations spent on this answer.
    pub iterations: usize,
    /// Whether the new plan came from the warm start.
    pub warm: bool,
    /// Candidates refined for it.
    pub candidates: usize,
    /// Stage times of this answer.
    pub stages: Stages,
}

impl Answer {
    fn new(follow: Follow, why: Why) -> Self {
        Self { follow, why, iterations: 0, warm: false, candidates: 0, stages: Stages::default() }
    }
}

/// A verified plan made from some state, not yet published.
#[derive(Debug, Clone)]
struct Candidate {
    plan: JointPlan,
    /// The problem it starts from (with the start accelerations it has).
    problem: Problem,
    origin_ns: u64,
    sequence: u64,
    primal: f64,
}

/// The newest accepted state.
#[derive(Debug, Clone)]
struct Newest {
    problem: Problem,
    origin_ns: u64,
    sequence: u64,
}

/// A cold request in flight.
#[derive(Debug, Clone)]
struct Pending {
    id: u64,
    goals: Vec<Vector3<f64>>,
    obstacles: usize,
    /// Methods that have not answered yet.
    outstanding: usize,
}

/// The team's limits and tolerances.
#[derive(Debug, Clone, Copy)]
struct Rules {
    deadline: Duration,
    max_speed: f64,
    max_acceleration: f64,
    follow_tolerance: f64,
    warm_tolerance: f64,
}

/// A team's preloaded engines and its planning state.
#[derive(Debug)]
pub struct TeamPlanner {
    team: Team,
    rules: Rules,
    /// Warm-start safety filters, one per obstacle count.
    filters: EngineSet,
    /// Stopping-plan safety filters (the stopping horizon), one per count.
    stops: EngineSet,
    stop_reference: SmoothReference,
    fitter: Fitter,
    cold: ColdPlanner,
    held: Option<Held>,
    newest: Option<Newest>,
    pending: Option<Pending>,
    /// A verified cold plan whose start the robots had left: the next
    /// warm start's sample.
    fresh: Option<Candidate>,
}

impl TeamPlanner {
    /// Builds every engine (basis, sample grids, KKT factorisations) the
    /// team can need, so that no snapshot waits for one, and starts the
    /// cold-planning threads.
    pub fn preload(config: &TeamConfig) -> Result<Self, PreloadError> {
        let team = config.team()?;
        let buffer = tracking_buffer(&team, config.follow_tolerance_m);
        let buffered = |s: AmSettings| AmSettings {
            margin: s.margin.max(buffer + CONSTRAINT_HEADROOM),
            verify_margin: buffer,
            verify_skip: DENSE_FACTOR,
            ..s
        };
        let max = config.max_obstacles;
        let filter_settings = buffered(AmSettings { max_iterations: WARM_ITERATIONS, ..AmSettings::safety_filter() });
        let filters = EngineSet::preloaded(&team, Objective::Projection, filter_settings, max)?;
        let stop_horizon = (2.0 * config.max_speed / config.max_acceleration).max(0.5);
        let stop_team = stopping_team(&team, stop_horizon);
        // Stopping plans, the last resort before none, are verified at the
        // true sizes: robots a jam has left within the buffer of each other
        // are then still held apart under control instead of braking on
        // their own (and drifting) with no plan at all.
        let stop_settings = AmSettings { verify_margin: 0.0, ..buffered(AmSettings::safety_filter()) };
        let stops = EngineSet::preloaded(&stop_team, Objective::Projection, stop_settings, max)?;
        let stop_reference = SmoothReference::new(&stop_team).map_err(|e| match e {
            ReferenceError::Basis(b) => EngineError::Problem(b.into()),
            ReferenceError::Kkt(k) => EngineError::Kkt(k),
        })?;
        let basis = team.basis().map_err(|e| EngineError::Problem(e.into()))?;
        let fitter = Fitter::new(&basis).map_err(EngineError::Kkt)?;
        let mut methods = Vec::new();
        if let Some(l) = &config.learned {
            let planner = LearnedPlanner::load(&l.flow, l.init.as_deref(), l.sf_smoothing)?;
            let filters = planner.filters(&team, filter_settings, max)?;
            let settings = PipelineSettings {
                candidates: l.candidates,
                obstacle_candidates: l.obstacle_candidates,
                steps: l.flow_steps,
                obstacle_steps: l.obstacle_flow_steps,
                top_k: l.top_k,
                rounds: l.rounds,
                use_init: planner.model().has_init(),
                // Racing the optimiser, the learned planner keeps to one core.
                threads: 1,
                obstacle_threads: 1,
                ..PipelineSettings::default()
            };
            methods.push(Method::Learned { planner: Box::new(planner), settings, filters, plans: 0 });
        }
        let optimisers = EngineSet::preloaded(&team, Objective::smoothness(), buffered(AmSettings::optimiser()), max)?;
        methods.push(Method::Optimiser(optimisers));
        let cold = ColdPlanner::start(&config.name, methods, Duration::from_secs_f64(config.cold_budget_ms * 1e-3));
        Ok(Self {
            team,
            rules: Rules {
                deadline: Duration::from_secs_f64(config.deadline_ms * 1e-3),
                max_speed: config.max_speed,
                max_acceleration: config.max_acceleration,
                follow_tolerance: config.follow_tolerance_m,
                warm_tolerance: config.warm_tolerance_m,
            },
            filters,
            stops,
            stop_reference,
            fitter,
            cold,
            held: None,
            newest: None,
            pending: None,
            fresh: None,
        })
    }

    /// The team.
    pub fn team(&self) -> &Team {
        &self.team
    }

    /// The time an answer may take from the arrival of its snapshot.
    pub fn deadline(&self) -> Duration {
        self.rules.deadline
    }

    /// The plan the controllers follow, if any.
    pub fn held(&self) -> Option<&Held> {
        self.held.as_ref()
    }

    /// The newest accepted snapshot's sequence and timestamp.
    pub fn newest(&self) -> Option<(u64, u64)> {
        self.newest.as_ref().map(|n| (n.sequence, n.origin_ns))
    }

    /// Where late cold plans arrive; hand each to [`Self::on_cold`].
    pub(crate) fn cold_results(&self) -> crossbeam::channel::Receiver<ColdResult> {
        self.cold.results().clone()
    }

    /// Answers an accepted snapshot: `problem` (validated, of this team),
    /// measured at `origin_ns` in snapshot `sequence`, by `deadline`.
    pub fn answer(&mut self, problem: Problem, origin_ns: u64, sequence: u64, deadline: Instant) -> Answer {
        self.newest = Some(Newest { problem: problem.clone(), origin_ns, sequence });
        let mut answer = Answer::new(Follow::Nothing, Why::DeadlineMissed);
        let deviation = self.held.as_ref().map(|h| h.deviation(&problem, origin_ns));
        let mut why = Why::DeadlineMissed;

        // Warm start from the held plan, if the robots are on it.
        let warm_from = self.held.as_ref().filter(|h| {
            h.kind == Kind::Goals
                && same_task(&h.goals, h.obstacles, &problem)
                && deviation.is_some_and(|d| d <= self.rules.warm_tolerance)
        });
        if let Some(h) = warm_from {
            let (plan, origin) = (h.plan.clone(), h.origin_ns);
            let warm_deadline = deadline.min(Instant::now() + self.rules.deadline / 2);
            let found = self.refine(
                &plan,
                seconds(origin, origin_ns),
                &problem,
                origin_ns,
                sequence,
                warm_deadline,
                &mut answer,
            );
            match found {
                Ok(Some(candidate)) => {
                    answer.warm = true;
                    return self.adopt(candidate, answer);
                }
                Ok(None) => why = Why::NotVerified,
                Err(w) => why = w,
            }
        }
        // A verified cold plan the robots had left: repaired from here.
        if let Some(fresh) =
            self.fresh.take().filter(|f| same_task(&f.problem.goals, f.problem.obstacles.len(), &problem))
        {
            let dt = seconds(fresh.origin_ns, origin_ns);
            if let Ok(Some(candidate)) =
                self.refine(&fresh.plan, dt, &problem, origin_ns, sequence, deadline, &mut answer)
            {
                return self.adopt(candidate, answer);
            }
        }
        // Cold: keep a request for these goals running, or start one.
        let running = self.pending.as_ref().is_some_and(|p| same_task(&p.goals, p.obstacles, &problem));
        if !running {
            let id = self.cold.submit(&problem, origin_ns, sequence);
            self.pending = Some(Pending {
                id,
                goals: problem.goals.clone(),
                obstacles: problem.obstacles.len(),
                outstanding: self.cold.methods(),
            });
        }
        // Wait for it, leaving time to publish a fallback within the deadline.
        let wait_until = deadline.checked_sub(PUBLISH_MARGIN.min(self.rules.deadline / 10)).unwrap_or(deadline);
        let results = self.cold.results().clone();
        while self.pending.is_some() {
            // Past the deadline only a result already there is taken (a
            // blocking receive backs off by yielding, which can hand the
            // core to the cold threads for milliseconds).
            let received = if Instant::now() >= wait_until {
                results.try_recv().ok()
            } else {
                results.recv_deadline(wait_until).ok()
            };
            let Some(result) = received else { break };
            if let Some(adopted) = self.take_cold(result, &mut answer, deadline) {
                return adopted;
            }
        }
        if self.pending.is_none() && why == Why::DeadlineMissed {
            why = Why::NotVerified;
        }
        self.fallback(&problem, origin_ns, sequence, deviation, why, answer, deadline)
    }

    /// A cold result that arrived outside any snapshot's deadline: adopted
    /// if it verified and the newest state is at its start (or it can be
    /// repaired from there at once), returned as the answer to publish.
    pub(crate) fn on_cold(&mut self, result: ColdResult) -> Option<Answer> {
        let mut answer = Answer::new(Follow::Nothing, Why::None);
        let deadline = Instant::now() + self.rules.deadline;
        self.take_cold(result, &mut answer, deadline)
    }

    /// Takes one cold result: the answer if its plan was adopted.
    fn take_cold(&mut self, result: ColdResult, answer: &mut Answer, deadline: Instant) -> Option<Answer> {
        debug!(method = result.method, verified = result.outcome.plan.is_some(), "cold result");
        let pending = self.pending.as_mut().filter(|p| p.id == result.request.id)?;
        pending.outstanding = pending.outstanding.saturating_sub(1);
        answer.iterations += result.outcome.iterations;
        add_stages(&mut answer.stages, &result.outcome.stages);
        let Some(plan) = result.outcome.plan else {
            if pending.outstanding == 0 {
                self.pending = None;
            }
            return None;
        };
        // The first verified plan wins the race.
        self.cold.cancel();
        self.pending = None;
        answer.candidates = result.outcome.candidates;
        let request = result.request;
        let Ok(plan) = self.within_limits(plan, &request.problem) else {
            answer.why = Why::Limits;
            return None;
        };
        let candidate = Candidate {
            plan,
            problem: request.problem,
            origin_ns: request.origin_ns,
            sequence: request.sequence,
            primal: result.outcome.primal,
        };
        let newest = self.newest.clone()?;
        if !same_task(&candidate.problem.goals, candidate.problem.obstacles.len(), &newest.problem) {
            return None;
        }
        let dt = seconds(candidate.origin_ns, newest.origin_ns);
        if candidate.plan.deviation(dt.max(0.0), &newest.problem.starts) <= self.rules.follow_tolerance {
            return Some(self.adopt(candidate, answer.clone()));
        }
        match self.refine(&candidate.plan, dt, &newest.problem, newest.origin_ns, newest.sequence, deadline, answer) {
            Ok(Some(repaired)) => Some(self.adopt(repaired, answer.clone())),
            _ => {
                self.fresh = Some(candidate);
                None
            }
        }
    }

    /// The safety filter on `sample` shifted by `dt` for `problem`: a
    /// verified candidate within the limits, `None` if it did not verify,
    /// or why it cannot be published.
    #[allow(clippy::too_many_arguments)]
    fn refine(
        &self,
        sample: &JointPlan,
        dt: f64,
        problem: &Problem,
        origin_ns: u64,
        sequence: u64,
        deadline: Instant,
        answer: &mut Answer,
    ) -> Result<Option<Candidate>, Why> {
        let t = Instant::now();
        let mut start = problem.clone();
        let xi = {
            let _span = info_span!("warm_start").entered();
            sample.shifted(dt.max(0.0), &mut start, &self.fitter)
        };
        answer.stages.warm_start += t.elapsed();
        let t = Instant::now();
        let _span = info_span!("filter").entered();
        let outcome = self.filters.get(problem.obstacles.len()).and_then(|engine| {
            let prepared = engine.prepare(&start, Some(&xi)).ok()?;
            Some((engine, engine.run_within(&prepared, engine.cold_start(&prepared), &Budget::until(deadline))))
        });
        answer.stages.filter += t.elapsed();
        let Some((engine, outcome)) = outcome else { return Ok(None) };
        answer.iterations += outcome.iterations;
        answer.candidates = 1;
        if outcome.stop != Stop::Verified {
            return Ok(None);
        }
        let plan = self.within_limits(engine.plan(outcome.state.xi), &start)?;
        Ok(Some(Candidate { plan, problem: start, origin_ns, sequence, primal: outcome.primal }))
    }

    /// `plan` if it keeps the team's speed and acceleration limits; else
    /// stretched in time when the robots start at rest and every obstacle is
    /// static (the paths, and so the verified clearances, are unchanged);
    /// else [`Why::Limits`].
    fn within_limits(&self, plan: JointPlan, problem: &Problem) -> Result<JointPlan, Why> {
        let (speed, acceleration) = plan.peak_rates(DENSE_FACTOR * self.team.samples);
        let factor = (speed / self.rules.max_speed).max((acceleration / self.rules.max_acceleration).sqrt());
        if factor <= 1.0 {
            return Ok(plan);
        }
        let at_rest = problem.starts.iter().all(|s| s.velocity.norm() <= AT_REST && s.acceleration.norm() <= AT_REST);
        let static_obstacles = problem.obstacles.iter().all(|o| o.velocity.norm() == 0.0);
        if at_rest && static_obstacles && factor.is_finite() {
            Ok(plan.stretched(factor * (1.0 + 1e-6)))
        } else {
            Err(Why::Limits)
        }
    }

    /// Makes `candidate` the held plan (to the goals) and answers with it.
    fn adopt(&mut self, candidate: Candidate, mut answer: Answer) -> Answer {
        self.cold.cancel();
        self.pending = None;
        self.fresh = None;
        self.held = Some(held(candidate, Kind::Goals, self.team.samples));
        answer.follow = Follow::New;
        answer.why = Why::None;
        answer
    }

    /// Nothing new verified in time: the held plan if the robots follow it,
    /// else a verified stopping plan, else nothing.
    #[allow(clippy::too_many_arguments)]
    fn fallback(
        &mut self,
        problem: &Problem,
        origin_ns: u64,
        sequence: u64,
        deviation: Option<f64>,
        why: Why,
        mut answer: Answer,
        deadline: Instant,
    ) -> Answer {
        if deviation.is_some_and(|d| d <= self.rules.follow_tolerance) {
            answer.follow = Follow::Held;
            answer.why = why;
            return answer;
        }
        let why = if self.held.is_some() { Why::NotFollowing } else { why };
        answer.why = why;
        match self.stopping(
            problem,
            origin_ns,
            sequence,
            deadline.max(Instant::now() + self.rules.deadline / 2),
            &mut answer,
        ) {
            Some(candidate) => {
                self.held = Some(held(candidate, Kind::Stopping, self.team.samples));
                answer.follow = Follow::Stopping;
            }
            None => {
                self.held = None;
                answer.follow = Follow::Nothing;
            }
        }
        answer
    }

    /// A verified stopping plan from `problem`'s state, within the limits.
    fn stopping(
        &self,
        problem: &Problem,
        origin_ns: u64,
        sequence: u64,
        deadline: Instant,
        answer: &mut Answer,
    ) -> Option<Candidate> {
        let _span = info_span!("stopping").entered();
        let t = Instant::now();
        let inset = self.team.robot.radius * AmSettings::safety_filter().margin;
        let stop = stopping_problem(problem, self.stops.team().horizon, inset);
        stop.validate().ok()?;
        let engine = self.stops.get(stop.obstacles.len())?;
        let sample = self.stop_reference.coefficients(&stop);
        let prepared = engine.prepare(&stop, Some(&sample)).ok()?;
        let outcome = engine.run_within(&prepared, engine.cold_start(&prepared), &Budget::until(deadline));
        answer.stages.filter += t.elapsed();
        answer.iterations += outcome.iterations;
        if outcome.stop != Stop::Verified {
            return None;
        }
        let plan = self.within_limits(engine.plan(outcome.state.xi), &stop).ok()?;
        Some(Candidate { plan, problem: stop, origin_ns, sequence, primal: outcome.primal })
    }
}

/// The held plan `candidate` becomes.
fn held(candidate: Candidate, kind: Kind, samples: usize) -> Held {
    let (max_speed, max_acceleration) = candidate.plan.peak_rates(DENSE_FACTOR * samples);
    let smoothness = candidate.plan.smoothness(samples);
    Held {
        smoothness,
        max_speed,
        max_acceleration,
        origin_ns: candidate.origin_ns,
        sequence: candidate.sequence,
        kind,
        primal: candidate.primal,
        goals: candidate.problem.goals,
        obstacles: candidate.problem.obstacles.len(),
        plan: candidate.plan,
    }
}

/// Adds the durations of `more` to `into`.
fn add_stages(into: &mut Stages, more: &Stages) {
    into.warm_start += more.warm_start;
    into.sample += more.sample;
    into.rank += more.rank;
    into.init += more.init;
    into.filter += more.filter;
    into.optimise += more.optimise;
    into.select += more.select;
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::metrics::Metrics;
    use flowopt_planner::problem::{Dim, StartState};
    use flowopt_planner::scenario::RandomScenario;

    fn config(robots: usize, extra: &str) -> TeamConfig {
        let text = format!(
            "name = \"t\"\ndim = 2\nrobots = {robots}\nrobot = {{ radius = 0.1 }}\n\
             workspace = {{ min = [-1.0, -1.0], max = [1.0, 1.0] }}\nmax_obstacles = 2\ndeadline_ms = 1000.0\n{extra}"
        );
        toml::from_str(&text).unwrap()
    }

    /// Answers `problem` measured at `origin_ns` (s 1), the deadline
    /// running from `received`.
    fn answer(planner: &mut TeamPlanner, problem: &Problem, origin_ns: u64, received: Instant) -> Answer {
        let deadline = received + planner.deadline();
        planner.answer(problem.clone(), origin_ns, origin_ns / 1_000_000, deadline)
    }

    /// Checks that the held plan starts at `problem`'s state at its origin
    /// and keeps the true sizes on the dense grid, and, from starts apart,
    /// the tracking buffer too: robots grown by the follow tolerance
    /// (default 5 mm) do not touch.
    fn assert_verified_from(planner: &TeamPlanner, problem: &Problem) {
        let held = planner.held().expect("a held plan");
        let starts: Vec<StartState> = held.plan.at(0.0).iter().map(|k| StartState::at_rest(k.position)).collect();
        assert!(held.plan.deviation(0.0, &problem.starts) < 1e-6, "starts at the measured state");
        let team = Team { horizon: held.plan.horizon, ..problem.team.clone() };
        let check = Problem { team: team.clone(), starts, ..problem.clone() };
        let m = Metrics::measure(&check, &held.plan);
        assert!(m.min_robot_scaled >= 1.0 && m.workspace_excess <= 0.0, "{m:?}");
        let mut grown = team;
        grown.robot.radius += planner.rules.follow_tolerance;
        grown.robot.half_height += planner.rules.follow_tolerance;
        let buffered = Metrics::measure(&Problem { team: grown, ..check }, &held.plan);
        assert!(buffered.min_robot_scaled >= 1.0, "keeps the tracking buffer: {buffered:?}");
    }

    /// The first team of the shipped configuration `file` (under the
    /// repository root), renamed `name` with a long deadline: preloads with
    /// the learned planner racing the optimiser and plans a random problem
    /// cold, verified. Returns the team's configuration.
    fn shipped_team_plans_cold(file: &str, name: &str) -> TeamConfig {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let config = crate::config::DaemonConfig::load(&root.join(file)).unwrap();
        let mut team = config.teams[0].clone();
        team.name = name.into();
        team.deadline_ms = 10_000.0;
        let mut planner = TeamPlanner::preload(&team).unwrap();
        assert_eq!(planner.cold.methods(), 2, "the learned pipeline races the optimiser");
        let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
        let a = answer(&mut planner, &problem, 1_000_000_000, Instant::now());
        assert_eq!((a.follow, a.why, a.warm), (Follow::New, Why::None, false));
        assert_verified_from(&planner, &problem);
        team
    }

    #[test]
    fn the_default_config_preloads_the_shipped_weights_and_plans_cold() {
        let team = shipped_team_plans_cold("config/default.toml", "t");
        // Weights for another dimension are refused at preload.
        let mut three = team.clone();
        three.dim = Dim::Three;
        three.robot = toml::from_str("radius = 0.1").unwrap();
        three.workspace = toml::from_str("min = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]").unwrap();
        assert!(matches!(TeamPlanner::preload(&three), Err(PreloadError::Model(_))));
    }

    #[test]
    fn the_3d_config_preloads_the_3d_weights_and_plans_cold() {
        shipped_team_plans_cold("config/team3d.toml", "t3");
    }

    #[test]
    fn a_cold_plan_then_a_warm_replan_along_it_are_both_verified() {
        let mut planner = TeamPlanner::preload(&config(8, "")).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
        let first = answer(&mut planner, &problem, 1_000_000_000, Instant::now());
        assert_eq!((first.follow, first.warm), (Follow::New, false));
        assert_verified_from(&planner, &problem);
        let plan0 = planner.held().unwrap().plan.clone();

        // The robots followed the plan for 0.4 s.
        let mut moved = problem.clone();
        for (s, k) in moved.starts.iter_mut().zip(plan0.at(0.4)) {
            s.position = k.position;
            s.velocity = k.velocity;
        }
        let second = answer(&mut planner, &moved, 1_400_000_000, Instant::now());
        assert_eq!((second.follow, second.warm), (Follow::New, true));
        assert_verified_from(&planner, &moved);
        assert!(second.iterations < 100, "warm replans stay cheap: {}", second.iterations);
        assert_eq!(planner.held().unwrap().origin_ns, 1_400_000_000);
    }

    #[test]
    fn changed_goals_get_a_cold_plan() {
        let mut planner = TeamPlanner::preload(&config(4, "")).unwrap();
        let a = RandomScenario::new(planner.team().clone()).generate(1).unwrap();
        answer(&mut planner, &a, 1_000_000_000, Instant::now());
        let mut b = a.clone();
        b.goals.swap(0, 1);
        let replanned = answer(&mut planner, &b, 1_020_000_000, Instant::now());
        assert_eq!((replanned.follow, replanned.warm), (Follow::New, false));
        assert_verified_from(&planner, &b);
    }

    #[test]
    fn robots_that_left_the_plan_get_no_warm_start_and_a_stopping_plan_when_nothing_verifies_in_time() {
        let mut planner = TeamPlanner::preload(&config(16, "")).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(5).unwrap();
        answer(&mut planner, &problem, 1_000_000_000, Instant::now());
        // One second later the robots have not moved (frozen, or a restarted
        // controller), and the deadline has already passed.
        let long_ago = Instant::now() - Duration::from_secs(5);
        let late = answer(&mut planner, &problem, 2_000_000_000, long_ago);
        assert_eq!((late.follow, late.why, late.warm), (Follow::Stopping, Why::NotFollowing, false));
        let held = planner.held().unwrap();
        assert_eq!((held.kind, held.origin_ns), (Kind::Stopping, 2_000_000_000));
        assert!(held.plan.deviation(held.plan.horizon, &problem.starts) < 1e-6, "robots at rest stay where they are");
        assert_verified_from(&planner, &problem);
    }

    #[test]
    fn a_held_plan_is_reissued_while_the_robots_follow_it() {
        let mut planner = TeamPlanner::preload(&config(16, "")).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(5).unwrap();
        answer(&mut planner, &problem, 1_000_000_000, Instant::now());
        let plan0 = planner.held().unwrap().plan.clone();
        let mut moved = problem.clone();
        for (s, k) in moved.starts.iter_mut().zip(plan0.at(0.3)) {
            s.position = k.position;
            s.velocity = k.velocity;
        }
        // New goals arrive and no plan for them verifies in time.
        moved.goals.rotate_left(1);
        let long_ago = Instant::now() - Duration::from_secs(5);
        let late = answer(&mut planner, &moved, 1_300_000_000, long_ago);
        assert_eq!((late.follow, late.why), (Follow::Held, Why::DeadlineMissed));
        assert_eq!(planner.held().unwrap().origin_ns, 1_000_000_000, "unchanged, with its own origin");
    }

    #[test]
    fn plans_keep_the_limits_stretched_from_rest() {
        let mut planner = TeamPlanner::preload(&config(4, "max_speed = 0.1\nmax_acceleration = 0.2\n")).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(3).unwrap();
        let a = answer(&mut planner, &problem, 1_000_000_000, Instant::now());
        assert_eq!(a.follow, Follow::New);
        let held = planner.held().unwrap();
        let (speed, acceleration) = held.plan.peak_rates(4 * planner.team().samples);
        assert!(speed <= 0.1 && acceleration <= 0.2, "{speed} {acceleration}");
        assert!(held.plan.horizon > planner.team().horizon, "stretched: {}", held.plan.horizon);
        assert_verified_from(&planner, &problem);
        // From a moving start the plan cannot be stretched: refused.
        let mut moving = problem.clone();
        moving.starts[0].velocity.x = 0.05;
        moving.goals.swap(0, 1);
        let b = answer(&mut planner, &moving, 2_000_000_000, Instant::now() - Duration::from_secs(5));
        assert_ne!(b.follow, Follow::New);
    }

    #[test]
    fn a_late_cold_plan_is_adopted_when_the_robots_are_still_at_its_start() {
        let mut planner = TeamPlanner::preload(&config(16, "")).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(5).unwrap();
        let long_ago = Instant::now() - Duration::from_secs(5);
        let late = answer(&mut planner, &problem, 1_000_000_000, long_ago);
        assert_eq!(late.follow, Follow::Stopping, "nothing in time: the robots rest");
        let results = planner.cold_results();
        let result = results.recv_timeout(Duration::from_secs(30)).expect("the cold plan keeps running");
        let adopted = planner.on_cold(result).expect("adopted");
        assert_eq!((adopted.follow, adopted.why), (Follow::New, Why::None));
        assert_eq!(planner.held().unwrap().kind, Kind::Goals);
        assert_verified_from(&planner, &problem);
    }
}
