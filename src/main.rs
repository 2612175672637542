//! `flowopt`: centralized multi-robot trajectory planning.
//!
//! One binary, one subcommand per job; `flowopt --help` lists them.

mod bench;
mod instances;
mod methods;
mod solve;
mod stats;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Centralized multi-robot trajectory planning (Flow-Opt).
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Plan one instance and report success, time and quality.
    Solve(solve::SolveArgs),
    /// Run a method over seeded instances and summarise (median, p95, ...).
    Bench(bench::BenchArgs),
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Solve(args) => solve::run(args),
        Command::Bench(args) => bench::run(args),
    }
}
