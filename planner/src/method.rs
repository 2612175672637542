//! One interface for every way to plan a problem (OMPL's
//! `Planner::solve(PlannerTerminationCondition)` in spirit): a [`Planner`]
//! plans a [`Problem`] within a [`Budget`] (a deadline, a cancel token, or
//! both) and returns a [`Planned`], whose stage times are one type,
//! [`Stages`], from the planners to the wire. The from-scratch optimiser
//! ([`crate::optimiser::Optimiser`]), the learned pipeline
//! (`flowopt_models::pipeline::LearnedPipeline`) and the race between them
//! (`flowopt_methods::Race`) implement it.

use std::time::Duration;

use thiserror::Error;

use crate::am::{AmState, Budget, EngineError, Prepared, Stop};
use crate::basis::DENSE_FACTOR;
use crate::plan::JointPlan;
use crate::problem::{Problem, Team};

/// Time spent in each planning stage (zero for a stage not run): one type
/// from the planners to the wire (`flowopt_client::StageTimings`, in µs).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stages {
    /// Shifting the previous plan to the new start and fitting it.
    pub warm_start: Duration,
    /// Encoding, noise and flow integration.
    pub sample: Duration,
    /// Decoding, rerouting and ranking the candidates.
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

impl Stages {
    /// Adds `other`'s times to these.
    pub fn add(&mut self, other: &Stages) {
        self.warm_start += other.warm_start;
        self.sample += other.sample;
        self.rank += other.rank;
        self.init += other.init;
        self.filter += other.filter;
        self.optimise += other.optimise;
        self.select += other.select;
    }

    /// The sum of every stage.
    pub fn total(&self) -> Duration {
        self.warm_start + self.sample + self.rank + self.init + self.filter + self.optimise + self.select
    }
}

/// What a planner made of a problem.
#[derive(Debug, Clone)]
pub struct Planned {
    /// The plan returned: verified when [`Planned::verified`], else the
    /// last iterate (closest to feasible).
    pub plan: JointPlan,
    /// Why its run stopped ([`Stop::Verified`]: it passed the dense
    /// verification).
    pub stop: Stop,
    /// Its primal residual (m).
    pub primal: f64,
    /// Iterations spent (every candidate's, every attempt's).
    pub iterations: usize,
    /// Iterations of the run that made the returned plan (the chosen
    /// candidate's; the optimiser's, every attempt's).
    pub run_iterations: usize,
    /// Candidates refined (1 for the optimiser).
    pub candidates: usize,
    /// Stage times.
    pub stages: Stages,
    /// Wall time from the call to this plan (for a race: to the winner's).
    pub wall: Duration,
    /// The planner that made it.
    pub by: &'static str,
    /// Where the run that made it started: its prepared problem and first
    /// iterate (for a residual study of the same start); `None` where that
    /// is the problem's cold start.
    pub start: Option<Box<(Prepared, AmState)>>,
}

impl Planned {
    /// Whether the plan passed the dense verification.
    pub fn verified(&self) -> bool {
        self.stop == Stop::Verified
    }

    /// Whether the plan keeps `problem`'s acceleration limit
    /// ([`Team::max_acceleration`]) on the dense re-sampling, or can be
    /// stretched in time to ([`Problem::stretchable`]); true without a
    /// limit. A race takes the first verified plan that does.
    pub fn within_limits(&self, problem: &Problem) -> bool {
        let Some(limit) = problem.team.max_acceleration else { return true };
        problem.stretchable() || {
            let (_, acceleration) = self.plan.peak_rates(DENSE_FACTOR * problem.team.samples);
            acceleration <= limit * (1.0 + 1e-9)
        }
    }
}

/// Why a planner could not plan.
#[derive(Debug, Error)]
pub enum PlanError {
    /// The engine refused the problem or could not be built.
    #[error("PlanError::Engine: {0}")]
    Engine(#[from] EngineError),
    /// The planner cannot plan for this team (no weights for its
    /// dimension or basis, ...).
    #[error("PlanError::Unavailable: {0}")]
    Unavailable(String),
    /// The planner failed.
    #[error("PlanError::Failed: {0}")]
    Failed(String),
    /// The request was cancelled before the planner started it.
    #[error("PlanError::Cancelled: cancelled before it started")]
    Cancelled,
}

/// A way to plan.
pub trait Planner: Send {
    /// Its name in reports (`optimiser`, `learned`, `race`).
    fn name(&self) -> &'static str;

    /// Plans `problem` within `budget`; whatever is random is seeded by
    /// `seed`, so that a plan is a function of the problem and the seed.
    /// Engines a problem needs are built on first use (`ready` builds them
    /// ahead).
    fn plan(&mut self, problem: &Problem, budget: &Budget<'_>, seed: u64) -> Result<Planned, PlanError>;

    /// Builds what planning for `team` with `obstacles` obstacles needs
    /// (factorisations), so that a timed plan does not pay for it.
    fn ready(&mut self, team: &Team, obstacles: usize) -> Result<(), PlanError>;
}
