//! Training the flow policy.

use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use rand::Rng;

use super::card::{card_input, write_card};
use super::data::{Reading, split, statistics};
use super::run::run_loop;
use super::settings::{TrainConfig, TrainReport};
use crate::ModelError;
use crate::dataset::Dataset;
use crate::flow::{FlowConfig, FlowModel};
use crate::layers::{initialise, noise};
use crate::shipped::Weights;
use crate::tokens::TokenMap;
use crate::weights::save;

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
