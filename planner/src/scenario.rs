//! Problem instances: seeded random teams, antipodal swaps, scenario files.
//!
//! ```
//! use flowopt_planner::problem::{Dim, Team};
//! use flowopt_planner::scenario::{RandomScenario, antipodal};
//!
//! let team = Team::default_for(Dim::Two, 16);
//! let a = RandomScenario::new(team.clone()).with_obstacles(8).generate(42).unwrap();
//! let b = RandomScenario::new(team.clone()).with_obstacles(8).generate(42).unwrap();
//! assert_eq!(a, b); // seeded: the same seed gives the same instance
//! let swap = antipodal(&team, 0.9).unwrap();
//! assert_eq!(swap.goals[0], -swap.starts[0].position);
//! ```

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::problem::{Dim, Obstacle, Problem, ProblemError, Spheroid, StartState, Team, Workspace, scaled_norm};

/// Draws per robot or obstacle before a random instance is declared too dense.
const MAX_DRAWS: usize = 20_000;

/// Why a scenario could not be produced.
#[derive(Debug, Error)]
pub enum ScenarioError {
    /// Rejection sampling found no room.
    #[error("ScenarioError::TooDense: no room for {what} #{index} after {MAX_DRAWS} draws")]
    TooDense {
        /// "start", "goal" or "obstacle".
        what: &'static str,
        /// Its index.
        index: usize,
    },
    /// A scene family's smallest team is larger.
    #[error("ScenarioError::TooFewRobots: {family} scenes are for teams of at least {least} robots")]
    TooFewRobots {
        /// The family's name.
        family: &'static str,
        /// Its smallest team.
        least: usize,
    },
    /// The produced or loaded problem is invalid.
    #[error("ScenarioError::Invalid: {0}")]
    Invalid(#[from] ProblemError),
    /// The scenario text does not parse.
    #[error("ScenarioError::Parse: {0}")]
    Parse(String),
    /// A point in the file has the wrong number of coordinates.
    #[error("ScenarioError::BadPoint: {what} has {got} coordinates, the scenario is {dim}D")]
    BadPoint {
        /// Which point.
        what: String,
        /// Coordinates given.
        got: usize,
        /// Scenario dimension.
        dim: usize,
    },
}

/// A generator of seeded random instances for a team.
///
/// Starts and goals are uniform in the workspace with pairwise scaled
/// distance at least `spacing`; obstacles (drawn after the robots, so the
/// same seed gives the same robots with or without them) are uniform in the
/// workspace with radii in `obstacle_radius` and keep a scaled distance of at
/// least `spacing` from every start (at t = 0) and goal (at t = T).
#[derive(Debug, Clone, PartialEq)]
pub struct RandomScenario {
    /// The team.
    pub team: Team,
    /// Number of obstacles.
    pub obstacles: usize,
    /// Obstacle radius range (m); the half-height equals the radius.
    pub obstacle_radius: (f64, f64),
    /// Largest obstacle speed (m/s); 0 for static obstacles.
    pub obstacle_speed: f64,
    /// Largest start speed (m/s); 0 plans from rest.
    pub start_speed: f64,
    /// Smallest scaled distance between starts, between goals, and between
    /// robots and obstacles (1 = touching).
    pub spacing: f64,
}

impl RandomScenario {
    /// Defaults: no obstacles (radius 0.05-0.15 m when added), from rest,
    /// spacing 1.25.
    pub fn new(team: Team) -> Self {
        Self { team, obstacles: 0, obstacle_radius: (0.05, 0.15), obstacle_speed: 0.0, start_speed: 0.0, spacing: 1.25 }
    }

    /// With `count` static obstacles.
    pub fn with_obstacles(mut self, count: usize) -> Self {
        self.obstacles = count;
        self
    }

    /// With obstacles moving at up to `speed` m/s.
    pub fn with_obstacle_speed(mut self, speed: f64) -> Self {
        self.obstacle_speed = speed;
        self
    }

    /// With start velocities of up to `speed` m/s (the replanning case).
    pub fn with_start_speed(mut self, speed: f64) -> Self {
        self.start_speed = speed;
        self
    }

    /// The instance for `seed`.
    pub fn generate(&self, seed: u64) -> Result<Problem, ScenarioError> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let team = &self.team;
        let dim = team.dim;
        let (a, b) = team.separation();
        let starts = self.spread(&mut rng, "start", a, b)?;
        let goals = self.spread(&mut rng, "goal", a, b)?;
        let starts: Vec<StartState> = starts
            .into_iter()
            .map(|p| StartState {
                position: p,
                velocity: random_vector(&mut rng, dim, self.start_speed),
                acceleration: Vector3::zeros(),
            })
            .collect();
        let mut obstacles = Vec::with_capacity(self.obstacles);
        for index in 0..self.obstacles {
            let mut placed = None;
            for _ in 0..MAX_DRAWS {
                let radius = rng.random_range(self.obstacle_radius.0..=self.obstacle_radius.1);
                let o = Obstacle {
                    position: uniform_point(&mut rng, dim, &team.workspace),
                    velocity: random_vector(&mut rng, dim, self.obstacle_speed),
                    shape: Spheroid::ball(radius),
                };
                let (ao, bo) = team.obstacle_separation(&o.shape);
                let clear = starts.iter().all(|s| scaled_norm(dim, &(s.position - o.at(0.0)), ao, bo) >= self.spacing)
                    && goals.iter().all(|g| scaled_norm(dim, &(g - o.at(team.horizon)), ao, bo) >= self.spacing);
                if clear {
                    placed = Some(o);
                    break;
                }
            }
            obstacles.push(placed.ok_or(ScenarioError::TooDense { what: "obstacle", index })?);
        }
        let problem = Problem { team: team.clone(), starts, goals, obstacles };
        problem.validate()?;
        Ok(problem)
    }

    /// `n` points uniform in the workspace, pairwise scaled distance >= spacing.
    fn spread(
        &self,
        rng: &mut ChaCha8Rng,
        what: &'static str,
        a: f64,
        b: f64,
    ) -> Result<Vec<Vector3<f64>>, ScenarioError> {
        let dim = self.team.dim;
        let mut points: Vec<Vector3<f64>> = Vec::with_capacity(self.team.robots);
        for index in 0..self.team.robots {
            let mut placed = None;
            for _ in 0..MAX_DRAWS {
                let p = uniform_point(rng, dim, &self.team.workspace);
                if points.iter().all(|q| scaled_norm(dim, &(p - q), a, b) >= self.spacing) {
                    placed = Some(p);
                    break;
                }
            }
            points.push(placed.ok_or(ScenarioError::TooDense { what, index })?);
        }
        Ok(points)
    }
}

fn uniform_point(rng: &mut ChaCha8Rng, dim: Dim, ws: &Workspace) -> Vector3<f64> {
    let mut p = Vector3::zeros();
    for a in 0..dim.axes() {
        p[a] = rng.random_range(ws.min[a]..=ws.max[a]);
    }
    p
}

/// A vector of uniformly random direction and magnitude in `[0, max]`.
fn random_vector(rng: &mut ChaCha8Rng, dim: Dim, max: f64) -> Vector3<f64> {
    if max <= 0.0 {
        return Vector3::zeros();
    }
    loop {
        let mut v = Vector3::zeros();
        for a in 0..dim.axes() {
            v[a] = rng.random_range(-1.0..=1.0);
        }
        let norm = v.norm();
        if norm > 1e-3 && norm <= 1.0 {
            return v / norm * rng.random_range(0.0..=max);
        }
    }
}

/// Point `i` of `n` evenly spaced on the unit circle (2D) or a unit
/// Fibonacci sphere (3D) around the origin, turned by `turn` (rad) about z.
pub(crate) fn ring_point(dim: Dim, i: usize, n: usize, turn: f64) -> Vector3<f64> {
    match dim {
        Dim::Two => {
            let angle = turn + std::f64::consts::TAU * i as f64 / n as f64;
            Vector3::new(angle.cos(), angle.sin(), 0.0)
        }
        Dim::Three => {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let ring = (1.0 - z * z).sqrt();
            let angle = turn + i as f64 * 2.399_963_229_728_653;
            Vector3::new(ring * angle.cos(), ring * angle.sin(), z)
        }
    }
}

/// The antipodal swap: robots evenly spaced on a circle (2D) or a Fibonacci
/// sphere (3D) of `radius` around the workspace centre, each going to the
/// diametrically opposite point.
pub fn antipodal(team: &Team, radius: f64) -> Result<Problem, ScenarioError> {
    let n = team.robots;
    let centre = (team.workspace.min + team.workspace.max) / 2.0;
    let offsets: Vec<Vector3<f64>> = (0..n).map(|i| ring_point(team.dim, i, n, 0.0) * radius).collect();
    let mut centre2 = centre;
    if team.dim == Dim::Two {
        centre2.z = 0.0;
    }
    let problem = Problem {
        team: team.clone(),
        starts: offsets.iter().map(|o| StartState::at_rest(centre2 + o)).collect(),
        goals: offsets.iter().map(|o| centre2 - o).collect(),
        obstacles: Vec::new(),
    };
    problem.validate()?;
    Ok(problem)
}

/// The scenario file format (TOML, or JSON for a `.json` file). Points are
/// arrays of `dim` numbers.
///
/// ```toml
/// dim = 2
/// horizon = 5.0            # optional, s
/// robot = { radius = 0.1 } # half_height too in 3D
/// workspace = { min = [-1.0, -1.0], max = [1.0, 1.0] }
///
/// [[robots]]
/// start = [-0.5, 0.0]
/// goal = [0.5, 0.0]
/// velocity = [0.1, 0.0]    # optional start velocity
///
/// [[obstacles]]
/// position = [0.0, 0.5]
/// velocity = [0.0, -0.1]   # optional
/// radius = 0.1             # half_height too in 3D
/// ```
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    /// 2 or 3.
    pub dim: Dim,
    /// Horizon (s); default 5.
    #[serde(default = "default_horizon")]
    pub horizon: f64,
    /// Bernstein degree; by default 10, raised for a workspace where 50
    /// samples would leave fast robots too far apart between samples
    /// ([`Team::resolved_for_workspace`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub degree: Option<usize>,
    /// Samples; by default 50, raised likewise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples: Option<usize>,
    /// Robot size.
    pub robot: FileShape,
    /// Workspace box.
    pub workspace: FileBox,
    /// One entry per robot.
    pub robots: Vec<FileRobot>,
    /// Obstacles.
    #[serde(default)]
    pub obstacles: Vec<FileObstacle>,
}

/// A size in a scenario file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileShape {
    /// Horizontal radius (m).
    pub radius: f64,
    /// Vertical half-height (m); defaults to the radius.
    pub half_height: Option<f64>,
}

impl FileShape {
    /// The spheroid it describes.
    pub fn spheroid(&self) -> Spheroid {
        Spheroid { radius: self.radius, half_height: self.half_height.unwrap_or(self.radius) }
    }
}

/// A point of a `dim`-dimensional scenario given as a list of coordinates.
fn point(dim: Dim, what: String, v: &[f64]) -> Result<Vector3<f64>, ScenarioError> {
    let d = dim.axes();
    if v.len() != d {
        return Err(ScenarioError::BadPoint { what, got: v.len(), dim: d });
    }
    let mut p = Vector3::zeros();
    p.as_mut_slice()[..d].copy_from_slice(v);
    Ok(p)
}

/// The workspace box in a scenario file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileBox {
    /// Lower corner.
    pub min: Vec<f64>,
    /// Upper corner.
    pub max: Vec<f64>,
}

impl FileBox {
    /// The box of a `dim`-dimensional team.
    pub fn workspace(&self, dim: Dim) -> Result<Workspace, ScenarioError> {
        Ok(Workspace {
            min: point(dim, "workspace.min".into(), &self.min)?,
            max: point(dim, "workspace.max".into(), &self.max)?,
        })
    }
}

/// One robot in a scenario file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileRobot {
    /// Start position.
    pub start: Vec<f64>,
    /// Goal position.
    pub goal: Vec<f64>,
    /// Start velocity (default rest).
    pub velocity: Option<Vec<f64>>,
    /// Start acceleration (default zero).
    pub acceleration: Option<Vec<f64>>,
}

/// One obstacle in a scenario file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileObstacle {
    /// Centre at t = 0.
    pub position: Vec<f64>,
    /// Velocity (default static).
    pub velocity: Option<Vec<f64>>,
    /// Horizontal radius.
    pub radius: f64,
    /// Vertical half-height (default the radius).
    pub half_height: Option<f64>,
}

/// The horizon a team file (scenario or daemon configuration) that gives
/// none plans over.
pub fn default_horizon() -> f64 {
    Team::DEFAULT_HORIZON
}

/// The Bernstein degree of a team file that gives none.
pub fn default_degree() -> usize {
    Team::DEFAULT_DEGREE
}

/// The constraint samples of a team file that gives none.
pub fn default_samples() -> usize {
    Team::DEFAULT_SAMPLES
}

/// The team a file describes (scenario files and the daemon's `[[team]]`
/// tables share these fields), not yet validated.
pub fn file_team(
    dim: Dim,
    robots: usize,
    robot: &FileShape,
    workspace: &FileBox,
    horizon: f64,
    degree: usize,
    samples: usize,
) -> Result<Team, ScenarioError> {
    Ok(Team {
        dim,
        robots,
        robot: robot.spheroid(),
        workspace: workspace.workspace(dim)?,
        horizon,
        degree,
        samples,
        obstacle_prediction: None,
        start_recovery: None,
        max_acceleration: None,
        max_speed: None,
    })
}

impl ScenarioFile {
    /// Parses a scenario in TOML and validates the problem.
    pub fn from_toml(text: &str) -> Result<Problem, ScenarioError> {
        let file: ScenarioFile = toml::from_str(text).map_err(|e| ScenarioError::Parse(e.to_string()))?;
        file.into_problem()
    }

    /// Parses a scenario in JSON and validates the problem.
    pub fn from_json(text: &str) -> Result<Problem, ScenarioError> {
        let file: ScenarioFile = serde_json::from_str(text).map_err(|e| ScenarioError::Parse(e.to_string()))?;
        file.into_problem()
    }

    /// Converts to a validated problem.
    pub fn into_problem(self) -> Result<Problem, ScenarioError> {
        let dim = self.dim;
        let point = |what: String, v: &[f64]| point(dim, what, v);
        let optional = |what: String, v: &Option<Vec<f64>>| match v {
            Some(v) => point(what, v),
            None => Ok(Vector3::zeros()),
        };
        let resolved = file_team(
            dim,
            self.robots.len(),
            &self.robot,
            &self.workspace,
            self.horizon,
            default_degree(),
            default_samples(),
        )?
        .resolved_for_workspace();
        let team = Team {
            degree: self.degree.unwrap_or(resolved.degree),
            samples: self.samples.unwrap_or(resolved.samples),
            ..resolved
        };
        let mut starts = Vec::with_capacity(self.robots.len());
        let mut goals = Vec::with_capacity(self.robots.len());
        for (i, r) in self.robots.iter().enumerate() {
            starts.push(StartState {
                position: point(format!("robots[{i}].start"), &r.start)?,
                velocity: optional(format!("robots[{i}].velocity"), &r.velocity)?,
                acceleration: optional(format!("robots[{i}].acceleration"), &r.acceleration)?,
            });
            goals.push(point(format!("robots[{i}].goal"), &r.goal)?);
        }
        let obstacles = self
            .obstacles
            .iter()
            .enumerate()
            .map(|(m, o)| {
                Ok(Obstacle {
                    position: point(format!("obstacles[{m}].position"), &o.position)?,
                    velocity: optional(format!("obstacles[{m}].velocity"), &o.velocity)?,
                    shape: Spheroid { radius: o.radius, half_height: o.half_height.unwrap_or(o.radius) },
                })
            })
            .collect::<Result<Vec<_>, ScenarioError>>()?;
        let problem = Problem { team, starts, goals, obstacles };
        problem.validate()?;
        Ok(problem)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_instances_are_seeded_and_spaced() {
        let team = Team::default_for(Dim::Two, 16);
        let generator = RandomScenario::new(team.clone()).with_obstacles(8).with_start_speed(0.3);
        let p = generator.generate(3).unwrap();
        assert_eq!(p, generator.generate(3).unwrap());
        assert_ne!(p, generator.generate(4).unwrap());
        assert_eq!(p.obstacles.len(), 8);
        for i in 0..16 {
            assert!(p.starts[i].velocity.norm() <= 0.3 + 1e-12);
            for j in i + 1..16 {
                assert!(team.scaled_distance(&(p.goals[i] - p.goals[j])) >= 1.25);
            }
        }
    }

    #[test]
    fn obstacles_do_not_change_the_robots_of_a_seed() {
        let team = Team::default_for(Dim::Three, 8);
        let without = RandomScenario::new(team.clone()).generate(9).unwrap();
        let with = RandomScenario::new(team).with_obstacles(3).generate(9).unwrap();
        assert_eq!(without.starts, with.starts);
        assert_eq!(without.goals, with.goals);
    }

    #[test]
    fn one_more_obstacle_keeps_the_others_of_a_seed() {
        let team = Team::default_for(Dim::Two, 16);
        let eight = RandomScenario::new(team.clone()).with_obstacles(8).generate(4).unwrap();
        let mut nine = RandomScenario::new(team).with_obstacles(9).generate(4).unwrap();
        assert!(nine.obstacles.pop().is_some());
        assert_eq!(eight, nine);
    }

    #[test]
    fn an_overfull_team_is_reported_as_too_dense() {
        let team = Team::default_for(Dim::Two, 200);
        assert!(matches!(RandomScenario::new(team).generate(1), Err(ScenarioError::TooDense { what: "start", .. })));
    }

    #[test]
    fn antipodal_circle_that_does_not_fit_is_rejected() {
        let team = Team::default_for(Dim::Two, 32);
        assert!(matches!(antipodal(&team, 0.9), Err(ScenarioError::Invalid(ProblemError::StartsOverlap { .. }))));
        antipodal(&Team::default_for(Dim::Three, 32), 1.3).unwrap();
    }

    #[test]
    fn scenario_files_round_trip_and_report_bad_points() {
        let text = r#"
            dim = 2
            robot = { radius = 0.1 }
            workspace = { min = [-1.0, -1.0], max = [1.0, 1.0] }
            [[robots]]
            start = [-0.5, 0.0]
            goal = [0.5, 0.0]
            velocity = [0.1, 0.0]
            [[robots]]
            start = [0.5, 0.0]
            goal = [-0.5, 0.0]
            [[obstacles]]
            position = [0.0, 0.5]
            velocity = [0.0, -0.05]
            radius = 0.1
        "#;
        let file: ScenarioFile = toml::from_str(text).unwrap();
        let p = file.into_problem().unwrap();
        assert_eq!(p.robots(), 2);
        assert_eq!(p.starts[0].velocity.x, 0.1);
        assert_eq!(p.obstacles[0].velocity.y, -0.05);
        assert_eq!((p.team.degree, p.team.samples), (10, 50));
        // A workspace too big for 50 samples gets the resolution it needs,
        // unless the file gives its own.
        let wide = text.replace("min = [-1.0, -1.0], max = [1.0, 1.0]", "min = [-4.0, -4.0], max = [4.0, 4.0]");
        let team = toml::from_str::<ScenarioFile>(&wide).unwrap().into_problem().unwrap().team;
        assert_eq!((team.degree, team.samples), (17, 84));
        assert_eq!(team, Team { degree: 10, samples: 50, ..team.clone() }.resolved_for_workspace());
        let fixed = format!("degree = 12\n{wide}");
        let team = toml::from_str::<ScenarioFile>(&fixed).unwrap().into_problem().unwrap().team;
        assert_eq!((team.degree, team.samples), (12, 84));
        let bad = text.replace("goal = [0.5, 0.0]", "goal = [0.5, 0.0, 1.0]");
        let file: ScenarioFile = toml::from_str(&bad).unwrap();
        assert!(matches!(file.into_problem(), Err(ScenarioError::BadPoint { got: 3, dim: 2, .. })));
    }
}
