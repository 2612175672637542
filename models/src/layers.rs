//! Building blocks shared by the flow policy and the initialiser, laid out
//! for CPU inference: dense weights are stored `[in, out]` so a product is
//! one contiguous GEMM (candle's `Linear` multiplies by a transposed
//! `[out, in]` weight, about 3x slower here); activations are SiLU (erf-GELU
//! costs 4-10x more); LayerNorm and softmax use the differentiable ops, as
//! fast on CPU as the fused ones, so training and inference share one path.
//!
//! Parameter names carry their initialisation ([`initialise`]): `*.w` is
//! normal with standard deviation `1/sqrt(in)`, `*.b` zero, and every
//! parameter under a `zero` prefix starts at zero (adaLN-Zero gates and
//! output heads, so a fresh block is the identity).

use candle_core::{D, DType, Device, Result, Tensor, Var};
use candle_nn::{Init, VarBuilder, VarMap};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// `y = x W + b` with `W` stored `[in, out]`.
#[derive(Debug, Clone)]
pub struct Dense {
    w: Tensor,
    b: Tensor,
}

impl Dense {
    /// The layer `input -> output` under `vb`.
    pub fn new(vb: VarBuilder, input: usize, output: usize) -> Result<Self> {
        Ok(Self {
            w: vb.get_with_hints((input, output), "w", Init::Const(0.0))?,
            b: vb.get_with_hints(output, "b", Init::Const(0.0))?,
        })
    }

    /// Applies the layer to the last axis of `x` (any leading axes).
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        x.broadcast_matmul(&self.w)?.broadcast_add(&self.b)
    }
}

/// A two-layer perceptron with a SiLU between.
#[derive(Debug, Clone)]
pub struct Mlp {
    first: Dense,
    second: Dense,
}

impl Mlp {
    /// `input -> hidden -> output` under `vb`.
    pub fn new(vb: VarBuilder, input: usize, hidden: usize, output: usize) -> Result<Self> {
        Ok(Self { first: Dense::new(vb.pp("in"), input, hidden)?, second: Dense::new(vb.pp("out"), hidden, output)? })
    }

    /// Applies it to the last axis.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        self.second.forward(&self.first.forward(x)?.silu()?)
    }
}

/// LayerNorm over the last axis without an affine part (adaLN supplies it).
pub fn norm(x: &Tensor) -> Result<Tensor> {
    let centred = x.broadcast_sub(&x.mean_keepdim(D::Minus1)?)?;
    let var = centred.sqr()?.mean_keepdim(D::Minus1)?;
    centred.broadcast_div(&(var + 1e-5)?.sqrt()?)
}

/// `x (1 + scale) + shift`, broadcasting the modulation over candidates.
pub fn modulate(x: &Tensor, shift: &Tensor, scale: &Tensor) -> Result<Tensor> {
    x.broadcast_mul(&(scale + 1.0)?)?.broadcast_add(shift)
}

/// Multi-head attention of `x` (`[B, n, D]`) over a context: the same
/// context for every token (`[B, m, D]`), or one per token (`[B, n, m, D]`).
/// The context's keys and values can be projected once ([`Attention::keys_values`])
/// and reused for every call that reads the same context.
#[derive(Debug, Clone)]
pub struct Attention {
    q: Dense,
    kv: Dense,
    out: Dense,
    heads: usize,
}

impl Attention {
    /// Width `width` split into `heads` heads; `zero_out` starts the output
    /// projection at zero (a fresh cross-attention adds nothing).
    pub fn new(vb: VarBuilder, width: usize, heads: usize, zero_out: bool) -> Result<Self> {
        let out = if zero_out { vb.pp("zero").pp("out") } else { vb.pp("out") };
        Ok(Self {
            q: Dense::new(vb.pp("q"), width, width)?,
            kv: Dense::new(vb.pp("kv"), width, 2 * width)?,
            out: Dense::new(out, width, width)?,
            heads,
        })
    }

    /// The keys and values of `context` (`[B, m, D]` or `[B, n, m, D]`; the
    /// result has its shape with `2 D` last).
    pub fn keys_values(&self, context: &Tensor) -> Result<Tensor> {
        self.kv.forward(context)
    }

    /// Attends from `x` to `context`.
    pub fn forward(&self, x: &Tensor, context: &Tensor) -> Result<Tensor> {
        self.attend(x, &self.keys_values(context)?)
    }

    /// Attends from `x` (`[B, n, D]`) to projected keys and values
    /// (`[B or 1, m, 2D]` shared by the tokens, or `[B or 1, n, m, 2D]`, one
    /// context per token).
    pub fn attend(&self, x: &Tensor, kv: &Tensor) -> Result<Tensor> {
        let (b, n, d) = x.dims3()?;
        let (h, dh) = (self.heads, d / self.heads);
        let scale = 1.0 / (dh as f64).sqrt();
        let q = self.q.forward(x)?;
        let y = if kv.rank() == 3 {
            let (bk, m, _) = kv.dims3()?;
            let q = q.reshape((b, n, h, dh))?.transpose(1, 2)?.contiguous()?;
            let kv = kv.reshape((bk, m, 2, h, dh))?;
            let k = kv.narrow(2, 0, 1)?.squeeze(2)?.permute((0, 2, 3, 1))?.contiguous()?;
            let v = kv.narrow(2, 1, 1)?.squeeze(2)?.transpose(1, 2)?.contiguous()?;
            let att = candle_nn::ops::softmax(&(q.broadcast_matmul(&k)? * scale)?, D::Minus1)?;
            att.broadcast_matmul(&v)?.transpose(1, 2)?.reshape((b, n, d))?
        } else {
            // Token i of every candidate that shares a context attends to
            // the same keys: one small product per (context, token, head)
            // over the `g` candidates.
            let (bk, nk, m, _) = kv.dims4()?;
            if nk != n || bk == 0 || b % bk != 0 {
                candle_core::bail!("{nk} contexts of {bk} for {n} tokens of {b}");
            }
            let (g, batch) = (b / bk, bk * n * h);
            let q = q.reshape((bk, g, n, h, dh))?.permute((0, 2, 3, 1, 4))?.contiguous()?.reshape((batch, g, dh))?;
            let kv = kv.reshape((bk, n, m, 2, h, dh))?;
            let k = kv.narrow(3, 0, 1)?.squeeze(3)?.permute((0, 1, 3, 4, 2))?.contiguous()?.reshape((batch, dh, m))?;
            let v = kv.narrow(3, 1, 1)?.squeeze(3)?.permute((0, 1, 3, 2, 4))?.contiguous()?.reshape((batch, m, dh))?;
            let att = candle_nn::ops::softmax(&(q.matmul(&k)? * scale)?, D::Minus1)?;
            att.matmul(&v)?.reshape((bk, n, h, g, dh))?.permute((0, 3, 1, 2, 4))?.reshape((b, n, d))?
        };
        self.out.forward(&y)
    }
}

/// A transformer block with per-token adaLN-Zero conditioning: self-attention
/// over the robot tokens, cross-attention to obstacle tokens when there are
/// any, and an MLP.
#[derive(Debug, Clone)]
pub struct Block {
    modulation: Dense,
    attention: Attention,
    cross: Attention,
    mlp: Mlp,
}

impl Block {
    /// A block of `width` with `heads` heads and MLP `hidden`.
    pub fn new(vb: VarBuilder, width: usize, heads: usize, hidden: usize) -> Result<Self> {
        Ok(Self {
            modulation: Dense::new(vb.pp("zero").pp("modulation"), width, 6 * width)?,
            attention: Attention::new(vb.pp("attention"), width, heads, false)?,
            cross: Attention::new(vb.pp("cross"), width, heads, true)?,
            mlp: Mlp::new(vb.pp("mlp"), width, hidden, width)?,
        })
    }

    /// The cross-attention's keys and values of obstacle tokens (see
    /// [`Attention::keys_values`]), for [`Block::forward`].
    pub fn obstacle_context(&self, obstacles: &Tensor) -> Result<Tensor> {
        self.cross.keys_values(obstacles)
    }

    /// The block on tokens `x` (`[B, n, D]`) with activated conditioning
    /// `c` (`[B or 1, n, D]`) and the obstacles' context from
    /// [`Block::obstacle_context`] (m >= 1).
    pub fn forward(&self, x: &Tensor, c: &Tensor, obstacles: Option<&Tensor>) -> Result<Tensor> {
        let m = self.modulation.forward(c)?.chunk(6, D::Minus1)?;
        let h = modulate(&norm(x)?, &m[0], &m[1])?;
        let mut x = (x + self.attention.forward(&h, &h)?.broadcast_mul(&m[2])?)?;
        if let Some(o) = obstacles {
            x = (&x + self.cross.attend(&norm(&x)?, o)?)?;
        }
        let h = modulate(&norm(&x)?, &m[3], &m[4])?;
        &x + self.mlp.forward(&h)?.broadcast_mul(&m[5])?
    }
}

/// Sinusoidal embedding of times in `[0, 1]` (`[B]` -> `[B, 2 freqs]`),
/// frequencies geometric from 1 to 1000.
pub fn time_embedding(t: &Tensor, freqs: usize) -> Result<Tensor> {
    let f: Vec<f32> = (0..freqs).map(|i| (1000f32.ln() * i as f32 / (freqs.max(2) - 1) as f32).exp()).collect();
    let f = Tensor::from_vec(f, (1, freqs), t.device())?.to_dtype(t.dtype())?;
    let arg = t.unsqueeze(1)?.broadcast_mul(&f)?;
    Tensor::cat(&[arg.sin()?, arg.cos()?], 1)
}

/// Overwrites every variable of `vars` with its seeded initial value (see
/// the module docs), in name order so the result depends on `seed` only.
pub fn initialise(vars: &VarMap, seed: u64) -> Result<()> {
    let mut named: Vec<(String, Var)> = match vars.data().lock() {
        Ok(data) => data.iter().map(|(k, v)| (k.clone(), v.clone())).collect(),
        Err(_) => candle_core::bail!("the variable map is poisoned"),
    };
    named.sort_by(|a, b| a.0.cmp(&b.0));
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for (name, var) in named {
        let dims = var.dims().to_vec();
        let count: usize = dims.iter().product();
        let zero = name.split('.').any(|p| p == "zero") || name.ends_with(".b");
        let values: Vec<f32> = if zero {
            vec![0.0; count]
        } else {
            let std = 1.0 / (dims[0] as f32).sqrt();
            (0..count)
                .map(|_| {
                    let z: f32 = StandardNormal.sample(&mut rng);
                    std * z
                })
                .collect::<Vec<f32>>()
        };
        var.set(&Tensor::from_vec(values, dims, &Device::Cpu)?.to_dtype(var.dtype())?)?;
    }
    Ok(())
}

/// Seeded standard-normal noise of `shape` (f32).
pub fn noise(rng: &mut ChaCha8Rng, shape: &[usize], device: &Device) -> Result<Tensor> {
    let count = shape.iter().product();
    let values: Vec<f32> = (0..count).map(|_| StandardNormal.sample(rng)).collect();
    Tensor::from_vec(values, shape, device)?.to_dtype(DType::F32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    fn close(a: &Tensor, b: &Tensor) -> f32 {
        (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap()
    }

    #[test]
    fn each_token_attends_to_its_own_context() {
        let vars = VarMap::new();
        let vb = VarBuilder::from_varmap(&vars, DType::F32, &Device::Cpu);
        let (width, heads, b, n, m) = (8, 2, 6, 3, 4);
        let attention = Attention::new(vb, width, heads, false).unwrap();
        let x = Tensor::randn(0f32, 1.0, (b, n, width), &Device::Cpu).unwrap();
        // Per token, shared by all candidates (`[1, n, m, D]`), by each
        // group of 3 (two problems, `[2, n, m, D]`) and one per candidate
        // (`[B, n, m, D]`): token i of candidate c attends as every token
        // does to c's context i alone.
        for contexts in [1, 2, b] {
            let context = Tensor::randn(0f32, 1.0, (contexts, n, m, width), &Device::Cpu).unwrap();
            let got = attention.attend(&x, &attention.keys_values(&context).unwrap()).unwrap();
            for c in 0..b {
                let own = context.narrow(0, c / (b / contexts), 1).unwrap();
                let row = x.narrow(0, c, 1).unwrap();
                for i in 0..n {
                    let shared = own.narrow(1, i, 1).unwrap().squeeze(1).unwrap();
                    let want = attention.forward(&row, &shared).unwrap().narrow(1, i, 1).unwrap();
                    let diff = close(&got.narrow(0, c, 1).unwrap().narrow(1, i, 1).unwrap(), &want);
                    assert!(diff < 1e-5, "{contexts} contexts, candidate {c}, token {i}: {diff}");
                }
            }
        }
    }
}
