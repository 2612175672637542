//! Command-line selection of problem instances, shared by every subcommand
//! that plans: a scenario file, the antipodal swap, or seeded random teams.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use flowopt_planner::problem::{Dim, Problem, Team};
use flowopt_planner::scenario::{RandomScenario, ScenarioFile, antipodal};

/// Workspace dimension on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DimArg {
    /// Planar.
    #[value(name = "2")]
    Two,
    /// Spatial.
    #[value(name = "3")]
    Three,
}

impl From<DimArg> for Dim {
    fn from(d: DimArg) -> Self {
        match d {
            DimArg::Two => Dim::Two,
            DimArg::Three => Dim::Three,
        }
    }
}

/// Which instances to plan.
#[derive(Debug, Clone, Args)]
pub struct InstanceArgs {
    /// Number of robots (random and antipodal instances).
    #[arg(long, default_value_t = 16)]
    pub robots: usize,
    /// Workspace dimension.
    #[arg(long, value_enum, default_value = "2")]
    pub dim: DimArg,
    /// Number of random static obstacles.
    #[arg(long, default_value_t = 0)]
    pub obstacles: usize,
    /// Largest obstacle speed (m/s); 0 keeps them static.
    #[arg(long, default_value_t = 0.0)]
    pub obstacle_speed: f64,
    /// Largest random start speed (m/s); 0 plans from rest.
    #[arg(long, default_value_t = 0.0)]
    pub start_speed: f64,
    /// Seed of the (first) random instance; instance i uses seed + i.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Plan the antipodal swap on a circle (2D) or sphere (3D) instead.
    #[arg(long, conflicts_with = "scenario_file")]
    pub antipodal: bool,
    /// Radius of the antipodal circle or sphere (m); default 90% of the
    /// workspace half-width.
    #[arg(long, requires = "antipodal")]
    pub radius: Option<f64>,
    /// Read the instance from a scenario file (TOML, or JSON by extension).
    #[arg(long)]
    pub scenario_file: Option<PathBuf>,
}

impl InstanceArgs {
    /// The default team these arguments describe (random and antipodal).
    pub fn team(&self) -> Team {
        Team::default_for(self.dim.into(), self.robots)
    }

    /// The random-instance generator these arguments describe.
    pub fn generator(&self) -> RandomScenario {
        RandomScenario::new(self.team())
            .with_obstacles(self.obstacles)
            .with_obstacle_speed(self.obstacle_speed)
            .with_start_speed(self.start_speed)
    }

    /// Instance number `index` (a file or the antipodal swap ignore it).
    pub fn instance(&self, index: u64) -> Result<Problem> {
        if let Some(path) = &self.scenario_file {
            return load_scenario(path);
        }
        if self.antipodal {
            let team = self.team();
            let half = (0..team.dim.axes())
                .map(|a| (team.workspace.max[a] - team.workspace.min[a]) / 2.0)
                .fold(f64::INFINITY, f64::min);
            let radius = self.radius.unwrap_or(0.9 * half);
            return antipodal(&team, radius).context("building the antipodal swap");
        }
        let seed = self.seed + index;
        self.generator().generate(seed).with_context(|| format!("generating random instance with seed {seed}"))
    }
}

/// Reads a scenario file: JSON for a `.json` file, TOML otherwise.
pub fn load_scenario(path: &Path) -> Result<Problem> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading scenario {}", path.display()))?;
    let problem = if path.extension().is_some_and(|e| e == "json") {
        ScenarioFile::from_json(&text)
    } else {
        ScenarioFile::from_toml(&text)
    };
    problem.with_context(|| format!("scenario {}", path.display()))
}
