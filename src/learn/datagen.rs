//! `flowopt datagen`: training data from the from-scratch optimiser or the
//! learned pipeline.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use flowopt_methods::build::learned;
use flowopt_methods::{Method, PlannerSettings};
use flowopt_models::ModelError;
use flowopt_models::datagen::generate;
use flowopt_models::dataset::{DataSolver, DatagenConfig, WeightFile};
use flowopt_models::shipped::{Weights, WeightsRef};
use flowopt_planner::method::Planner;
use flowopt_planner::optimiser::Optimiser;
use indicatif::{ProgressBar, ProgressStyle};

use crate::offline::instances::FamilyArg;

/// Generate a training dataset of verified solutions (resumable).
#[derive(Debug, Args)]
pub struct DatagenArgs {
    /// Dataset directory (created; an interrupted run resumes in it).
    #[arg(long, default_value = "data/train")]
    out: PathBuf,
    /// Scene family (`flowopt_planner::scenes`); the workspace grows with
    /// the team for every family but `random`.
    #[arg(long, value_enum, default_value = "random")]
    family: FamilyArg,
    /// Workspace dimension.
    #[arg(long, default_value_t = 2)]
    dim: usize,
    /// Team sizes, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "8,16,32")]
    robots: Vec<usize>,
    /// One bucket per obstacle count 0..=max.
    #[arg(long, default_value_t = 8)]
    max_obstacles: usize,
    /// Largest random start speed (m/s).
    #[arg(long, default_value_t = 0.5)]
    start_speed: f64,
    /// Instances attempted per (team size, obstacle count) bucket.
    #[arg(long, default_value_t = 1000)]
    per_bucket: usize,
    /// Instances per shard (the unit of resumption).
    #[arg(long, default_value_t = 250)]
    shard_size: usize,
    /// First seed (test instances use small seeds).
    #[arg(long, default_value_t = 1_000_000_000)]
    first_seed: u64,
    /// Worker threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Who solves the instances.
    #[arg(long, value_enum, default_value = "optimiser")]
    solver: SolverArg,
    /// `--solver pipeline`: the flow policy [default: the shipped weights
    /// for the dimension, models/weights/flow.safetensors or flow3d].
    #[arg(long)]
    flow_weights: Option<PathBuf>,
    /// `--solver pipeline`: the SF initialiser [default: the shipped one
    /// for the dimension, models/weights/init.safetensors or init3d].
    #[arg(long)]
    init_weights: Option<PathBuf>,
}

/// Who solves a dataset's instances, on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum SolverArg {
    /// The from-scratch optimiser.
    Optimiser,
    /// The learned pipeline (default settings, one thread per instance):
    /// its verified plans, e.g. of scenes the optimiser fails.
    Pipeline,
}

/// Runs `flowopt datagen`.
pub fn run(args: DatagenArgs) -> Result<()> {
    let mut config = DatagenConfig {
        family: args.family.into(),
        dim: args.dim,
        robots: args.robots,
        max_obstacles: args.max_obstacles,
        start_speed: args.start_speed,
        per_bucket: args.per_bucket,
        shard_size: args.shard_size,
        first_seed: args.first_seed,
        solver: DataSolver::Optimiser,
    };
    let dim = config.dimension()?;
    if args.solver == SolverArg::Pipeline {
        let (flow, init) = (Weights::shipped_flow(dim).file(), Weights::shipped_init(dim).file());
        let hashed = |path: PathBuf| WeightFile::hashed(&path).with_context(|| format!("reading {}", path.display()));
        config.solver = DataSolver::Pipeline {
            flow: hashed(args.flow_weights.unwrap_or(flow))?,
            init: Some(hashed(args.init_weights.unwrap_or(init))?),
        };
    }
    let mut buckets = 0;
    for &robots in &config.robots {
        buckets += config.obstacle_counts(robots).context("placing the family's first scene")?.len();
    }
    let total = buckets * config.per_bucket;
    let progress = ProgressBar::new(total as u64);
    progress.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} instances [{elapsed_precise} eta {eta}]")?);
    let started = Instant::now();
    let solver = config.solver.clone();
    let make = move || -> Result<Box<dyn Planner>, ModelError> { solver_for(&solver, dim) };
    let manifest = generate(&config, &args.out, args.threads, &make, |n| progress.inc(n as u64))
        .with_context(|| format!("generating the dataset in {}", args.out.display()))?;
    progress.finish_and_clear();
    println!(
        "{}: kept {} of {} instances in {:.0} s; sha256 {}",
        args.out.display(),
        manifest.kept,
        manifest.attempted,
        started.elapsed().as_secs_f64(),
        manifest.sha256
    );
    Ok(())
}

/// A planner of the solver `solver` records, for teams of `dim`: the
/// optimiser with its defaults, or the learned pipeline as `flowopt`
/// plans (the recorded weights, the initialiser where there are obstacles)
/// on one thread per instance.
fn solver_for(solver: &DataSolver, dim: flowopt_planner::problem::Dim) -> Result<Box<dyn Planner>, ModelError> {
    let settings = PlannerSettings::default();
    Ok(match solver {
        DataSolver::Optimiser => Box::new(Optimiser::new(settings.optimiser())),
        DataSolver::Pipeline { flow, init } => {
            let mut settings = settings;
            settings.learned.flow = WeightsRef::File(flow.checked()?.to_path_buf());
            settings.learned.init =
                init.as_ref().map(|i| i.checked().map(|p| WeightsRef::File(p.to_path_buf()))).transpose()?;
            settings.threads = 1;
            Box::new(learned(&settings, Method::Flowopt, dim)?)
        }
    })
}
