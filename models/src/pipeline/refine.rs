//! Refining ranked candidates with the safety filter on the settings'
//! threads, stopping at the first verified one where asked, and selecting
//! the plan to return.

use std::sync::atomic::{AtomicUsize, Ordering};

use flowopt_planner::am::{AmState, Budget, Engine, Stop};
use flowopt_planner::plan::JointPlan;

use super::outcome::{Query, Refined};
use super::settings::{PipelineSettings, Settle};
use crate::ModelError;

/// The refined candidate to return, and whether it is verified: the
/// best-ranked verified one ([`Settle::FirstVerified`]) or the verified one
/// with the lowest smoothness ([`Settle::Smoothest`]); without any, the one
/// with the lowest primal residual.
pub(super) fn select(refined: &[Refined], settle: Settle) -> (usize, bool) {
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

/// The safety filter's start of every job: made already, or made by `make`
/// (from the job indices) when the job's turn comes.
pub(super) struct Starts<'a> {
    pub(super) ready: Vec<Option<AmState>>,
    pub(super) make: &'a MakeStarts<'a>,
}

/// Makes the starts of the jobs at the given indices.
pub(super) type MakeStarts<'a> = dyn Fn(&[usize]) -> Result<Vec<AmState>, ModelError> + Sync + 'a;

impl Starts<'_> {
    /// Job `j`'s start.
    pub(super) fn get(&self, j: usize) -> Result<AmState, ModelError> {
        match &self.ready[j] {
            Some(start) => Ok(start.clone()),
            None => (self.make)(&[j])?.pop().ok_or_else(|| ModelError::Config("no start was made".into())),
        }
    }
}

/// One candidate to refine.
#[derive(Debug, Clone, Copy)]
pub(super) struct Job {
    /// Index of its query.
    pub(super) query: usize,
    /// Index of its sample among the query's.
    pub(super) sample: usize,
    /// The sample's primal residual.
    pub(super) primal: f64,
    /// Its rank among the query's samples (0 = lowest primal residual).
    pub(super) rank: usize,
}

/// Runs the safety filter on every job (grouped by query, in rank order;
/// a job's start made when its turn comes if it was not yet), on the
/// settings' threads; returns `(query, refined)` in job order. With
/// [`Settle::FirstVerified`] a query's jobs ranked below its best verified
/// one so far are cancelled (running) or skipped (not started).
pub(super) fn refine(
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
