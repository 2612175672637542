//! The flow-matching policy (METHOD.md section 3): a velocity field over
//! plan tokens (one per robot; [`crate::coding`]) conditioned on the flow
//! time, the robots' start-goal-velocity rows and the obstacles.
//!
//! - Conditioning: a start-goal encoder (MLP over each robot's row) gives a
//!   per-robot embedding, added to the token and, with the time embedding,
//!   driving every block's adaLN; obstacles go through a PointNet (a shared
//!   MLP per obstacle row) and are read by cross-attention, so the model is
//!   invariant to obstacle order and count.
//! - No robot-index embedding: tokens are told apart by their conditions, so
//!   the model is permutation-equivariant and serves any team size.
//! - Sampling integrates `dx/dt = v(x, t)` from noise at `t = 0` to `t = 1`
//!   with Euler or midpoint (RK2) steps, batched over candidates; the
//!   conditioning is encoded once per problem and broadcast.

use candle_core::{Device, Result, Tensor};
use candle_nn::VarBuilder;
use serde::{Deserialize, Serialize};

use crate::layers::{Block, Dense, Mlp, modulate, norm, time_embedding};

/// Sizes of the flow model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlowConfig {
    /// Workspace dimension.
    pub dim: usize,
    /// Bernstein coefficients per curve.
    pub n_xi: usize,
    /// Token width `D`.
    pub width: usize,
    /// Attention heads.
    pub heads: usize,
    /// DiT blocks.
    pub layers: usize,
    /// MLP hidden width.
    pub hidden: usize,
    /// Sinusoidal time frequencies.
    pub time_freqs: usize,
}

impl FlowConfig {
    /// The default size for this CPU (see docs/LEARNED.md for the timing).
    pub fn small(dim: usize, n_xi: usize) -> Self {
        Self { dim, n_xi, width: 128, heads: 4, layers: 3, hidden: 256, time_freqs: 32 }
    }

    /// Values per plan token.
    pub fn token_width(&self) -> usize {
        crate::coding::token_width(self.dim, self.n_xi)
    }
}

/// How to integrate the flow.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// Explicit Euler: one network call per step.
    Euler,
    /// Explicit midpoint (RK2): two network calls per step.
    Midpoint,
}

/// The conditioning of one batch, encoded once.
#[derive(Debug, Clone)]
pub struct Encoded {
    /// Per-robot start-goal embeddings, `[B or 1, n, D]`.
    pub robots: Tensor,
    /// Obstacle tokens, `[B, m, D]`, or `None` without obstacles.
    pub obstacles: Option<Tensor>,
}

/// The velocity field network.
#[derive(Debug, Clone)]
pub struct FlowModel {
    config: FlowConfig,
    token_in: Dense,
    robot_encoder: Mlp,
    obstacle_encoder: Mlp,
    time: Mlp,
    blocks: Vec<Block>,
    final_modulation: Dense,
    head: Dense,
}

impl FlowModel {
    /// The model under `vb`.
    pub fn new(vb: VarBuilder, config: &FlowConfig) -> Result<Self> {
        let d = config.width;
        let dim = config.dim;
        Ok(Self {
            config: config.clone(),
            token_in: Dense::new(vb.pp("token_in"), config.token_width(), d)?,
            robot_encoder: Mlp::new(vb.pp("robot_encoder"), crate::coding::robot_width(dim), d, d)?,
            obstacle_encoder: Mlp::new(vb.pp("obstacle_encoder"), crate::coding::obstacle_width(dim), d, d)?,
            time: Mlp::new(vb.pp("time"), 2 * config.time_freqs, d, d)?,
            blocks: (0..config.layers)
                .map(|l| Block::new(vb.pp(format!("block{l}")), d, config.heads, config.hidden))
                .collect::<Result<_>>()?,
            final_modulation: Dense::new(vb.pp("zero").pp("final_modulation"), d, 2 * d)?,
            head: Dense::new(vb.pp("zero").pp("head"), d, config.token_width())?,
        })
    }

    /// Its configuration.
    pub fn config(&self) -> &FlowConfig {
        &self.config
    }

    /// Encodes normalised robot rows (`[B, n, 3 dim]`) and obstacle rows
    /// (`[B, m, 2 dim + 2]`; `m = 0` for none).
    pub fn encode(&self, robots: &Tensor, obstacles: &Tensor) -> Result<Encoded> {
        let obstacles = if obstacles.dim(1)? == 0 { None } else { Some(self.obstacle_encoder.forward(obstacles)?) };
        Ok(Encoded { robots: self.robot_encoder.forward(robots)?, obstacles })
    }

    /// The velocity at normalised tokens `x` (`[B, n, W]`) and times `t`
    /// (`[B]`, or `[1]` shared by the batch).
    pub fn velocity(&self, x: &Tensor, t: &Tensor, encoded: &Encoded) -> Result<Tensor> {
        let time = self.time.forward(&time_embedding(t, self.config.time_freqs)?)?.unsqueeze(1)?;
        let c = encoded.robots.broadcast_add(&time)?.silu()?;
        let mut h = self.token_in.forward(x)?.broadcast_add(&encoded.robots)?;
        for block in &self.blocks {
            h = block.forward(&h, &c, encoded.obstacles.as_ref())?;
        }
        let m = self.final_modulation.forward(&c)?.chunk(2, candle_core::D::Minus1)?;
        self.head.forward(&modulate(&norm(&h)?, &m[0], &m[1])?)
    }

    /// Integrates the flow from `noise` (`[B, n, W]`, t = 0) to t = 1 in
    /// `steps` steps of `solver`; `None` when `stop` returns true between
    /// two steps (the caller no longer needs the samples).
    pub fn sample(
        &self,
        noise: &Tensor,
        encoded: &Encoded,
        steps: usize,
        solver: Solver,
        stop: &dyn Fn() -> bool,
    ) -> Result<Option<Tensor>> {
        let steps = steps.max(1);
        let dt = 1.0 / steps as f64;
        let at = |t: f64| Tensor::new(&[t as f32], &Device::Cpu);
        let mut x = noise.clone();
        for s in 0..steps {
            if stop() {
                return Ok(None);
            }
            let t = s as f64 * dt;
            let v = match solver {
                Solver::Euler => self.velocity(&x, &at(t)?, encoded)?,
                Solver::Midpoint => {
                    let half = (&x + (self.velocity(&x, &at(t)?, encoded)? * (dt / 2.0))?)?;
                    self.velocity(&half, &at(t + dt / 2.0)?, encoded)?
                }
            };
            x = (x + (v * dt)?)?;
        }
        Ok(Some(x))
    }

    /// The conditional flow-matching loss on normalised data tokens `x1`
    /// with noise `x0` and times `t` (`[B]`): `mean ||v(x_t, t) - (x1 - x0)||^2`
    /// with `x_t = (1 - t) x0 + t x1`.
    pub fn loss(&self, x1: &Tensor, x0: &Tensor, t: &Tensor, encoded: &Encoded) -> Result<Tensor> {
        let target = (x1 - x0)?;
        let tb = t.reshape(((), 1, 1))?;
        let xt = (x0 + target.broadcast_mul(&tb)?)?;
        let v = self.velocity(&xt, t, encoded)?;
        (v - target)?.sqr()?.mean_all()
    }
}
