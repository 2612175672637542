//! The SF initialiser (METHOD.md section 4): one transformer block that
//! reads a flow sample's tokens with the robots' start-goal rows and the
//! obstacles, and outputs the safety filter's starting point
//! `(xi_bar^0, lambda^0)`: a correction of the sample's token (in the
//! policy's token space, [`crate::tokens`]) and a multiplier for every
//! coefficient. Its output heads
//! start at zero, so an untrained initialiser is exactly the plain start
//! (`xi_bar^0 = xi`, `lambda^0 = 0`, the `flow-no-init` ablation) and
//! training can only move away from it where that lowers the loss.

use candle_core::{Result, Tensor};
use candle_nn::VarBuilder;
use serde::{Deserialize, Serialize};

use crate::layers::{Block, Dense, Mlp};

/// Sizes of the initialiser.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitConfig {
    /// Workspace dimension.
    pub dim: usize,
    /// Bernstein coefficients per curve.
    pub n_xi: usize,
    /// Token width.
    pub width: usize,
    /// Attention heads.
    pub heads: usize,
    /// MLP hidden width.
    pub hidden: usize,
    /// Multiplier units: the network's output times this.
    pub lambda_scale: f64,
    /// Unrolled SF iterations it was trained through.
    pub unroll: usize,
    /// Smoothing weight of the SF metric it was trained through
    /// (`Objective::filter`; default and weights from before the field: 0,
    /// the plain projection, as the shipped initialiser).
    #[serde(default)]
    pub sf_smoothing: f64,
}

impl InitConfig {
    /// The default size.
    pub fn small(dim: usize, n_xi: usize) -> Self {
        Self { dim, n_xi, width: 64, heads: 4, hidden: 128, lambda_scale: 1.0, unroll: 15, sf_smoothing: 0.0 }
    }
}

/// The initialiser network.
#[derive(Debug, Clone)]
pub struct InitModel {
    config: InitConfig,
    token_in: Dense,
    robot_encoder: Mlp,
    obstacle_encoder: Mlp,
    block: Block,
    xi_head: Dense,
    lambda_head: Dense,
}

/// The initialiser's output for a batch.
#[derive(Debug, Clone)]
pub struct InitOutput {
    /// Correction of the normalised sample tokens, `[B, n, W]` (times the
    /// token std gives a change of tokens in the policy's token space,
    /// [`crate::tokens::TokenMap::to_coefficients`] then coefficients).
    pub delta: Tensor,
    /// Multipliers, `[B, D, n, n_xi]`.
    pub lambda: Tensor,
}

impl InitModel {
    /// The model under `vb`.
    pub fn new(vb: VarBuilder, config: &InitConfig) -> Result<Self> {
        let d = config.width;
        let w = crate::coding::token_width(config.dim, config.n_xi);
        Ok(Self {
            config: config.clone(),
            token_in: Dense::new(vb.pp("token_in"), w, d)?,
            robot_encoder: Mlp::new(vb.pp("robot_encoder"), crate::coding::robot_width(config.dim), d, d)?,
            obstacle_encoder: Mlp::new(vb.pp("obstacle_encoder"), crate::coding::obstacle_width(config.dim), d, d)?,
            block: Block::new(vb.pp("block"), d, config.heads, config.hidden)?,
            xi_head: Dense::new(vb.pp("zero").pp("xi_head"), d, w)?,
            lambda_head: Dense::new(vb.pp("zero").pp("lambda_head"), d, config.dim * config.n_xi)?,
        })
    }

    /// Its configuration.
    pub fn config(&self) -> &InitConfig {
        &self.config
    }

    /// The starting point for normalised sample tokens (`[B, n, W]`), robot
    /// rows (`[B or 1, n, 3 dim]`) and obstacle rows (`[B, m, .]`, m >= 0).
    pub fn forward(&self, tokens: &Tensor, robots: &Tensor, obstacles: &Tensor) -> Result<InitOutput> {
        let (b, n, _) = tokens.dims3()?;
        let cond = self.robot_encoder.forward(robots)?;
        let obstacles = if obstacles.dim(1)? == 0 {
            None
        } else {
            Some(self.block.obstacle_context(&self.obstacle_encoder.forward(obstacles)?)?)
        };
        let h = self.token_in.forward(tokens)?.broadcast_add(&cond)?;
        let h = self.block.forward(&h, &cond.silu()?, obstacles.as_ref())?;
        let lambda = (self.lambda_head.forward(&h)? * self.config.lambda_scale)?
            .reshape((b, n, self.config.dim, self.config.n_xi))?
            .transpose(1, 2)?
            .contiguous()?;
        Ok(InitOutput { delta: self.xi_head.forward(&h)?, lambda })
    }
}

/// Spreads token-layout interior values (`[B, n, dim x interior]`) into
/// full coefficient layout (`[B, D, n, n_xi]`, zeros at the boundary
/// coefficients).
pub fn tokens_to_coefficients(tokens: &Tensor, dim: usize, n_xi: usize) -> Result<Tensor> {
    let (b, n, w) = tokens.dims3()?;
    let interior = w / dim;
    let edge = (n_xi - interior) / 2;
    let t = tokens.reshape((b, n, dim, interior))?.transpose(1, 2)?;
    let zeros = Tensor::zeros((b, dim, n, edge), tokens.dtype(), tokens.device())?;
    Tensor::cat(&[&zeros, &t, &zeros], 3)?.contiguous()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_from_before_the_metric_field_were_trained_through_the_plain_projection() {
        let old = r#"{"dim":2,"n_xi":11,"width":64,"heads":4,"hidden":128,"lambda_scale":1.0,"unroll":15}"#;
        let config: InitConfig = serde_json::from_str(old).expect("an old configuration parses");
        assert_eq!(config, InitConfig::small(2, 11));
    }
}
