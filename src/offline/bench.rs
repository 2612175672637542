//! `flowopt bench`: run a method over seeded instances and summarise.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use flowopt_methods::Method;
use flowopt_models::pipeline::Query;
use flowopt_planner::am::Budget;

use crate::offline::harness::{Harness, Record, StageMs, plan_distance};
use crate::offline::instances::{InstanceArgs, infeasible_json};
use crate::offline::planning_args::PlanningArgs;
use crate::offline::stats::{IterationStats, mean, quantile};

/// Benchmark a planning method on seeded scenes of a family.
#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(flatten)]
    planning: PlanningArgs,
    #[command(flatten)]
    instance: InstanceArgs,
    /// Number of instances (seeds seed..seed+problems).
    #[arg(long, default_value_t = 100)]
    problems: u64,
    /// Skip the untimed residual study (the iterations to 0.01 / 0.001 m
    /// are then not reported): it runs up to 10,000 iterations, which is
    /// most of the time a big team's benchmark takes.
    #[arg(long)]
    no_study: bool,
    /// Learned methods: also plan every instance with this many noise seeds
    /// (untimed) and report the mean pairwise distance between the verified
    /// plans (diversity).
    #[arg(long, default_value_t = 0)]
    diversity: usize,
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
    /// Scene family (`scenario-file` for a file).
    pub family: String,
    /// Robots per instance.
    pub robots: usize,
    /// Workspace dimension.
    pub dim: usize,
    /// Obstacles per instance (the first's).
    pub obstacles: usize,
    /// The first instance's scene parameters (its seed is `seed`).
    pub scene: Option<flowopt_planner::scenes::SceneParams>,
    /// Instances run.
    pub problems: u64,
    /// First seed.
    pub seed: u64,
    /// Instances certified infeasible before planning (a robot that cannot
    /// brake inside the box: `--max-acceleration`); not planned.
    pub certified_infeasible: u64,
    /// The longest certification (ms; 0 without any).
    pub certify_max_ms: f64,
    /// Fraction of the planned instances (all but the certified
    /// infeasible ones) whose plan passed the success verdict.
    pub success_rate: f64,
    /// With the team's acceleration limit (`--max-acceleration`): the
    /// successful plans over it, which a daemon refuses from motion (from
    /// rest among static obstacles it stretches them in time).
    pub over_acceleration: Option<u64>,
    /// Median planning time (ms), planned instances.
    pub median_ms: f64,
    /// 95th-percentile planning time (ms), planned instances.
    pub p95_ms: f64,
    /// Mean smoothness over successful instances.
    pub mean_smoothness: f64,
    /// Mean arc length over successful instances (m).
    pub mean_arc_length: f64,
    /// Mean AM iterations, planned instances.
    pub mean_iterations: f64,
    /// Median AM iterations, planned instances.
    pub median_iterations: f64,
    /// Mean iterations to primal residual 0.01 m of the same start, over
    /// the instances that reached it (see `Record::iterations_to_0_01`).
    pub mean_iterations_to_0_01: f64,
    /// Fraction of instances whose study reached 0.01 m.
    pub reached_0_01: f64,
    /// The same to 0.001 m.
    pub mean_iterations_to_0_001: f64,
    /// Fraction of instances whose study reached 0.001 m.
    pub reached_0_001: f64,
    /// Median stage times of the learned pipeline (ms).
    pub median_stages_ms: Option<serde_json::Value>,
    /// Mean pairwise RMS distance (m) between verified plans of one problem
    /// from different noise seeds (`--diversity`).
    pub mean_pairwise_distance_m: Option<f64>,
}

#[derive(Serialize)]
struct InstanceLine<'a> {
    seed: u64,
    #[serde(flatten)]
    record: &'a Record,
}

/// Runs `flowopt bench`.
pub fn run(args: BenchArgs) -> Result<()> {
    let settings = args.planning.settings()?;
    let method = settings.method;
    let mut harness = Harness::new(settings, args.no_study);
    let mut distances = Vec::new();
    let mut out = match &args.per_instance {
        Some(path) => Some(std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?),
        None => None,
    };
    let progress = ProgressBar::new(args.problems);
    progress.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed_precise}]")?);
    let started = Instant::now();
    let mut records = Vec::with_capacity(args.problems as usize);
    let mut first = None;
    let mut certify_ms = Vec::new();
    for index in 0..args.problems {
        let (problem, params) = args.instance.instance(index)?;
        if index == 0 {
            first = Some((problem.team.clone(), problem.obstacles.len(), params));
        }
        let seed = args.instance.seed + index;
        let checked = Instant::now();
        if let Some(why) = InstanceArgs::certified_infeasible(&problem) {
            certify_ms.push(checked.elapsed().as_secs_f64() * 1e3);
            if let Some(file) = out.as_mut() {
                writeln!(file, "{}", serde_json::json!({ "seed": seed, "infeasible": infeasible_json(&why) }))?;
            }
            progress.inc(1);
            continue;
        }
        let record = harness.run(method, &problem, seed)?;
        if args.diversity > 1 && matches!(method, Method::Flowopt | Method::FlowNoInit) {
            let mut plans = Vec::new();
            let pipeline = harness.pipeline(method, problem.team.dim)?;
            for k in 0..args.diversity as u64 {
                let query = Query::from(&problem);
                let noise = seed + 1_000_003 * (k + 1);
                let mut outs = pipeline.plan_batch(&[query], &Budget::unlimited(), noise)?;
                let out = outs.pop().context("the pipeline returned no plan")?;
                if out.verified {
                    plans.push(out.xi().to_vec());
                }
            }
            for a in 0..plans.len() {
                for b in a + 1..plans.len() {
                    distances.push(plan_distance(&problem.team, &plans[a], &plans[b]));
                }
            }
        }
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
    let (team, obstacles, scene) = first.context("no instance was planned")?;
    let to_0_01 = IterationStats::of(records.iter().map(|r| r.iterations_to_0_01));
    let to_0_001 = IterationStats::of(records.iter().map(|r| r.iterations_to_0_001));
    let summary = Summary {
        method,
        family: scene.as_ref().map_or("scenario-file".into(), |p| p.family.name().to_string()),
        robots: team.robots,
        dim: team.dim.axes(),
        obstacles,
        scene,
        problems: args.problems,
        seed: args.instance.seed,
        certified_infeasible: certify_ms.len() as u64,
        certify_max_ms: certify_ms.iter().copied().fold(0.0, f64::max),
        success_rate: successes.len() as f64 / records.len().max(1) as f64,
        over_acceleration: team
            .max_acceleration
            .map(|limit| successes.iter().filter(|r| r.max_acceleration > limit * (1.0 + 1e-9)).count() as u64),
        median_ms: quantile(&times, 0.5),
        p95_ms: quantile(&times, 0.95),
        mean_smoothness: mean(&successes.iter().map(|r| r.smoothness).collect::<Vec<_>>()),
        mean_arc_length: mean(&successes.iter().map(|r| r.arc_length).collect::<Vec<_>>()),
        mean_iterations: mean(&iterations),
        median_iterations: quantile(&iterations, 0.5),
        mean_iterations_to_0_01: to_0_01.mean,
        reached_0_01: to_0_01.reached,
        mean_iterations_to_0_001: to_0_001.mean,
        reached_0_001: to_0_001.reached,
        median_stages_ms: stage_medians(&records),
        mean_pairwise_distance_m: (!distances.is_empty()).then(|| mean(&distances)),
    };
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        println!(
            "{:?} on {}: {} robots, {}D, {} obstacles, {} instances (seeds {}..{}), {:.1} s in all",
            summary.method,
            summary.family,
            summary.robots,
            summary.dim,
            summary.obstacles,
            summary.problems,
            summary.seed,
            summary.seed + summary.problems,
            started.elapsed().as_secs_f64()
        );
        println!(
            "success rate     {:.1}% of {} planned ({} certified infeasible, each within {:.3} ms)",
            100.0 * summary.success_rate,
            records.len(),
            summary.certified_infeasible,
            summary.certify_max_ms
        );
        if let (Some(over), Some(limit)) = (summary.over_acceleration, team.max_acceleration) {
            println!("acceleration     {over} successful plans over the limit of {limit} m/s^2");
        }
        println!("time             median {:.2} ms, p95 {:.2} ms", summary.median_ms, summary.p95_ms);
        println!("iterations       mean {:.1}, median {}", summary.mean_iterations, summary.median_iterations);
        println!(
            "to primal 0.01   mean {:.1} iterations ({:.0}% reached); 0.001: mean {:.1} ({:.0}% reached)",
            summary.mean_iterations_to_0_01,
            100.0 * summary.reached_0_01,
            summary.mean_iterations_to_0_001,
            100.0 * summary.reached_0_001
        );
        if let Some(stages) = &summary.median_stages_ms {
            println!("stages (median)  {stages}");
        }
        if let Some(d) = summary.mean_pairwise_distance_m {
            println!("diversity        mean pairwise distance {d:.4} m");
        }
        println!("smoothness       mean {:.4} m^2/s^4 (successes)", summary.mean_smoothness);
        println!("arc length       mean {:.4} m (successes)", summary.mean_arc_length);
    }
    Ok(())
}

/// Median of every pipeline stage time, when the records have them.
fn stage_medians(records: &[Record]) -> Option<serde_json::Value> {
    let stages: Vec<_> = records.iter().filter_map(|r| r.stages).collect();
    if stages.is_empty() {
        return None;
    }
    let median = |f: &dyn Fn(&StageMs) -> f64| quantile(&stages.iter().map(f).collect::<Vec<_>>(), 0.5);
    Some(serde_json::json!({
        "sample": median(&|s| s.sample_ms),
        "rank": median(&|s| s.rank_ms),
        "init": median(&|s| s.init_ms),
        "filter": median(&|s| s.filter_ms),
        "select": median(&|s| s.select_ms),
        "total": median(&|s| s.total_ms),
    }))
}
