//! The pipeline's settings, with their defaults.

use serde::{Deserialize, Serialize};

use crate::flow::Solver;
use crate::shipped::WeightsRef;

/// The default weight of the safety filter's smoothness-weighted metric
/// (`Objective::SmoothProjection`) for the pipeline. Measured on 20 unseen
/// 2D instances each (docs/LEARNED.md): at 0 (the paper's plain projection)
/// the filter's minimal-distance repairs add sharp detours (smoothness 5-6x
/// the optimiser's at 16 robots); 3 brings it within 15% at 8, 16 and 32
/// robots with every instance solved; 5 and above lose 32-robot instances
/// to the iteration cap.
pub const DEFAULT_SF_SMOOTHING: f64 = 3.0;

/// The learned pipeline's settings: its weights and how it runs, every
/// knob with its default declared once ([`Default`]). A daemon team's
/// `[team.planner.learned]` table and `flowopt bench --set learned.KEY=V`
/// read it; keys left out keep their defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineSettings {
    /// Flow policy weights: `"shipped"` (the shipped weights of the team's
    /// dimension, built into the binary) or a file.
    pub flow: WeightsRef,
    /// SF initialiser weights, for the methods that start the safety filter
    /// from it (`flowopt`: these or the shipped ones; `auto`: these where
    /// given, else none).
    pub init: Option<WeightsRef>,
    /// Weight of the correction's smoothness in the safety filter's metric
    /// (`Objective::SmoothProjection`; 0 is the paper's plain projection).
    pub sf_smoothing: f64,
    /// Candidates sampled per problem without obstacles (at least 1 is
    /// sampled).
    pub candidates: usize,
    /// Candidates sampled per problem with obstacles (static or moving),
    /// where fewer lose instances.
    pub obstacle_candidates: usize,
    /// Flow integration steps for problems without obstacles.
    pub flow_steps: usize,
    /// Flow integration steps for problems with obstacles (static or
    /// moving), where one step loses instances.
    pub obstacle_flow_steps: usize,
    /// Flow integrator.
    pub solver: Solver,
    /// Candidates refined by the safety filter (clamped to 1..=candidates).
    pub top_k: usize,
    /// Start the SF from the initialiser (`false`, or no initialiser
    /// loaded: from the samples with a zero multiplier, the `flow-no-init`
    /// ablation), on problems with obstacles only unless
    /// `init_without_obstacles` ([`Self::init_for`]). Set by the method
    /// (`flowopt` uses the initialiser, `flow-no-init` does not), not a knob.
    #[serde(skip)]
    pub use_init: bool,
    /// Use the initialiser on problems without obstacles too. Off by
    /// default: there it lowered no scene's filter iterations by more than
    /// 2% and cost 0.2-0.7 ms of the plan (docs/LEARNED.md, "The
    /// initialiser where it can matter"); with obstacles it is what
    /// verifies the 16-robot obstacle field at all.
    pub init_without_obstacles: bool,
    /// Threads sampling (the candidates split between them) and refining
    /// candidates in parallel, for problems without obstacles: 1 (two cores
    /// slow each other on batches this small). Not a key: the planner
    /// settings' `threads` caps it (`PlannerSettings::learned`).
    #[serde(skip)]
    pub threads: usize,
    /// The same for problems with obstacles (static or moving): 2. Not a
    /// key either.
    #[serde(skip)]
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
    /// Most rounds [`super::FlowOpt::plan_batch`] samples a problem in: while no
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
            flow: WeightsRef::Shipped,
            init: None,
            sf_smoothing: DEFAULT_SF_SMOOTHING,
            candidates: 4,
            obstacle_candidates: 8,
            flow_steps: 1,
            obstacle_flow_steps: 2,
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
        if obstacles == 0 { self.flow_steps } else { self.obstacle_flow_steps }
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
