//! Command-line selection of problem instances, shared by every subcommand
//! that plans: a scenario file or a seeded scene of a family.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use flowopt_planner::problem::{Dim, Problem, ProblemError};
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
    /// Two rooms swapping through one or two doors.
    Doorway,
    /// Warehouse aisles.
    Aisles,
    /// A dense pillar forest.
    PillarForest,
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
            FamilyArg::Doorway => Family::Doorway,
            FamilyArg::Aisles => Family::Aisles,
            FamilyArg::PillarForest => Family::PillarForest,
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
    /// The robots' largest acceleration (m/s^2; 0: unknown, no check), 3
    /// in the daemon's teams: a robot moving towards a side of the box
    /// faster than any plan within it stops before the side (`CannotBrake`),
    /// or two robots closing on each other faster than both can brake or
    /// swerve (`CannotAvoid`), makes the instance certified infeasible. The
    /// success verdict does not check acceleration.
    #[arg(long, default_value_t = 0.0)]
    pub max_acceleration: f64,
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
        let (mut problem, params) = match &self.scenario_file {
            Some(path) => (load_scenario(path)?, None),
            None => {
                let scene = self.scene(index);
                let (problem, params) = scene.generate().with_context(|| {
                    format!("generating the {} scene with seed {}", scene.family.name(), scene.seed)
                })?;
                (problem, Some(params))
            }
        };
        problem.team.max_acceleration = (self.max_acceleration > 0.0).then_some(self.max_acceleration);
        if let Some(a) = problem.team.max_acceleration {
            // The braking bound for this team shape, once (about a second;
            // a start-up cost like an engine's factorisations), so that no
            // instance's check waits for it.
            let t = &problem.team;
            flowopt_planner::braking::prepare(t.degree, t.samples, t.horizon, a);
        }
        Ok((problem, params))
    }

    /// Why `problem` is certified infeasible before any planning (a robot
    /// that cannot brake inside the box, a pair that cannot keep apart), if
    /// it is.
    pub fn certified_infeasible(problem: &Problem) -> Option<ProblemError> {
        match problem.validate() {
            Err(e @ (ProblemError::CannotBrake { .. } | ProblemError::CannotAvoid { .. })) => Some(e),
            _ => None,
        }
    }
}

/// A certified infeasibility as `solve --json` and the bench's
/// per-instance lines give it: the reason's wire name, the robot, and the
/// constraint in words.
pub fn infeasible_json(why: &ProblemError) -> serde_json::Value {
    match *why {
        ProblemError::CannotBrake { robot, axis, upper, speed, overshoot } => serde_json::json!({
            "reason": "CannotBrake", "robot": robot, "axis": axis, "upper": upper,
            "speed_m_s": speed, "overshoot_m": overshoot, "message": why.to_string(),
        }),
        ProblemError::CannotAvoid { i, j, scaled, at } => serde_json::json!({
            "reason": "CannotAvoid", "robot": i, "other": j, "scaled_distance": scaled,
            "at_s": at, "message": why.to_string(),
        }),
        _ => serde_json::json!({ "message": why.to_string() }),
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

#[cfg(test)]
mod tests {
    use super::*;

    fn moving(max_acceleration: f64) -> InstanceArgs {
        InstanceArgs {
            family: FamilyArg::Random,
            robots: 16,
            dim: DimArg::Two,
            obstacles: 0,
            obstacle_speed: 0.0,
            start_speed: 1.0,
            max_acceleration,
            seed: 900,
            scenario_file: None,
        }
    }

    #[test]
    fn a_start_that_cannot_brake_is_certified_with_the_robot_and_the_side_unless_the_limit_is_unknown() {
        // Seed 900 at 1 m/s: robot 5, 54 mm inside the lower y side, moves at it at 0.79 m/s.
        let (problem, _) = moving(3.0).instance(0).unwrap();
        match InstanceArgs::certified_infeasible(&problem) {
            Some(ProblemError::CannotBrake { robot: 5, axis: 1, upper: false, speed, overshoot }) => {
                assert!((speed - 0.79).abs() < 0.01 && overshoot > 0.05, "{speed} {overshoot}");
            }
            other => panic!("{other:?}"),
        }
        let (unknown, _) = moving(0.0).instance(0).unwrap();
        assert_eq!(unknown.team.max_acceleration, None);
        assert!(InstanceArgs::certified_infeasible(&unknown).is_none());
        // Seed 909: robots 7 and 14 close faster than both can swerve.
        let (problem, _) = moving(3.0).instance(9).unwrap();
        match InstanceArgs::certified_infeasible(&problem) {
            Some(ProblemError::CannotAvoid { i: 7, j: 14, scaled, at }) => {
                assert!(scaled < 0.9 && at > 0.1 && at < 0.3, "{scaled} at {at}");
            }
            other => panic!("{other:?}"),
        }
        // From rest nothing is certified.
        let rest = InstanceArgs { start_speed: 0.0, ..moving(3.0) };
        assert!(InstanceArgs::certified_infeasible(&rest.instance(0).unwrap().0).is_none());
    }
}
