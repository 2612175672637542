//! `flowopt solve`: plan one instance and report how it went.

use anyhow::Result;
use clap::Args;

use crate::offline::harness::Harness;
use crate::offline::instances::InstanceArgs;
use crate::offline::planning_args::PlanningArgs;

/// Plan one instance.
#[derive(Debug, Args)]
pub struct SolveArgs {
    #[command(flatten)]
    instance: InstanceArgs,
    #[command(flatten)]
    planning: PlanningArgs,
    /// Skip the untimed residual study (the iterations to 0.01 / 0.001 m
    /// are then not reported).
    #[arg(long)]
    no_study: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// Runs `flowopt solve`.
pub fn run(args: SolveArgs) -> Result<()> {
    let (problem, scene) = args.instance.instance(0)?;
    let settings = args.planning.settings()?;
    let method = settings.method;
    let mut harness = Harness::new(settings, args.no_study);
    let record = harness.run(method, &problem, args.instance.seed)?;
    if args.json {
        let line = serde_json::json!({ "method": method, "scene": scene, "record": record });
        println!("{line}");
    } else {
        let team = &problem.team;
        println!("{method}: {} robots, {}D, {} obstacles", team.robots, team.dim.axes(), problem.obstacles.len());
        println!("success          {} (by the {})", record.success, record.by);
        println!("time             {:.2} ms", record.time_ms);
        println!("iterations       {} (stop: {:?})", record.iterations, record.stop);
        println!("primal residual  {:.2e} m", record.primal_residual);
        println!("smoothness       {:.4} m^2/s^4", record.smoothness);
        println!("arc length       {:.4} m", record.arc_length);
        println!("min clearance    {:.4} m", record.min_clearance);
    }
    Ok(())
}
