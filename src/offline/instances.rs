//! Command-line selection of problem instances, shared by every subcommand
//! that plans: a scenario file or a seeded scene of a family.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use flowopt_planner::problem::{Dim, Problem};
use flowopt_planner::scenario::ScenarioFile;
use flowopt_planner::scenes::{Family, Scene, SceneParams};

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

/// Scene family on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FamilyArg {
    /// Uniform random starts and goals in the default box (the benchmark).
    Random,
    /// Uniform random at constant density (the box grows with the team).
    Crowd,
    /// Antipodal swap on a circle (2D) or sphere (3D).
    Swap,
    /// Two lanes crossing at right angles.
    Crossing,
    /// Counterflow through a field of pillars.
    ObstacleField,
    /// Grid to ring (or sphere).
    Formation,
}

impl From<FamilyArg> for Family {
    fn from(f: FamilyArg) -> Self {
        match f {
            FamilyArg::Random => Family::Random,
            FamilyArg::Crowd => Family::Crowd,
            FamilyArg::Swap => Family::Swap,
            FamilyArg::Crossing => Family::Crossing,
            FamilyArg::ObstacleField => Family::ObstacleField,
            FamilyArg::Formation => Family::Formation,
        }
    }
}

/// Which instances to plan.
#[derive(Debug, Clone, Args)]
pub struct InstanceArgs {
    /// Scene family (`flowopt_planner::scenes`); the box grows with the team
    /// for every family but `random`.
    #[arg(long, value_enum, default_value = "random")]
    pub family: FamilyArg,
    /// Number of robots.
    #[arg(long, default_value_t = 16)]
    pub robots: usize,
    /// Workspace dimension.
    #[arg(long, value_enum, default_value = "2")]
    pub dim: DimArg,
    /// Random and crowd families: number of random static obstacles.
    #[arg(long, default_value_t = 0)]
    pub obstacles: usize,
    /// Random and crowd families: largest obstacle speed (m/s); 0 keeps them static.
    #[arg(long, default_value_t = 0.0)]
    pub obstacle_speed: f64,
    /// Random and crowd families: largest random start speed (m/s); 0 plans from rest.
    #[arg(long, default_value_t = 0.0)]
    pub start_speed: f64,
    /// Seed of the (first) instance; instance i uses seed + i.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Read the instance from a scenario file (TOML, or JSON by extension).
    #[arg(long)]
    pub scenario_file: Option<PathBuf>,
}

impl InstanceArgs {
    /// The scene of instance number `index`.
    pub fn scene(&self, index: u64) -> Scene {
        Scene {
            obstacles: self.obstacles,
            obstacle_speed: self.obstacle_speed,
            start_speed: self.start_speed,
            ..Scene::new(self.family.into(), self.dim.into(), self.robots, self.seed + index)
        }
    }

    /// Instance number `index` (a file ignores it) and, for a generated
    /// scene, what it was made of.
    pub fn instance(&self, index: u64) -> Result<(Problem, Option<SceneParams>)> {
        if let Some(path) = &self.scenario_file {
            return Ok((load_scenario(path)?, None));
        }
        let scene = self.scene(index);
        let (problem, params) = scene
            .generate()
            .with_context(|| format!("generating the {} scene with seed {}", scene.family.name(), scene.seed))?;
        Ok((problem, Some(params)))
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
