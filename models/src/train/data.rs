//! Training data as the loops read it: statistics, buckets normalised
//! and split, training and validation batches.

use std::path::PathBuf;

use candle_core::{Device, Tensor};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::ModelError;
use crate::coding::Coding;
use crate::dataset::{Bucket, DatagenConfig, Dataset};
use crate::flow::FlowConfig;
use crate::pairs::{pair_rows, pair_width};
use crate::tokens::TokenMap;
use crate::weights::{Columns, Stats};

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
    pub(super) fn batch(&self, ids: &[u32]) -> Result<Batch, ModelError> {
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
pub(super) fn bucket_pairs(config: &DatagenConfig, bucket: &Bucket) -> Result<Option<Tensor>, ModelError> {
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
