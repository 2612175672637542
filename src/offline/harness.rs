//! What `solve`, `bench` and `eval` measure of a plan: the planners of
//! `flowopt_methods` (built once per method and team), the plan's
//! [`Record`] (success, time, quality), and the untimed residual study of
//! the run that made it.

use anyhow::{Context, Result};
use flowopt_methods::build::{self, learned};
use flowopt_methods::{Method, Planned, Planner, PlannerSettings, Stages};
use flowopt_models::pipeline::{LearnedPipeline, PipelineOutcome, Query};
use flowopt_planner::am::{AmSettings, AmState, Budget, EngineSet, Objective, Prepared, Residuals, Stop};
use flowopt_planner::metrics::Metrics;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Dim, Problem, Team};
use serde::Serialize;

/// Cap of the residual studies' iterations.
const STUDY_CAP: usize = 10_000;

/// What one planning run produced and cost.
#[derive(Debug, Clone, Serialize)]
pub struct Record {
    /// Every constraint holds on the dense re-sampling (see `Metrics::success`).
    pub success: bool,
    /// AM iterations of the run that made the plan.
    pub iterations: usize,
    /// Wall time of the planner (ms; a race: to the winner).
    pub time_ms: f64,
    /// Mean over robots of the sum of squared accelerations.
    pub smoothness: f64,
    /// Mean path length (m).
    pub arc_length: f64,
    /// Smallest robot-robot or robot-obstacle surface gap (m).
    pub min_clearance: f64,
    /// Largest acceleration of the plan on the dense re-sampling (m/s^2).
    pub max_acceleration: f64,
    /// Primal residual of the returned plan (m).
    pub primal_residual: f64,
    /// Why the AM stopped.
    pub stop: Stop,
    /// Iterations of the same start (the baseline's cold start, the SF
    /// method's sample, or the chosen candidate's SF start) until the
    /// primal residual is at or below 0.01 m, in a separate untimed
    /// residual study (`None`: not within its cap).
    pub iterations_to_0_01: Option<usize>,
    /// The same to 0.001 m.
    pub iterations_to_0_001: Option<usize>,
    /// Stage times of a learned plan (ms).
    pub stages: Option<StageMs>,
    /// The planner that made it.
    pub by: &'static str,
    /// The returned plan's coefficients.
    #[serde(skip)]
    pub xi: Vec<f64>,
    /// Residuals of every iterate of the untimed residual study.
    #[serde(skip)]
    pub study: Vec<Residuals>,
}

/// A learned plan's stage times in ms, as reports print them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageMs {
    /// Encoding, noise and flow integration.
    pub sample_ms: f64,
    /// Decoding, rerouting and ranking.
    pub rank_ms: f64,
    /// The initialiser.
    pub init_ms: f64,
    /// The safety filter.
    pub filter_ms: f64,
    /// Selection.
    pub select_ms: f64,
    /// All of them.
    pub total_ms: f64,
}

impl From<Stages> for StageMs {
    fn from(s: Stages) -> Self {
        let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
        Self {
            sample_ms: ms(s.sample),
            rank_ms: ms(s.rank),
            init_ms: ms(s.init),
            filter_ms: ms(s.filter),
            select_ms: ms(s.select),
            total_ms: ms(s.total()),
        }
    }
}

/// The planners of a run, built once per (method, team), and the residual
/// studies' engines.
pub struct Harness {
    settings: PlannerSettings,
    no_study: bool,
    planners: Vec<(Method, Team, Box<dyn Planner>)>,
    pipelines: Vec<(Method, Dim, LearnedPipeline)>,
    studies: Vec<EngineSet>,
    /// Methods whose `auto` fallback was reported.
    said_alone: bool,
}

impl Harness {
    /// Planners of `settings` (its `method` is the default method);
    /// without the residual study if `no_study`.
    pub fn new(settings: PlannerSettings, no_study: bool) -> Self {
        Self { settings, no_study, planners: Vec::new(), pipelines: Vec::new(), studies: Vec::new(), said_alone: false }
    }

    /// The settings of `method`.
    fn with(&self, method: Method) -> PlannerSettings {
        PlannerSettings { method, ..self.settings.clone() }
    }

    /// The planner of `method` for `team`, built on first use, with the
    /// engines for `obstacles` ready.
    fn planner(&mut self, method: Method, team: &Team, obstacles: usize) -> Result<&mut Box<dyn Planner>> {
        let index = match self.planners.iter().position(|(m, t, _)| *m == method && t == team) {
            Some(i) => i,
            None => {
                let settings = self.with(method);
                let (mut members, alone) = build::members(&settings, team)?;
                if let Some(why) = alone.filter(|_| !self.said_alone) {
                    eprintln!("auto: the optimiser plans alone: {why}");
                    self.said_alone = true;
                }
                let planner = match members.len() {
                    1 => members.remove(0),
                    _ => Box::new(flowopt_methods::Race::start(method.name(), members, None, || {})),
                };
                self.planners.push((method, team.clone(), planner));
                self.planners.len() - 1
            }
        };
        let planner = &mut self.planners[index].2;
        planner.ready(team, obstacles)?;
        Ok(planner)
    }

    /// The learned pipeline of `method` for teams of `dim`, loaded on first
    /// use.
    pub fn pipeline(&mut self, method: Method, dim: Dim) -> Result<&mut LearnedPipeline> {
        let index = match self.pipelines.iter().position(|(m, d, _)| *m == method && *d == dim) {
            Some(i) => i,
            None => {
                let pipeline = learned(&self.with(method), method, dim).context("loading the learned pipeline")?;
                self.pipelines.push((method, dim, pipeline));
                self.pipelines.len() - 1
            }
        };
        Ok(&mut self.pipelines[index].2)
    }

    /// Why the learned methods cannot plan for `team` (no weights, or
    /// weights for another dimension or basis), or `None` if they can.
    pub fn learned_unavailable(&mut self, team: &Team) -> Option<String> {
        match self.pipeline(Method::FlowNoInit, team.dim) {
            Err(e) => Some(format!("{e:#}")),
            Ok(p) => p.planner().model().check(team).err().map(|e| e.to_string()),
        }
    }

    /// Plans `problem` with `method`, timing the planner; the residual
    /// study starts from the same point as the timed run.
    pub fn run(&mut self, method: Method, problem: &Problem, seed: u64) -> Result<Record> {
        self.run_hiding(method, problem, 0, seed)
    }

    /// [`Harness::run`] with the problem's last `hidden` obstacles hidden
    /// from the learned methods' networks (the robustness study; the
    /// optimiser sees everything).
    pub fn run_hiding(&mut self, method: Method, problem: &Problem, hidden: usize, seed: u64) -> Result<Record> {
        if hidden > 0 && matches!(method, Method::Flowopt | Method::FlowNoInit) {
            let (mut outcomes, ms) = self.plan_learned_batch(method, std::slice::from_ref(problem), hidden, seed)?;
            let out = outcomes.pop().context("the pipeline returned no plan")?;
            let chosen = &out.refined[out.chosen];
            let study = self.study(problem, Some((&chosen.prepared, &chosen.start)))?;
            let outcome = &chosen.outcome;
            let plan = JointPlan::new(&problem.team, outcome.state.xi.clone());
            let run = (outcome.stop, outcome.primal, outcome.iterations, ms);
            return Ok(Record::of(problem, plan, run, study, Some(out.stages.into()), "learned"));
        }
        let planner = self.planner(method, &problem.team, problem.obstacles.len())?;
        let planned: Planned = planner.plan(problem, &Budget::unlimited(), seed)?;
        let start = planned.start.as_deref().map(|(p, s)| (p, s));
        let study = self.study(problem, start)?;
        let stages = (planned.by == "learned").then(|| planned.stages.into());
        let run = (planned.stop, planned.primal, planned.run_iterations, planned.wall.as_secs_f64() * 1e3);
        Ok(Record::of(problem, planned.plan, run, study, stages, planned.by))
    }

    /// Plans `problems` (one team shape and obstacle count) together with a
    /// learned method, hiding each problem's last `hidden` obstacles from
    /// the networks (the safety filter still enforces them); returns the
    /// outcomes and the batch's wall time (ms).
    pub fn plan_learned_batch(
        &mut self,
        method: Method,
        problems: &[Problem],
        hidden: usize,
        seed: u64,
    ) -> Result<(Vec<PipelineOutcome>, f64)> {
        let Some(first) = problems.first() else { return Ok((Vec::new(), 0.0)) };
        let obstacles = first.obstacles.len();
        anyhow::ensure!(hidden <= obstacles, "cannot hide {hidden} of {obstacles} obstacles");
        let pipeline = self.pipeline(method, first.team.dim)?;
        pipeline.filter(&first.team, obstacles)?;
        let seen: Vec<Problem> = problems
            .iter()
            .map(|p| {
                let mut seen = p.clone();
                seen.obstacles.truncate(obstacles - hidden);
                seen
            })
            .collect();
        let queries: Vec<Query<'_>> =
            seen.iter().zip(problems).map(|(seen, enforced)| Query { seen, enforced }).collect();
        let start = std::time::Instant::now();
        let outcomes = pipeline.plan_batch(&queries, &Budget::unlimited(), seed).context("running the pipeline")?;
        Ok((outcomes, start.elapsed().as_secs_f64() * 1e3))
    }

    /// The untimed residual study: from `from` (the run's prepared problem
    /// and start) with the safety filter's study engine, else from the cold
    /// start of `problem` with the optimiser's. Empty without the study.
    fn study(&mut self, problem: &Problem, from: Option<(&Prepared, &AmState)>) -> Result<Vec<Residuals>> {
        if self.no_study {
            return Ok(Vec::new());
        }
        let (objective, base) = match from {
            Some(_) => (Objective::filter(self.settings.learned.sf_smoothing), self.settings.filter),
            None => (Objective::smoothness(), self.settings.optimiser()),
        };
        let settings = AmSettings { max_iterations: STUDY_CAP, restarts: 0, ..base.residual_study(0.001) };
        let team = &problem.team;
        let index = match self.studies.iter().position(|s| s.is_for(team, objective, &settings)) {
            Some(i) => i,
            None => {
                self.studies.push(EngineSet::new(team, objective, settings));
                self.studies.len() - 1
            }
        };
        let engine = self.studies[index].engine(problem.obstacles.len()).context("building the study engine")?;
        Ok(match from {
            Some((prepared, start)) => engine.run(prepared, start.clone()).history,
            None => {
                let prepared = engine.prepare(problem, None).context("preparing the residual study")?;
                engine.run(&prepared, engine.cold_start(&prepared)).history
            }
        })
    }
}

impl Record {
    /// The record of `plan` for `problem`, made by a run that ended
    /// `(stop, primal, iterations, time_ms)`.
    fn of(
        problem: &Problem,
        plan: JointPlan,
        (stop, primal, iterations, time_ms): (Stop, f64, usize, f64),
        study: Vec<Residuals>,
        stages: Option<StageMs>,
        by: &'static str,
    ) -> Self {
        let metrics = Metrics::measure(problem, &plan);
        let first_below = |level: f64| study.iter().position(|r| r.primal <= level);
        Record {
            success: metrics.success(problem.team.separation().0),
            iterations,
            time_ms,
            smoothness: metrics.smoothness,
            arc_length: metrics.arc_length,
            min_clearance: metrics.min_clearance(),
            max_acceleration: metrics.max_acceleration,
            primal_residual: primal,
            stop,
            iterations_to_0_01: first_below(0.01),
            iterations_to_0_001: first_below(0.001),
            stages,
            by,
            xi: plan.coeffs,
            study,
        }
    }
}

/// Root-mean-square distance (m) between the positions of two plans of
/// one team over `samples` instants.
pub fn plan_distance(team: &Team, a: &[f64], b: &[f64]) -> f64 {
    let pa = JointPlan::new(team, a.to_vec()).sampled(team.samples, 0);
    let pb = JointPlan::new(team, b.to_vec()).sampled(team.samples, 0);
    let sq: f64 = pa.iter().zip(&pb).map(|(x, y)| (x - y) * (x - y)).sum();
    (sq / (team.robots * team.samples) as f64).sqrt()
}
