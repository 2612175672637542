//! `flowopt`: centralized multi-robot trajectory planning.
//!
//! One binary, one subcommand per job; `flowopt --help` lists them.

mod learn;
mod live;
mod offline;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use learn::{datagen, train};
use live::{bench_ipc, demo, ros2, serve, sim};
use offline::{bench, eval, solve};
use tracing_subscriber::filter::{EnvFilter, LevelFilter};
use tracing_subscriber::prelude::*;

/// Centralized multi-robot trajectory planning (Flow-Opt).
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    /// Write a Chrome/Perfetto trace of every span (planning stages) here.
    #[arg(long, global = true, value_name = "FILE")]
    trace_out: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the planning daemon on a configuration.
    Serve(serve::ServeArgs),
    /// Run simulated robots that publish their state and track the daemon's plans.
    Sim(sim::SimArgs),
    /// Start the daemon and the simulator as two processes and report.
    Demo(demo::DemoArgs),
    /// Bridge a team between ROS 2 (mocap poses, goals, obstacles) and the
    /// daemon (paths, trajectories, statuses), without a ROS install.
    Ros2(ros2::Ros2Args),
    /// Plan one instance and report success, time and quality.
    Solve(solve::SolveArgs),
    /// Run a method over seeded instances and summarise (median, p95, ...).
    Bench(bench::BenchArgs),
    /// Measure the round trip of a snapshot and a plan between two processes.
    BenchIpc(bench_ipc::BenchIpcArgs),
    /// Generate training data with the from-scratch optimiser.
    Datagen(datagen::DatagenArgs),
    /// Train the flow policy or the SF initialiser.
    Train(train::TrainArgs),
    /// Compare the methods on seeded test instances; write docs/RESULTS.md and figures.
    Eval(eval::EvalArgs),
}

/// Runs the command; an error is printed as one line (its causes joined),
/// whatever `RUST_BACKTRACE` says: refusals such as a second daemon for a
/// served team are expected outcomes, not crashes.
fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("flowopt: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    // Planning runs candle on one thread: its products are small, and the
    // safety filter has the cores (docs/LEARNED.md). Training keeps
    // candle's default (40 flow steps on data/n8: 21.0 s, 21.3 s at one).
    let tensor_threads = if matches!(cli.command, Command::Train(_)) { None } else { Some(1) };
    // SAFETY: only the argument parsing has run; no other thread exists yet.
    unsafe { flowopt_models::runtime::configure(tensor_threads) };
    // Logs: RUST_LOG, or warnings plus the daemon's and simulator's
    // progress. The trace, if asked for, records every span at INFO.
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new("warn,flowopt_daemon=info,flowopt::live::observe=info,iceoryx2_bb_loggers=error,ros2_client::distributions=error"));
    let fmt = tracing_subscriber::fmt::layer().with_writer(std::io::stderr).with_filter(filter);
    let mut _flush = None;
    // `demo` hands the trace file to its daemon process instead.
    let traced_here = !matches!(cli.command, Command::Demo(_));
    let chrome = cli.trace_out.as_ref().filter(|_| traced_here).map(|path| {
        let (layer, guard) = tracing_chrome::ChromeLayerBuilder::new().file(path).include_args(true).build();
        _flush = Some(guard);
        layer.with_filter(LevelFilter::INFO)
    });
    tracing_subscriber::registry().with(fmt).with(chrome).try_init().context("cannot install the logger")?;
    match cli.command {
        Command::Serve(args) => serve::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Demo(args) => demo::run(args, cli.trace_out),
        Command::Ros2(args) => ros2::run(args),
        Command::Solve(args) => solve::run(args),
        Command::Bench(args) => bench::run(args),
        Command::BenchIpc(args) => bench_ipc::run(args),
        Command::Datagen(args) => datagen::run(args),
        Command::Train(args) => train::run(args),
        Command::Eval(args) => eval::run(args),
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    use super::Cli;

    #[test]
    fn the_command_line_is_well_formed_and_small() {
        Cli::command().debug_assert();
        let options = |name: &str| {
            let cmd = Cli::command();
            let sub = cmd.find_subcommand(name).unwrap_or_else(|| panic!("no subcommand {name}"));
            sub.get_arguments().filter(|a| !a.is_positional()).count()
        };
        // The everyday flags are named; research knobs go through --set.
        for name in ["solve", "bench"] {
            assert!(options(name) <= 25, "{name} has {} options", options(name));
        }
        for argv in [
            &["flowopt", "bench", "--config", "config/default.toml", "--problems", "20", "--json"][..],
            &["flowopt", "solve", "--set", "learned.candidates=8", "--set", "optimiser.veer=false"][..],
        ] {
            assert!(Cli::command().try_get_matches_from(argv).is_ok(), "{argv:?}");
        }
        assert!(Cli::command().try_get_matches_from(["flowopt", "bench", "--candidates", "8"]).is_err());
    }
}
