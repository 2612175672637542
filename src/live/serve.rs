//! `flowopt serve`: the planning daemon.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result};
use clap::Args;
use signal_hook::consts::{SIGINT, SIGTERM};

use crate::live::daemon_args::DaemonArgs;

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
}

/// Runs `flowopt serve` until SIGINT or SIGTERM.
pub fn run(args: ServeArgs) -> Result<()> {
    let config = args.daemon.load()?;
    let shutdown = Arc::new(AtomicBool::new(false));
    for signal in [SIGINT, SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&shutdown)).context("cannot install the signal handlers")?;
    }
    flowopt_daemon::serve(&config, shutdown, args.metrics)?;
    Ok(())
}
