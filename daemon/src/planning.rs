//! One team's planner: every snapshot is answered from its own measured
//! state, warm-started from the previous plan when the goals are unchanged
//! and cold otherwise, within a deadline.
//!
//! - **Warm start.** The previous plan, shifted by the time between the two
//!   snapshots (and held at its goal past its end), is sampled at the K
//!   instants of the new horizon and fitted to the basis under the new
//!   boundary conditions (the measured position and velocity, the previous
//!   plan's acceleration at that time, the goals at rest). The safety filter
//!   projects the fit; a verified result is the plan.
//! - **Cold plan.** When the goals or the obstacle count change, there is no
//!   previous plan, or the filter does not verify within its cap, the
//!   learned planner ([`flowopt_models::pipeline`], when the team has
//!   weights) plans from the measured state; if it has none or its plan does
//!   not verify, the from-scratch optimiser does.
//! - **Deadline.** Both stop when the deadline passes; the best iterate so far
//!   is published as [`PlanStatus::DeadlineMissed`] and the next snapshot is
//!   warm-started from it.

use std::time::{Duration, Instant};

use flowopt_client::{JointTrajectory, PlanStatus, Reason, StageTimings, StateSnapshot};
use flowopt_planner::am::{AmOutcome, AmSettings, Engine, EngineError, Objective, Stop};
use flowopt_planner::basis::BOUNDARY_ROWS;
use flowopt_planner::metrics::DENSE_FACTOR;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Problem, Team};
use flowopt_planner::route::Fitter;
use nalgebra::Vector3;
use tracing::info_span;

use flowopt_models::pipeline::{FlowOpt, PipelineSettings};

use crate::config::{ConfigError, TeamConfig};
use crate::convert::{Rejection, problem_from};

/// Why a team's planner cannot be built.
#[derive(Debug, thiserror::Error)]
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
/// robots). A warm start that does not verify at once is usually close, and
/// a cold plan from a state in near-contact rarely fits in the rest of the
/// deadline: measured with `flowopt demo`, 2000 gave fewer deadline misses
/// than the filter's default 500.
const WARM_ITERATIONS: usize = 2000;

/// Relative buffer every plan keeps beyond the robots' separation on the
/// dense verification grid, for tracking error and measurement noise.
/// Within the first constraint interval after the (measured, possibly
/// near-contact) start the buffer is not required.
pub const TRACKING_BUFFER: f64 = 0.02;

/// Goals closer than this (m) count as unchanged.
const SAME_GOAL: f64 = 1e-9;

/// What planning one snapshot produced.
#[derive(Debug, Clone)]
pub struct Planned {
    /// The message status.
    pub status: PlanStatus,
    /// Why (rejections and failures).
    pub rejection: Option<Rejection>,
    /// The plan, for the statuses that carry one.
    pub plan: Option<JointPlan>,
    /// Its primal residual (m).
    pub primal: f64,
    /// Its smoothness.
    pub smoothness: f64,
    /// Iterations spent.
    pub iterations: usize,
    /// Whether the plan came from the warm start.
    pub warm: bool,
    /// Stage timings (`queue_us` and `total_us` are filled by the caller).
    pub timings: StageTimings,
}

impl Planned {
    fn rejected(rejection: Rejection, timings: StageTimings) -> Self {
        Self {
            status: PlanStatus::RejectedInput,
            rejection: Some(rejection),
            plan: None,
            primal: f64::NAN,
            smoothness: f64::NAN,
            iterations: 0,
            warm: false,
            timings,
        }
    }

    /// Writes everything but the timestamps and sequence into `msg`.
    pub fn write(&self, msg: &mut JointTrajectory) {
        msg.status = self.status;
        if let Some(r) = self.rejection {
            msg.reason = r.reason;
            msg.reason_index = r.index;
        }
        if let Some(plan) = &self.plan {
            // The configuration was checked against the message capacity.
            if msg.write_plan(plan).is_err() {
                msg.status = PlanStatus::NoPlan;
                msg.reason = Reason::Solver;
            }
        }
        msg.primal_residual = self.primal;
        msg.smoothness = self.smoothness;
        msg.iterations = self.iterations as u32;
        msg.warm_started = self.warm as u32;
        msg.candidates = u32::from(self.plan.is_some());
        msg.timings = self.timings;
    }
}

/// The plan the next snapshot is warm-started from.
#[derive(Debug, Clone)]
struct Previous {
    plan: JointPlan,
    origin_ns: u64,
    goals: Vec<Vector3<f64>>,
    obstacles: usize,
}

/// A team's learned planner: the networks, the pipeline settings and the
/// safety filters (one per obstacle count) in the configured metric.
#[derive(Debug)]
struct Learned {
    model: FlowOpt,
    settings: PipelineSettings,
    filters: Vec<Engine>,
}

/// A team's preloaded engines and its planning state.
#[derive(Debug)]
pub struct TeamPlanner {
    name: String,
    team: Team,
    max_obstacles: usize,
    deadline: Duration,
    /// From-scratch optimisers, one per obstacle count.
    optimisers: Vec<Engine>,
    /// Safety filters, one per obstacle count.
    filters: Vec<Engine>,
    fitter: Fitter,
    /// The learned planner, if configured.
    learned: Option<Learned>,
    /// Cold plans made so far (seeds the flow noise).
    cold_plans: u64,
    previous: Option<Previous>,
}

/// Microseconds, saturating at `u32::MAX`.
pub(crate) fn us(d: Duration) -> u32 {
    d.as_micros().min(u32::MAX as u128) as u32
}

impl TeamPlanner {
    /// Builds every engine (basis, sample grids, KKT factorisations) the
    /// team can need, so that no snapshot waits for one.
    pub fn preload(config: &TeamConfig) -> Result<Self, PreloadError> {
        let team = config.team()?;
        let engines = |objective: Objective, settings: AmSettings| {
            (0..=config.max_obstacles)
                .map(|m| Engine::new(&team, m, objective, settings))
                .collect::<Result<Vec<_>, _>>()
        };
        let buffered = |s: AmSettings| AmSettings { verify_margin: TRACKING_BUFFER, verify_skip: DENSE_FACTOR, ..s };
        let optimisers = engines(Objective::smoothness(), buffered(AmSettings::optimiser()))?;
        let filter_settings = buffered(AmSettings { max_iterations: WARM_ITERATIONS, ..AmSettings::safety_filter() });
        let filters = engines(Objective::Projection, filter_settings)?;
        let fitter = Fitter::new(optimisers[0].basis()).map_err(EngineError::Kkt)?;
        let learned = match &config.learned {
            Some(l) => {
                let model = FlowOpt::load(&l.flow, l.init.as_deref())?;
                model.check(&team)?;
                let settings = PipelineSettings {
                    candidates: l.candidates,
                    steps: l.flow_steps,
                    top_k: l.top_k,
                    use_init: model.has_init(),
                    ..PipelineSettings::default()
                };
                let filters = engines(Objective::filter(l.sf_smoothing), filter_settings)?;
                Some(Learned { model, settings, filters })
            }
            None => None,
        };
        Ok(Self {
            name: config.name.clone(),
            team,
            max_obstacles: config.max_obstacles,
            deadline: Duration::from_secs_f64(config.deadline_ms * 1e-3),
            optimisers,
            filters,
            fitter,
            learned,
            cold_plans: 0,
            previous: None,
        })
    }

    /// The team.
    pub fn team(&self) -> &Team {
        &self.team
    }

    /// The last plan made, if any, with its time origin (ns).
    pub fn last_plan(&self) -> Option<(&JointPlan, u64)> {
        self.previous.as_ref().map(|p| (&p.plan, p.origin_ns))
    }

    /// Plans for `snapshot`, which arrived at `received`; the deadline runs
    /// from then.
    pub fn plan(&mut self, snapshot: &StateSnapshot, received: Instant) -> Planned {
        let deadline = received + self.deadline;
        let mut timings = StageTimings::default();
        let t0 = Instant::now();
        let problem = {
            let _span = info_span!("validate").entered();
            problem_from(snapshot, &self.team, &self.name, self.max_obstacles)
        };
        timings.validate_us = us(t0.elapsed());
        let mut problem = match problem {
            Ok(p) => p,
            Err(rejection) => return Planned::rejected(rejection, timings),
        };
        let obstacles = problem.obstacles.len();

        let mut iterations = 0;
        let mut warm_result = None;
        if let Some(previous) = self.warm_candidate(&problem, snapshot.timestamp_ns) {
            let t = Instant::now();
            let xi = {
                let _span = info_span!("warm_start").entered();
                self.shifted(previous, &mut problem, snapshot.timestamp_ns)
            };
            timings.warm_start_us = us(t.elapsed());
            let t = Instant::now();
            let outcome = {
                let _span = info_span!("filter").entered();
                let engine = &self.filters[obstacles];
                engine.prepare(&problem, Some(&xi)).map(|prepared| {
                    let state = engine.cold_start(&prepared);
                    engine.run_until(&prepared, state, deadline)
                })
            };
            timings.filter_us = us(t.elapsed());
            if let Ok(outcome) = outcome {
                // A failed warm start's iterations count; a kept one's are
                // counted with the plan below.
                if outcome.stop == Stop::IterationCap {
                    iterations += outcome.iterations;
                } else {
                    warm_result = Some(outcome);
                }
            }
        }
        let learned = match warm_result {
            None => self.learned_plan(&problem, deadline, &mut timings),
            Some(_) => None,
        };
        let (outcome, warm) = match (warm_result, learned) {
            (Some(o), _) => (o, true),
            (None, Some(o)) => (o, false),
            (None, None) => {
                let t = Instant::now();
                let outcome = {
                    let _span = info_span!("optimise").entered();
                    let engine = &self.optimisers[obstacles];
                    engine
                        .prepare(&problem, None)
                        .map(|prepared| engine.solve_prepared_until(&prepared, Some(deadline)))
                };
                timings.optimise_us = us(t.elapsed());
                match outcome {
                    Ok(o) => (o, false),
                    Err(_) => {
                        let mut failed =
                            Planned::rejected(Rejection { reason: Reason::Solver, index: u32::MAX }, timings);
                        failed.status = PlanStatus::NoPlan;
                        return failed;
                    }
                }
            }
        };
        iterations += outcome.iterations;
        self.finish(outcome, warm, iterations, problem, snapshot.timestamp_ns, timings)
    }

    /// A cold plan from the learned pipeline, if the team has one and its
    /// plan verifies (or the deadline stopped it).
    fn learned_plan(&mut self, problem: &Problem, deadline: Instant, timings: &mut StageTimings) -> Option<AmOutcome> {
        let Learned { model, settings, filters } = self.learned.as_ref()?;
        self.cold_plans += 1;
        let _span = info_span!("learned").entered();
        let sf = &filters[problem.obstacles.len()];
        let out = model.plan(problem, sf, settings, self.cold_plans, Some(deadline)).ok()?;
        let us_of = |ms: f64| (ms * 1e3).clamp(0.0, u32::MAX as f64) as u32;
        timings.sample_us = us_of(out.times.sample_ms).max(1);
        timings.rank_us = us_of(out.times.rank_ms);
        timings.init_us = us_of(out.times.init_ms);
        timings.filter_us = timings.filter_us.saturating_add(us_of(out.times.filter_ms));
        timings.select_us = us_of(out.times.select_ms);
        let chosen = out.refined.into_iter().nth(out.chosen)?;
        matches!(chosen.outcome.stop, Stop::Verified | Stop::Deadline).then_some(chosen.outcome)
    }

    fn finish(
        &mut self,
        outcome: AmOutcome,
        warm: bool,
        iterations: usize,
        problem: Problem,
        origin_ns: u64,
        timings: StageTimings,
    ) -> Planned {
        let status = match outcome.stop {
            Stop::Verified | Stop::Tolerance => PlanStatus::Ok,
            Stop::IterationCap => PlanStatus::Degraded,
            Stop::Deadline => PlanStatus::DeadlineMissed,
        };
        let plan = JointPlan::new(&self.team, outcome.state.xi);
        let smoothness = plan.smoothness(self.team.samples);
        self.previous =
            Some(Previous { plan: plan.clone(), origin_ns, goals: problem.goals, obstacles: problem.obstacles.len() });
        Planned {
            status,
            rejection: None,
            plan: Some(plan),
            primal: outcome.primal,
            smoothness,
            iterations,
            warm,
            timings,
        }
    }

    /// The previous plan, if the new problem can be warm-started from it.
    fn warm_candidate(&self, problem: &Problem, origin_ns: u64) -> Option<&Previous> {
        let p = self.previous.as_ref()?;
        let same_goals = p.goals.iter().zip(&problem.goals).all(|(a, b)| (a - b).norm() <= SAME_GOAL);
        let fresh = origin_ns >= p.origin_ns;
        (same_goals && fresh && p.obstacles == problem.obstacles.len()).then_some(p)
    }

    /// The previous plan shifted to start at `origin_ns` and fitted under
    /// the new boundary conditions, which take their start accelerations
    /// from it (written into `problem`).
    fn shifted(&self, previous: &Previous, problem: &mut Problem, origin_ns: u64) -> Vec<f64> {
        let team = &self.team;
        let (axes, n, nx, k) = (team.dim.axes(), team.robots, team.degree + 1, team.samples);
        let dt = (origin_ns - previous.origin_ns) as f64 * 1e-9;
        for (s, kin) in problem.starts.iter_mut().zip(previous.plan.at(dt)) {
            s.acceleration = kin.acceleration;
        }
        let mut series = vec![vec![0.0; k]; axes * n];
        for s in 0..k {
            let t = dt + team.horizon * s as f64 / (k - 1) as f64;
            for (i, kin) in previous.plan.at(t).iter().enumerate() {
                for a in 0..axes {
                    series[a * n + i][s] = kin.position[a];
                }
            }
        }
        let mut xi = vec![0.0; axes * n * nx];
        let boundary = problem.boundary_values();
        for (row, b) in boundary.chunks_exact(BOUNDARY_ROWS).enumerate() {
            self.fitter.fit(&series[row], b, &mut xi[row * nx..(row + 1) * nx]);
        }
        xi
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::metrics::Metrics;
    use flowopt_planner::problem::Dim;
    use flowopt_planner::scenario::RandomScenario;

    fn config(robots: usize, deadline_ms: f64) -> TeamConfig {
        let text = format!(
            "name = \"t\"\ndim = 2\nrobots = {robots}\nrobot = {{ radius = 0.1 }}\n\
             workspace = {{ min = [-1.0, -1.0], max = [1.0, 1.0] }}\nmax_obstacles = 2\ndeadline_ms = {deadline_ms}\n"
        );
        toml::from_str(&text).unwrap()
    }

    fn snapshot(problem: &Problem, timestamp_ns: u64) -> StateSnapshot {
        let mut s = StateSnapshot::new();
        s.set_team("t").unwrap();
        s.dim = 2;
        s.robots = problem.robots() as u32;
        s.timestamp_ns = timestamp_ns;
        for (i, r) in s.robot.iter_mut().take(problem.robots()).enumerate() {
            r.position = problem.starts[i].position.into();
            r.velocity = problem.starts[i].velocity.into();
            r.goal = problem.goals[i].into();
        }
        s
    }

    #[test]
    fn the_learned_config_preloads_the_shipped_weights_and_plans_cold_with_them() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let config = crate::config::DaemonConfig::load(&root.join("config/learned.toml")).unwrap();
        let mut team = config.teams[0].clone();
        team.name = "t".into();
        team.deadline_ms = 10_000.0;
        let learned = team.learned.as_mut().unwrap();
        learned.flow = root.join(&learned.flow);
        learned.init = learned.init.as_ref().map(|p| root.join(p));
        let mut planner = TeamPlanner::preload(&team).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
        let planned = planner.plan(&snapshot(&problem, 1), Instant::now());
        assert_eq!(planned.status, PlanStatus::Ok);
        assert!(!planned.warm && planned.timings.sample_us > 0, "the pipeline made the cold plan");
        let m = Metrics::measure(&problem, planned.plan.as_ref().unwrap());
        assert!(m.success(planner.team().separation().0));
        // Weights for another dimension are refused at preload.
        let mut three = team.clone();
        three.dim = Dim::Three;
        three.robot = toml::from_str("radius = 0.1").unwrap();
        three.workspace = toml::from_str("min = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]").unwrap();
        assert!(matches!(TeamPlanner::preload(&three), Err(PreloadError::Model(_))));
    }

    #[test]
    fn a_cold_plan_then_a_warm_replan_along_it_are_both_verified() {
        let mut planner = TeamPlanner::preload(&config(8, 1000.0)).unwrap();
        let problem = RandomScenario::new(Team::default_for(Dim::Two, 8)).generate(11).unwrap();
        let first = planner.plan(&snapshot(&problem, 1_000_000_000), Instant::now());
        assert_eq!((first.status, first.warm), (PlanStatus::Ok, false));
        let plan = first.plan.unwrap();
        assert!(Metrics::measure(&problem, &plan).success(problem.team.separation().0));

        // The robots followed the plan for 0.4 s.
        let mut moved = problem.clone();
        for (s, k) in moved.starts.iter_mut().zip(plan.at(0.4)) {
            s.position = k.position;
            s.velocity = k.velocity;
        }
        let second = planner.plan(&snapshot(&moved, 1_400_000_000), Instant::now());
        assert_eq!((second.status, second.warm), (PlanStatus::Ok, true));
        moved.starts.iter_mut().zip(plan.at(0.4)).for_each(|(s, k)| s.acceleration = k.acceleration);
        let m = Metrics::measure(&moved, &second.plan.unwrap());
        assert!(m.success(problem.team.separation().0), "{m:?}");
        assert!(second.iterations < 100, "warm replans stay cheap: {}", second.iterations);
    }

    #[test]
    fn changed_goals_get_a_cold_plan_and_bad_input_a_rejection() {
        let mut planner = TeamPlanner::preload(&config(4, 1000.0)).unwrap();
        let scenario = RandomScenario::new(Team::default_for(Dim::Two, 4));
        let a = scenario.generate(1).unwrap();
        assert!(planner.plan(&snapshot(&a, 10), Instant::now()).plan.is_some());
        let mut b = a.clone();
        b.goals.swap(0, 1);
        let replanned = planner.plan(&snapshot(&b, 20), Instant::now());
        assert_eq!((replanned.status, replanned.warm), (PlanStatus::Ok, false));
        let mut bad = snapshot(&b, 30);
        bad.robot[0].goal[0] = f64::NAN;
        let rejected = planner.plan(&bad, Instant::now());
        assert_eq!(rejected.status, PlanStatus::RejectedInput);
        assert_eq!(rejected.rejection.unwrap().reason, Reason::NonFinite);
        assert!(planner.last_plan().is_some(), "a rejection keeps the last plan");
    }

    #[test]
    fn a_passed_deadline_publishes_the_best_iterate_as_missed() {
        let mut planner = TeamPlanner::preload(&config(16, 1000.0)).unwrap();
        let problem = RandomScenario::new(Team::default_for(Dim::Two, 16)).generate(5).unwrap();
        let long_ago = Instant::now() - Duration::from_secs(5);
        let late = planner.plan(&snapshot(&problem, 10), long_ago);
        assert_eq!(late.status, PlanStatus::DeadlineMissed);
        assert!(late.plan.is_some());
    }
}
