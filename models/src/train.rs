//! Training loops: seeded, checkpointed, validated, ending in a weight file
//! ([`crate::weights`]) and a model card beside it.
//!
//! Batches come from one (team size, obstacle count) bucket at a time, so
//! every tensor in a batch has one shape (no padding or masks); buckets are
//! drawn in proportion to their size and batches hold about
//! `tokens_per_batch` robot tokens. The last `validation_fraction` of every
//! bucket is held out. A checkpoint (weights and step) is written every
//! `checkpoint_every` steps; a restarted run resumes from it with fresh
//! optimiser moments.

use std::path::{Path, PathBuf};
use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW, VarBuilder, VarMap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use flowopt_planner::am::{AmSettings, Engine, Objective, Prepared};

use crate::ModelError;
use crate::coding::Coding;
use crate::datagen::write_json;
use crate::dataset::{Bucket, DatagenConfig, Dataset};
use crate::flow::{FlowConfig, FlowModel};
use crate::init::{InitConfig, InitModel, tokens_to_coefficients};
use crate::layers::{initialise, noise};
use crate::pairs::{pair_rows, pair_width};
use crate::shipped::Weights;
use crate::tokens::TokenMap;
use crate::unrolled::UnrolledSf;
use crate::weights::{Columns, Stats, save};

/// Optimisation settings shared by both trainings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Optimiser steps.
    pub steps: usize,
    /// Robot tokens per batch (batch size = this / team size).
    pub tokens_per_batch: usize,
    /// Peak learning rate (AdamW, no weight decay).
    pub lr: f64,
    /// Final learning rate of the cosine schedule.
    pub lr_min: f64,
    /// Linear warm-up steps.
    pub warmup: usize,
    /// Global gradient-norm clip.
    pub clip: f64,
    /// Seed of the initial weights, batches, noise and times.
    pub seed: u64,
    /// Fraction of every bucket held out for validation.
    pub validation_fraction: f64,
    /// Steps between validations (and checkpoints).
    pub checkpoint_every: usize,
}

impl TrainConfig {
    /// Learning rate at `step`.
    pub fn lr_at(&self, step: usize) -> f64 {
        if step < self.warmup {
            return self.lr * (step + 1) as f64 / self.warmup as f64;
        }
        let progress = (step - self.warmup) as f64 / (self.steps - self.warmup).max(1) as f64;
        self.lr_min + 0.5 * (self.lr - self.lr_min) * (1.0 + (std::f64::consts::PI * progress.min(1.0)).cos())
    }
}

/// What a finished training reports (the model card's metrics).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainReport {
    /// Steps run in this process (after any resumed checkpoint).
    pub steps_run: usize,
    /// Mean training loss over the last validation interval.
    pub final_train_loss: f64,
    /// Validation loss at the first and last validation.
    pub first_validation_loss: f64,
    /// Validation loss at the end.
    pub validation_loss: f64,
    /// Wall time of this process's training (s).
    pub wall_s: f64,
}

/// The model card written beside a weight file.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelCard {
    /// `flow` or `init`.
    pub kind: String,
    /// The network configuration.
    pub config: serde_json::Value,
    /// The training settings.
    pub training: TrainConfig,
    /// Datasets trained on: directory and content hash.
    pub datasets: Vec<(String, String)>,
    /// Other inputs (the flow model an initialiser was trained on).
    pub inputs: Vec<(String, String)>,
    /// Training metrics.
    pub metrics: TrainReport,
    /// Training instances and held-out instances.
    pub instances: (usize, usize),
    /// The command line of the process that trained it (cards from before
    /// this field: empty).
    #[serde(default)]
    pub command: Vec<String>,
}

/// A bucket split for training, its rows and tokens normalised (the tokens
/// are what the trained network reads, in its token space).
pub(crate) struct Split {
    pub data: Bucket,
    /// Instances `0..train` train, the rest validate.
    pub train: usize,
    /// Index of the dataset it came from.
    pub source: usize,
    /// Pair rows `[N, n, m, pair_width]` along the references, for a policy
    /// that reads them and a bucket with obstacles.
    pub pairs: Option<Tensor>,
}

/// One batch of a [`Split`].
pub(crate) struct Batch {
    /// Robot rows.
    pub robots: Tensor,
    /// Obstacle rows.
    pub obstacles: Tensor,
    /// Tokens.
    pub tokens: Tensor,
    /// Pair rows, if the split has them.
    pub pairs: Option<Tensor>,
}

impl Split {
    /// The batch of instances `ids`.
    fn batch(&self, ids: &[u32]) -> Result<Batch, ModelError> {
        let ids = Tensor::new(ids, &Device::Cpu)?;
        let d = &self.data;
        Ok(Batch {
            robots: d.robot_rows.index_select(&ids, 0)?,
            obstacles: d.obstacle_rows.index_select(&ids, 0)?,
            tokens: d.tokens.index_select(&ids, 0)?,
            pairs: self.pairs.as_ref().map(|p| p.index_select(&ids, 0)).transpose()?,
        })
    }
}

/// What a flow policy reads of a dataset besides its rows: its token space
/// and whether pair rows.
pub(crate) struct Reading {
    /// The map from the datasets' coefficients to its tokens.
    pub tokens: TokenMap,
    /// Whether it reads pair rows.
    pub pairs: bool,
}

impl Reading {
    /// What a policy of `config` reads.
    pub fn of(config: &FlowConfig) -> Result<Self, ModelError> {
        Ok(Self { tokens: TokenMap::new(config.tokens, config.dim, config.n_xi)?, pairs: config.pairs })
    }
}

/// The pair rows of a bucket's instances along their reference curves
/// (`None` without obstacles).
fn bucket_pairs(config: &DatagenConfig, bucket: &Bucket) -> Result<Option<Tensor>, ModelError> {
    if bucket.obstacles == 0 || bucket.is_empty() {
        return Ok(None);
    }
    let mut rows = Vec::new();
    let mut width = 0;
    for &seed in &bucket.seeds {
        let problem = config.problem(bucket.robots, bucket.obstacles, seed)?;
        width = pair_width(problem.team.dim.axes());
        rows.extend(pair_rows(&problem, &Coding::new(&problem.team)?.reference(&problem)));
    }
    Ok(Some(Tensor::from_vec(rows, (bucket.len(), bucket.robots, bucket.obstacles, width), &Device::Cpu)?))
}

/// Statistics over every bucket of `data`, the tokens in the space of
/// `tokens`.
pub fn statistics(data: &[(PathBuf, Dataset)], tokens: &TokenMap) -> Result<Stats, ModelError> {
    let buckets: Vec<&Bucket> = data.iter().flat_map(|(_, d)| &d.buckets).collect();
    let cat = |f: &dyn Fn(&Bucket) -> Tensor| -> Result<Tensor, ModelError> {
        let parts: Vec<Tensor> = buckets.iter().map(|b| f(b).flatten_to(1)).collect::<Result<_, _>>()?;
        let parts: Vec<Tensor> = parts.into_iter().filter(|t| t.dim(0).is_ok_and(|n| n > 0)).collect();
        if parts.is_empty() {
            return Err(ModelError::Config("the dataset has no instance".into()));
        }
        Ok(Tensor::cat(&parts, 0)?)
    };
    let obstacle_parts: Vec<Tensor> = buckets
        .iter()
        .filter(|b| b.obstacles > 0 && !b.is_empty())
        .map(|b| b.obstacle_rows.flatten_to(1))
        .collect::<Result<_, _>>()?;
    let obstacle = if obstacle_parts.is_empty() {
        let width = buckets.first().map_or(0, |b| b.obstacle_rows.dim(2).unwrap_or(0));
        Columns { mean: vec![0.0; width], std: vec![1.0; width] }
    } else {
        Columns::of(&Tensor::cat(&obstacle_parts, 0)?)?
    };
    Ok(Stats {
        token: Columns::of(&tokens.to_model(&cat(&|b| b.tokens.clone())?)?)?,
        robot: Columns::of(&cat(&|b| b.robot_rows.clone())?)?,
        obstacle,
    })
}

/// Normalises and splits every bucket, as `reading` reads it.
pub(crate) fn split(
    data: &[(PathBuf, Dataset)],
    stats: &Stats,
    reading: &Reading,
    fraction: f64,
) -> Result<Vec<Split>, ModelError> {
    let mut out = Vec::new();
    for (source, b) in data.iter().enumerate().flat_map(|(i, (_, d))| d.buckets.iter().map(move |b| (i, b))) {
        if b.len() < 2 {
            continue;
        }
        let pairs = if reading.pairs { bucket_pairs(&data[source].1.manifest.config, b)? } else { None };
        let held = ((b.len() as f64 * fraction).ceil() as usize).clamp(1, b.len() - 1);
        out.push(Split {
            data: Bucket {
                robots: b.robots,
                obstacles: b.obstacles,
                seeds: b.seeds.clone(),
                robot_rows: stats.robot.normalise(&b.robot_rows)?,
                obstacle_rows: stats.obstacle.normalise(&b.obstacle_rows)?,
                tokens: stats.token.normalise(&reading.tokens.to_model(&b.tokens)?)?,
            },
            train: b.len() - held,
            source,
            pairs,
        });
    }
    if out.is_empty() {
        return Err(ModelError::Config("no bucket has two instances to split".into()));
    }
    Ok(out)
}

/// Draws a training batch: a bucket in proportion to its size, then
/// instance indices with replacement.
pub(crate) fn draw(splits: &[Split], rng: &mut ChaCha8Rng, tokens: usize) -> (usize, Vec<u32>) {
    let total: usize = splits.iter().map(|s| s.train).sum();
    let mut pick = rng.random_range(0..total);
    let k = splits
        .iter()
        .position(|s| {
            if pick < s.train {
                true
            } else {
                pick -= s.train;
                false
            }
        })
        .unwrap_or(0);
    let size = (tokens / splits[k].data.robots).max(1);
    let ids = (0..size).map(|_| rng.random_range(0..splits[k].train) as u32).collect();
    (k, ids)
}

/// Validation batches: for every bucket, its held-out instances in chunks.
pub(crate) fn validation_batches(splits: &[Split], tokens: usize) -> Vec<(usize, Vec<u32>)> {
    let mut out = Vec::new();
    for (k, s) in splits.iter().enumerate() {
        let size = (tokens / s.data.robots).max(1);
        let ids: Vec<u32> = (s.train as u32..s.data.len() as u32).collect();
        out.extend(ids.chunks(size).map(|c| (k, c.to_vec())));
    }
    out
}

/// A batch loss: bucket index, instance indices, generator.
type BatchLoss<'a> = dyn FnMut(usize, &[u32], &mut ChaCha8Rng) -> Result<Tensor, ModelError> + 'a;

/// Where a run keeps its checkpoint.
struct Checkpoint {
    weights: PathBuf,
    state: PathBuf,
}

#[derive(Serialize, Deserialize)]
struct CheckpointState {
    step: usize,
}

impl Checkpoint {
    fn new(dir: &Path, kind: &str) -> Self {
        Self {
            weights: dir.join(format!("{kind}-checkpoint.safetensors")),
            state: dir.join(format!("{kind}-checkpoint.json")),
        }
    }

    /// Loads the checkpoint into `vars` if there is one; returns its step.
    fn resume(&self, vars: &mut VarMap) -> Result<usize, ModelError> {
        if !self.state.exists() || !self.weights.exists() {
            return Ok(0);
        }
        let state: CheckpointState =
            serde_json::from_slice(&std::fs::read(&self.state).map_err(|e| ModelError::io(&self.state, e))?)
                .map_err(|e| ModelError::Format(format!("{}: {e}", self.state.display())))?;
        vars.load(&self.weights)?;
        Ok(state.step)
    }

    fn write(&self, vars: &VarMap, step: usize) -> Result<(), ModelError> {
        if let Some(dir) = self.weights.parent() {
            std::fs::create_dir_all(dir).map_err(|e| ModelError::io(dir, e))?;
        }
        let tmp = self.weights.with_extension("tmp");
        vars.save(&tmp)?;
        std::fs::rename(&tmp, &self.weights).map_err(|e| ModelError::io(&self.weights, e))?;
        write_json(&self.state, &CheckpointState { step })
    }
}

/// One optimiser step with gradient clipping; returns the loss.
pub(crate) fn step(opt: &mut AdamW, vars: &VarMap, loss: &Tensor, clip: f64) -> Result<f64, ModelError> {
    let value = f64::from(loss.to_dtype(DType::F32)?.to_scalar::<f32>()?);
    let mut grads = loss.backward()?;
    let all = vars.all_vars();
    let mut sq = 0.0;
    for v in &all {
        if let Some(g) = grads.get(v.as_tensor()) {
            sq += f64::from(g.sqr()?.sum_all()?.to_scalar::<f32>()?);
        }
    }
    let norm = sq.sqrt();
    if norm > clip {
        let s = clip / (norm + 1e-6);
        for v in &all {
            if let Some(g) = grads.get(v.as_tensor()) {
                let scaled = (g * s)?;
                grads.insert(v.as_tensor(), scaled);
            }
        }
    }
    opt.step(&grads)?;
    Ok(value)
}

/// A fresh AdamW over `vars` (no weight decay).
pub(crate) fn optimiser(vars: &VarMap, lr: f64) -> Result<AdamW, ModelError> {
    Ok(AdamW::new(vars.all_vars(), ParamsAdamW { lr, weight_decay: 0.0, ..Default::default() })?)
}

/// The generic loop: `loss(split, ids, rng)` gives a batch loss; validation
/// runs `loss` on every held-out batch with a fixed-seed generator.
pub(crate) fn run_loop(
    kind: &str,
    vars: &mut VarMap,
    cfg: &TrainConfig,
    splits: &[Split],
    checkpoint_dir: &Path,
    mut loss: impl FnMut(usize, &[u32], &mut ChaCha8Rng) -> Result<Tensor, ModelError>,
    mut progress: impl FnMut(usize, f64, Option<f64>),
) -> Result<TrainReport, ModelError> {
    let checkpoint = Checkpoint::new(checkpoint_dir, kind);
    let first = checkpoint.resume(vars)?;
    let mut opt = optimiser(vars, cfg.lr_at(first))?;
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5eed_0000 ^ first as u64);
    let validation = validation_batches(splits, cfg.tokens_per_batch);
    let validate = |loss: &mut BatchLoss| {
        let mut vrng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x7a11d);
        let mut sum = 0.0;
        let mut count = 0.0;
        for (k, ids) in &validation {
            let l = loss(*k, ids, &mut vrng)?;
            sum += f64::from(l.to_dtype(DType::F32)?.to_scalar::<f32>()?) * ids.len() as f64;
            count += ids.len() as f64;
        }
        Ok::<f64, ModelError>(sum / count.max(1.0))
    };
    let started = Instant::now();
    let first_validation = validate(&mut loss)?;
    progress(first, f64::NAN, Some(first_validation));
    let mut window = Vec::new();
    let mut last_validation = first_validation;
    for s in first..cfg.steps {
        opt.set_learning_rate(cfg.lr_at(s));
        let (k, ids) = draw(splits, &mut rng, cfg.tokens_per_batch);
        let l = loss(k, &ids, &mut rng)?;
        let value = step(&mut opt, vars, &l, cfg.clip)?;
        if !value.is_finite() {
            return Err(ModelError::Config(format!("the {kind} loss diverged at step {s}")));
        }
        window.push(value);
        let done = s + 1;
        let val = if done % cfg.checkpoint_every == 0 || done == cfg.steps {
            last_validation = validate(&mut loss)?;
            checkpoint.write(vars, done)?;
            Some(last_validation)
        } else {
            None
        };
        progress(done, value, val);
        if val.is_some() && done != cfg.steps {
            window.clear();
        }
    }
    Ok(TrainReport {
        steps_run: cfg.steps.saturating_sub(first),
        final_train_loss: window.iter().sum::<f64>() / window.len().max(1) as f64,
        first_validation_loss: first_validation,
        validation_loss: last_validation,
        wall_s: started.elapsed().as_secs_f64(),
    })
}

/// Where a flow policy's training starts.
#[derive(Debug, Clone, PartialEq)]
pub enum FlowStart {
    /// Fresh weights of this configuration, statistics from the data.
    Fresh(FlowConfig),
    /// The weights, configuration and statistics of a trained policy
    /// (fine-tuning; the data is normalised with its statistics).
    From(PathBuf),
}

/// Trains the flow policy on `data` from `start` and writes `out` (weights)
/// and `out.json` (model card, naming the weights it started from); the
/// checkpoint lives in `checkpoint_dir`.
pub fn train_flow(
    data: &[(PathBuf, Dataset)],
    start: &FlowStart,
    cfg: &TrainConfig,
    out: &Path,
    checkpoint_dir: &Path,
    progress: impl FnMut(usize, f64, Option<f64>),
) -> Result<TrainReport, ModelError> {
    let mut vars = VarMap::new();
    let (model, stats, inputs) = match start {
        FlowStart::Fresh(model) => {
            (model.clone(), statistics(data, &TokenMap::new(model.tokens, model.dim, model.n_xi)?)?, Vec::new())
        }
        FlowStart::From(path) => {
            let loaded = crate::weights::load::<FlowConfig>(&Weights::File(path.clone()), "flow")?;
            (loaded.config, loaded.stats, vec![card_input(path)?])
        }
    };
    let net = FlowModel::new(VarBuilder::from_varmap(&vars, DType::F32, &Device::Cpu), &model)?;
    match start {
        FlowStart::Fresh(_) => initialise(&vars, cfg.seed)?,
        FlowStart::From(path) => vars.load(path)?,
    }
    let splits = split(data, &stats, &Reading::of(&model)?, cfg.validation_fraction)?;
    let report = run_loop(
        "flow",
        &mut vars,
        cfg,
        &splits,
        checkpoint_dir,
        |k, ids, rng| {
            let b = splits[k].batch(ids)?;
            let encoded = net.encode(&b.robots, &b.obstacles, b.pairs.as_ref())?;
            let x1 = b.tokens;
            let x0 = noise(rng, x1.dims(), &Device::Cpu)?;
            let t: Vec<f32> = (0..ids.len()).map(|_| rng.random::<f32>()).collect();
            let t = Tensor::from_vec(t, ids.len(), &Device::Cpu)?;
            Ok(net.loss(&x1, &x0, &t, &encoded)?)
        },
        progress,
    )?;
    save(out, &vars, "flow", &model, &stats)?;
    write_card(out, "flow", &model, cfg, data, inputs, &splits, &report)?;
    Ok(report)
}

/// A model card's entry for weights a training read (the policy it
/// fine-tuned, the policy an initialiser learnt from): path and sha256.
fn card_input(path: &Path) -> Result<(String, String), ModelError> {
    let file = crate::dataset::WeightFile::hashed(path)?;
    Ok((file.path.display().to_string(), file.sha256))
}

/// Writes `out.json`, the model card of the weights at `out`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_card(
    out: &Path,
    kind: &str,
    model: &impl Serialize,
    cfg: &TrainConfig,
    data: &[(PathBuf, Dataset)],
    inputs: Vec<(String, String)>,
    splits: &[Split],
    report: &TrainReport,
) -> Result<(), ModelError> {
    let card = ModelCard {
        kind: kind.into(),
        config: serde_json::to_value(model).map_err(|e| ModelError::Format(e.to_string()))?,
        training: cfg.clone(),
        datasets: data.iter().map(|(p, d)| (p.display().to_string(), d.manifest.sha256.clone())).collect(),
        inputs,
        metrics: report.clone(),
        instances: (splits.iter().map(|s| s.train).sum(), splits.iter().map(|s| s.data.len() - s.train).sum()),
        command: std::env::args_os().map(|a| a.to_string_lossy().into_owned()).collect(),
    };
    write_json(&out.with_extension("json"), &card)
}

/// Settings of the initialiser's training data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitData {
    /// Training problems per bucket (the held-out ones are kept apart).
    pub per_bucket: usize,
    /// Flow sampling steps (Euler) that make the samples.
    pub flow_steps: usize,
}

/// The SF side of one bucket of initialiser training data (its tensors,
/// with the flow samples as tokens, are a [`Split`]).
struct InitBucket {
    engine: Engine,
    sf: UnrolledSf,
    /// Prepared SF problems, their targets the flow samples.
    prepared: Vec<Prepared>,
}

/// Trains the initialiser through `init.unroll` unrolled SF iterations on
/// samples of the flow model at `flow_path`, and writes `out` and its card.
#[allow(clippy::too_many_arguments)]
pub fn train_init(
    data: &[(PathBuf, Dataset)],
    flow_path: &Path,
    init: &InitConfig,
    samples: &InitData,
    cfg: &TrainConfig,
    out: &Path,
    checkpoint_dir: &Path,
    progress: impl FnMut(usize, f64, Option<f64>),
) -> Result<TrainReport, ModelError> {
    let flow = crate::weights::load::<FlowConfig>(&Weights::File(flow_path.to_path_buf()), "flow")?;
    let stats = flow.stats.clone();
    let flow_net = FlowModel::new(flow.vars, &flow.config)?;
    let reading = Reading::of(&flow.config)?;
    let all = split(data, &stats, &reading, cfg.validation_fraction)?;
    // Keep per bucket the first `per_bucket` training and up to a quarter
    // as many held-out instances, and make their flow samples.
    let mut splits = Vec::new();
    let mut buckets = Vec::new();
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x1417);
    for s in all {
        let (n, m) = (s.data.robots, s.data.obstacles);
        let train = s.train.min(samples.per_bucket);
        let held = (samples.per_bucket / 4).max(1).min(s.data.len() - s.train);
        let ids: Vec<u32> = (0..train as u32).chain(s.train as u32..(s.train + held) as u32).collect();
        let Batch { robots, obstacles, pairs, .. } = s.batch(&ids)?;
        // The bucket's instances, in their family's workspace.
        let config = &data[s.source].1.manifest.config;
        let team = config.problem(n, m, s.data.seeds[0])?.team;
        // The unrolled filter projects onto the fixed separation (no chord
        // inflation): its engine must too.
        let settings = AmSettings { chord: false, ..AmSettings::safety_filter() };
        let engine = Engine::new(&team, m, Objective::filter(init.sf_smoothing), settings)?;
        let sf = UnrolledSf::new(&engine, DType::F32)?;
        let coding = Coding::new(&team)?;
        let encoded = flow_net.encode(&robots, &obstacles, pairs.as_ref())?;
        let x0 = noise(&mut rng, &[ids.len(), n, flow.config.token_width()], &Device::Cpu)?;
        let sampled = flow_net
            .sample(&x0, &encoded, samples.flow_steps, crate::flow::Solver::Euler, &|| false)?
            .ok_or_else(|| ModelError::Config("sampling cannot stop here".into()))?;
        let raw = reading.tokens.to_coefficients(&stats.token.denormalise(&sampled)?)?;
        let width = flow.config.token_width() * n;
        let raw = raw.flatten_all()?.to_vec1::<f32>()?;
        let mut prepared = Vec::with_capacity(ids.len());
        for (j, &id) in ids.iter().enumerate() {
            let problem = config.problem(n, m, s.data.seeds[id as usize])?;
            if problem.team != team {
                return Err(ModelError::Config(format!(
                    "{}: the {} family's instances lie in workspaces that vary with the seed; the initialiser \
                     trains through one safety filter per bucket",
                    data[s.source].0.display(),
                    config.family.name()
                )));
            }
            let sample = coding.decode(&coding.reference(&problem), &raw[j * width..(j + 1) * width]);
            prepared.push(engine.prepare(&problem, Some(&sample))?);
        }
        let seeds = ids.iter().map(|&i| s.data.seeds[i as usize]).collect();
        let data =
            Bucket { robots: n, obstacles: m, seeds, robot_rows: robots, obstacle_rows: obstacles, tokens: sampled };
        splits.push(Split { data, train, source: s.source, pairs: None });
        buckets.push(InitBucket { engine, sf, prepared });
    }
    let mut vars = VarMap::new();
    let net = InitModel::new(VarBuilder::from_varmap(&vars, DType::F32, &Device::Cpu), init)?;
    initialise(&vars, cfg.seed)?;
    let report = run_loop(
        "init",
        &mut vars,
        cfg,
        &splits,
        checkpoint_dir,
        |k, ids, _rng| {
            let b = &buckets[k];
            let rows = splits[k].batch(ids)?;
            let out = net.forward(&rows.tokens, &rows.robots, &rows.obstacles)?;
            let chosen: Vec<&Prepared> = ids.iter().map(|&i| &b.prepared[i as usize]).collect();
            let batch = b.sf.batch(&b.engine, &chosen)?;
            let delta = reading.tokens.to_coefficients(&stats.token.scale(&out.delta)?)?;
            let delta = tokens_to_coefficients(&delta, init.dim, init.n_xi)?;
            let xi0 = (&batch.sample + delta)?;
            let (xi_l, _, residuals) = b.sf.unroll(&xi0, &out.lambda, &batch, init.unroll)?;
            let fixed_point = residuals.sum(0)?.mean_all()?;
            let distance = b.sf.distance(&xi_l, &batch)?.mean_all()?;
            Ok((fixed_point + distance)?)
        },
        progress,
    )?;
    save(out, &vars, "init", init, &stats)?;
    write_card(out, "init", init, cfg, data, vec![card_input(flow_path)?], &splits, &report)?;
    Ok(report)
}
