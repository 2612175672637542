//! The planning methods the CLI can run and time on one instance.

use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::ValueEnum;
use std::path::PathBuf;

use flowopt_models::flow::Solver;
use flowopt_models::pipeline::{LearnedPlanner, PipelineOutcome, PipelineSettings, PipelineTimes, Query, Settle};
use flowopt_models::shipped::Weights;
use flowopt_planner::am::{
    AmOutcome, AmSettings, AmState, Budget, Engine, EngineSet, Objective, Prepared, Residuals, Stop,
};
use flowopt_planner::metrics::Metrics;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Dim, Problem, Team};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// A planning method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The optimiser and the learned pipeline raced on the two cores: the
    /// first verified plan wins and the other is cancelled (the optimiser
    /// alone for teams over 32 robots, or where the learned planner has no
    /// weights for the team). The pipeline races without the initialiser,
    /// as the daemon's shipped configurations plan: the SF does as well or
    /// better started from the samples (docs/LEARNED.md, "Teaching the
    /// policy obstacles").
    Auto,
    /// The from-scratch AM optimiser (smoothness cost, cold start).
    Baseline,
    /// The safety filter projecting the baseline's solution perturbed by
    /// uniform noise of 10% of the separation on every coefficient (timed:
    /// the SF alone).
    SafetyFilter,
    /// The Flow-Opt pipeline: flow samples, ranking, learned SF
    /// initialisation (where there are obstacles; `--init-without-obstacles`
    /// everywhere), safety filter, selection.
    Flowopt,
    /// The pipeline with the SF started from the flow samples themselves
    /// (zero multiplier): the paper's ablation.
    FlowNoInit,
}

impl Method {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Method::Auto => "auto",
            Method::Baseline => "baseline",
            Method::SafetyFilter => "safety-filter",
            Method::Flowopt => "flowopt",
            Method::FlowNoInit => "flow-no-init",
        }
    }

    /// Whether it starts the safety filter from the SF initialiser (and so
    /// loads one): the paper's pipeline alone; `auto` races without it,
    /// as the daemon's shipped configurations plan.
    pub fn uses_initialiser(self) -> bool {
        self == Method::Flowopt
    }
}

/// The learned planner's weights and pipeline settings on the command line.
#[derive(Debug, Clone, clap::Args)]
pub struct LearnedArgs {
    /// Flow policy weights [default: the shipped weights for the team's
    /// dimension, models/weights/flow.safetensors in 2D and
    /// models/weights/flow3d.safetensors in 3D].
    #[arg(long)]
    pub flow_weights: Option<PathBuf>,
    /// SF initialiser weights, read by `--method flowopt` only [default: the
    /// shipped ones for the team's dimension, models/weights/init.safetensors
    /// in 2D and models/weights/init3d.safetensors in 3D].
    #[arg(long)]
    pub init_weights: Option<PathBuf>,
    /// Candidates sampled per problem without obstacles.
    #[arg(long, default_value_t = PipelineSettings::default().candidates)]
    pub candidates: usize,
    /// Candidates sampled per problem with obstacles.
    #[arg(long, default_value_t = PipelineSettings::default().obstacle_candidates)]
    pub obstacle_candidates: usize,
    /// Flow integration steps for problems without obstacles.
    #[arg(long, default_value_t = PipelineSettings::default().steps)]
    pub flow_steps: usize,
    /// Flow integration steps for problems with obstacles.
    #[arg(long, default_value_t = PipelineSettings::default().obstacle_steps)]
    pub obstacle_flow_steps: usize,
    /// Flow integrator.
    #[arg(long, value_enum, default_value = "euler")]
    pub solver: SolverArg,
    /// Candidates refined by the safety filter.
    #[arg(long, default_value_t = PipelineSettings::default().top_k)]
    pub top_k: usize,
    /// Most sampling rounds per plan: while no refined candidate of a
    /// round verifies, sample and refine as many again with fresh noise.
    #[arg(long, default_value_t = PipelineSettings::default().rounds)]
    pub rounds: usize,
    /// Scale of the flow's initial noise.
    #[arg(long, default_value_t = 1.0)]
    pub temperature: f64,
    /// Weight of the correction's smoothness in the safety filter's metric
    /// (`Objective::SmoothProjection`; 0 is the paper's plain projection).
    #[arg(long, default_value_t = flowopt_models::pipeline::DEFAULT_SF_SMOOTHING, value_parser = smoothing_weight)]
    pub sf_smoothing: f64,
    /// Leave samples that pass through static obstacles as sampled (no
    /// rerouting of their robots before the safety filter).
    #[arg(long)]
    pub no_reroute: bool,
    /// Threads the pipeline samples and refines on where there are no
    /// obstacles (racing the optimiser, `auto` keeps to one).
    #[arg(long, default_value_t = PipelineSettings::default().threads)]
    pub threads: usize,
    /// Threads the pipeline samples and refines on where there are
    /// obstacles (`auto`: one).
    #[arg(long, default_value_t = PipelineSettings::default().obstacle_threads)]
    pub obstacle_threads: usize,
    /// Start the safety filter from the initialiser on problems without
    /// obstacles too (`--method flowopt`; by default it is used where there
    /// are obstacles).
    #[arg(long)]
    pub init_without_obstacles: bool,
    /// Refine every one of the top-k and return the smoothest verified plan
    /// (the paper's selection), instead of stopping at the best-ranked
    /// candidate that verifies.
    #[arg(long)]
    pub smoothest: bool,
}

/// Flow integrator on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SolverArg {
    /// Explicit Euler.
    Euler,
    /// Explicit midpoint (RK2).
    Midpoint,
}

/// Parses a safety-filter smoothing weight: a finite number, 0 or more.
pub fn smoothing_weight(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(w) if w.is_finite() && w >= 0.0 => Ok(w),
        Ok(_) => Err(format!("{text} is not a weight: give a finite number, 0 or more")),
        Err(e) => Err(format!("{text}: {e}")),
    }
}

/// The shipped flow policy's and initialiser's weight files for teams of
/// `dim` (paths from the repository root, for tools that hash the files).
pub fn shipped_weights(dim: Dim) -> (PathBuf, PathBuf) {
    (Weights::shipped_flow(dim).file(), Weights::shipped_init(dim).file())
}

impl LearnedArgs {
    /// The flow policy's and the initialiser's weights for teams of `dim`
    /// (the shipped ones, built in, unless given).
    pub fn weights(&self, dim: Dim) -> (Weights, Weights) {
        let given = |path: &Option<PathBuf>, shipped: Weights| path.clone().map_or(shipped, Weights::File);
        (given(&self.flow_weights, Weights::shipped_flow(dim)), given(&self.init_weights, Weights::shipped_init(dim)))
    }

    /// The safety filter's objective.
    pub fn sf_objective(&self) -> Objective {
        Objective::filter(self.sf_smoothing)
    }

    /// The pipeline settings for `method`.
    pub fn settings(&self, method: Method) -> PipelineSettings {
        PipelineSettings {
            candidates: self.candidates,
            obstacle_candidates: self.obstacle_candidates,
            steps: self.flow_steps,
            obstacle_steps: self.obstacle_flow_steps,
            solver: match self.solver {
                SolverArg::Euler => Solver::Euler,
                SolverArg::Midpoint => Solver::Midpoint,
            },
            top_k: self.top_k,
            temperature: self.temperature,
            use_init: method.uses_initialiser(),
            init_without_obstacles: self.init_without_obstacles,
            // Racing the optimiser, the pipeline refines on one core.
            threads: if method == Method::Auto { 1 } else { self.threads.max(1) },
            obstacle_threads: if method == Method::Auto { 1 } else { self.obstacle_threads.max(1) },
            reroute: !self.no_reroute,
            settle: if self.smoothest { Settle::Smoothest } else { Settle::FirstVerified },
            rounds: self.rounds,
        }
    }
}

/// Overrides of the engine settings from the command line.
#[derive(Debug, Clone, Copy, Default)]
pub struct Overrides {
    /// Iteration cap.
    pub max_iterations: Option<usize>,
    /// Primal tolerance; setting it turns the dense verification off (the
    /// paper's stopping rule).
    pub tolerance: Option<f64>,
    /// Start from the smoothest curves, without routing around obstacles.
    pub straight_start: bool,
    /// Restarts of the optimiser.
    pub restarts: Option<usize>,
    /// No chord inflation between instants.
    pub no_chord: bool,
    /// No broad phase.
    pub all_pairs: bool,
    /// No veering of head-on robots.
    pub no_veer: bool,
    /// The optimiser's pair checks on one thread at every team size.
    pub one_thread: bool,
    /// No untimed residual study.
    pub no_study: bool,
}

impl Overrides {
    fn apply(&self, mut s: AmSettings) -> AmSettings {
        if let Some(cap) = self.max_iterations {
            s.max_iterations = cap;
        }
        if let Some(tol) = self.tolerance {
            s.tolerance = tol;
            s.verify_every = 0;
        }
        if self.straight_start {
            s.routed_start = false;
        }
        if let Some(r) = self.restarts {
            s.restarts = r;
        }
        s.chord &= !self.no_chord;
        s.broad_phase &= !self.all_pairs;
        s.veer &= !self.no_veer;
        s.two_threads &= !self.one_thread;
        s
    }
}

/// What one planning run produced and cost.
#[derive(Debug, Clone, Serialize)]
pub struct Record {
    /// Every constraint holds on the dense re-sampling (see `Metrics::success`).
    pub success: bool,
    /// AM iterations (of the timed stage).
    pub iterations: usize,
    /// Wall time of the timed stage (ms).
    pub time_ms: f64,
    /// Mean over robots of the sum of squared accelerations.
    pub smoothness: f64,
    /// Mean path length (m).
    pub arc_length: f64,
    /// Smallest robot-robot or robot-obstacle surface gap (m).
    pub min_clearance: f64,
    /// Primal residual of the returned plan (m).
    pub primal_residual: f64,
    /// Why the AM stopped.
    pub stop: Stop,
    /// Iterations of the same start (the baseline's cold start, the SF
    /// method's sample, or the chosen candidate's SF start) until the primal residual is at or below 0.01 m, in a
    /// separate untimed residual study (`None`: not within its cap).
    pub iterations_to_0_01: Option<usize>,
    /// The same to 0.001 m.
    pub iterations_to_0_001: Option<usize>,
    /// Pipeline stage times (learned methods).
    pub stages: Option<PipelineTimes>,
    /// The returned plan's coefficients.
    #[serde(skip)]
    pub xi: Vec<f64>,
    /// Residuals of every iterate of the untimed residual study.
    #[serde(skip)]
    pub study: Vec<Residuals>,
}

/// What an engine is used for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Use {
    Optimise,
    Filter,
    /// Residual studies: no verification, primal tolerance 0.001, history.
    StudyOptimise,
    StudyFilter,
}

/// The largest team `auto` races the learned pipeline for (the largest the
/// shipped weights were trained on). Above it the optimiser plans alone:
/// on crowds of 64 robots it won every race (seeds 11-30), and at 128 the
/// racing pipeline slowed it from 182 to 248 ms median (docs/BENCHMARKS.md).
const RACE_MAX_ROBOTS: usize = 32;

/// Cap of the residual studies' iterations.
const STUDY_CAP: usize = 10_000;

/// The first iterate whose primal residual is at or below `level`.
fn first_below(history: &[Residuals], level: f64) -> Option<usize> {
    history.iter().position(|r| r.primal <= level)
}

/// Engines built once per (team, objective, settings) and obstacle count
/// and reused: construction (factorisations) is a start-up cost, not a
/// per-plan one.
pub struct Planner {
    overrides: Overrides,
    learned_args: Option<LearnedArgs>,
    /// The learned planners loaded so far, per workspace dimension.
    learned: Vec<(Dim, LearnedPlanner)>,
    engines: Vec<EngineSet>,
    /// `auto` said once why it planned with the optimiser alone.
    said_alone: bool,
}

impl Planner {
    /// A planner applying `overrides` to the default settings; the learned
    /// methods load their weights from `learned` on first use.
    pub fn new(overrides: Overrides, learned: Option<LearnedArgs>) -> Self {
        Self { overrides, learned_args: learned, learned: Vec::new(), engines: Vec::new(), said_alone: false }
    }

    /// The objective and settings of the engines for `usage`.
    fn configuration(&self, usage: Use) -> (Objective, AmSettings) {
        let filter = self.learned_args.as_ref().map_or(Objective::Projection, LearnedArgs::sf_objective);
        match usage {
            Use::Filter => (filter, self.overrides.apply(AmSettings::safety_filter())),
            Use::Optimise => (Objective::smoothness(), self.overrides.apply(AmSettings::optimiser())),
            Use::StudyFilter | Use::StudyOptimise => {
                let (objective, base) = if usage == Use::StudyFilter {
                    (filter, AmSettings::safety_filter())
                } else {
                    (Objective::smoothness(), AmSettings::optimiser())
                };
                let mut s = base.residual_study(0.001);
                s.max_iterations = STUDY_CAP;
                s.restarts = 0;
                s.chord &= !self.overrides.no_chord;
                s.broad_phase &= !self.overrides.all_pairs;
                (objective, s)
            }
        }
    }

    /// The index of the engine set for `usage` on `team`, with the engine
    /// for `obstacles` built.
    fn engine_set(&mut self, team: &Team, obstacles: usize, usage: Use) -> Result<usize> {
        let (objective, settings) = self.configuration(usage);
        let index = match self.engines.iter().position(|set| set.is_for(team, objective, &settings)) {
            Some(i) => i,
            None => {
                self.engines.push(EngineSet::new(team, objective, settings));
                self.engines.len() - 1
            }
        };
        self.engines[index].engine(obstacles).context("building the AM engine")?;
        Ok(index)
    }

    fn engine(&mut self, team: &Team, obstacles: usize, usage: Use) -> Result<&Engine> {
        let index = self.engine_set(team, obstacles, usage)?;
        self.engines[index].get(obstacles).context("the engine was built")
    }

    /// The untimed residual study with the engine for `usage`: from
    /// `from` (a learned candidate's prepared problem and start) when
    /// given, else from the cold start of `problem` prepared with `sample`.
    /// Empty with `--no-study`.
    fn study(
        &mut self,
        problem: &Problem,
        usage: Use,
        sample: Option<&[f64]>,
        from: Option<(&Prepared, &AmState)>,
    ) -> Result<Vec<Residuals>> {
        if self.overrides.no_study {
            return Ok(Vec::new());
        }
        let engine = self.engine(&problem.team, problem.obstacles.len(), usage)?;
        Ok(match from {
            Some((prepared, start)) => engine.run(prepared, start.clone()).history,
            None => {
                let prepared = engine.prepare(problem, sample).context("preparing the residual study")?;
                engine.run(&prepared, engine.cold_start(&prepared)).history
            }
        })
    }

    /// The learned planner for teams of `dim`, its weights loaded on first
    /// use; with the initialiser (where its file exists) when `init`, for
    /// the methods that use it ([`Method::uses_initialiser`]): the others
    /// neither load nor check it, so a policy trained later plans under
    /// `auto` beside the shipped initialiser of another policy.
    fn load_learned(&mut self, dim: Dim, init: bool) -> Result<&LearnedPlanner> {
        let args = self.learned_args.as_ref().context("no learned-planner weights were given")?;
        let cached = self.learned.iter().position(|(d, l)| *d == dim && (!init || l.model().has_init()));
        let index = match cached {
            Some(i) => i,
            None => {
                let (flow, init_weights) = args.weights(dim);
                let init_weights = init_weights.path().is_none_or(|p| p.exists()).then_some(init_weights);
                let init_weights = init_weights.filter(|_| init);
                let learned = LearnedPlanner::load(&flow, init_weights.as_ref(), args.sf_smoothing)
                    .with_context(|| format!("loading the learned planner from {flow}"))?;
                self.learned.retain(|(d, _)| *d != dim);
                self.learned.push((dim, learned));
                self.learned.len() - 1
            }
        };
        Ok(&self.learned[index].1)
    }

    /// Why the learned methods cannot plan for `team` (no weights, or
    /// weights for another dimension or basis), or `None` if they can.
    pub fn learned_unavailable(&mut self, team: &Team) -> Option<String> {
        match self.load_learned(team.dim, false) {
            Err(e) => Some(format!("{e:#}")),
            Ok(learned) => learned.model().check(team).err().map(|e| e.to_string()),
        }
    }

    /// Plans `problem` with a learned method, its last `hidden` obstacles
    /// hidden from the networks; returns the outcome and the wall time (ms).
    /// `seed` seeds the flow noise.
    pub fn plan_learned(
        &mut self,
        method: Method,
        problem: &Problem,
        hidden: usize,
        seed: u64,
    ) -> Result<(PipelineOutcome, f64)> {
        let (mut outcomes, ms) = self.plan_learned_batch(method, std::slice::from_ref(problem), hidden, seed)?;
        Ok((outcomes.pop().context("the pipeline returned no plan")?, ms))
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
        let set = self.engine_set(&first.team, obstacles, Use::Filter)?;
        self.load_learned(first.team.dim, method.uses_initialiser())?;
        let (Some((_, learned)), Some(args)) =
            (self.learned.iter().find(|(d, _)| *d == first.team.dim), self.learned_args.as_ref())
        else {
            anyhow::bail!("the learned planner is not loaded");
        };
        let model = learned.model();
        if method.uses_initialiser() && !model.has_init() {
            anyhow::bail!("{} is missing: flowopt needs the SF initialiser", args.weights(first.team.dim).1);
        }
        let seen: Vec<Problem> = problems
            .iter()
            .map(|p| {
                let mut seen = p.clone();
                seen.obstacles.truncate(obstacles - hidden);
                seen
            })
            .collect();
        let queries: Vec<Query> = seen.iter().zip(problems).map(|(seen, enforced)| Query { seen, enforced }).collect();
        let sf = self.engines[set].get(obstacles).context("the filter was built")?;
        let start = Instant::now();
        let outcomes = model
            .plan_batch(&queries, sf, &args.settings(method), seed, &Budget::unlimited())
            .context("running the pipeline")?;
        Ok((outcomes, start.elapsed().as_secs_f64() * 1e3))
    }

    /// Plans `problem` with `method`, timing the method's own stage; the
    /// residual study starts from the same point as the timed run.
    pub fn run(&mut self, method: Method, problem: &Problem, seed: u64) -> Result<Record> {
        self.run_hiding(method, problem, 0, seed)
    }

    /// [`Planner::run`] with the problem's last `hidden` obstacles hidden
    /// from the learned methods' networks (the robustness study; the
    /// optimisers see everything).
    pub fn run_hiding(&mut self, method: Method, problem: &Problem, hidden: usize, seed: u64) -> Result<Record> {
        let obstacles = problem.obstacles.len();
        if method == Method::Auto {
            return self.race(problem, seed);
        }
        if matches!(method, Method::Flowopt | Method::FlowNoInit) {
            let (out, time_ms) = self.plan_learned(method, problem, hidden, seed)?;
            let chosen = &out.refined[out.chosen];
            let study = self.study(problem, Use::StudyFilter, None, Some((&chosen.prepared, &chosen.start)))?;
            return Ok(Record::of(problem, chosen.outcome.clone(), time_ms, study, Some(out.times)));
        }
        let optimiser = self.engine(&problem.team, obstacles, Use::Optimise)?;
        let start = Instant::now();
        let solved = optimiser.solve(problem).context("optimising")?;
        let optimise_ms = start.elapsed().as_secs_f64() * 1e3;
        // The baseline is studied from its cold start, the SF from its sample.
        let (outcome, time_ms, sample) = if method == Method::SafetyFilter {
            let noise = 0.1 * problem.team.separation().0;
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let sample: Vec<f64> = solved.state.xi.iter().map(|x| x + noise * rng.random_range(-1.0..=1.0)).collect();
            let filter = self.engine(&problem.team, obstacles, Use::Filter)?;
            let start = Instant::now();
            let filtered = filter.filter(problem, &sample, None).context("filtering")?;
            (filtered, start.elapsed().as_secs_f64() * 1e3, Some(sample))
        } else {
            (solved, optimise_ms, None)
        };
        let usage = if sample.is_some() { Use::StudyFilter } else { Use::StudyOptimise };
        let study = self.study(problem, usage, sample.as_deref(), None)?;
        Ok(Record::of(problem, outcome, time_ms, study, None))
    }

    /// [`Method::Auto`]: the optimiser and the learned pipeline on two
    /// threads; the first verified plan wins and cancels the other. Timed
    /// to the winner's plan; the record is the winner's (or, if neither
    /// verified, the optimiser's), studied as that method's run would be.
    fn race(&mut self, problem: &Problem, seed: u64) -> Result<Record> {
        let obstacles = problem.obstacles.len();
        let too_big = (problem.team.robots > RACE_MAX_ROBOTS)
            .then(|| format!("the learned planner races teams of up to {RACE_MAX_ROBOTS} robots"));
        if let Some(why) = too_big.or_else(|| self.learned_unavailable(&problem.team)) {
            if !self.said_alone {
                eprintln!("auto: the optimiser plans alone: {why}");
                self.said_alone = true;
            }
            return self.run_hiding(Method::Baseline, problem, 0, seed);
        }
        let optimiser_set = self.engine_set(&problem.team, obstacles, Use::Optimise)?;
        let filter_set = self.engine_set(&problem.team, obstacles, Use::Filter)?;
        let settings = self.learned_args.as_ref().context("learned arguments")?.settings(Method::Auto);
        let (Some(optimiser), Some(sf), Some(learned)) = (
            self.engines[optimiser_set].get(obstacles),
            self.engines[filter_set].get(obstacles),
            self.learned.iter().find(|(d, _)| *d == problem.team.dim).map(|(_, l)| l),
        ) else {
            anyhow::bail!("the racing planners are not loaded");
        };
        // 0: nobody yet; 1: the optimiser; 2: the learned pipeline.
        let winner = AtomicU8::new(0);
        let start = Instant::now();
        let finish = |me: u8, verified: bool| {
            let won = verified && winner.compare_exchange(0, me, Ordering::AcqRel, Ordering::Acquire).is_ok();
            (won, start.elapsed().as_secs_f64() * 1e3)
        };
        let lost_optimiser = || winner.load(Ordering::Acquire) == 2;
        let lost_learned = || winner.load(Ordering::Acquire) == 1;
        let (optimised, piped) = std::thread::scope(|scope| {
            let optimising = scope.spawn(|| {
                let prepared = optimiser.prepare(problem, None)?;
                let budget = Budget::unlimited().or_cancelled(&lost_optimiser);
                let outcome = optimiser.solve_prepared_within(&prepared, &budget);
                let (_, ms) = finish(1, outcome.stop == Stop::Verified);
                anyhow::Ok((outcome, ms))
            });
            let sampling = scope.spawn(|| {
                let budget = Budget::unlimited().or_cancelled(&lost_learned);
                let out = learned.model().plan(problem, sf, &settings, seed, &budget);
                let (_, ms) = finish(2, out.as_ref().is_ok_and(|o| o.verified));
                (out, ms)
            });
            let optimised = optimising.join().map_err(|_| anyhow::anyhow!("the optimiser thread panicked"));
            let piped = sampling.join().map_err(|_| anyhow::anyhow!("the learned thread panicked"));
            (optimised, piped)
        });
        let (outcome, optimise_ms) = optimised??;
        if winner.load(Ordering::Acquire) == 2 {
            let (out, ms) = piped?;
            let out = out.context("the learned pipeline")?;
            let chosen = &out.refined[out.chosen];
            let study = self.study(problem, Use::StudyFilter, None, Some((&chosen.prepared, &chosen.start)))?;
            return Ok(Record::of(problem, chosen.outcome.clone(), ms, study, Some(out.times)));
        }
        let study = self.study(problem, Use::StudyOptimise, None, None)?;
        Ok(Record::of(problem, outcome, optimise_ms, study, None))
    }
}

impl Record {
    fn of(
        problem: &Problem,
        outcome: AmOutcome,
        time_ms: f64,
        study: Vec<Residuals>,
        stages: Option<PipelineTimes>,
    ) -> Self {
        let plan = flowopt_planner::plan::JointPlan::new(&problem.team, outcome.state.xi.clone());
        let metrics = Metrics::measure(problem, &plan);
        Record {
            success: metrics.success(problem.team.separation().0),
            iterations: outcome.iterations,
            time_ms,
            smoothness: metrics.smoothness,
            arc_length: metrics.arc_length,
            min_clearance: metrics.min_clearance(),
            primal_residual: outcome.primal,
            stop: outcome.stop,
            iterations_to_0_01: first_below(&study, 0.01),
            iterations_to_0_001: first_below(&study, 0.001),
            stages,
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
