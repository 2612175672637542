//! The Flow-Opt pipeline (METHOD.md section 5): sample candidates from the
//! flow policy, rank them by primal residual, start the safety filter on
//! the best few (from the initialiser's output, or from the samples
//! themselves for the `flow-no-init` ablation), and return the verified
//! plan with the lowest smoothness. Every stage is timed.

use std::path::Path;
use std::time::Instant;

use candle_core::{Device, Tensor};
use flowopt_planner::am::{AmOutcome, AmState, Engine, Prepared, Stop};
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Problem, Team};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::ModelError;
use crate::coding::{Coding, conditions, obstacle_width, robot_width};
use crate::flow::{FlowConfig, FlowModel, Solver};
use crate::init::{InitConfig, InitModel};
use crate::layers::noise;
use crate::weights::{Stats, load};

/// How the pipeline runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PipelineSettings {
    /// Candidates sampled per problem.
    pub candidates: usize,
    /// Flow integration steps.
    pub steps: usize,
    /// Flow integrator.
    pub solver: Solver,
    /// Candidates refined by the safety filter.
    pub top_k: usize,
    /// Start the SF from the initialiser (`false`: from the samples with a
    /// zero multiplier, the `flow-no-init` ablation).
    pub use_init: bool,
    /// Threads refining candidates in parallel.
    pub threads: usize,
    /// Scale of the initial noise (1 samples the learned distribution;
    /// lower values trade diversity for samples nearer its mode).
    pub temperature: f64,
}

impl Default for PipelineSettings {
    fn default() -> Self {
        Self { candidates: 16, steps: 4, solver: Solver::Euler, top_k: 4, use_init: true, threads: 2, temperature: 1.0 }
    }
}

/// Wall time of every stage (ms).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageTimes {
    /// Encoding, noise and flow integration.
    pub sample_ms: f64,
    /// Decoding and primal residuals of every candidate.
    pub rank_ms: f64,
    /// The initialiser (zero without it).
    pub init_ms: f64,
    /// The safety filter on the top-k.
    pub filter_ms: f64,
    /// Choosing the plan.
    pub select_ms: f64,
    /// Everything.
    pub total_ms: f64,
}

/// One refined candidate.
#[derive(Debug, Clone)]
pub struct Refined {
    /// Its rank among the samples (0 = lowest primal residual).
    pub rank: usize,
    /// Primal residual of the sample.
    pub sample_primal: f64,
    /// The SF problem (target: the sample).
    pub prepared: Prepared,
    /// Where the SF started.
    pub start: AmState,
    /// How it ended.
    pub outcome: AmOutcome,
    /// Smoothness of the result (mean over robots of sum ||p''||^2).
    pub smoothness: f64,
}

/// What a pipeline run produced.
#[derive(Debug, Clone)]
pub struct PipelineOutcome {
    /// The refined candidates, best-ranked first.
    pub refined: Vec<Refined>,
    /// Index into `refined` of the returned plan: the verified one with the
    /// lowest smoothness, or else the one with the lowest primal residual.
    pub chosen: usize,
    /// Whether the returned plan was verified by the safety filter.
    pub verified: bool,
    /// Stage times.
    pub times: StageTimes,
    /// Every sampled candidate's coefficients (for diversity studies).
    pub samples: Vec<Vec<f64>>,
}

impl PipelineOutcome {
    /// The returned plan's coefficients.
    pub fn xi(&self) -> &[f64] {
        &self.refined[self.chosen].outcome.state.xi
    }
}

/// The learned planner: a flow policy and optionally an initialiser.
#[derive(Debug, Clone)]
pub struct FlowOpt {
    flow: FlowModel,
    stats: Stats,
    init: Option<InitModel>,
}

impl FlowOpt {
    /// Loads the flow policy at `flow` and the initialiser at `init`; the
    /// initialiser must share the policy's statistics.
    pub fn load(flow: &Path, init: Option<&Path>) -> Result<Self, ModelError> {
        let f = load::<FlowConfig>(flow, "flow")?;
        let model = FlowModel::new(f.vars, &f.config)?;
        let init = match init {
            Some(path) => {
                let i = load::<InitConfig>(path, "init")?;
                if i.stats != f.stats || i.config.dim != f.config.dim || i.config.n_xi != f.config.n_xi {
                    return Err(ModelError::Config(format!(
                        "{} was not trained on samples of {}",
                        path.display(),
                        flow.display()
                    )));
                }
                Some(InitModel::new(i.vars, &i.config)?)
            }
            None => None,
        };
        Ok(Self { flow: model, stats: f.stats, init })
    }

    /// Whether an initialiser is loaded.
    pub fn has_init(&self) -> bool {
        self.init.is_some()
    }

    /// Whether the networks were built for `team`'s dimension and basis.
    pub fn check(&self, team: &Team) -> Result<(), ModelError> {
        let c = self.flow.config();
        if c.dim != team.dim.axes() || c.n_xi != team.degree + 1 {
            return Err(ModelError::Config(format!(
                "the flow model plans {}D with {} coefficients, the team is {}D with {}",
                c.dim,
                c.n_xi,
                team.dim.axes(),
                team.degree + 1
            )));
        }
        Ok(())
    }

    /// Samples `count` normalised token sets for `problem` with noise seeded
    /// by `seed`; returns them `[count, n, W]` with the normalised
    /// condition rows.
    fn sample(
        &self,
        problem: &Problem,
        count: usize,
        settings: &PipelineSettings,
        seed: u64,
    ) -> Result<(Tensor, Tensor, Tensor), ModelError> {
        let dim = problem.team.dim.axes();
        let (n, m) = (problem.robots(), problem.obstacles.len());
        let (robot_rows, obstacle_rows) = conditions(problem);
        let robots =
            self.stats.robot.normalise(&Tensor::from_vec(robot_rows, (1, n, robot_width(dim)), &Device::Cpu)?)?;
        let obstacles = self
            .stats
            .obstacle
            .normalise(&Tensor::from_vec(obstacle_rows, (1, m, obstacle_width(dim)), &Device::Cpu)?)?
            .broadcast_as((count, m, obstacle_width(dim)))?
            .contiguous()?;
        let encoded = self.flow.encode(&robots, &obstacles)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let x0 =
            (noise(&mut rng, &[count, n, self.flow.config().token_width()], &Device::Cpu)? * settings.temperature)?;
        let tokens = self.flow.sample(&x0, &encoded, settings.steps, settings.solver)?;
        Ok((tokens, robots, obstacles))
    }

    /// Plans `problem` with the safety filter `sf` (built for its team and
    /// obstacle count); `seed` seeds the flow noise. With a `deadline`, the
    /// safety filter stops there ([`Stop::Deadline`]) with its best iterate.
    pub fn plan(
        &self,
        problem: &Problem,
        sf: &Engine,
        settings: &PipelineSettings,
        seed: u64,
        deadline: Option<Instant>,
    ) -> Result<PipelineOutcome, ModelError> {
        self.check(&problem.team)?;
        let started = Instant::now();
        let count = settings.candidates.max(1);
        let (tokens, robots, obstacles) = self.sample(problem, count, settings, seed)?;
        let raw = self.stats.token.denormalise(&tokens)?.flatten_all()?.to_vec1::<f32>()?;
        let sampled = Instant::now();

        let coding = Coding::new(&problem.team)?;
        let reference = coding.reference(problem);
        let width = raw.len() / count;
        let samples: Vec<Vec<f64>> = raw.chunks_exact(width).map(|t| coding.decode(&reference, t)).collect();
        let probe = sf.prepare(problem, Some(&samples[0]))?;
        let mut order: Vec<(usize, f64)> = samples.iter().map(|x| sf.primal_residual(&probe, x)).enumerate().collect();
        order.sort_by(|a, b| a.1.total_cmp(&b.1));
        order.truncate(settings.top_k.clamp(1, count));
        let ranked = Instant::now();

        let mut starts: Vec<AmState> = order
            .iter()
            .map(|&(i, _)| AmState { xi: samples[i].clone(), lambda: vec![0.0; samples[i].len()] })
            .collect();
        if let (Some(init), true) = (&self.init, settings.use_init) {
            let ids = Tensor::new(order.iter().map(|&(i, _)| i as u32).collect::<Vec<_>>().as_slice(), &Device::Cpu)?;
            let k = order.len();
            let out = init.forward(&tokens.index_select(&ids, 0)?, &robots, &obstacles.narrow(0, 0, k)?)?;
            let delta = self.stats.token.scale(&out.delta)?.flatten_all()?.to_vec1::<f32>()?;
            let lambda = out.lambda.flatten_all()?.to_vec1::<f32>()?;
            let zero = vec![0.0; reference.len()];
            let per = lambda.len() / k;
            for (j, start) in starts.iter_mut().enumerate() {
                let moved = coding.decode(&zero, &delta[j * width..(j + 1) * width]);
                for (x, d) in start.xi.iter_mut().zip(moved) {
                    *x += d;
                }
                start.lambda = lambda[j * per..(j + 1) * per].iter().map(|&v| f64::from(v)).collect();
            }
        }
        let initialised = Instant::now();

        let jobs: Vec<(usize, f64, AmState)> =
            order.iter().zip(starts).map(|(&(i, primal), s)| (i, primal, s)).collect();
        let refined = refine(problem, sf, &samples, jobs, settings.threads, deadline)?;
        let filtered = Instant::now();

        let verified: Vec<usize> = (0..refined.len()).filter(|&j| refined[j].outcome.stop == Stop::Verified).collect();
        let chosen = if verified.is_empty() {
            (0..refined.len())
                .min_by(|&a, &b| refined[a].outcome.primal.total_cmp(&refined[b].outcome.primal))
                .unwrap_or(0)
        } else {
            verified
                .iter()
                .copied()
                .min_by(|&a, &b| refined[a].smoothness.total_cmp(&refined[b].smoothness))
                .unwrap_or(0)
        };
        let done = Instant::now();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        Ok(PipelineOutcome {
            chosen,
            verified: !verified.is_empty(),
            times: StageTimes {
                sample_ms: ms(started, sampled),
                rank_ms: ms(sampled, ranked),
                init_ms: ms(ranked, initialised),
                filter_ms: ms(initialised, filtered),
                select_ms: ms(filtered, done),
                total_ms: ms(started, done),
            },
            refined,
            samples,
        })
    }
}

/// Runs the safety filter on every job (`(sample index, sample primal,
/// start)`, in rank order) on `threads` threads.
fn refine(
    problem: &Problem,
    sf: &Engine,
    samples: &[Vec<f64>],
    jobs: Vec<(usize, f64, AmState)>,
    threads: usize,
    deadline: Option<Instant>,
) -> Result<Vec<Refined>, ModelError> {
    crate::runtime::strided(jobs.len(), threads, |rank| {
        let (i, primal, start) = &jobs[rank];
        let prepared = sf.prepare(problem, Some(&samples[*i]))?;
        let outcome = match deadline {
            Some(d) => sf.run_until(&prepared, start.clone(), d),
            None => sf.run(&prepared, start.clone()),
        };
        let smoothness = JointPlan::new(&problem.team, outcome.state.xi.clone()).smoothness(problem.team.samples);
        Ok(Some(Refined { rank, sample_primal: *primal, prepared, start: start.clone(), outcome, smoothness }))
    })
}
