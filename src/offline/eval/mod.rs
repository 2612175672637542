//! `flowopt eval`: the evaluation report. Runs the from-scratch optimiser
//! and the learned pipeline (with and without the SF initialiser) on the
//! same seeded test instances (seeds from `--seed`, never used for
//! training), in one process, one instance at a time, and writes
//! `docs/RESULTS.md` with eight tables and SVG figures under `docs/figures/`:
//! six on the benchmark's random instances, then the scene families and
//! the baseline's scaling with the team size ([`families`]). Rows a method
//! cannot produce (no weights for the team) say so instead of showing a
//! number.

mod families;
mod figures;
mod header;
mod measures;
mod report;
mod rows;
mod studies;
mod tables;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use crate::offline::harness::Harness;
use crate::offline::planning_args::SettingsArgs;
use header::{HeaderFacts, calibration_us};
use rows::Runs;

/// Write the evaluation report: tables and figures comparing the methods.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Fewer instances per row (20 instead of 100) and one throughput
    /// batch: the whole report in minutes.
    #[arg(long)]
    quick: bool,
    /// Instances per row (overrides the count `--quick` chooses).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    problems: Option<u64>,
    /// First instance seed; instance i uses seed + i.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The report to write.
    #[arg(long, default_value = "docs/RESULTS.md")]
    out: PathBuf,
    /// Directory of the figures (linked relative to the report when under
    /// its directory, else by absolute path).
    #[arg(long, default_value = "docs/figures")]
    figures: PathBuf,
    #[command(flatten)]
    settings: SettingsArgs,
}

/// Runs `flowopt eval`.
pub fn run(args: EvalArgs) -> Result<()> {
    let started = Instant::now();
    let problems = args.problems.unwrap_or(if args.quick { 20 } else { 100 });
    std::fs::create_dir_all(&args.figures).with_context(|| format!("creating {}", args.figures.display()))?;
    let progress = ProgressBar::new(0);
    progress.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed_precise}]")?);
    let settings = args.settings.settings()?;
    let mut runs = Runs {
        planner: Harness::new(settings.clone(), false),
        scenes: Harness::new(settings.clone(), true),
        problems,
        seed: args.seed,
        records: HashMap::new(),
        failed: HashMap::new(),
        progress,
        unavailable: HashMap::new(),
    };
    let command = if args.quick { "flowopt eval --quick".to_string() } else { "flowopt eval".to_string() };
    let mut doc = String::new();
    let figures = relative_figures(&args.out, &args.figures)?;

    doc.push_str(&tables::method_comparison(&mut runs, &command)?);
    doc.push_str(&tables::iterations(&mut runs, &command)?);
    doc.push_str(&tables::success_versus_time(&mut runs, &command, &args.figures, &figures)?);
    doc.push_str(&tables::throughput(&settings, args.quick, args.seed, &command)?);
    doc.push_str(&studies::robustness(&mut runs, &command, &args.figures, &figures)?);
    doc.push_str(&studies::clearance(&mut runs, &command, &args.figures, &figures)?);
    doc.push_str(&studies::residual_figure(&mut runs, &args.figures, &figures)?);
    doc.push_str(&studies::trajectory_figures(&mut runs, args.seed, &args.figures, &figures)?);
    doc.push_str(&families::family_table(&mut runs, &command)?);
    doc.push_str(&families::scaling(&mut runs, &command, &args.figures, &figures)?);
    runs.progress.finish_and_clear();

    let header = header::header(&HeaderFacts {
        command: &command,
        problems,
        seed: args.seed,
        seconds: started.elapsed().as_secs_f64(),
        calibration_us: calibration_us()?,
        settings: &settings,
    });
    let text = header + &doc;
    std::fs::write(&args.out, text).with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "wrote {} and the figures in {} in {:.0} s",
        args.out.display(),
        args.figures.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The figures directory as the report links it: relative to the report
/// when under its directory, else absolute.
fn relative_figures(report: &Path, figures: &Path) -> Result<String> {
    let base = report.parent().unwrap_or(Path::new(""));
    match figures.strip_prefix(base) {
        Ok(relative) => Ok(relative.display().to_string()),
        Err(_) => Ok(std::path::absolute(figures)
            .with_context(|| format!("resolving {}", figures.display()))?
            .display()
            .to_string()),
    }
}
