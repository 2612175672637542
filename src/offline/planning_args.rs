//! How the planning subcommands choose their planner: `--method`,
//! `--config FILE`, `--set KEY=VALUE` and `--threads N`, read into the one
//! [`PlannerSettings`] the daemon reads too.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use flowopt_daemon::config::DaemonConfig;
use flowopt_methods::{Method, PlannerSettings};

/// The planner: method and settings.
#[derive(Debug, Clone, Args)]
pub struct PlanningArgs {
    /// Planning method: auto, baseline, flowopt, flow-no-init or
    /// safety-filter [default: the settings', else auto].
    #[arg(long, value_parser = method)]
    pub method: Option<Method>,
    #[command(flatten)]
    pub settings: SettingsArgs,
}

impl PlanningArgs {
    /// The settings these arguments give, with the method given.
    pub fn settings(&self) -> Result<PlannerSettings> {
        let mut settings = self.settings.settings()?;
        if let Some(method) = self.method {
            settings.method = method;
        }
        Ok(settings)
    }
}

/// Parses a method's name, listing the names on a mistake.
fn method(text: &str) -> Result<Method, String> {
    text.parse()
}

/// The planners' settings: a file and assignments.
#[derive(Debug, Clone, Args)]
pub struct SettingsArgs {
    /// Planner settings: a daemon configuration (its first team's
    /// `[team.planner]`, with that team's tracking buffer: plans as that
    /// daemon does), or a TOML file of planner settings.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Sets any planner knob, KEY dotted, VALUE a TOML value or a word
    /// (`learned.candidates=8`, `optimiser.chord=false`,
    /// `learned.flow=path`); repeatable, applied in order.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Threads the optimiser iterates on, this one among them (teams of 32
    /// robots or more; the same plans for every count); `--set threads=N`
    /// [default: the settings', else the machine's cores less one].
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
}

impl SettingsArgs {
    /// The settings these arguments give.
    pub fn settings(&self) -> Result<PlannerSettings> {
        let mut settings = match &self.config {
            None => PlannerSettings::default(),
            Some(path) => {
                let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
                let table: toml::Table =
                    toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
                if table.contains_key("team") {
                    let daemon = DaemonConfig::load(path)?;
                    let team = daemon.teams.first().context("the daemon configuration has no team")?;
                    team.planner_settings(&team.team()?)
                } else {
                    PlannerSettings::from_file(path)?
                }
            }
        };
        for assignment in &self.set {
            settings.set(assignment)?;
        }
        if let Some(threads) = self.threads {
            settings.threads = threads;
        }
        Ok(settings)
    }
}
