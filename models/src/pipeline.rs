//! The Flow-Opt pipeline (METHOD.md section 5): sample candidates from the
//! flow policy, reroute the robots a sample leaves inside a static obstacle
//! (the policy barely reads obstacles: docs/LEARNED.md), rank the
//! candidates by primal residual, start the safety filter on
//! the best few (from the initialiser's output, or from the samples
//! themselves for the `flow-no-init` ablation), and return the
//! best-ranked verified plan (or the smoothest: [`Settle`]). Every stage
//! is timed.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use candle_core::{Device, Tensor};
use flowopt_planner::am::{AmOutcome, AmSettings, AmState, Budget, Engine, EngineSet, Objective, Prepared, Stop};
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
use crate::shipped::Weights;
use crate::tokens::TokenMap;
use crate::weights::{Stats, load};

/// The default weight of the safety filter's smoothness-weighted metric
/// (`Objective::SmoothProjection`) for the pipeline. Measured on 20 unseen
/// 2D instances each (docs/LEARNED.md): at 0 (the paper's plain projection)
/// the filter's minimal-distance repairs add sharp detours (smoothness 5-6x
/// the optimiser's at 16 robots); 3 brings it within 15% at 8, 16 and 32
/// robots with every instance solved; 5 and above lose 32-robot instances
/// to the iteration cap.
pub const DEFAULT_SF_SMOOTHING: f64 = 3.0;

/// How the pipeline runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PipelineSettings {
    /// Candidates sampled per problem without obstacles (at least 1 is
    /// sampled).
    pub candidates: usize,
    /// Candidates sampled per problem with obstacles (static or moving),
    /// where fewer lose instances.
    pub obstacle_candidates: usize,
    /// Flow integration steps for problems without obstacles.
    pub steps: usize,
    /// Flow integration steps for problems with obstacles (static or
    /// moving), where one step loses instances.
    pub obstacle_steps: usize,
    /// Flow integrator.
    pub solver: Solver,
    /// Candidates refined by the safety filter (clamped to 1..=candidates).
    pub top_k: usize,
    /// Start the SF from the initialiser (`false`, or no initialiser
    /// loaded: from the samples with a zero multiplier, the `flow-no-init`
    /// ablation), on problems with obstacles only unless
    /// `init_without_obstacles` ([`Self::init_for`]).
    pub use_init: bool,
    /// Use the initialiser on problems without obstacles too. Off by
    /// default: there it lowered no scene's filter iterations by more than
    /// 2% and cost 0.2-0.7 ms of the plan (docs/LEARNED.md, "The
    /// initialiser where it can matter"); with obstacles it is what
    /// verifies the 16-robot obstacle field at all.
    pub init_without_obstacles: bool,
    /// Threads sampling (the candidates split between them) and refining
    /// candidates in parallel, for problems without obstacles.
    pub threads: usize,
    /// The same for problems with obstacles (static or moving).
    pub obstacle_threads: usize,
    /// Scale of the initial noise (1 samples the learned distribution;
    /// lower values trade diversity for samples nearer its mode).
    pub temperature: f64,
    /// Before ranking, give every robot whose sample passes through a
    /// static obstacle the optimiser's route around the static obstacles
    /// ([`flowopt_planner::am::Rerouter`]); the safety filter then stays
    /// near that route.
    pub reroute: bool,
    /// Which refined candidate is returned, and so how many are refined.
    pub settle: Settle,
    /// Most rounds [`FlowOpt::plan_batch`] samples a problem in: while no
    /// refined candidate of a round verifies (and the budget lasts),
    /// as many candidates again are sampled with fresh noise and their
    /// top-k refined.
    pub rounds: usize,
}

/// Which verified candidate the pipeline returns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Settle {
    /// The best-ranked candidate that verifies: candidates ranked below one
    /// that verified are cancelled or never started, those ranked above it
    /// run to their end. The result does not depend on the threads'
    /// timing. 16 random robots (docs/LEARNED.md): the filter stage
    /// 2.05 -> 0.68 ms against [`Settle::Smoothest`], smoothness 2.254 ->
    /// 2.331 (the optimiser's 2.330).
    #[default]
    FirstVerified,
    /// Refine every one of the top-k and return the smoothest verified plan
    /// (the paper's selection).
    Smoothest,
}

/// The defaults: 4 candidates in 1 Euler step on one core without
/// obstacles and the filter started from the samples, 8 in 2 steps on both
/// cores with them and the filter started by the initialiser, the best 6
/// refined until one verifies, up to 8 rounds of that while none does (the
/// 16-robot obstacle field: 45% verified in one round, 100% in eight). One
/// core without obstacles: the second core's share of so small a batch
/// runs slower beside the first (the two contend for the cache) and the
/// first refined candidate nearly always verifies, so random teams of 32
/// planned in 6.9 ms against 8.1 on two, 3D teams of 64 in 12.7 against
/// 13.8; with obstacles two stay faster (16 robots and 8 obstacles 8.3
/// against 9.9 ms, the 16-robot obstacle field 67 against 107 ms;
/// docs/LEARNED.md). Without obstacles 4
/// candidates verified every random, swap, crossing, formation and crowd
/// scene of 16-64 robots (2D and 3D) that 8 did, in 12-35% less time; with
/// obstacles 4 lost instances (the 16-robot obstacle field 95%, moving
/// obstacles 98%). Measured on
/// 100 unseen 16-robot instances (docs/LEARNED.md): with 8 obstacles 16
/// candidates and the top 4 solved 97%, the top 6 of 16 99%, the top 6 of
/// 8 100% in 32% less time; 4 steps instead of 2 cost 1.7 ms more for no
/// better plans, 1 step lost instances with obstacles. Without obstacles 1
/// step solved every random, swap, crossing, formation and crowd scene of
/// 16-64 robots (2D and 3D) that 2 did, with the sampling stage halved and
/// smoothness within 7%.
impl Default for PipelineSettings {
    fn default() -> Self {
        Self {
            candidates: 4,
            obstacle_candidates: 8,
            steps: 1,
            obstacle_steps: 2,
            solver: Solver::Euler,
            top_k: 6,
            use_init: true,
            init_without_obstacles: false,
            threads: 1,
            obstacle_threads: 2,
            temperature: 1.0,
            reroute: true,
            settle: Settle::FirstVerified,
            rounds: 8,
        }
    }
}

impl PipelineSettings {
    /// Candidates sampled for a problem with `obstacles` obstacles.
    pub fn candidates_for(&self, obstacles: usize) -> usize {
        if obstacles == 0 { self.candidates } else { self.obstacle_candidates }
    }

    /// Flow integration steps for a problem with `obstacles` obstacles.
    pub fn steps_for(&self, obstacles: usize) -> usize {
        if obstacles == 0 { self.steps } else { self.obstacle_steps }
    }

    /// Threads for a problem with `obstacles` obstacles (at least 1). The
    /// pipeline passes the obstacles its networks see, as for the
    /// candidates, steps and initialiser.
    pub fn threads_for(&self, obstacles: usize) -> usize {
        if obstacles == 0 { self.threads } else { self.obstacle_threads }.max(1)
    }

    /// Whether the initialiser starts the SF on a problem with `obstacles`
    /// obstacles (when one is loaded).
    pub fn init_for(&self, obstacles: usize) -> bool {
        self.use_init && (obstacles > 0 || self.init_without_obstacles)
    }
}

/// One problem for the pipeline: the networks are conditioned on `seen`,
/// the safety filter enforces `enforced`. Both are the same problem in
/// normal use; the robustness study hides an obstacle from the networks
/// (`seen` lacks it) that the filter must still avoid.
#[derive(Debug, Clone, Copy)]
pub struct Query<'a> {
    /// What the flow policy and the initialiser are conditioned on.
    pub seen: &'a Problem,
    /// What the safety filter enforces (same team, starts and goals).
    pub enforced: &'a Problem,
}

impl<'a> From<&'a Problem> for Query<'a> {
    fn from(problem: &'a Problem) -> Self {
        Query { seen: problem, enforced: problem }
    }
}

/// Wall time of every stage (ms); for a batch, the whole batch's.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct PipelineTimes {
    /// Encoding, noise and flow integration.
    pub sample_ms: f64,
    /// Decoding, rerouting and primal residuals of every candidate.
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

impl PipelineTimes {
    /// Adds `other`'s stage times to these.
    fn add(&mut self, other: &Self) {
        self.sample_ms += other.sample_ms;
        self.rank_ms += other.rank_ms;
        self.init_ms += other.init_ms;
        self.filter_ms += other.filter_ms;
        self.select_ms += other.select_ms;
        self.total_ms += other.total_ms;
    }
}

/// One refined candidate.
#[derive(Debug, Clone)]
pub struct Refined {
    /// Its rank among the samples (0 = lowest primal residual).
    pub rank: usize,
    /// Primal residual of the sample.
    pub sample_primal: f64,
    /// The SF problem (`cold()`: the sample; `target()`: the cost's
    /// linear term).
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
    pub times: PipelineTimes,
    /// Every sampled candidate's coefficients, as rerouted (for diversity
    /// studies).
    pub samples: Vec<Vec<f64>>,
}

impl PipelineOutcome {
    /// The returned plan's coefficients.
    pub fn xi(&self) -> &[f64] {
        &self.refined[self.chosen].outcome.state.xi
    }

    /// The returned plan's primal residual (infinite without a plan).
    pub fn primal(&self) -> f64 {
        self.refined.get(self.chosen).map_or(f64::INFINITY, |r| r.outcome.primal)
    }
}

/// The learned planner: a flow policy and optionally an initialiser.
#[derive(Debug, Clone)]
pub struct FlowOpt {
    flow: FlowModel,
    stats: Stats,
    tokens: TokenMap,
    init: Option<InitModel>,
}

impl FlowOpt {
    /// Loads the flow policy at `flow` and the initialiser at `init`; the
    /// initialiser must share the policy's statistics.
    pub fn load(flow: &Weights, init: Option<&Weights>) -> Result<Self, ModelError> {
        let f = load::<FlowConfig>(flow, "flow")?;
        let model = FlowModel::new(f.vars, &f.config)?;
        let tokens = TokenMap::new(f.config.tokens, f.config.dim, f.config.n_xi)?;
        let init = match init {
            Some(weights) => {
                let i = load::<InitConfig>(weights, "init")?;
                if i.stats != f.stats || i.config.dim != f.config.dim || i.config.n_xi != f.config.n_xi {
                    return Err(ModelError::Config(format!("{weights} was not trained on samples of {flow}")));
                }
                Some(InitModel::new(i.vars, &i.config)?)
            }
            None => None,
        };
        Ok(Self { flow: model, stats: f.stats, tokens, init })
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

    /// Samples `count` normalised token sets per query (whose reference
    /// curves are `references`) with noise seeded by `seed`, all queries in
    /// one batch; returns them `[P count, n, W]` (query-major) with the
    /// normalised condition rows `[P, n, .]` and `[P, m, .]`.
    fn sample(
        &self,
        queries: &[Query<'_>],
        references: &[Vec<f64>],
        count: usize,
        settings: &PipelineSettings,
        seed: u64,
        budget: &Budget<'_>,
    ) -> Result<(Tensor, Tensor, Tensor), ModelError> {
        let first = queries[0].seen;
        let dim = first.team.dim.axes();
        let (p, n, m) = (queries.len(), first.robots(), first.obstacles.len());
        let (mut robot_rows, mut obstacle_rows) = (Vec::new(), Vec::new());
        for q in queries {
            let (r, o) = conditions(q.seen);
            robot_rows.extend(r);
            obstacle_rows.extend(o);
        }
        let robots =
            self.stats.robot.normalise(&Tensor::from_vec(robot_rows, (p, n, robot_width(dim)), &Device::Cpu)?)?;
        let obstacles = self.stats.obstacle.normalise(&Tensor::from_vec(
            obstacle_rows,
            (p, m, obstacle_width(dim)),
            &Device::Cpu,
        )?)?;
        let pairs = if self.flow.reads_pairs() && m > 0 {
            let rows = queries.iter().zip(references).flat_map(|(q, r)| crate::pairs::pair_rows(q.seen, r)).collect();
            Some(Tensor::from_vec(rows, (p, n, m, crate::pairs::pair_width(dim)), &Device::Cpu)?)
        } else {
            None
        };
        let encoded = self.flow.encode(&robots, &obstacles, pairs.as_ref())?;
        // One problem's conditioning broadcasts over its candidates (the
        // per-robot adaLN then runs once, not once per candidate); several
        // problems need it per candidate.
        let encoded = if p == 1 { encoded } else { encoded.repeat_each(count)? };
        let steps = settings.steps_for(m);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let x0 =
            (noise(&mut rng, &[p * count, n, self.flow.config().token_width()], &Device::Cpu)? * settings.temperature)?;
        // The candidates split between the threads, each integrating its
        // share on one core (candle itself runs one thread when planning).
        let rows = p * count;
        let threads = settings.threads_for(m).clamp(1, rows);
        let share = rows.div_ceil(threads);
        let parts = crate::runtime::parallel(threads, threads, |t| {
            let (first, len) = (t * share, share.min(rows.saturating_sub(t * share)));
            if len == 0 {
                return Ok(None);
            }
            let part = encoded.rows(first, len)?;
            let x = x0.narrow(0, first, len)?;
            let sampled = self.flow.sample(&x, &part, steps, settings.solver, &|| budget.spent().is_some())?;
            Ok(Some(sampled.ok_or(ModelError::Stopped)?))
        })?;
        let tokens = if parts.len() == 1 { parts[0].clone() } else { Tensor::cat(&parts, 0)? };
        Ok((tokens, robots, obstacles))
    }

    /// Plans one problem (see [`FlowOpt::plan_batch`]).
    pub fn plan<'a>(
        &self,
        query: impl Into<Query<'a>>,
        sf: &Engine,
        settings: &PipelineSettings,
        seed: u64,
        budget: &Budget<'_>,
    ) -> Result<PipelineOutcome, ModelError> {
        let mut outcomes = self.plan_batch(&[query.into()], sf, settings, seed, budget)?;
        outcomes.pop().ok_or_else(|| ModelError::Config("the pipeline returned no plan".into()))
    }

    /// Plans several problems of one team shape and obstacle count together:
    /// every candidate of every problem is sampled in one batch, the
    /// initialiser runs once over all refined candidates, and the safety
    /// filter `sf` (built for the enforced problems' team and obstacle
    /// count) refines them all on [`PipelineSettings::threads_for`] threads. `seed` seeds
    /// the flow noise. The safety filter stops ([`Stop::Deadline`],
    /// [`Stop::Cancelled`]) with its current iterate once `budget` is spent. Returns one outcome per
    /// query, in order; their stage times are the batch's.
    ///
    /// Queries none of whose refined candidates verify are planned again,
    /// together, with fresh noise, up to `settings.rounds` rounds in all
    /// while the budget lasts: each keeps the first round that verifies,
    /// or else the one whose returned candidate has the lowest primal
    /// residual, and the stage times of every round it took part in.
    pub fn plan_batch(
        &self,
        queries: &[Query<'_>],
        sf: &Engine,
        settings: &PipelineSettings,
        seed: u64,
        budget: &Budget<'_>,
    ) -> Result<Vec<PipelineOutcome>, ModelError> {
        let Some(first) = queries.first() else { return Ok(Vec::new()) };
        for q in queries {
            self.check(&q.enforced.team)?;
            if q.seen.team != first.seen.team
                || q.enforced.team != q.seen.team
                || q.seen.obstacles.len() != first.seen.obstacles.len()
            {
                return Err(ModelError::Config("a batch needs one team shape and one count of seen obstacles".into()));
            }
            if q.enforced.obstacles.len() != sf.obstacles() {
                return Err(ModelError::Config(format!(
                    "the safety filter is built for {} obstacles, a query enforces {}",
                    sf.obstacles(),
                    q.enforced.obstacles.len()
                )));
            }
            if q.seen.starts != q.enforced.starts || q.seen.goals != q.enforced.goals {
                return Err(ModelError::Config(
                    "a query's seen and enforced problems differ in starts or goals".into(),
                ));
            }
        }
        let mut outcomes = self.plan_round(queries, sf, settings, seed, budget)?;
        for round in 1..settings.rounds.max(1) {
            let again: Vec<usize> = (0..outcomes.len()).filter(|&q| !outcomes[q].verified).collect();
            if again.is_empty() || budget.spent().is_some() {
                break;
            }
            let retried: Vec<Query<'_>> = again.iter().map(|&q| queries[q]).collect();
            let fresh = self.plan_round(&retried, sf, settings, round_seed(seed, round), budget)?;
            for (&q, mut outcome) in again.iter().zip(fresh) {
                let kept = &outcomes[q];
                outcome.times.add(&kept.times);
                if outcome.verified || outcome.primal() < kept.primal() {
                    outcomes[q] = outcome;
                } else {
                    outcomes[q].times = outcome.times;
                }
            }
        }
        Ok(outcomes)
    }

    /// One round of [`Self::plan_batch`] (which validated the queries):
    /// sample, rank, initialise, filter.
    fn plan_round(
        &self,
        queries: &[Query<'_>],
        sf: &Engine,
        settings: &PipelineSettings,
        seed: u64,
        budget: &Budget<'_>,
    ) -> Result<Vec<PipelineOutcome>, ModelError> {
        let Some(first) = queries.first() else { return Ok(Vec::new()) };
        let started = Instant::now();
        // The settings that depend on the obstacles follow those the networks see.
        let m = first.seen.obstacles.len();
        let count = settings.candidates_for(m).max(1);
        let top_k = settings.top_k.clamp(1, count);
        // The seen and enforced problems share their starts and goals, so
        // their reference curves.
        let coding = Coding::new(&first.enforced.team)?;
        let references: Vec<Vec<f64>> = queries.iter().map(|q| coding.reference(q.enforced)).collect();
        let (tokens, robots, obstacles) = self.sample(queries, &references, count, settings, seed, budget)?;
        let raw = self.tokens.to_coefficients(&self.stats.token.denormalise(&tokens)?)?;
        let raw = raw.flatten_all()?.to_vec1::<f32>()?;
        let sampled = Instant::now();

        let width = raw.len() / (count * queries.len());
        let mut samples = Vec::with_capacity(queries.len());
        let mut jobs = Vec::with_capacity(queries.len() * top_k);
        for (qi, (q, reference)) in queries.iter().zip(&references).enumerate() {
            let mut decoded: Vec<Vec<f64>> = raw[qi * count * width..(qi + 1) * count * width]
                .chunks_exact(width)
                .map(|t| coding.decode(reference, t))
                .collect();
            // The initialiser still reads the samples as sampled, its
            // training distribution: fed the rerouted ones it measured 93%
            // success with 8 obstacles instead of 100% (docs/LEARNED.md).
            if settings.reroute {
                let mut rerouter = sf.rerouter(q.enforced)?;
                for x in &mut decoded {
                    rerouter.apply(x);
                }
            }
            let probe = sf.prepare(q.enforced, Some(&decoded[0]))?;
            let mut order: Vec<(usize, f64)> =
                decoded.iter().map(|x| sf.primal_residual(&probe, x)).enumerate().collect();
            order.sort_by(|a, b| a.1.total_cmp(&b.1));
            jobs.extend(order.into_iter().take(top_k).enumerate().map(|(rank, (sample, primal))| Job {
                query: qi,
                sample,
                primal,
                rank,
            }));
            samples.push(decoded);
        }
        let ranked = Instant::now();

        // The SF's starts of the jobs at `ids`: the samples, moved and given
        // a multiplier by the initialiser (one batch) when it is used.
        let zero = vec![0.0; references[0].len()];
        let start_of = |ids: &[usize]| -> Result<Vec<AmState>, ModelError> {
            let mut starts: Vec<AmState> = ids
                .iter()
                .map(|&j| {
                    let xi = samples[jobs[j].query][jobs[j].sample].clone();
                    AmState { lambda: vec![0.0; xi.len()], xi }
                })
                .collect();
            let (Some(init), true) = (&self.init, settings.init_for(m)) else { return Ok(starts) };
            let index = |f: &dyn Fn(&Job) -> usize| {
                Tensor::new(ids.iter().map(|&j| f(&jobs[j]) as u32).collect::<Vec<_>>().as_slice(), &Device::Cpu)
            };
            let sample_ids = index(&|j| j.query * count + j.sample)?;
            let query_ids = index(&|j| j.query)?;
            let out = init.forward(
                &tokens.index_select(&sample_ids, 0)?,
                &robots.index_select(&query_ids, 0)?,
                &obstacles.index_select(&query_ids, 0)?,
            )?;
            let delta = self.tokens.to_coefficients(&self.stats.token.scale(&out.delta)?)?;
            let delta = delta.flatten_all()?.to_vec1::<f32>()?;
            let lambda = out.lambda.flatten_all()?.to_vec1::<f32>()?;
            let per = lambda.len() / ids.len();
            for (k, start) in starts.iter_mut().enumerate() {
                let moved = coding.decode(&zero, &delta[k * width..(k + 1) * width]);
                for (x, d) in start.xi.iter_mut().zip(moved) {
                    *x += d;
                }
                start.lambda = lambda[k * per..(k + 1) * per].iter().map(|&v| f64::from(v)).collect();
            }
            Ok(starts)
        };
        // Every start now, in one batch; stopping at the first verified
        // candidate, only those of the first wave (one per thread), the
        // others when (if) their turn comes.
        let eager: Vec<usize> = (0..jobs.len())
            .filter(|&j| settings.settle == Settle::Smoothest || jobs[j].rank < settings.threads_for(m))
            .collect();
        let mut ready: Vec<Option<AmState>> = jobs.iter().map(|_| None).collect();
        for (j, start) in eager.iter().zip(start_of(&eager)?) {
            ready[*j] = Some(start);
        }
        let starts = Starts { ready, make: &start_of };
        let initialised = Instant::now();

        let refined = refine(queries, sf, &samples, &jobs, &starts, settings, budget)?;
        let filtered = Instant::now();

        let mut per_query: Vec<Vec<Refined>> = queries.iter().map(|_| Vec::new()).collect();
        for (query, r) in refined {
            per_query[query].push(r);
        }
        let mut outcomes = Vec::with_capacity(queries.len());
        for (samples, mine) in samples.into_iter().zip(per_query) {
            let (chosen, verified) = select(&mine, settings.settle);
            outcomes.push(PipelineOutcome {
                refined: mine,
                chosen,
                verified,
                times: PipelineTimes::default(),
                samples,
            });
        }
        let done = Instant::now();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        let times = PipelineTimes {
            sample_ms: ms(started, sampled),
            rank_ms: ms(sampled, ranked),
            init_ms: ms(ranked, initialised),
            filter_ms: ms(initialised, filtered),
            select_ms: ms(filtered, done),
            total_ms: ms(started, done),
        };
        for o in &mut outcomes {
            o.times = times;
        }
        Ok(outcomes)
    }
}

/// The learned planner as the daemon and the command line assemble it:
/// the networks (with the initialiser when its weights are given) and the
/// metric of the safety filter that repairs their samples.
#[derive(Debug, Clone)]
pub struct LearnedPlanner {
    model: FlowOpt,
    sf_objective: Objective,
}

impl LearnedPlanner {
    /// Loads the flow policy at `flow` and the initialiser at `init`;
    /// `sf_smoothing` weighs the smoothness of the filter's corrections
    /// ([`Objective::filter`]; finite, 0 or more).
    pub fn load(flow: &Weights, init: Option<&Weights>, sf_smoothing: f64) -> Result<Self, ModelError> {
        if !(sf_smoothing.is_finite() && sf_smoothing >= 0.0) {
            return Err(ModelError::Config(format!("the SF smoothing weight {sf_smoothing} is not finite and >= 0")));
        }
        Ok(Self { model: FlowOpt::load(flow, init)?, sf_objective: Objective::filter(sf_smoothing) })
    }

    /// The networks.
    pub fn model(&self) -> &FlowOpt {
        &self.model
    }

    /// The safety filter's objective.
    pub fn sf_objective(&self) -> Objective {
        self.sf_objective
    }

    /// The safety filters for `team` (whose dimension and basis the
    /// networks must plan in) with `settings`, built for every obstacle
    /// count up to `max_obstacles`.
    pub fn filters(&self, team: &Team, settings: AmSettings, max_obstacles: usize) -> Result<EngineSet, ModelError> {
        self.model.check(team)?;
        Ok(EngineSet::preloaded(team, self.sf_objective, settings, max_obstacles)?)
    }
}

/// The refined candidate to return, and whether it is verified: the
/// best-ranked verified one ([`Settle::FirstVerified`]) or the verified one
/// with the lowest smoothness ([`Settle::Smoothest`]); without any, the one
/// with the lowest primal residual.
fn select(refined: &[Refined], settle: Settle) -> (usize, bool) {
    let verified: Vec<usize> = (0..refined.len()).filter(|&j| refined[j].outcome.stop == Stop::Verified).collect();
    let chosen = match (verified.is_empty(), settle) {
        (true, _) => {
            (0..refined.len()).min_by(|&a, &b| refined[a].outcome.primal.total_cmp(&refined[b].outcome.primal))
        }
        (false, Settle::FirstVerified) => verified.iter().copied().min_by_key(|&j| refined[j].rank),
        (false, Settle::Smoothest) => {
            verified.iter().copied().min_by(|&a, &b| refined[a].smoothness.total_cmp(&refined[b].smoothness))
        }
    };
    (chosen.unwrap_or(0), !verified.is_empty())
}

/// The flow noise's seed of round `round` of a plan seeded by `seed`
/// (round 0: `seed` itself).
fn round_seed(seed: u64, round: usize) -> u64 {
    seed.wrapping_add((round as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// The safety filter's start of every job: made already, or made by `make`
/// (from the job indices) when the job's turn comes.
struct Starts<'a> {
    ready: Vec<Option<AmState>>,
    make: &'a MakeStarts<'a>,
}

/// Makes the starts of the jobs at the given indices.
type MakeStarts<'a> = dyn Fn(&[usize]) -> Result<Vec<AmState>, ModelError> + Sync + 'a;

impl Starts<'_> {
    /// Job `j`'s start.
    fn get(&self, j: usize) -> Result<AmState, ModelError> {
        match &self.ready[j] {
            Some(start) => Ok(start.clone()),
            None => (self.make)(&[j])?.pop().ok_or_else(|| ModelError::Config("no start was made".into())),
        }
    }
}

/// One candidate to refine.
#[derive(Debug, Clone, Copy)]
struct Job {
    /// Index of its query.
    query: usize,
    /// Index of its sample among the query's.
    sample: usize,
    /// The sample's primal residual.
    primal: f64,
    /// Its rank among the query's samples (0 = lowest primal residual).
    rank: usize,
}

/// Runs the safety filter on every job (grouped by query, in rank order;
/// a job's start made when its turn comes if it was not yet), on the
/// settings' threads; returns `(query, refined)` in job order. With
/// [`Settle::FirstVerified`] a query's jobs ranked below its best verified
/// one so far are cancelled (running) or skipped (not started).
fn refine(
    queries: &[Query<'_>],
    sf: &Engine,
    samples: &[Vec<Vec<f64>>],
    jobs: &[Job],
    starts: &Starts<'_>,
    settings: &PipelineSettings,
    budget: &Budget<'_>,
) -> Result<Vec<(usize, Refined)>, ModelError> {
    // Per query, the best rank verified so far (usize::MAX: none).
    let settled: Vec<AtomicUsize> = queries.iter().map(|_| AtomicUsize::new(usize::MAX)).collect();
    let first_verified = settings.settle == Settle::FirstVerified;
    let threads = queries.first().map_or(1, |q| settings.threads_for(q.seen.obstacles.len()));
    crate::runtime::parallel(jobs.len(), threads, |j| {
        let Job { query: qi, sample: i, primal, rank } = jobs[j];
        let outranked = || first_verified && settled[qi].load(Ordering::Acquire) < rank;
        if outranked() {
            return Ok(None);
        }
        let cancelled = || budget.cancelled.is_some_and(|c| c()) || outranked();
        let mine = Budget { deadline: budget.deadline, cancelled: Some(&cancelled) };
        let problem = queries[qi].enforced;
        let prepared = sf.prepare(problem, Some(&samples[qi][i]))?;
        let start = starts.get(j)?;
        let outcome = sf.run_within(&prepared, start.clone(), &mine);
        if outcome.stop == Stop::Verified {
            settled[qi].fetch_min(rank, Ordering::AcqRel);
        }
        let smoothness = JointPlan::new(&problem.team, outcome.state.xi.clone()).smoothness(problem.team.samples);
        Ok(Some((qi, Refined { rank, sample_primal: primal, prepared, start, outcome, smoothness })))
    })
}
