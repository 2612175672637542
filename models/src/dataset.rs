//! The training dataset: verified solutions of seeded instances of a scene
//! family (`flowopt_planner::scenes`; the random benchmark by default) by
//! the from-scratch optimiser or by the learned pipeline ([`DataSolver`]),
//! stored as safetensors shards, one bucket per (team size, obstacle count),
//! with a JSON manifest that records the generating configuration.
//!
//! Layout of a dataset directory:
//! - `dataset.json`: [`Manifest`] (format, version, [`DatagenConfig`], shards,
//!   content hash);
//! - `n{robots}-m{obstacles}-{shard}.safetensors`, each holding `N` instances:
//!   `seeds` `[N]` (i64; the instance is `DatagenConfig::problem(n, m, seed)`),
//!   `robots` `[N, n, 3 dim]`, `obstacles` `[N, m, 2 dim + 2]` (see
//!   [`crate::coding::conditions`]), `tokens` `[N, n, dim (n_xi - 6)]` (the
//!   solution coded by [`crate::coding::Coding`]) and `smoothness` `[N]`, all
//!   f32 but the seeds.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};
use flowopt_planner::problem::{Dim, Problem};
use flowopt_planner::scenes::{Family, Scene};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::ModelError;

/// Name of the manifest in a dataset directory.
pub const MANIFEST: &str = "dataset.json";
/// Format tag of the manifest.
pub const FORMAT: &str = "flowopt-dataset";
/// Version of the layout described in this module.
pub const VERSION: u32 = 1;

/// What `flowopt datagen` generates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatagenConfig {
    /// Scene family (`random` in datasets written before families).
    #[serde(default)]
    pub family: Family,
    /// Workspace dimension (2 or 3).
    pub dim: usize,
    /// Team sizes.
    pub robots: Vec<usize>,
    /// Obstacle counts `0..=max_obstacles` (static obstacles), one bucket
    /// each; only the random and crowd families place random obstacles.
    pub max_obstacles: usize,
    /// Largest start speed (m/s) of the random and crowd families: plans
    /// start from moving states.
    pub start_speed: f64,
    /// Instances attempted per (team size, obstacle count) bucket.
    pub per_bucket: usize,
    /// Instances per shard.
    pub shard_size: usize,
    /// Seeds are `first_seed + 10^7 n + 10^6 m + index`; test instances use
    /// small seeds, so training never sees them.
    pub first_seed: u64,
    /// Who solves the instances (the optimiser in datasets written before
    /// this choice).
    #[serde(default)]
    pub solver: DataSolver,
}

/// Who solves a dataset's instances; only verified solutions that pass the
/// success verdict are kept either way.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DataSolver {
    /// The from-scratch optimiser (`AmSettings::optimiser`).
    #[default]
    Optimiser,
    /// The learned pipeline with its default settings, on one thread per
    /// instance, its flow noise seeded by the instance's seed: solutions
    /// where the optimiser fails (the obstacle field), to train on.
    Pipeline {
        /// The flow policy.
        flow: WeightFile,
        /// The SF initialiser, if any.
        init: Option<WeightFile>,
    },
}

/// A weight file and the hash of its contents when the dataset began (a
/// resumed run refuses weights that changed since).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct WeightFile {
    /// Where it is.
    pub path: PathBuf,
    /// sha256 of its contents.
    pub sha256: String,
}

impl WeightFile {
    /// `path` with the hash of its contents now.
    pub fn hashed(path: &Path) -> Result<Self, ModelError> {
        let path = path.to_path_buf();
        Ok(Self { sha256: hash_files(std::slice::from_ref(&path))?, path })
    }

    /// Its path, once its contents are checked to be those hashed.
    pub fn checked(&self) -> Result<&Path, ModelError> {
        let now = hash_files(std::slice::from_ref(&self.path))?;
        if now != self.sha256 {
            return Err(ModelError::Config(format!(
                "{} changed since the dataset began (sha256 {} there, {now} now)",
                self.path.display(),
                self.sha256
            )));
        }
        Ok(&self.path)
    }
}

impl DatagenConfig {
    /// The workspace dimension.
    pub fn dimension(&self) -> Result<Dim, ModelError> {
        match self.dim {
            2 => Ok(Dim::Two),
            3 => Ok(Dim::Three),
            d => Err(ModelError::Config(format!("dimension {d} is neither 2 nor 3"))),
        }
    }

    /// Seed of instance `index` of bucket `(robots, obstacles)`.
    pub fn seed(&self, robots: usize, obstacles: usize, index: usize) -> u64 {
        self.first_seed + 10_000_000 * robots as u64 + 1_000_000 * obstacles as u64 + index as u64
    }

    /// The instance a seed stands for.
    pub fn problem(&self, robots: usize, obstacles: usize, seed: u64) -> Result<Problem, ModelError> {
        let scene = Scene {
            obstacles,
            start_speed: self.start_speed,
            ..Scene::new(self.family, self.dimension()?, robots, seed)
        };
        Ok(scene.generate()?.0)
    }

    /// The obstacle counts of `robots`-robot teams, one bucket each:
    /// `0..=max_obstacles` for the families that take random obstacles, else
    /// the one count the family places itself (its first instance's).
    pub fn obstacle_counts(&self, robots: usize) -> Result<Vec<usize>, ModelError> {
        Ok(if self.family.takes_random_obstacles() {
            (0..=self.max_obstacles).collect()
        } else {
            vec![self.problem(robots, 0, self.seed(robots, 0, 0))?.obstacles.len()]
        })
    }

    /// Shards per bucket.
    pub fn shards_per_bucket(&self) -> usize {
        self.per_bucket.div_ceil(self.shard_size.max(1))
    }

    /// File name of shard `shard` of bucket `(robots, obstacles)`.
    pub fn shard_name(robots: usize, obstacles: usize, shard: usize) -> String {
        format!("n{robots:02}-m{obstacles}-{shard:05}.safetensors")
    }
}

/// The manifest of a finished dataset.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Manifest {
    /// Always [`FORMAT`].
    pub format: String,
    /// The layout version, [`VERSION`].
    pub version: u32,
    /// How it was generated.
    pub config: DatagenConfig,
    /// Shard files with their bucket and instance count.
    pub shards: Vec<ShardEntry>,
    /// Instances attempted and kept (successful solutions).
    pub attempted: usize,
    /// Instances kept.
    pub kept: usize,
    /// SHA-256 of the shard files' bytes, in manifest order.
    pub sha256: String,
}

/// One shard in the manifest.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ShardEntry {
    /// File name in the dataset directory.
    pub file: String,
    /// Team size.
    pub robots: usize,
    /// Obstacle count.
    pub obstacles: usize,
    /// Instances attempted.
    pub attempted: usize,
    /// Instances kept.
    pub kept: usize,
}

/// All instances of one (team size, obstacle count) bucket, in memory.
#[derive(Debug, Clone)]
pub struct Bucket {
    /// Team size.
    pub robots: usize,
    /// Obstacle count.
    pub obstacles: usize,
    /// Instance seeds.
    pub seeds: Vec<u64>,
    /// `[N, n, 3 dim]`.
    pub robot_rows: Tensor,
    /// `[N, m, 2 dim + 2]`.
    pub obstacle_rows: Tensor,
    /// `[N, n, token width]`.
    pub tokens: Tensor,
}

impl Bucket {
    /// Number of instances.
    pub fn len(&self) -> usize {
        self.seeds.len()
    }

    /// Whether the bucket holds no instance.
    pub fn is_empty(&self) -> bool {
        self.seeds.is_empty()
    }
}

/// A loaded dataset.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// Its manifest.
    pub manifest: Manifest,
    /// Buckets in (robots, obstacles) order.
    pub buckets: Vec<Bucket>,
}

impl Dataset {
    /// Loads every shard of the dataset in `dir` and checks the hash.
    pub fn load(dir: &Path) -> Result<Self, ModelError> {
        let manifest: Manifest = serde_json::from_slice(&read(&dir.join(MANIFEST))?)
            .map_err(|e| ModelError::Format(format!("{}: {e}", dir.join(MANIFEST).display())))?;
        if manifest.format != FORMAT || manifest.version != VERSION {
            return Err(ModelError::Format(format!(
                "{} is {} v{}, expected {FORMAT} v{VERSION}",
                dir.display(),
                manifest.format,
                manifest.version
            )));
        }
        let hash = hash_files(&manifest.shards.iter().map(|s| dir.join(&s.file)).collect::<Vec<_>>())?;
        if hash != manifest.sha256 {
            return Err(ModelError::Format(format!(
                "{}: shard contents do not match the manifest hash",
                dir.display()
            )));
        }
        let mut grouped: BTreeMap<(usize, usize), Vec<BTreeMap<String, Tensor>>> = BTreeMap::new();
        for shard in &manifest.shards {
            if shard.kept == 0 {
                continue;
            }
            let path = dir.join(&shard.file);
            let tensors = candle_core::safetensors::load(&path, &Device::Cpu)
                .map_err(|e| ModelError::Format(format!("{}: {e}", path.display())))?;
            grouped.entry((shard.robots, shard.obstacles)).or_default().push(tensors.into_iter().collect());
        }
        let mut buckets = Vec::new();
        for ((robots, obstacles), shards) in grouped {
            let cat = |name: &str| -> Result<Tensor, ModelError> {
                let parts = shards
                    .iter()
                    .map(|s| s.get(name).cloned().ok_or_else(|| ModelError::Format(format!("a shard lacks `{name}`"))))
                    .collect::<Result<Vec<_>, _>>()?;
                Ok(Tensor::cat(&parts, 0)?)
            };
            let seeds = cat("seeds")?.to_dtype(DType::I64)?.to_vec1::<i64>()?.into_iter().map(|s| s as u64).collect();
            buckets.push(Bucket {
                robots,
                obstacles,
                seeds,
                robot_rows: cat("robots")?,
                obstacle_rows: cat("obstacles")?,
                tokens: cat("tokens")?,
            });
        }
        Ok(Self { manifest, buckets })
    }

    /// Instances in all buckets.
    pub fn len(&self) -> usize {
        self.buckets.iter().map(Bucket::len).sum()
    }

    /// Whether there is no instance at all.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// SHA-256 over the bytes of `files` in order, hex.
pub fn hash_files(files: &[PathBuf]) -> Result<String, ModelError> {
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    for path in files {
        let mut f = std::fs::File::open(path).map_err(|e| ModelError::io(path, e))?;
        loop {
            let got = f.read(&mut buf).map_err(|e| ModelError::io(path, e))?;
            if got == 0 {
                break;
            }
            hasher.update(&buf[..got]);
        }
    }
    Ok(hasher.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

fn read(path: &Path) -> Result<Vec<u8>, ModelError> {
    std::fs::read(path).map_err(|e| ModelError::io(path, e))
}
