//! `flowopt solve`: plan one instance and report how it went.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use flowopt_client::pieces::{DEFAULT_PIECE_S, Pieces};
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::Problem;

use crate::offline::harness::Harness;
use crate::offline::instances::{InstanceArgs, infeasible_json};
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
    /// Write each robot's verified plan as the polynomial pieces a
    /// Crazyflie flies (Crazyswarm's CSV: per 0.5 s piece a duration and 8
    /// coefficients per axis) to `DIR/robot_<i>.csv`.
    #[arg(long, value_name = "DIR")]
    crazyflie: Option<PathBuf>,
}

/// Runs `flowopt solve`.
pub fn run(args: SolveArgs) -> Result<()> {
    let (problem, scene) = args.instance.instance(0)?;
    let settings = args.planning.settings()?;
    let method = settings.method;
    if let Some(why) = InstanceArgs::certified_infeasible(&problem) {
        if args.json {
            println!(
                "{}",
                serde_json::json!({ "method": method, "scene": scene, "infeasible": infeasible_json(&why) })
            );
        } else {
            println!("certified infeasible: {why}");
        }
        return Ok(());
    }
    let mut harness = Harness::new(settings, args.no_study);
    let record = harness.run(method, &problem, args.instance.seed)?;
    let crazyflie = match &args.crazyflie {
        Some(dir) if record.success => Some(write_pieces(dir, &problem, &record.xi)?),
        Some(_) => bail!("the plan did not verify: no Crazyflie pieces written"),
        None => None,
    };
    if args.json {
        let line = serde_json::json!({ "method": method, "scene": scene, "record": record, "crazyflie_max_error_m": crazyflie });
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
        if let (Some(dir), Some(error)) = (&args.crazyflie, crazyflie) {
            println!("crazyflie        {} (pieces within {error:.1e} m of the plan)", dir.display());
        }
    }
    Ok(())
}

/// Writes every robot's plan `xi` of `problem` as Crazyflie pieces in
/// `dir`; returns the largest distance of any robot's pieces from its plan.
fn write_pieces(dir: &Path, problem: &Problem, xi: &[f64]) -> Result<f64> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let plan = JointPlan::new(&problem.team, xi.to_vec());
    let mut worst: f64 = 0.0;
    for robot in 0..plan.robots {
        let pieces = Pieces::of(&plan, robot, DEFAULT_PIECE_S)?;
        worst = worst.max(pieces.max_error(&plan, robot, 2001));
        let path = dir.join(format!("robot_{robot}.csv"));
        std::fs::write(&path, pieces.csv()).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(worst)
}
