//! The learned half of Flow-Opt (METHOD.md sections 3-5), in candle:
//!
//! - [`coding`]: how problems and plans are presented to the networks;
//! - [`tokens`]: what the flow policy's tokens hold (coefficients or
//!   positions);
//! - [`pairs`]: where each obstacle lies against each robot's reference;
//! - [`dataset`], [`datagen`]: optimiser solutions as training data;
//! - [`layers`]: the building blocks, laid out for inference;
//! - [`flow`]: the flow-matching policy and its samplers;
//! - [`init`]: the SF initialiser;
//! - [`unrolled`]: the differentiable safety filter it is trained through;
//! - [`train`]: training loops, checkpoints and model cards;
//! - [`weights`]: weight files with their configuration and statistics;
//! - [`shipped`]: weight files on disk or built in (the shipped weights);
//! - [`pipeline`]: sample, rank, initialise, filter, select.

pub mod coding;
pub mod datagen;
pub mod dataset;
pub mod flow;
pub mod init;
pub mod layers;
pub mod pairs;
pub mod pipeline;
pub mod runtime;
pub mod shipped;
pub mod tokens;
pub mod train;
pub mod unrolled;
pub mod weights;

use std::path::Path;

use thiserror::Error;

/// Why a learned-planner operation failed.
#[derive(Debug, Error)]
pub enum ModelError {
    /// A tensor operation failed.
    #[error("ModelError::Tensor: {0}")]
    Tensor(#[from] candle_core::Error),
    /// A file could not be read or written.
    #[error("ModelError::Io: {path}: {message}")]
    Io {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A file's contents are not what they should be.
    #[error("ModelError::Format: {0}")]
    Format(String),
    /// A configuration is inconsistent.
    #[error("ModelError::Config: {0}")]
    Config(String),
    /// An instance could not be generated.
    #[error("ModelError::Scenario: {0}")]
    Scenario(#[from] flowopt_planner::scenario::ScenarioError),
    /// The planner refused a problem or could not be built.
    #[error("ModelError::Engine: {0}")]
    Engine(#[from] flowopt_planner::am::EngineError),
    /// The caller's budget ran out (a deadline, or another planner won)
    /// before the samples were drawn.
    #[error("ModelError::Stopped: the budget ran out while sampling")]
    Stopped,
    /// The reference curves could not be built.
    #[error("ModelError::Reference: {0}")]
    Reference(#[from] flowopt_planner::reference::ReferenceError),
}

impl ModelError {
    fn io(path: &Path, e: std::io::Error) -> Self {
        ModelError::Io { path: path.display().to_string(), message: e.to_string() }
    }
}
