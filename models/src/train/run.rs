//! The generic training loop: batches, optimiser steps with clipping,
//! validation, checkpoints.

use std::path::{Path, PathBuf};
use std::time::Instant;

use candle_core::{DType, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW, VarMap};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::data::{Split, draw, validation_batches};
use super::settings::{TrainConfig, TrainReport};
use crate::ModelError;
use crate::datagen::write_json;

/// A batch loss: bucket index, instance indices, generator.
pub(super) type BatchLoss<'a> = dyn FnMut(usize, &[u32], &mut ChaCha8Rng) -> Result<Tensor, ModelError> + 'a;

/// Where a run keeps its checkpoint.
pub(super) struct Checkpoint {
    weights: PathBuf,
    state: PathBuf,
}

#[derive(Serialize, Deserialize)]
pub(super) struct CheckpointState {
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
