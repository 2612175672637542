//! Options shared by the subcommands that talk to the daemon.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use flowopt_daemon::config::{DaemonConfig, TeamConfig};

/// The shipped default configuration, used when `config/default.toml` is
/// not found (running from outside the repository; without the learned
/// planner, whose weights are in the repository).
const DEFAULT_CONFIG: &str = include_str!("../../config/default.toml");
/// Where the default configuration lives in the repository.
const DEFAULT_CONFIG_PATH: &str = "config/default.toml";

/// Which configuration and which services.
#[derive(Debug, Clone, Args)]
pub struct DaemonArgs {
    /// Daemon configuration (TOML).
    #[arg(long, default_value = DEFAULT_CONFIG_PATH)]
    pub config: PathBuf,
    /// Service prefix, overriding the configuration's `ipc.prefix` (a unique
    /// one isolates a test or a demo).
    #[arg(long)]
    pub ipc_prefix: Option<String>,
}

impl DaemonArgs {
    /// The configuration with the overrides applied.
    pub fn load(&self) -> Result<DaemonConfig> {
        let mut config = if self.config.as_os_str() == DEFAULT_CONFIG_PATH && !self.config.exists() {
            let mut config: DaemonConfig =
                toml::from_str(DEFAULT_CONFIG).context("the built-in default configuration")?;
            config.check()?;
            // The weights live in the repository: away from it the
            // optimiser plans alone.
            for team in &mut config.teams {
                if team.learned.take().is_some() {
                    eprintln!(
                        "{DEFAULT_CONFIG_PATH} not found: the built-in configuration plans with the optimiser alone"
                    );
                }
            }
            config
        } else {
            DaemonConfig::load(&self.config)?
        };
        if let Some(prefix) = &self.ipc_prefix {
            config.ipc.prefix = prefix.clone();
        }
        Ok(config)
    }

    /// The configuration and the team called `team` (the first if `None`).
    pub fn team(&self, team: Option<&str>) -> Result<(DaemonConfig, TeamConfig)> {
        let config = self.load()?;
        let found = match team {
            Some(name) => config.teams.iter().find(|t| t.name == name),
            None => config.teams.first(),
        }
        .with_context(|| format!("no team {team:?} in {}", self.config.display()))?
        .clone();
        Ok((config, found))
    }
}
