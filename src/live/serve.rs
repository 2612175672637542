//! `flowopt serve`: the planning daemon.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result};
use clap::Args;
use signal_hook::consts::{SIGINT, SIGTERM};

use crate::live::daemon_args::DaemonArgs;
use crate::live::observe::{ObserveArgs, Observer, Watched};

/// Run the daemon.
#[derive(Debug, Args)]
pub struct ServeArgs {
    #[command(flatten)]
    daemon: DaemonArgs,
    /// Serve the teams' Prometheus metrics (answers by status and reason,
    /// latency, late answers, cold planners' wins) on this address, e.g.
    /// `127.0.0.1:9464`, at `/metrics`.
    #[arg(long, value_name = "ADDR")]
    metrics: Option<std::net::SocketAddr>,
    /// Recording and live view of every team's traffic.
    #[command(flatten)]
    observe: ObserveArgs,
}

/// Runs `flowopt serve` until SIGINT or SIGTERM.
pub fn run(args: ServeArgs) -> Result<()> {
    let config = args.daemon.load()?;
    let shutdown = Arc::new(AtomicBool::new(false));
    for signal in [SIGINT, SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&shutdown)).context("cannot install the signal handlers")?;
    }
    let teams = config.teams.iter().map(|t| Ok(Watched::new(&t.name, &t.team()?))).collect::<Result<Vec<_>>>()?;
    let observer = Observer::start(&args.observe, &config.ipc.prefix, &teams)?;
    let served = flowopt_daemon::serve(&config, shutdown, args.metrics);
    if let Some(observer) = observer {
        observer.finish()?;
    }
    served?;
    Ok(())
}
