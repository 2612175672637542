//! The flow-matching policy (METHOD.md section 3): a velocity field over
//! plan tokens (one per robot; [`crate::coding`]) conditioned on the flow
//! time, the robots' start-goal-velocity rows and the obstacles.
//!
//! - Conditioning: a start-goal encoder (MLP over each robot's row) gives a
//!   per-robot embedding, added to the token and, with the time embedding,
//!   driving every block's adaLN; obstacles go through a PointNet (a shared
//!   MLP per obstacle row) and are read by cross-attention, so the model is
//!   invariant to obstacle order and count. With [`FlowConfig::pairs`] a
//!   third MLP reads each robot-obstacle pair row ([`crate::pairs`]): their
//!   sum over the obstacles joins the robot's embedding, and each robot
//!   attends to its own pairs (obstacle token plus pair embedding).
//! - The cross-attentions' keys and values depend on the problem only: they
//!   are projected once per problem ([`FlowModel::encode`]), not per step.
//! - No robot-index embedding: tokens are told apart by their conditions, so
//!   the model is permutation-equivariant and serves any team size.
//! - Sampling integrates `dx/dt = v(x, t)` from noise at `t = 0` to `t = 1`
//!   with Euler or midpoint (RK2) steps, batched over candidates; the
//!   conditioning is encoded once per problem and broadcast.

use candle_core::{Device, Result, Tensor};
use candle_nn::VarBuilder;
use serde::{Deserialize, Serialize};

use crate::layers::{Block, Dense, Mlp, modulate, norm, time_embedding};
use crate::tokens::TokenSpace;

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
    /// What the tokens hold (weights from before the field: coefficients).
    #[serde(default)]
    pub tokens: TokenSpace,
    /// Whether it reads the robot-obstacle pair rows (weights from before
    /// the field: no).
    #[serde(default)]
    pub pairs: bool,
}

impl FlowConfig {
    /// The default size for this CPU (see docs/LEARNED.md for the timing),
    /// in positions and with pair rows.
    pub fn small(dim: usize, n_xi: usize) -> Self {
        Self {
            dim,
            n_xi,
            width: 128,
            heads: 4,
            layers: 3,
            hidden: 256,
            time_freqs: 32,
            tokens: TokenSpace::Positions,
            pairs: true,
        }
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
    /// Per-robot embeddings, `[B or 1, n, D]`.
    pub robots: Tensor,
    /// Per block, the cross-attention's keys and values of the obstacles
    /// (`[B or 1, m, 2D]`, or one context per robot with pair rows,
    /// `[B or 1, n, m, 2D]`); `None` without obstacles.
    pub obstacles: Option<Vec<Tensor>>,
}

impl Encoded {
    /// Every problem's conditioning repeated for its `count` candidates
    /// (problem-major).
    pub fn repeat_each(&self, count: usize) -> Result<Self> {
        let each = |t: &Tensor| repeat_each(t, count);
        Ok(Self {
            robots: each(&self.robots)?,
            obstacles: self.obstacles.as_ref().map(|o| o.iter().map(each).collect()).transpose()?,
        })
    }

    /// The conditioning of candidates `first..first + len` (a conditioning
    /// broadcast over the batch stays as it is).
    pub fn rows(&self, first: usize, len: usize) -> Result<Self> {
        let rows = |t: &Tensor| if t.dim(0)? == 1 { Ok(t.clone()) } else { t.narrow(0, first, len) };
        Ok(Self {
            robots: rows(&self.robots)?,
            obstacles: self.obstacles.as_ref().map(|o| o.iter().map(rows).collect()).transpose()?,
        })
    }
}

/// `t` (`[P, ...]`) with each of its rows repeated `count` times in a row.
fn repeat_each(t: &Tensor, count: usize) -> Result<Tensor> {
    if count == 1 {
        return Ok(t.clone());
    }
    let mut dims = t.dims().to_vec();
    let rows = dims[0];
    dims.insert(1, count);
    let mut flat = dims.clone();
    flat.remove(1);
    flat[0] = rows * count;
    t.unsqueeze(1)?.broadcast_as(dims)?.contiguous()?.reshape(flat)
}

/// The velocity field network.
#[derive(Debug, Clone)]
pub struct FlowModel {
    config: FlowConfig,
    token_in: Dense,
    robot_encoder: Mlp,
    obstacle_encoder: Mlp,
    pair_encoder: Option<Mlp>,
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
            pair_encoder: if config.pairs {
                Some(Mlp::new(vb.pp("pair_encoder"), crate::pairs::pair_width(dim), d, d)?)
            } else {
                None
            },
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

    /// Encodes normalised robot rows (`[B, n, 3 dim]`), obstacle rows
    /// (`[B, m, 2 dim + 2]`; `m = 0` for none) and, for a policy with
    /// [`FlowConfig::pairs`], the pair rows (`[B, n, m, pair_width]`, as
    /// [`crate::pairs::pair_rows`] writes them: already in scaled units, not
    /// normalised).
    pub fn encode(&self, robots: &Tensor, obstacles: &Tensor, pairs: Option<&Tensor>) -> Result<Encoded> {
        let mut embedding = self.robot_encoder.forward(robots)?;
        if obstacles.dim(1)? == 0 {
            return Ok(Encoded { robots: embedding, obstacles: None });
        }
        let mut context = self.obstacle_encoder.forward(obstacles)?;
        if let Some(encoder) = &self.pair_encoder {
            let Some(pairs) = pairs else { candle_core::bail!("this flow policy reads pair rows") };
            let pairs = encoder.forward(pairs)?;
            embedding = (embedding + pairs.sum(2)?)?;
            context = pairs.broadcast_add(&context.unsqueeze(1)?)?;
        }
        let obstacles = self.blocks.iter().map(|b| b.obstacle_context(&context)).collect::<Result<_>>()?;
        Ok(Encoded { robots: embedding, obstacles: Some(obstacles) })
    }

    /// Whether it reads pair rows.
    pub fn reads_pairs(&self) -> bool {
        self.pair_encoder.is_some()
    }

    /// The velocity at normalised tokens `x` (`[B, n, W]`) and times `t`
    /// (`[B]`, or `[1]` shared by the batch).
    pub fn velocity(&self, x: &Tensor, t: &Tensor, encoded: &Encoded) -> Result<Tensor> {
        let time = self.time.forward(&time_embedding(t, self.config.time_freqs)?)?.unsqueeze(1)?;
        let c = encoded.robots.broadcast_add(&time)?.silu()?;
        let mut h = self.token_in.forward(x)?.broadcast_add(&encoded.robots)?;
        for (k, block) in self.blocks.iter().enumerate() {
            h = block.forward(&h, &c, encoded.obstacles.as_ref().map(|o| &o[k]))?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_from_before_the_token_and_pair_fields_read_coefficients_without_pairs() {
        let old = r#"{"dim":3,"n_xi":11,"width":128,"heads":4,"layers":3,"hidden":256,"time_freqs":32}"#;
        let config: FlowConfig = serde_json::from_str(old).expect("an old configuration parses");
        assert_eq!((config.tokens, config.pairs), (TokenSpace::Coefficients, false));
        assert_eq!(FlowConfig { tokens: TokenSpace::Positions, pairs: true, ..config }, FlowConfig::small(3, 11));
    }
}
