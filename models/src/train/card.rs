//! The model card written beside a weight file.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::data::Split;
use super::settings::{TrainConfig, TrainReport};
use crate::ModelError;
use crate::datagen::write_json;
use crate::dataset::Dataset;

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

/// A model card's entry for weights a training read (the policy it
/// fine-tuned, the policy an initialiser learnt from): path and sha256.
pub(super) fn card_input(path: &Path) -> Result<(String, String), ModelError> {
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
