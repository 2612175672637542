//! `flowopt datagen`: solve seeded instances of a scene family with a
//! planner (the from-scratch optimiser or the learned pipeline, recorded as
//! the configuration's [`DataSolver`]; the caller builds it) on every core
//! and keep the successful solutions as a [`crate::dataset`]. Shards are
//! written atomically and skipped when present, so an interrupted run
//! resumes where it stopped.

use std::collections::BTreeMap;
use std::path::Path;

use candle_core::{Device, Tensor};
use std::sync::Mutex;

use flowopt_planner::am::Budget;
use flowopt_planner::method::Planner;
use flowopt_planner::metrics::Metrics;
use flowopt_planner::plan::JointPlan;

use crate::ModelError;
use crate::coding::{Coding, conditions, obstacle_width, robot_width};
use crate::dataset::{DataSolver, DatagenConfig, FORMAT, MANIFEST, Manifest, ShardEntry, VERSION, hash_files};

/// One kept instance.
struct Solved {
    seed: u64,
    robots: Vec<f32>,
    obstacles: Vec<f32>,
    tokens: Vec<f32>,
    smoothness: f32,
}

/// Makes the planners that solve a dataset's instances (one per worker).
pub type MakePlanner<'a> = dyn Fn() -> Result<Box<dyn Planner>, ModelError> + Sync + 'a;

/// Generates (or completes) the dataset `config` describes in `dir` with
/// `threads` worker threads, each planning with a planner `make` makes (the
/// solver `config.solver` records); `progress` is told how many instances
/// each finished shard attempted. Returns the manifest it wrote.
pub fn generate(
    config: &DatagenConfig,
    dir: &Path,
    threads: usize,
    make: &MakePlanner<'_>,
    mut progress: impl FnMut(usize),
) -> Result<Manifest, ModelError> {
    // The weights the dataset records are the weights it is solved with.
    if let DataSolver::Pipeline { flow, init } = &config.solver {
        flow.checked()?;
        if let Some(init) = init {
            init.checked()?;
        }
    }
    std::fs::create_dir_all(dir).map_err(|e| ModelError::io(dir, e))?;
    let config_path = dir.join("datagen.json");
    if config_path.exists() {
        let existing: DatagenConfig =
            serde_json::from_slice(&std::fs::read(&config_path).map_err(|e| ModelError::io(&config_path, e))?)
                .map_err(|e| ModelError::Format(format!("{}: {e}", config_path.display())))?;
        if existing != *config {
            return Err(ModelError::Config(format!(
                "{} holds a dataset of another configuration; choose another directory",
                dir.display()
            )));
        }
    } else {
        write_json(&config_path, config)?;
    }
    let planners = (0..threads.max(1)).map(|_| make().map(Mutex::new)).collect::<Result<Vec<_>, _>>()?;
    let mut shards = Vec::new();
    for &robots in &config.robots {
        for obstacles in config.obstacle_counts(robots)? {
            // The family's workspace for this team (its first instance's;
            // an instance in another one gets an engine of its own).
            let team = config.problem(robots, obstacles, config.seed(robots, obstacles, 0))?.team;
            let coding = Coding::new(&team)?;
            for shard in 0..config.shards_per_bucket() {
                let file = DatagenConfig::shard_name(robots, obstacles, shard);
                let first = shard * config.shard_size;
                let attempted = config.shard_size.min(config.per_bucket - first);
                let path = dir.join(&file);
                let kept = if path.exists() {
                    count_kept(&path)?
                } else {
                    let bucket = (robots, obstacles);
                    let solved = solve_range(config, &planners, &coding, bucket, first..first + attempted)?;
                    write_shard(&path, config.dim, robots, obstacles, &solved)?;
                    solved.len()
                };
                progress(attempted);
                shards.push(ShardEntry { file, robots, obstacles, attempted, kept });
            }
        }
    }
    let manifest = Manifest {
        format: FORMAT.into(),
        version: VERSION,
        config: config.clone(),
        attempted: shards.iter().map(|s| s.attempted).sum(),
        kept: shards.iter().map(|s| s.kept).sum(),
        sha256: hash_files(&shards.iter().map(|s| dir.join(&s.file)).collect::<Vec<_>>())?,
        shards,
    };
    write_json(&dir.join(MANIFEST), &manifest)?;
    Ok(manifest)
}

/// Solves the instances `range` of a bucket on as many threads as there
/// are `planners`, keeping the successes in seed order.
fn solve_range(
    config: &DatagenConfig,
    planners: &[Mutex<Box<dyn Planner>>],
    coding: &Coding,
    (robots, obstacles): (usize, usize),
    range: std::ops::Range<usize>,
) -> Result<Vec<Solved>, ModelError> {
    crate::runtime::parallel(range.len(), planners.len(), |j| {
        let index = range.start + j;
        let seed = config.seed(robots, obstacles, index);
        // Instances too dense to place, or with another obstacle count,
        // are skipped like failures.
        let Ok(problem) = config.problem(robots, obstacles, seed) else { return Ok(None) };
        if problem.obstacles.len() != obstacles {
            return Ok(None);
        }
        // As many jobs run at once as there are planners: one is free.
        let mut planner = loop {
            if let Some(free) = planners.iter().find_map(|p| p.try_lock().ok()) {
                break free;
            }
            std::thread::yield_now();
        };
        let planned =
            planner.plan(&problem, &Budget::unlimited(), seed).map_err(|e| ModelError::Config(e.to_string()))?;
        drop(planner);
        if !planned.verified() {
            return Ok(None);
        }
        let xi = planned.plan.coeffs;
        let metrics = Metrics::measure(&problem, &JointPlan::new(&problem.team, xi.clone()));
        if !metrics.success(problem.team.separation().0) {
            return Ok(None);
        }
        let (robot_rows, obstacle_rows) = conditions(&problem);
        let reference = coding.reference(&problem);
        Ok(Some(Solved {
            seed,
            robots: robot_rows,
            obstacles: obstacle_rows,
            tokens: coding.encode(&reference, &xi),
            smoothness: metrics.smoothness as f32,
        }))
    })
}

fn write_shard(path: &Path, dim: usize, robots: usize, obstacles: usize, solved: &[Solved]) -> Result<(), ModelError> {
    let n = solved.len();
    let dev = Device::Cpu;
    let flat = |f: &dyn Fn(&Solved) -> &[f32]| solved.iter().flat_map(|s| f(s).iter().copied()).collect::<Vec<f32>>();
    let width = solved.first().map_or(0, |s| s.tokens.len() / robots.max(1));
    let mut tensors = BTreeMap::new();
    tensors.insert("seeds", Tensor::from_vec(solved.iter().map(|s| s.seed as i64).collect::<Vec<_>>(), n, &dev)?);
    tensors.insert("robots", Tensor::from_vec(flat(&|s| &s.robots), (n, robots, robot_width(dim)), &dev)?);
    tensors.insert("obstacles", Tensor::from_vec(flat(&|s| &s.obstacles), (n, obstacles, obstacle_width(dim)), &dev)?);
    tensors.insert("tokens", Tensor::from_vec(flat(&|s| &s.tokens), (n, robots, width), &dev)?);
    tensors.insert("smoothness", Tensor::from_vec(solved.iter().map(|s| s.smoothness).collect::<Vec<_>>(), n, &dev)?);
    let tmp = path.with_extension("tmp");
    safetensors::serialize_to_file(tensors.iter().map(|(k, t)| (*k, t)), None, &tmp)
        .map_err(|e| ModelError::Format(format!("{}: {e}", tmp.display())))?;
    std::fs::rename(&tmp, path).map_err(|e| ModelError::io(path, e))
}

fn count_kept(path: &Path) -> Result<usize, ModelError> {
    let tensors = candle_core::safetensors::load(path, &Device::Cpu)
        .map_err(|e| ModelError::Format(format!("{}: {e}", path.display())))?;
    let seeds = tensors.get("seeds").ok_or_else(|| ModelError::Format(format!("{} lacks `seeds`", path.display())))?;
    Ok(seeds.dim(0)?)
}

/// Writes `value` as pretty JSON, atomically.
pub(crate) fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<(), ModelError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| ModelError::Format(e.to_string()))?;
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text + "\n").map_err(|e| ModelError::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| ModelError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::{DataSolver, Dataset};
    use flowopt_planner::am::AmSettings;
    use flowopt_planner::optimiser::Optimiser;
    use flowopt_planner::scenes::Family;

    /// The from-scratch optimiser, as `DataSolver::Optimiser` records.
    fn optimiser() -> Result<Box<dyn Planner>, ModelError> {
        Ok(Box::new(Optimiser::new(AmSettings::optimiser())))
    }

    #[test]
    fn a_tiny_dataset_round_trips_and_resumes() {
        let dir = std::env::temp_dir().join(format!("flowopt-datagen-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let config = DatagenConfig {
            family: Family::Random,
            dim: 2,
            robots: vec![3],
            max_obstacles: 1,
            start_speed: 0.3,
            per_bucket: 3,
            shard_size: 2,
            first_seed: 1_000_000_000,
            solver: DataSolver::Optimiser,
        };
        let mut attempted = 0;
        let manifest = generate(&config, &dir, 2, &optimiser, |n| attempted += n).unwrap();
        assert_eq!((attempted, manifest.attempted, manifest.shards.len()), (6, 6, 4));
        assert!(manifest.kept >= 5, "3 robots almost always succeed: kept {}", manifest.kept);
        let data = Dataset::load(&dir).unwrap();
        assert_eq!(data.len(), manifest.kept);
        let bucket = &data.buckets[1];
        assert_eq!((bucket.robots, bucket.obstacles), (3, 1));
        assert_eq!(bucket.tokens.dims(), &[bucket.len(), 3, 10]);
        assert_eq!(bucket.obstacle_rows.dims(), &[bucket.len(), 1, 6]);
        // The seeds name the instances: the stored rows are the problem's.
        let problem = config.problem(3, 1, bucket.seeds[0]).unwrap();
        let rows = bucket.robot_rows.get(0).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert_eq!(rows, conditions(&problem).0);
        // A second run finds every shard and rewrites the same manifest.
        let again = generate(&config, &dir, 1, &optimiser, |_| {}).unwrap();
        assert_eq!(again.sha256, manifest.sha256);
        // Another configuration in the same directory is refused.
        let other = DatagenConfig { per_bucket: 4, ..config };
        assert!(matches!(generate(&other, &dir, 1, &optimiser, |_| {}), Err(ModelError::Config(_))));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn family_datasets_hold_their_familys_scenes() {
        // The swap (antipodal goals), the crossing (its box varies with the
        // seed) and the obstacle field (pillars of its own).
        for family in [Family::Swap, Family::Crossing, Family::ObstacleField] {
            let dir = std::env::temp_dir().join(format!("flowopt-datagen-{}-{}", family.name(), std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            let config = DatagenConfig {
                family,
                dim: 2,
                robots: vec![8],
                max_obstacles: 3,
                start_speed: 0.0,
                per_bucket: 2,
                shard_size: 2,
                first_seed: 1_000_000_000,
                solver: DataSolver::Optimiser,
            };
            let manifest = generate(&config, &dir, 1, &optimiser, |_| {}).unwrap();
            assert_eq!(manifest.shards.len(), 1, "{family:?}: one bucket; the family places its own obstacles");
            assert_eq!(manifest.kept, 2, "{family:?}: the optimiser solves 8-robot scenes");
            let data = Dataset::load(&dir).unwrap();
            let bucket = &data.buckets[0];
            for (row, &seed) in bucket.seeds.iter().enumerate() {
                let problem = config.problem(8, bucket.obstacles, seed).unwrap();
                assert_eq!(problem.obstacles.len(), bucket.obstacles);
                if family == Family::Swap {
                    for (start, goal) in problem.starts.iter().zip(&problem.goals) {
                        assert!((start.position + goal).norm() < 1e-12, "an antipodal swap");
                    }
                }
                let rows = bucket.robot_rows.get(row).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
                assert_eq!(rows, conditions(&problem).0);
            }
            std::fs::remove_dir_all(&dir).unwrap();
        }
    }
}
