//! What the pipeline plans (a [`Query`]) and what it returns (a
//! [`PipelineOutcome`] of [`Refined`] candidates).

use flowopt_planner::am::{AmOutcome, AmState, Prepared};
use flowopt_planner::method::Stages;
use flowopt_planner::problem::Problem;

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
    pub stages: Stages,
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
