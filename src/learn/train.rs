//! `flowopt train flow|init`: train the learned planner's networks.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use flowopt_models::dataset::Dataset;
use flowopt_models::flow::FlowConfig;
use flowopt_models::init::InitConfig;
use flowopt_models::tokens::TokenSpace;
use flowopt_models::train::{FlowStart, InitData, TrainConfig, TrainReport, train_flow, train_init};
use indicatif::{ProgressBar, ProgressStyle};

/// Train a network of the learned planner.
#[derive(Debug, Args)]
pub struct TrainArgs {
    #[command(subcommand)]
    network: Network,
}

#[derive(Debug, Subcommand)]
enum Network {
    /// The flow-matching policy.
    Flow(FlowArgs),
    /// The SF initialiser, through the unrolled safety filter, on samples
    /// of a trained flow policy.
    Init(InitArgs),
}

/// Reports a step, its loss and any validation loss.
type Report = Box<dyn FnMut(usize, f64, Option<f64>)>;

/// Settings every training takes.
#[derive(Debug, Args)]
struct Common {
    /// Dataset directories (from `flowopt datagen`), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "data/n16,data/n8,data/n32")]
    data: Vec<PathBuf>,
    /// Optimiser steps.
    #[arg(long, default_value_t = 6000)]
    steps: usize,
    /// Robot tokens per batch.
    #[arg(long, default_value_t = 1024)]
    tokens_per_batch: usize,
    /// Peak learning rate.
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    /// Seed of the weights, batches and noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Steps between validations and checkpoints.
    #[arg(long, default_value_t = 250)]
    checkpoint_every: usize,
    /// Checkpoint directory (a run resumes from the checkpoint found here).
    #[arg(long)]
    checkpoints: Option<PathBuf>,
}

impl Common {
    fn config(&self) -> TrainConfig {
        TrainConfig {
            steps: self.steps,
            tokens_per_batch: self.tokens_per_batch,
            lr: self.lr,
            lr_min: self.lr / 50.0,
            warmup: (self.steps / 20).clamp(1, 500),
            clip: 1.0,
            seed: self.seed,
            validation_fraction: 0.05,
            checkpoint_every: self.checkpoint_every,
        }
    }

    fn datasets(&self) -> Result<Vec<(PathBuf, Dataset)>> {
        self.data
            .iter()
            .map(|p| Ok((p.clone(), Dataset::load(p).with_context(|| format!("loading the dataset {}", p.display()))?)))
            .collect()
    }

    fn progress(&self, what: &str) -> Result<(ProgressBar, Report)> {
        let bar = ProgressBar::new(self.steps as u64);
        bar.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed_precise} eta {eta}]")?);
        let handle = bar.clone();
        let what = what.to_string();
        let mut smoothed = f64::NAN;
        let report = move |step: usize, loss: f64, validation: Option<f64>| {
            if loss.is_finite() {
                smoothed = if smoothed.is_nan() { loss } else { 0.98 * smoothed + 0.02 * loss };
            }
            handle.set_position(step as u64);
            handle.set_message(format!("loss {smoothed:.4}"));
            if let Some(v) = validation {
                // Also on stderr for logs of background runs.
                handle.suspend(|| eprintln!("{what}: step {step}: train loss {smoothed:.5}, validation loss {v:.5}"));
            }
        };
        Ok((bar, Box::new(report)))
    }
}

#[derive(Debug, Args)]
struct FlowArgs {
    #[command(flatten)]
    common: Common,
    /// Output weights (a model card is written beside them, `.json`).
    #[arg(long, default_value = "models/weights/flow.safetensors")]
    out: PathBuf,
    /// Token width.
    #[arg(long, default_value_t = 128)]
    width: usize,
    /// DiT blocks.
    #[arg(long, default_value_t = 3)]
    layers: usize,
    /// Attention heads.
    #[arg(long, default_value_t = 4)]
    heads: usize,
    /// MLP hidden width.
    #[arg(long, default_value_t = 256)]
    hidden: usize,
    /// What the tokens hold: the plan's deviation from the reference at
    /// interior positions, or at its interior Bernstein coefficients (the
    /// weights before positions; docs/LEARNED.md).
    #[arg(long, value_enum, default_value = "positions")]
    tokens: TokensArg,
    /// Do not read the robot-obstacle pair rows (as the weights before them).
    #[arg(long)]
    no_pairs: bool,
    /// Fine-tune these trained weights (their architecture and
    /// normalisation; the architecture flags above are then unused).
    #[arg(long, value_name = "WEIGHTS")]
    from: Option<PathBuf>,
}

/// What a new flow policy's tokens hold, on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum TokensArg {
    /// Positions at interior instants.
    Positions,
    /// Interior Bernstein coefficients.
    Coefficients,
}

impl From<TokensArg> for TokenSpace {
    fn from(t: TokensArg) -> Self {
        match t {
            TokensArg::Positions => TokenSpace::Positions,
            TokensArg::Coefficients => TokenSpace::Coefficients,
        }
    }
}

#[derive(Debug, Args)]
struct InitArgs {
    #[command(flatten)]
    common: Common,
    /// The trained flow policy whose samples it learns to repair.
    #[arg(long, default_value = "models/weights/flow.safetensors")]
    flow: PathBuf,
    /// Output weights (a model card is written beside them, `.json`).
    #[arg(long, default_value = "models/weights/init.safetensors")]
    out: PathBuf,
    /// Token width.
    #[arg(long, default_value_t = 64)]
    width: usize,
    /// Unrolled SF iterations (at the SF's penalty schedule: all at the
    /// first penalty up to 25).
    #[arg(long, default_value_t = 15)]
    unroll: usize,
    /// Training problems per (team size, obstacle count) bucket.
    #[arg(long, default_value_t = 200)]
    per_bucket: usize,
    /// Flow sampling steps of the training samples.
    #[arg(long, default_value_t = 4)]
    flow_steps: usize,
    /// Smoothing weight of the unrolled SF's metric (0: the plain
    /// projection, as the shipped initialiser; 3, the pipeline's metric,
    /// measured on par with it: docs/LEARNED.md).
    #[arg(long, default_value_t = 0.0, value_parser = smoothing_weight)]
    sf_smoothing: f64,
}

/// Parses a safety-filter smoothing weight: a finite number, 0 or more.
fn smoothing_weight(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(w) if w.is_finite() && w >= 0.0 => Ok(w),
        Ok(_) => Err(format!("{text} is not a weight: give a finite number, 0 or more")),
        Err(e) => Err(format!("{text}: {e}")),
    }
}

/// Runs `flowopt train`.
pub fn run(args: TrainArgs) -> Result<()> {
    match args.network {
        Network::Flow(a) => {
            let data = a.common.datasets()?;
            let dim = data.first().map_or(2, |(_, d)| d.manifest.config.dim);
            let start = match a.from {
                Some(path) => FlowStart::From(path),
                None => FlowStart::Fresh(FlowConfig {
                    width: a.width,
                    layers: a.layers,
                    heads: a.heads,
                    hidden: a.hidden,
                    tokens: a.tokens.into(),
                    pairs: !a.no_pairs,
                    ..FlowConfig::small(dim, flowopt_planner::problem::Team::DEFAULT_DEGREE + 1)
                }),
            };
            let checkpoints = a.common.checkpoints.clone().unwrap_or_else(|| PathBuf::from("runs/flow"));
            let (bar, progress) = a.common.progress("flow")?;
            let started = Instant::now();
            let report = train_flow(&data, &start, &a.common.config(), &a.out, &checkpoints, progress)
                .context("training the flow policy")?;
            bar.finish_and_clear();
            finished(&a.out, &report, started);
        }
        Network::Init(a) => {
            let data = a.common.datasets()?;
            let dim = data.first().map_or(2, |(_, d)| d.manifest.config.dim);
            let init = InitConfig {
                width: a.width,
                unroll: a.unroll,
                sf_smoothing: a.sf_smoothing,
                ..InitConfig::small(dim, flowopt_planner::problem::Team::DEFAULT_DEGREE + 1)
            };
            let samples = InitData { per_bucket: a.per_bucket, flow_steps: a.flow_steps };
            let checkpoints = a.common.checkpoints.clone().unwrap_or_else(|| PathBuf::from("runs/init"));
            let (bar, progress) = a.common.progress("init")?;
            let started = Instant::now();
            let report =
                train_init(&data, &a.flow, &init, &samples, &a.common.config(), &a.out, &checkpoints, progress)
                    .context("training the initialiser")?;
            bar.finish_and_clear();
            finished(&a.out, &report, started);
        }
    }
    Ok(())
}

/// Prints where a finished training wrote its weights and how it went.
fn finished(out: &std::path::Path, report: &TrainReport, started: Instant) {
    println!(
        "{}: validation loss {:.5} (from {:.5} at this run's first step), {} steps in {:.0} s",
        out.display(),
        report.validation_loss,
        report.first_validation_loss,
        report.steps_run,
        started.elapsed().as_secs_f64()
    );
}
