//! `flowopt bench`: run a method over seeded instances and summarise.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use crate::instances::InstanceArgs;
use crate::methods::{Method, Planner, Record};
use crate::solve::EngineArgs;
use crate::stats::{mean, quantile};

/// Benchmark a planning method on seeded random instances.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Planning method.
    #[arg(long, value_enum, default_value = "baseline")]
    method: Method,
    #[command(flatten)]
    instance: InstanceArgs,
    /// Number of instances (seeds seed..seed+problems).
    #[arg(long, default_value_t = 100)]
    problems: u64,
    #[command(flatten)]
    engine: EngineArgs,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Also write one JSON line per instance to this file.
    #[arg(long)]
    per_instance: Option<PathBuf>,
}

/// The summary `flowopt bench` prints.
#[derive(Debug, Serialize)]
pub struct Summary {
    /// Method benchmarked.
    pub method: Method,
    /// Robots per instance.
    pub robots: usize,
    /// Workspace dimension.
    pub dim: usize,
    /// Obstacles per instance.
    pub obstacles: usize,
    /// Instances run.
    pub problems: u64,
    /// First seed.
    pub seed: u64,
    /// Fraction of instances whose plan passed the success verdict.
    pub success_rate: f64,
    /// Median planning time (ms), all instances.
    pub median_ms: f64,
    /// 95th-percentile planning time (ms), all instances.
    pub p95_ms: f64,
    /// Mean smoothness over successful instances.
    pub mean_smoothness: f64,
    /// Mean arc length over successful instances (m).
    pub mean_arc_length: f64,
    /// Mean AM iterations, all instances.
    pub mean_iterations: f64,
    /// Median AM iterations, all instances.
    pub median_iterations: f64,
}

#[derive(Serialize)]
struct InstanceLine<'a> {
    seed: u64,
    #[serde(flatten)]
    record: &'a Record,
}

/// Runs `flowopt bench`.
pub fn run(args: BenchArgs) -> Result<()> {
    let mut planner = Planner::new(args.engine.overrides());
    let mut out = match &args.per_instance {
        Some(path) => Some(std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?),
        None => None,
    };
    let progress = ProgressBar::new(args.problems);
    progress.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed_precise}]")?);
    let started = Instant::now();
    let mut records = Vec::with_capacity(args.problems as usize);
    for index in 0..args.problems {
        let problem = args.instance.instance(index)?;
        let seed = args.instance.seed + index;
        let record = planner.run(args.method, &problem, seed)?;
        if let Some(file) = out.as_mut() {
            writeln!(file, "{}", serde_json::to_string(&InstanceLine { seed, record: &record })?)?;
        }
        records.push(record);
        let ok = records.iter().filter(|r| r.success).count();
        progress.set_message(format!("{ok} ok"));
        progress.inc(1);
    }
    progress.finish_and_clear();
    let times: Vec<f64> = records.iter().map(|r| r.time_ms).collect();
    let iterations: Vec<f64> = records.iter().map(|r| r.iterations as f64).collect();
    let successes: Vec<&Record> = records.iter().filter(|r| r.success).collect();
    let team = args.instance.team();
    let summary = Summary {
        method: args.method,
        robots: team.robots,
        dim: team.dim.axes(),
        obstacles: args.instance.obstacles,
        problems: args.problems,
        seed: args.instance.seed,
        success_rate: successes.len() as f64 / records.len().max(1) as f64,
        median_ms: quantile(&times, 0.5),
        p95_ms: quantile(&times, 0.95),
        mean_smoothness: mean(&successes.iter().map(|r| r.smoothness).collect::<Vec<_>>()),
        mean_arc_length: mean(&successes.iter().map(|r| r.arc_length).collect::<Vec<_>>()),
        mean_iterations: mean(&iterations),
        median_iterations: quantile(&iterations, 0.5),
    };
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        println!(
            "{:?}: {} robots, {}D, {} obstacles, {} instances (seeds {}..{}), {:.1} s in all",
            summary.method,
            summary.robots,
            summary.dim,
            summary.obstacles,
            summary.problems,
            summary.seed,
            summary.seed + summary.problems,
            started.elapsed().as_secs_f64()
        );
        println!("success rate     {:.1}%", 100.0 * summary.success_rate);
        println!("time             median {:.2} ms, p95 {:.2} ms", summary.median_ms, summary.p95_ms);
        println!("iterations       mean {:.1}, median {}", summary.mean_iterations, summary.median_iterations);
        println!("smoothness       mean {:.4} m^2/s^4 (successes)", summary.mean_smoothness);
        println!("arc length       mean {:.4} m (successes)", summary.mean_arc_length);
    }
    Ok(())
}
