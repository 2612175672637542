//! `flowopt demo`: the daemon and the simulator as two processes on the
//! default configuration, under a service prefix of their own.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use serde::Serialize;

use crate::live::daemon_args::DaemonArgs;
use crate::live::sim::{SimReport, print_report};

/// How long the daemon may take to exit after SIGTERM.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// Run the daemon and the simulator together.
#[derive(Debug, Args)]
pub struct DemoArgs {
    #[command(flatten)]
    daemon: DaemonArgs,
    /// Seconds of simulation.
    #[arg(long, default_value_t = 30.0)]
    seconds: f64,
    /// Control rate of the simulator (Hz).
    #[arg(long, default_value_t = 50.0)]
    rate_hz: f64,
    /// Seed of the simulated scene.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// The demo's summary.
#[derive(Debug, Serialize)]
struct DemoReport {
    #[serde(flatten)]
    sim: SimReport,
    /// Whether the daemon exited cleanly on SIGTERM.
    daemon_clean_exit: bool,
}

/// Runs `flowopt demo`; `trace_out` is handed to the daemon.
pub fn run(args: DemoArgs, trace_out: Option<PathBuf>) -> Result<()> {
    let exe = std::env::current_exe().context("cannot find the flowopt executable")?;
    let prefix = args.daemon.ipc_prefix.clone().unwrap_or_else(|| format!("flowopt-demo-{}", std::process::id()));
    let config = args.daemon.config.display().to_string();
    let mut serve = Command::new(&exe);
    serve.args(["serve", "--config", &config, "--ipc-prefix", &prefix]);
    if let Some(path) = &trace_out {
        serve.arg("--trace-out").arg(path);
    }
    let mut daemon = serve.stdin(Stdio::null()).spawn().context("cannot start the daemon")?;
    let sim = Command::new(&exe)
        .args(["sim", "--config", &config, "--ipc-prefix", &prefix, "--json"])
        .args(["--seconds", &args.seconds.to_string(), "--rate-hz", &args.rate_hz.to_string()])
        .args(["--seed", &args.seed.to_string()])
        .stdin(Stdio::null())
        .stderr(Stdio::inherit())
        .output();
    let daemon_clean_exit = stop(&mut daemon)?;
    let sim = sim.context("cannot run the simulator")?;
    if !sim.status.success() {
        bail!("the simulator failed ({})", sim.status);
    }
    let report: SimReport = serde_json::from_slice(&sim.stdout).context("cannot read the simulator's report")?;
    if args.json {
        println!("{}", serde_json::to_string(&DemoReport { sim: report, daemon_clean_exit })?);
    } else {
        print_report(&report);
        println!("daemon           {}", if daemon_clean_exit { "exited cleanly" } else { "did NOT exit cleanly" });
    }
    Ok(())
}

/// Sends SIGTERM and waits; kills after the grace period. Returns whether
/// the daemon exited by itself with status 0.
fn stop(daemon: &mut Child) -> Result<bool> {
    if let Some(status) = daemon.try_wait()? {
        return Ok(status.success());
    }
    // SAFETY: plain kill(2) on our own child's pid.
    unsafe {
        libc::kill(daemon.id() as libc::pid_t, libc::SIGTERM);
    }
    let since = Instant::now();
    while since.elapsed() < SHUTDOWN_GRACE {
        if let Some(status) = daemon.try_wait()? {
            return Ok(status.success());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    daemon.kill()?;
    daemon.wait()?;
    Ok(false)
}
