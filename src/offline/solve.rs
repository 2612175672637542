//! `flowopt solve`: plan one instance and report how it went.

use anyhow::Result;
use clap::Args;

use crate::offline::instances::InstanceArgs;
use crate::offline::methods::{Method, Overrides, Planner};

/// Plan one instance.
#[derive(Debug, Args)]
pub struct SolveArgs {
    #[command(flatten)]
    instance: InstanceArgs,
    /// Planning method.
    #[arg(long, value_enum, default_value = "auto")]
    method: Method,
    #[command(flatten)]
    engine: EngineArgs,
    #[command(flatten)]
    learned: crate::offline::methods::LearnedArgs,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// Engine overrides shared by `solve` and `bench`.
#[derive(Debug, Clone, Args)]
pub struct EngineArgs {
    /// Iteration cap (default 10,000 for the optimiser, 500 for the SF).
    #[arg(long)]
    pub max_iterations: Option<usize>,
    /// Stop at this primal residual (m) without the dense verification
    /// (the paper's rule).
    #[arg(long)]
    pub tolerance: Option<f64>,
    /// Optimiser: start from the smoothest curves (the paper's cold start)
    /// instead of routing blocked robots around obstacles.
    #[arg(long)]
    pub straight_start: bool,
    /// Optimiser: perturbed restarts when an attempt stalls (default 3).
    #[arg(long)]
    pub restarts: Option<usize>,
    /// Ablation: constraints and verification at the fixed margin only,
    /// without the chord inflation between instants.
    #[arg(long)]
    pub no_chord: bool,
    /// Ablation: check every robot pair in every iteration (no broad phase).
    #[arg(long)]
    pub all_pairs: bool,
    /// Ablation: optimiser cold starts without veering head-on robots.
    #[arg(long)]
    pub no_veer: bool,
    /// Ablation: the optimiser checks its robot pairs on one thread (by
    /// default the biggest teams use two).
    #[arg(long)]
    pub one_thread: bool,
    /// Skip the untimed residual study (the iterations to 0.01 / 0.001 m
    /// are then not reported): it runs up to 10,000 iterations, which is
    /// most of the time a big team's benchmark takes.
    #[arg(long)]
    pub no_study: bool,
}

impl EngineArgs {
    /// As engine overrides.
    pub fn overrides(&self) -> Overrides {
        Overrides {
            max_iterations: self.max_iterations,
            tolerance: self.tolerance,
            straight_start: self.straight_start,
            restarts: self.restarts,
            no_chord: self.no_chord,
            all_pairs: self.all_pairs,
            no_veer: self.no_veer,
            one_thread: self.one_thread,
            no_study: self.no_study,
        }
    }
}

/// Runs `flowopt solve`.
pub fn run(args: SolveArgs) -> Result<()> {
    let (problem, scene) = args.instance.instance(0)?;
    let mut planner = Planner::new(args.engine.overrides(), Some(args.learned.clone()));
    let record = planner.run(args.method, &problem, args.instance.seed)?;
    if args.json {
        let line = serde_json::json!({ "method": args.method, "scene": scene, "record": record });
        println!("{line}");
    } else {
        let team = &problem.team;
        println!(
            "{:?}: {} robots, {}D, {} obstacles",
            args.method,
            team.robots,
            team.dim.axes(),
            problem.obstacles.len()
        );
        println!("success          {}", record.success);
        println!("time             {:.2} ms", record.time_ms);
        println!("iterations       {} (stop: {:?})", record.iterations, record.stop);
        println!("primal residual  {:.2e} m", record.primal_residual);
        println!("smoothness       {:.4} m^2/s^4", record.smoothness);
        println!("arc length       {:.4} m", record.arc_length);
        println!("min clearance    {:.4} m", record.min_clearance);
    }
    Ok(())
}
