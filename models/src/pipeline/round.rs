//! Planning with the pipeline: a batch of queries sampled, ranked,
//! initialised and refined together, round after round while none of a
//! query's candidates verifies.

use std::time::Instant;

use candle_core::{Device, Tensor};
use flowopt_planner::am::{AmState, Budget, Engine};
use flowopt_planner::method::Stages;

use super::model::FlowOpt;
use super::outcome::{PipelineOutcome, Query, Refined};
use super::refine::{Job, Starts, refine, select};
use super::settings::{PipelineSettings, Settle};
use crate::ModelError;
use crate::coding::Coding;

impl FlowOpt {
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
                outcome.stages.add(&kept.stages);
                if outcome.verified || outcome.primal() < kept.primal() {
                    outcomes[q] = outcome;
                } else {
                    outcomes[q].stages = outcome.stages;
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
            outcomes.push(PipelineOutcome { refined: mine, chosen, verified, stages: Stages::default(), samples });
        }
        let done = Instant::now();
        let stages = Stages {
            sample: sampled - started,
            rank: ranked - sampled,
            init: initialised - ranked,
            filter: filtered - initialised,
            select: done - filtered,
            ..Stages::default()
        };
        for o in &mut outcomes {
            o.stages = stages;
        }
        Ok(outcomes)
    }
}

/// The flow noise's seed of round `round` of a plan seeded by `seed`
/// (round 0: `seed` itself).
fn round_seed(seed: u64, round: usize) -> u64 {
    seed.wrapping_add((round as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
}
