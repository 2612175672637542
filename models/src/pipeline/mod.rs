//! The Flow-Opt pipeline (METHOD.md section 5): sample candidates from the
//! flow policy, reroute the robots a sample leaves inside a static obstacle
//! (the policy barely reads obstacles: docs/LEARNED.md), rank the
//! candidates by primal residual, start the safety filter on
//! the best few (from the initialiser's output, or from the samples
//! themselves for the `flow-no-init` ablation), and return the
//! best-ranked verified plan (or the smoothest: [`Settle`]). Every stage
//! is timed.
//!
//! - [`settings`]: [`PipelineSettings`] and their defaults;
//! - [`model`]: the networks ([`FlowOpt`]) and their sampling;
//! - [`round`]: sample, rank, initialise, refine, round after round;
//! - [`refine`]: the safety filter on the ranked candidates, and selection;
//! - [`outcome`]: what a query returns;
//! - [`learned`]: the loaded planner ([`LearnedPlanner`]) and the pipeline
//!   as a [`flowopt_planner::method::Planner`] ([`LearnedPipeline`]).

mod learned;
mod model;
mod outcome;
mod refine;
mod round;
mod settings;

pub use learned::{LearnedPipeline, LearnedPlanner};
pub use model::FlowOpt;
pub use outcome::{PipelineOutcome, Query, Refined};
pub use settings::{DEFAULT_SF_SMOOTHING, PipelineSettings, Settle};
