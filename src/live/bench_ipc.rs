//! `flowopt bench-ipc`: the round trip of the two messages alone, between
//! two processes. The parent publishes a 16-robot snapshot and busy-polls
//! for the plan; a child (`--echo`) busy-polls for the snapshot and answers
//! with a full 16-robot plan written in place. Both ports are the
//! production ones (publish + wake-up event).

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use flowopt_client::{Endpoint, PlanStatus, TeamChannel};
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Dim, Team};
use hdrhistogram::Histogram;
use serde::Serialize;

/// The team the messages describe.
const ROBOTS: usize = 16;
/// The team name used.
const TEAM: &str = "bench";
/// Round trips before measuring.
const WARM_UP: usize = 1000;
/// How long the echo process may take to come up.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// Measure the snapshot/plan round trip.
#[derive(Debug, Args)]
pub struct BenchIpcArgs {
    /// Round trips measured.
    #[arg(long, default_value_t = 20_000)]
    iterations: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Internal: run as the echoing peer under this prefix.
    #[arg(long, hide = true)]
    echo: Option<String>,
}

#[derive(Debug, Serialize)]
struct IpcReport {
    robots: usize,
    snapshot_bytes: usize,
    plan_bytes: usize,
    iterations: usize,
    median_us: f64,
    p90_us: f64,
    p99_us: f64,
    max_us: f64,
}

/// Runs `flowopt bench-ipc`.
pub fn run(args: BenchIpcArgs) -> Result<()> {
    if let Some(prefix) = &args.echo {
        return echo(prefix);
    }
    let prefix = format!("flowopt-bench-ipc-{}", std::process::id());
    let channel = TeamChannel::new(&prefix, TEAM)?;
    let endpoint = Endpoint::new("flowopt-bench-ipc")?;
    let mut states = endpoint.state_publisher(&channel)?;
    let mut plans = endpoint.plan_subscriber(&channel, &states)?;
    let exe = std::env::current_exe()?;
    let mut peer = Command::new(exe)
        .args(["bench-ipc", "--echo", &prefix])
        .stdin(Stdio::null())
        .spawn()
        .context("cannot start the echo process")?;
    let fill = |s: &mut flowopt_client::StateSnapshot| {
        s.dim = 2;
        s.robots = ROBOTS as u32;
        for (k, r) in s.robot.iter_mut().take(ROBOTS).enumerate() {
            r.position = [k as f64 * 0.1, 0.0, 0.0];
            r.goal = [0.0, k as f64 * 0.1, 0.0];
        }
    };
    // Connect: publish until the peer answers.
    let connect = Instant::now();
    loop {
        states.publish_with(fill)?;
        if plans.wait(Duration::from_millis(10))?.is_some() {
            break;
        }
        if connect.elapsed() > CONNECT_TIMEOUT {
            let _ = peer.kill();
            bail!("the echo process did not answer within {CONNECT_TIMEOUT:?}");
        }
    }
    let mut histogram = Histogram::<u64>::new_with_bounds(1, 10_000_000_000, 3)?;
    for i in 0..WARM_UP + args.iterations {
        let t0 = Instant::now();
        let sequence = states.publish_with(fill)?;
        loop {
            if let Some(plan) = plans.latest()?
                && plan.answers_sequence == sequence
            {
                break;
            }
            std::hint::spin_loop();
        }
        if i >= WARM_UP {
            histogram.record((t0.elapsed().as_nanos() as u64).max(1))?;
        }
    }
    states.publish_with(|s| s.sequence = 0)?;
    let _ = peer.wait();
    let q = |p: f64| histogram.value_at_quantile(p) as f64 * 1e-3;
    let report = IpcReport {
        robots: ROBOTS,
        snapshot_bytes: size_of::<flowopt_client::StateSnapshot>(),
        plan_bytes: size_of::<flowopt_client::JointTrajectory>(),
        iterations: args.iterations,
        median_us: q(0.5),
        p90_us: q(0.9),
        p99_us: q(0.99),
        max_us: histogram.max() as f64 * 1e-3,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "snapshot ({} B) -> plan ({} B) round trip, {} robots, {} iterations:",
            report.snapshot_bytes, report.plan_bytes, report.robots, report.iterations
        );
        println!(
            "median {:.2} us, p90 {:.2} us, p99 {:.2} us, max {:.1} us",
            report.median_us, report.p90_us, report.p99_us, report.max_us
        );
    }
    Ok(())
}

/// The peer: answers every snapshot with a 16-robot plan until a snapshot
/// with sequence 0 arrives.
fn echo(prefix: &str) -> Result<()> {
    let channel = TeamChannel::new(prefix, TEAM)?;
    let endpoint = Endpoint::new("flowopt-bench-ipc-echo")?;
    let states = endpoint.state_subscriber(&channel)?;
    let plans = endpoint.plan_publisher(&channel)?;
    let team = Team::default_for(Dim::Two, ROBOTS);
    let coeffs = (0..2 * ROBOTS * (team.degree + 1)).map(|k| k as f64 * 1e-3).collect();
    let plan = JointPlan::new(&team, coeffs);
    loop {
        let Some(snapshot) = states.latest()? else {
            std::hint::spin_loop();
            continue;
        };
        if snapshot.sequence == 0 {
            return Ok(());
        }
        let (sequence, timestamp) = (snapshot.sequence, snapshot.timestamp_ns);
        drop(snapshot);
        plans.publish_with(|p| {
            p.set_status(PlanStatus::Ok);
            let _ = p.write_plan(&plan);
            p.answers_sequence = sequence;
            p.state_timestamp_ns = timestamp;
            p.plan_sequence = sequence;
            p.plan_origin_ns = timestamp;
        })?;
    }
}
