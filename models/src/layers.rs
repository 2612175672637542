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

/// Multi-head attention of `x` (`[B, n, D]`) over a context (`[B, m, D]`).
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

    /// Attends from `x` to `context`.
    pub fn forward(&self, x: &Tensor, context: &Tensor) -> Result<Tensor> {
        let (b, n, d) = x.dims3()?;
        let m = context.dim(1)?;
        let (h, dh) = (self.heads, d / self.heads);
        let q = self.q.forward(x)?.reshape((b, n, h, dh))?.transpose(1, 2)?.contiguous()?;
        let kv = self.kv.forward(context)?.reshape((b, m, 2, h, dh))?;
        let k = kv.narrow(2, 0, 1)?.squeeze(2)?.permute((0, 2, 3, 1))?.contiguous()?;
        let v = kv.narrow(2, 1, 1)?.squeeze(2)?.transpose(1, 2)?.contiguous()?;
        let att = (q.matmul(&k)? * (1.0 / (dh as f64).sqrt()))?;
        let att = candle_nn::ops::softmax(&att, D::Minus1)?;
        let y = att.matmul(&v)?.transpose(1, 2)?.reshape((b, n, d))?;
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

    /// The block on tokens `x` (`[B, n, D]`) with activated conditioning
    /// `c` (`[B or 1, n, D]`) and obstacle tokens (`[B, m, D]`, m >= 1).
    pub fn forward(&self, x: &Tensor, c: &Tensor, obstacles: Option<&Tensor>) -> Result<Tensor> {
        let m = self.modulation.forward(c)?.chunk(6, D::Minus1)?;
        let h = modulate(&norm(x)?, &m[0], &m[1])?;
        let mut x = (x + self.attention.forward(&h, &h)?.broadcast_mul(&m[2])?)?;
        if let Some(o) = obstacles {
            x = (&x + self.cross.forward(&norm(&x)?, o)?)?;
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
