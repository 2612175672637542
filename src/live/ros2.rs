//! `flowopt ros2`: the ROS 2 bridge ([`flowopt_ros2`]) for one team of a
//! daemon: mocap poses, goals and obstacles in from ROS 2, the plans to
//! follow and every answer's status out. `--simulate` adds a simulated
//! team on ROS 2 (poses out, paths in) and `--with-daemon` starts the
//! daemon, so that one command shows the whole loop without robots.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow};
use clap::Args;
use flowopt_planner::scenario::RandomScenario;
use flowopt_ros2::mocap::{self, MocapReport};
use flowopt_ros2::{BridgeReport, BridgeSettings, BridgeTeam};
use serde::Serialize;
use signal_hook::consts::{SIGINT, SIGTERM};

use crate::live::daemon_args::DaemonArgs;
use crate::live::demo::stop_child;

/// Bridge a team between ROS 2 and the daemon.
#[derive(Debug, Args)]
pub struct Ros2Args {
    #[command(flatten)]
    daemon: DaemonArgs,
    /// Team to bridge (default: the configuration's first).
    #[arg(long)]
    team: Option<String>,
    /// A bridge file: its `[ros2]` table sets topics, frames, QoS and
    /// rates (docs/ROS2.md); without one, the defaults.
    #[arg(long, value_name = "FILE")]
    bridge: Option<PathBuf>,
    /// DDS domain (ROS_DOMAIN_ID), over the bridge file's.
    #[arg(long)]
    domain: Option<u16>,
    /// Also fly a simulated team on ROS 2: poses and goals published,
    /// paths followed.
    #[arg(long)]
    simulate: bool,
    /// Also start the daemon (`flowopt serve` on the same configuration).
    #[arg(long)]
    with_daemon: bool,
    /// Stop after this many seconds (default: at SIGINT or SIGTERM).
    #[arg(long)]
    seconds: Option<f64>,
    /// Seed of the simulated team's starts and goals.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Print one JSON report at the end.
    #[arg(long)]
    json: bool,
}

/// What a run did.
#[derive(Debug, Serialize)]
struct Ros2Report {
    bridge: BridgeReport,
    simulated: Option<MocapReport>,
}

/// Runs `flowopt ros2`.
pub fn run(args: Ros2Args) -> Result<()> {
    let mut settings = match &args.bridge {
        Some(path) => BridgeSettings::load(path)?,
        None => BridgeSettings::default(),
    };
    if let Some(domain) = args.domain {
        settings.domain_id = domain;
        settings = settings.checked()?;
    }
    let (config, team_config) = args.daemon.team(args.team.as_deref())?;
    let team = team_config.team()?;
    let bridged = BridgeTeam { name: team_config.name.clone(), robots: team.robots, dim: team.dim };
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [SIGINT, SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop)).context("cannot install the signal handlers")?;
    }
    let mut daemon = if args.with_daemon {
        let exe = std::env::current_exe().context("cannot find the flowopt executable")?;
        let child = Command::new(exe)
            .arg("serve")
            .args(args.daemon.child_args(&config.ipc.prefix))
            .stdin(Stdio::null())
            .spawn()
            .context("cannot start the daemon")?;
        Some(child)
    } else {
        None
    };
    let prefix = config.ipc.prefix.clone();
    let bridge = {
        let (settings, stop) = (settings.clone(), Arc::clone(&stop));
        std::thread::Builder::new()
            .name("ros2-bridge".into())
            .spawn(move || flowopt_ros2::run(&settings, &prefix, &bridged, &stop))
            .context("cannot start the bridge")?
    };
    let simulated = if args.simulate {
        let scenario = RandomScenario::new(team.clone());
        let first = scenario.generate(args.seed).context("drawing the simulated team's start")?;
        let starts = first.starts.iter().map(|s| [s.position.x, s.position.y, s.position.z]).collect();
        let arrived_m = team.robot.radius;
        let (name, settings, stop, seed) = (team_config.name.clone(), settings.clone(), Arc::clone(&stop), args.seed);
        let thread = std::thread::Builder::new()
            .name("ros2-mocap".into())
            .spawn(move || {
                let mut round = 0;
                let mut goals = || {
                    let draw = if round == 0 { Ok(first.clone()) } else { scenario.generate(seed.wrapping_add(round)) };
                    round += 1;
                    draw.map(|p| p.goals.iter().map(|g| [g.x, g.y, g.z]).collect()).unwrap_or_default()
                };
                mocap::run(&settings, &name, starts, &mut goals, arrived_m, &stop)
            })
            .context("cannot start the simulated team")?;
        Some(thread)
    } else {
        None
    };
    let started = Instant::now();
    while !stop.load(Ordering::Relaxed) && !bridge.is_finished() {
        if args.seconds.is_some_and(|s| started.elapsed().as_secs_f64() >= s) {
            stop.store(true, Ordering::Relaxed);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    stop.store(true, Ordering::Relaxed);
    let bridge = bridge.join().map_err(|_| anyhow!("the bridge panicked"))?;
    let simulated = match simulated {
        Some(thread) => Some(thread.join().map_err(|_| anyhow!("the simulated team panicked"))??),
        None => None,
    };
    if let Some(child) = daemon.as_mut() {
        stop_child(child)?;
    }
    let report = Ros2Report { bridge: bridge?, simulated };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    Ok(())
}
