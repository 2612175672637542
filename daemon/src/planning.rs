//! One team's planner: every problem (a validated snapshot) is planned
//! from its own measured state, warm-started from the previous plan when
//! the goals are unchanged and cold otherwise, within a deadline. It knows
//! nothing of the wire: the daemon's worker converts snapshots into
//! problems and writes the replies.
//!
//! - **Warm start.** The previous plan, shifted by the time between the two
//!   snapshots ([`JointPlan::shifted`]), is the safety filter's sample; a
//!   verified result is the plan.
//! - **Cold plan.** When the goals or the obstacle count change, there is no
//!   previous plan, or the filter does not verify within its cap, the
//!   learned planner ([`flowopt_models::pipeline`], when the team has
//!   weights) plans from the measured state; if it has none or its plan does
//!   not verify, the from-scratch optimiser does.
//! - **Deadline.** Both stop when the deadline passes; the best iterate so far
//!   is returned as [`Verdict::DeadlineMissed`] and the next problem is
//!   warm-started from it.

use std::time::{Duration, Instant};

use flowopt_models::pipeline::{LearnedPlanner, PipelineSettings};
use flowopt_planner::am::{AmOutcome, AmSettings, Engine, EngineError, EngineSet, Objective, Stop};
use flowopt_planner::metrics::DENSE_FACTOR;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Problem, Team};
use flowopt_planner::route::Fitter;
use nalgebra::Vector3;
use thiserror::Error;
use tracing::info_span;

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

/// Why a valid problem got no plan.
#[derive(Debug, Error)]
pub enum PlanError {
    /// The optimiser refused the problem.
    #[error("PlanError::Solver: {0}")]
    Solver(#[from] EngineError),
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

/// How far a plan got.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Verified collision-free on the dense grid with the tracking buffer.
    Verified,
    /// The solver's best iterate after its iteration cap: not verified.
    IterationCap,
    /// The deadline passed: the best iterate so far, not verified.
    DeadlineMissed,
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
    /// The safety filter (warm start and learned candidates).
    pub filter: Duration,
    /// The from-scratch optimiser.
    pub optimise: Duration,
    /// Choosing among refined candidates.
    pub select: Duration,
}

/// A plan made for one problem.
#[derive(Debug, Clone)]
pub struct Planned {
    /// The plan, starting at the problem's time origin.
    pub plan: JointPlan,
    /// How far it got.
    pub verdict: Verdict,
    /// Its primal residual (m).
    pub primal: f64,
    /// Its smoothness.
    pub smoothness: f64,
    /// Iterations spent (failed warm starts included).
    pub iterations: usize,
    /// Whether it came from the warm start.
    pub warm: bool,
    /// Candidates the safety filter refined (1 for warm starts and the
    /// optimiser).
    pub candidates: usize,
}

/// The plan the next problem is warm-started from.
#[derive(Debug, Clone)]
struct Previous {
    plan: JointPlan,
    origin_ns: u64,
    goals: Vec<Vector3<f64>>,
    obstacles: usize,
}

/// A team's learned planner with its pipeline settings and safety filters.
#[derive(Debug)]
struct Learned {
    planner: LearnedPlanner,
    settings: PipelineSettings,
    filters: EngineSet,
}

/// A team's preloaded engines and its planning state.
#[derive(Debug)]
pub struct TeamPlanner {
    team: Team,
    deadline: Duration,
    /// From-scratch optimisers, one per obstacle count.
    optimisers: EngineSet,
    /// Safety filters, one per obstacle count.
    filters: EngineSet,
    fitter: Fitter,
    /// The learned planner, if configured.
    learned: Option<Learned>,
    /// Cold plans made so far (seeds the flow noise).
    cold_plans: u64,
    previous: Option<Previous>,
}

/// The engine of `set` for `obstacles` obstacles, which the configuration
/// admitted and the preload built.
fn preloaded(set: &EngineSet, obstacles: usize) -> Result<&Engine, EngineError> {
    set.get(obstacles).ok_or_else(|| EngineError::ShapeMismatch {
        expected: "at most the configured obstacles".into(),
        got: format!("{obstacles} obstacles"),
    })
}

impl TeamPlanner {
    /// Builds every engine (basis, sample grids, KKT factorisations) the
    /// team can need, so that no problem waits for one.
    pub fn preload(config: &TeamConfig) -> Result<Self, PreloadError> {
        let team = config.team()?;
        let buffered = |s: AmSettings| AmSettings { verify_margin: TRACKING_BUFFER, verify_skip: DENSE_FACTOR, ..s };
        let optimisers = EngineSet::preloaded(
            &team,
            Objective::smoothness(),
            buffered(AmSettings::optimiser()),
            config.max_obstacles,
        )?;
        let filter_settings = buffered(AmSettings { max_iterations: WARM_ITERATIONS, ..AmSettings::safety_filter() });
        let filters = EngineSet::preloaded(&team, Objective::Projection, filter_settings, config.max_obstacles)?;
        let basis = team.basis().map_err(|e| EngineError::Problem(e.into()))?;
        let fitter = Fitter::new(&basis).map_err(EngineError::Kkt)?;
        let learned = match &config.learned {
            Some(l) => {
                let planner = LearnedPlanner::load(&l.flow, l.init.as_deref(), l.sf_smoothing)?;
                let filters = planner.filters(&team, filter_settings, config.max_obstacles)?;
                let settings = PipelineSettings {
                    candidates: l.candidates,
                    steps: l.flow_steps,
                    top_k: l.top_k,
                    use_init: planner.model().has_init(),
                    ..PipelineSettings::default()
                };
                Some(Learned { planner, settings, filters })
            }
            None => None,
        };
        Ok(Self {
            team,
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

    /// The time a plan may take from the arrival of its snapshot.
    pub fn deadline(&self) -> Duration {
        self.deadline
    }

    /// The last plan made, if any, with its time origin (ns).
    pub fn last_plan(&self) -> Option<(&JointPlan, u64)> {
        self.previous.as_ref().map(|p| (&p.plan, p.origin_ns))
    }

    /// Plans `problem` (validated, of this team), measured at `origin_ns`,
    /// stopping at `deadline`; records the stages' times in `stages`.
    pub fn plan(
        &mut self,
        mut problem: Problem,
        origin_ns: u64,
        deadline: Instant,
        stages: &mut Stages,
    ) -> Result<Planned, PlanError> {
        let obstacles = problem.obstacles.len();
        let mut iterations = 0;
        let mut warm_result = None;
        if let Some(previous) = self.warm_candidate(&problem, origin_ns) {
            let t = Instant::now();
            let xi = {
                let _span = info_span!("warm_start").entered();
                let dt = (origin_ns - previous.origin_ns) as f64 * 1e-9;
                previous.plan.shifted(dt, &mut problem, &self.fitter)
            };
            stages.warm_start = t.elapsed();
            let t = Instant::now();
            let outcome = {
                let _span = info_span!("filter").entered();
                let engine = preloaded(&self.filters, obstacles)?;
                engine.prepare(&problem, Some(&xi)).map(|prepared| {
                    let state = engine.cold_start(&prepared);
                    engine.run_until(&prepared, state, deadline)
                })
            };
            stages.filter = t.elapsed();
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
            None => self.learned_plan(&problem, deadline, stages),
            Some(_) => None,
        };
        let (outcome, warm, candidates) = match (warm_result, learned) {
            (Some(o), _) => (o, true, 1),
            (None, Some((o, refined))) => (o, false, refined),
            (None, None) => {
                let t = Instant::now();
                let outcome = {
                    let _span = info_span!("optimise").entered();
                    let engine = preloaded(&self.optimisers, obstacles)?;
                    engine
                        .prepare(&problem, None)
                        .map(|prepared| engine.solve_prepared_until(&prepared, Some(deadline)))
                };
                stages.optimise = t.elapsed();
                (outcome?, false, 1)
            }
        };
        iterations += outcome.iterations;
        Ok(self.finish(outcome, warm, candidates, iterations, problem, origin_ns))
    }

    /// A cold plan from the learned pipeline, if the team has one and its
    /// plan verifies (or the deadline stopped it), with the number of
    /// candidates refined.
    fn learned_plan(
        &mut self,
        problem: &Problem,
        deadline: Instant,
        stages: &mut Stages,
    ) -> Option<(AmOutcome, usize)> {
        let Learned { planner, settings, filters } = self.learned.as_ref()?;
        self.cold_plans += 1;
        let _span = info_span!("learned").entered();
        let sf = filters.get(problem.obstacles.len())?;
        let out = planner.model().plan(problem, sf, settings, self.cold_plans, Some(deadline)).ok()?;
        let duration = |ms: f64| Duration::from_secs_f64((ms * 1e-3).max(0.0));
        stages.sample = duration(out.times.sample_ms);
        stages.rank = duration(out.times.rank_ms);
        stages.init = duration(out.times.init_ms);
        stages.filter += duration(out.times.filter_ms);
        stages.select = duration(out.times.select_ms);
        let refined = out.refined.len();
        let chosen = out.refined.into_iter().nth(out.chosen)?;
        matches!(chosen.outcome.stop, Stop::Verified | Stop::Deadline).then_some((chosen.outcome, refined))
    }

    fn finish(
        &mut self,
        outcome: AmOutcome,
        warm: bool,
        candidates: usize,
        iterations: usize,
        problem: Problem,
        origin_ns: u64,
    ) -> Planned {
        let verdict = match outcome.stop {
            Stop::Verified | Stop::Tolerance => Verdict::Verified,
            Stop::IterationCap => Verdict::IterationCap,
            Stop::Deadline => Verdict::DeadlineMissed,
        };
        let plan = JointPlan::new(&self.team, outcome.state.xi);
        let smoothness = plan.smoothness(self.team.samples);
        self.previous =
            Some(Previous { plan: plan.clone(), origin_ns, goals: problem.goals, obstacles: problem.obstacles.len() });
        Planned { plan, verdict, primal: outcome.primal, smoothness, iterations, warm, candidates }
    }

    /// The previous plan, if the new problem can be warm-started from it.
    fn warm_candidate(&self, problem: &Problem, origin_ns: u64) -> Option<&Previous> {
        let p = self.previous.as_ref()?;
        let same_goals = p.goals.iter().zip(&problem.goals).all(|(a, b)| (a - b).norm() <= SAME_GOAL);
        let fresh = origin_ns >= p.origin_ns;
        (same_goals && fresh && p.obstacles == problem.obstacles.len()).then_some(p)
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

    /// Plans `problem`, measured at `origin_ns`, with the deadline running
    /// from `received`.
    fn plan(planner: &mut TeamPlanner, problem: &Problem, origin_ns: u64, received: Instant) -> (Planned, Stages) {
        let mut stages = Stages::default();
        let deadline = received + planner.deadline();
        let planned = planner.plan(problem.clone(), origin_ns, deadline, &mut stages).unwrap();
        (planned, stages)
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
        let top_k = learned.top_k;
        let mut planner = TeamPlanner::preload(&team).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
        let (planned, stages) = plan(&mut planner, &problem, 1, Instant::now());
        assert_eq!(planned.verdict, Verdict::Verified);
        assert!(!planned.warm && stages.sample > Duration::ZERO, "the pipeline made the cold plan");
        assert_eq!(planned.candidates, top_k, "every refined candidate is counted");
        let m = Metrics::measure(&problem, &planned.plan);
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
        let problem = RandomScenario::new(planner.team().clone()).generate(11).unwrap();
        let (first, _) = plan(&mut planner, &problem, 1_000_000_000, Instant::now());
        assert_eq!((first.verdict, first.warm), (Verdict::Verified, false));
        let plan0 = first.plan;
        assert!(Metrics::measure(&problem, &plan0).success(problem.team.separation().0));

        // The robots followed the plan for 0.4 s.
        let mut moved = problem.clone();
        for (s, k) in moved.starts.iter_mut().zip(plan0.at(0.4)) {
            s.position = k.position;
            s.velocity = k.velocity;
        }
        let (second, _) = plan(&mut planner, &moved, 1_400_000_000, Instant::now());
        assert_eq!((second.verdict, second.warm), (Verdict::Verified, true));
        moved.starts.iter_mut().zip(plan0.at(0.4)).for_each(|(s, k)| s.acceleration = k.acceleration);
        let m = Metrics::measure(&moved, &second.plan);
        assert!(m.success(problem.team.separation().0), "{m:?}");
        assert!(second.iterations < 100, "warm replans stay cheap: {}", second.iterations);
    }

    #[test]
    fn changed_goals_get_a_cold_plan() {
        let mut planner = TeamPlanner::preload(&config(4, 1000.0)).unwrap();
        let scenario = RandomScenario::new(planner.team().clone());
        let a = scenario.generate(1).unwrap();
        plan(&mut planner, &a, 10, Instant::now());
        let mut b = a.clone();
        b.goals.swap(0, 1);
        let (replanned, _) = plan(&mut planner, &b, 20, Instant::now());
        assert_eq!((replanned.verdict, replanned.warm), (Verdict::Verified, false));
        assert!(planner.last_plan().is_some());
    }

    #[test]
    fn a_passed_deadline_returns_the_best_iterate_as_missed() {
        let mut planner = TeamPlanner::preload(&config(16, 1000.0)).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(5).unwrap();
        let long_ago = Instant::now() - Duration::from_secs(5);
        let (late, _) = plan(&mut planner, &problem, 10, long_ago);
        assert_eq!(late.verdict, Verdict::DeadlineMissed);
    }
}
