//! Weight files: safetensors whose metadata carries the model kind, its
//! configuration and the normalisation statistics, so a file is
//! self-describing and a model is rebuilt from it alone.

use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::ModelError;
use crate::shipped::Weights;

/// Per-column mean and standard deviation of the network inputs, from the
/// training dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// Plan tokens (the coded deviation from the reference, in the
    /// policy's token space, [`crate::tokens::TokenSpace`]).
    pub token: Columns,
    /// Robot condition rows.
    pub robot: Columns,
    /// Obstacle rows.
    pub obstacle: Columns,
}

/// Mean and standard deviation per column.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Columns {
    /// Means.
    pub mean: Vec<f32>,
    /// Standard deviations; a column that varied less than
    /// [`Columns::FLOOR`] in training keeps its scale (std 1): the model never
    /// saw it change, and dividing by a tiny spread would turn an unseen value
    /// (a moving obstacle's velocity after static-only data) into a huge one.
    pub std: Vec<f32>,
}

impl Columns {
    /// Spread below which a column counts as constant in training.
    pub const FLOOR: f32 = 1e-3;

    /// The statistics of the rows of `x` (`[..., columns]`, f32).
    pub fn of(x: &Tensor) -> Result<Self, ModelError> {
        let cols = x.dim(candle_core::D::Minus1)?;
        let flat = x.reshape(((), cols))?.to_dtype(DType::F64)?;
        if flat.dim(0)? == 0 {
            return Ok(Self { mean: vec![0.0; cols], std: vec![1.0; cols] });
        }
        let mean = flat.mean(0)?;
        let var = flat.broadcast_sub(&mean)?.sqr()?.mean(0)?;
        let mean: Vec<f32> = mean.to_vec1::<f64>()?.into_iter().map(|v| v as f32).collect();
        let std = var
            .to_vec1::<f64>()?
            .into_iter()
            .map(|v| v.sqrt() as f32)
            .map(|s| if s < Self::FLOOR { 1.0 } else { s })
            .collect();
        Ok(Self { mean, std })
    }

    /// `(x - mean) / std` over the last axis.
    pub fn normalise(&self, x: &Tensor) -> Result<Tensor, ModelError> {
        let (mean, std) = self.tensors(x.device())?;
        Ok(x.broadcast_sub(&mean)?.broadcast_div(&std)?)
    }

    /// `x std + mean` over the last axis.
    pub fn denormalise(&self, x: &Tensor) -> Result<Tensor, ModelError> {
        let (mean, std) = self.tensors(x.device())?;
        Ok(x.broadcast_mul(&std)?.broadcast_add(&mean)?)
    }

    /// `x std` over the last axis (a difference of normalised values).
    pub fn scale(&self, x: &Tensor) -> Result<Tensor, ModelError> {
        let (_, std) = self.tensors(x.device())?;
        Ok(x.broadcast_mul(&std)?)
    }

    fn tensors(&self, device: &Device) -> Result<(Tensor, Tensor), ModelError> {
        Ok((Tensor::new(self.mean.as_slice(), device)?, Tensor::new(self.std.as_slice(), device)?))
    }
}

/// Writes the variables of `vars` to `path` with `kind`, `config` and
/// `stats` in the metadata (atomically).
pub fn save(path: &Path, vars: &VarMap, kind: &str, config: &impl Serialize, stats: &Stats) -> Result<(), ModelError> {
    let mut items: Vec<(String, Tensor)> = match vars.data().lock() {
        Ok(data) => data.iter().map(|(k, v)| (k.clone(), v.as_tensor().clone())).collect(),
        Err(_) => return Err(ModelError::Config("the variable map is poisoned".into())),
    };
    items.sort_by(|a, b| a.0.cmp(&b.0));
    let mut meta = HashMap::new();
    meta.insert("kind".to_string(), kind.to_string());
    meta.insert("config".to_string(), serde_json::to_string(config).map_err(|e| ModelError::Format(e.to_string()))?);
    meta.insert("stats".to_string(), serde_json::to_string(stats).map_err(|e| ModelError::Format(e.to_string()))?);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| ModelError::io(dir, e))?;
    }
    let tmp = path.with_extension("tmp");
    safetensors::serialize_to_file(items.iter().map(|(k, t)| (k.as_str(), t)), Some(meta), &tmp)
        .map_err(|e| ModelError::Format(format!("{}: {e}", tmp.display())))?;
    std::fs::rename(&tmp, path).map_err(|e| ModelError::io(path, e))
}

/// A loaded weight file: its configuration, statistics and a builder over
/// its tensors.
pub struct Loaded<C> {
    /// The model configuration.
    pub config: C,
    /// The normalisation statistics.
    pub stats: Stats,
    /// The weights.
    pub vars: VarBuilder<'static>,
}

/// Reads a weight file of `kind`.
pub fn load<C: DeserializeOwned>(weights: &Weights, kind: &str) -> Result<Loaded<C>, ModelError> {
    let bytes = weights.bytes()?;
    let bad = |what: String| ModelError::Format(format!("{weights}: {what}"));
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).map_err(|e| bad(e.to_string()))?;
    let meta = header.metadata().clone().ok_or_else(|| bad("no metadata".into()))?;
    let field = |name: &str| meta.get(name).cloned().ok_or_else(|| bad(format!("no `{name}` in the metadata")));
    let found = field("kind")?;
    if found != kind {
        return Err(bad(format!("holds a {found} model, expected {kind}")));
    }
    let config = serde_json::from_str(&field("config")?).map_err(|e| bad(format!("config: {e}")))?;
    let stats = serde_json::from_str(&field("stats")?).map_err(|e| bad(format!("stats: {e}")))?;
    let tensors = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu).map_err(|e| bad(e.to_string()))?;
    Ok(Loaded { config, stats, vars: VarBuilder::from_tensors(tensors, DType::F32, &Device::Cpu) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_column_constant_in_training_keeps_its_scale() {
        // Column 0 varies (std 1), column 1 is constant (a static obstacle's
        // velocity): a later value of 0.3 in it stays 0.3, not 300.
        let x = Tensor::new(&[[1f32, 0.0], [3.0, 0.0], [1.0, 0.0], [3.0, 0.0]], &Device::Cpu).unwrap();
        let c = Columns::of(&x).unwrap();
        assert_eq!((c.mean.clone(), c.std.clone()), (vec![2.0, 0.0], vec![1.0, 1.0]));
        let later = Tensor::new(&[[2f32, 0.3]], &Device::Cpu).unwrap();
        let got = c.normalise(&later).unwrap().to_vec2::<f32>().unwrap();
        assert!((got[0][0] - 0.0).abs() < 1e-6 && (got[0][1] - 0.3).abs() < 1e-6, "{got:?}");
    }
}
