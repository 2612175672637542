//! Options shared by the subcommands that talk to the daemon, and where
//! their configuration comes from.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use flowopt_daemon::config::{DaemonConfig, TeamConfig};
use tracing::info;

/// The shipped default configuration, built in: used when no configuration
/// is named and `config/default.toml` is not in the working directory. Its
/// learned planner uses the shipped weights, which are built in too.
const DEFAULT_CONFIG: &str = include_str!("../../config/default.toml");
/// Where the default configuration lives in the repository.
const DEFAULT_CONFIG_PATH: &str = "config/default.toml";
/// The environment variable that names a configuration.
const CONFIG_VAR: &str = "FLOWOPT_CONFIG";

/// Which configuration and which services.
#[derive(Debug, Clone, Args)]
pub struct DaemonArgs {
    /// Daemon configuration (TOML) [default: $FLOWOPT_CONFIG if set, else
    /// config/default.toml in the working directory if there, else the
    /// shipped default built into the binary]. A file that is named but
    /// missing is an error.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Service prefix, overriding the configuration's `ipc.prefix` (a unique
    /// one isolates a test or a demo).
    #[arg(long)]
    pub ipc_prefix: Option<String>,
}

impl DaemonArgs {
    /// The configuration file named by `--config` or the environment, or
    /// found in the working directory; `None` for the built-in default.
    pub fn file(&self) -> Option<PathBuf> {
        self.config
            .clone()
            .or_else(|| std::env::var_os(CONFIG_VAR).map(PathBuf::from))
            .or_else(|| Some(PathBuf::from(DEFAULT_CONFIG_PATH)).filter(|p| p.is_file()))
    }

    /// The configuration with the overrides applied.
    pub fn load(&self) -> Result<DaemonConfig> {
        let mut config = match self.file() {
            Some(path) => DaemonConfig::load(&path)?,
            None => {
                info!("no {DEFAULT_CONFIG_PATH} here and none named: the built-in default configuration");
                let config: DaemonConfig =
                    toml::from_str(DEFAULT_CONFIG).context("the built-in default configuration")?;
                config.check()?;
                config
            }
        };
        if let Some(prefix) = &self.ipc_prefix {
            config.ipc.prefix = prefix.clone();
        }
        Ok(config)
    }

    /// The arguments that make a child process read the same configuration
    /// on the services of `prefix`.
    pub fn child_args(&self, prefix: &str) -> Vec<String> {
        let mut args = Vec::new();
        if let Some(path) = self.file() {
            args.extend(["--config".to_string(), path.display().to_string()]);
        }
        args.extend(["--ipc-prefix".to_string(), prefix.to_string()]);
        args
    }

    /// The configuration and the team called `team` (the first if `None`).
    pub fn team(&self, team: Option<&str>) -> Result<(DaemonConfig, TeamConfig)> {
        let config = self.load()?;
        let found = match team {
            Some(name) => config.teams.iter().find(|t| t.name == name),
            None => config.teams.first(),
        }
        .with_context(|| format!("no team {team:?} in the configuration"))?
        .clone();
        Ok((config, found))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_default_is_the_shipped_file_and_plans_with_the_shipped_weights() {
        let shipped = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/default.toml")).unwrap();
        assert_eq!(DEFAULT_CONFIG, shipped);
        let config: DaemonConfig = toml::from_str(DEFAULT_CONFIG).unwrap();
        let planner = &config.teams[0].planner;
        assert_eq!(planner.learned.flow, flowopt_models::shipped::WeightsRef::Shipped);
        assert_eq!(planner.method, flowopt_methods::Method::Auto);
    }

    #[test]
    fn a_named_configuration_that_is_missing_is_an_error() {
        let args = DaemonArgs { config: Some("/no/such/flowopt.toml".into()), ipc_prefix: None };
        let err = format!("{:#}", args.load().unwrap_err());
        assert!(err.contains("/no/such/flowopt.toml"), "{err}");
    }
}
