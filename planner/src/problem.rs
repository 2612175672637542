//! The planning problem: a team of robots, where they start, where they go,
//! and what is in the way.
//!
//! A [`Team`] is the fixed part (dimension, size, robot shape, workspace,
//! horizon, basis); a [`Problem`] adds one instance (start states, goals,
//! obstacles). [`Problem::validate`] checks every input and returns a typed
//! [`ProblemError`]; every planner entry point validates first.
//!
//! Geometry conventions:
//! - positions are `nalgebra::Vector3<f64>` in metres; in 2D only `x` and `y`
//!   are read and `z` is ignored;
//! - robots and obstacles are axis-aligned spheroids with a horizontal radius
//!   and a vertical half-height (2D: discs, the half-height is unused);
//! - the workspace box bounds robot *centres*;
//! - the start sample is the measured state and is never constrained; a
//!   start may therefore sit within the [`FEASIBILITY_TOLERANCE`] of
//!   another robot or of the box.
//!
//! ```
//! use flowopt_planner::problem::{Dim, Team};
//! let team = Team::default_for(Dim::Two, 16);
//! assert_eq!(team.separation(), (0.2, 0.2));
//! ```

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::basis::{BOUNDARY_ROWS, Basis, BasisError};

/// Relative tolerance on every clearance: a plan is feasible when every
/// scaled distance is at least `1 - FEASIBILITY_TOLERANCE` (1% of the
/// separation) on a dense re-sampling, and robot centres stay within
/// `FEASIBILITY_TOLERANCE * separation` of the workspace box.
pub const FEASIBILITY_TOLERANCE: f64 = 0.01;

/// Workspace dimension.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(try_from = "u8", into = "u8")]
pub enum Dim {
    /// Planar robots (x, y).
    Two,
    /// Spatial robots (x, y, z).
    Three,
}

impl Dim {
    /// Number of axes (2 or 3).
    pub fn axes(self) -> usize {
        match self {
            Dim::Two => 2,
            Dim::Three => 3,
        }
    }
}

impl TryFrom<u8> for Dim {
    type Error = ProblemError;
    fn try_from(value: u8) -> Result<Self, Self::Error> {
        match value {
            2 => Ok(Dim::Two),
            3 => Ok(Dim::Three),
            other => Err(ProblemError::BadDimension(other as usize)),
        }
    }
}

impl From<Dim> for u8 {
    fn from(d: Dim) -> u8 {
        d.axes() as u8
    }
}

/// An axis-aligned spheroid: horizontal radius and vertical half-height.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Spheroid {
    /// Radius in the x-y plane (m).
    pub radius: f64,
    /// Half-height along z (m); unused in 2D.
    pub half_height: f64,
}

impl Spheroid {
    /// A sphere (or disc) of `radius`.
    pub fn ball(radius: f64) -> Self {
        Self { radius, half_height: radius }
    }
}

/// The box robot centres must stay in.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Workspace {
    /// Lower corner.
    pub min: Vector3<f64>,
    /// Upper corner.
    pub max: Vector3<f64>,
}

impl Workspace {
    /// The cube `[-half, half]^3` (in 2D, the square).
    pub fn centred(half: f64) -> Self {
        Self { min: Vector3::repeat(-half), max: Vector3::repeat(half) }
    }

    /// Whether `p` lies in the box grown by `slack` on every side.
    pub fn contains(&self, dim: Dim, p: &Vector3<f64>, slack: f64) -> bool {
        (0..dim.axes()).all(|a| p[a] >= self.min[a] - slack && p[a] <= self.max[a] + slack)
    }
}

/// A moving or static spheroidal obstacle: `o(t) = position + velocity * t`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Obstacle {
    /// Centre at the start of the plan (m).
    pub position: Vector3<f64>,
    /// Constant velocity (m/s); zero for a static obstacle.
    pub velocity: Vector3<f64>,
    /// Its own size (not inflated by the robot).
    pub shape: Spheroid,
}

impl Obstacle {
    /// Centre at time `t` seconds after the plan start.
    pub fn at(&self, t: f64) -> Vector3<f64> {
        self.position + self.velocity * t
    }
}

/// The measured state a plan starts from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StartState {
    /// Position (m).
    pub position: Vector3<f64>,
    /// Velocity (m/s).
    pub velocity: Vector3<f64>,
    /// Acceleration (m/s^2).
    pub acceleration: Vector3<f64>,
}

impl StartState {
    /// At rest at `position`.
    pub fn at_rest(position: Vector3<f64>) -> Self {
        Self { position, velocity: Vector3::zeros(), acceleration: Vector3::zeros() }
    }
}

/// The fixed description of a team: everything a planner can precompute for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Team {
    /// Workspace dimension.
    pub dim: Dim,
    /// Number of robots.
    pub robots: usize,
    /// Every robot's shape.
    pub robot: Spheroid,
    /// The box robot centres stay in.
    pub workspace: Workspace,
    /// Planning horizon T (s): the goal is reached, at rest, at T.
    pub horizon: f64,
    /// Bernstein degree (default 10).
    pub degree: usize,
    /// Samples K the constraints are imposed at (default 50).
    pub samples: usize,
    /// How far ahead (s) a moving obstacle's motion is predicted from its
    /// report: plans keep clear of it along its reported velocity over that
    /// long, and of static obstacles over their whole horizon. `None`: the
    /// whole horizon. A walker's straight-line motion means little seconds
    /// ahead, and predicted over a 5 s plan it sweeps a goal more often than
    /// not; a daemon replanning at control rate sees its new course at once.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub obstacle_prediction: Option<f64>,
}

impl Team {
    /// Default Bernstein degree.
    pub const DEFAULT_DEGREE: usize = 10;
    /// Default number of samples.
    pub const DEFAULT_SAMPLES: usize = 50;
    /// Default horizon (s).
    pub const DEFAULT_HORIZON: f64 = 5.0;

    /// The documented default team of `robots`:
    /// - 2D: discs of radius 0.1 m in `[-1, 1]^2` (the paper's MMD setting);
    /// - 3D: spheroids of radius 0.1 m and half-height 0.15 m (taller, for
    ///   rotor downwash) in `[-1.5, 1.5]^3`;
    ///
    /// both with T = 5 s, degree 10 and K = 50.
    pub fn default_for(dim: Dim, robots: usize) -> Self {
        let (robot, workspace) = match dim {
            Dim::Two => (Spheroid::ball(0.1), Workspace::centred(1.0)),
            Dim::Three => (Spheroid { radius: 0.1, half_height: 0.15 }, Workspace::centred(1.5)),
        };
        Self {
            dim,
            robots,
            robot,
            workspace,
            horizon: Self::DEFAULT_HORIZON,
            degree: Self::DEFAULT_DEGREE,
            samples: Self::DEFAULT_SAMPLES,
            obstacle_prediction: None,
        }
    }

    /// Until when (s after its report) an obstacle moving at `velocity` is
    /// kept clear of: its prediction for a moving one, forever for a static
    /// one.
    pub fn predicted_until(&self, velocity: &Vector3<f64>) -> f64 {
        match self.obstacle_prediction {
            Some(p) if velocity.norm() > 0.0 => p,
            _ => f64::INFINITY,
        }
    }

    /// Separations the straight crossing of the workspace's diagonal may
    /// move between two samples before [`Team::resolved_for_workspace`]
    /// raises the resolution.
    pub const MOVE_PER_SAMPLE: f64 = 0.68;

    /// This team with its degree and sample count raised for its workspace.
    /// Unchanged while a robot crossing the workspace's diagonal in a
    /// straight line moves at most [`Team::MOVE_PER_SAMPLE`] (horizontal)
    /// separations between two samples; beyond, both grow in proportion to
    /// the diagonal: samples so that the chord inflation of fast pairs stays
    /// small, degree so that a longer path can bend past as many more
    /// robots. The default 2D team keeps degree 10 and K = 50 up to a box
    /// of half-width 2.40 m (the crowd of 128 robots at the 16-robot
    /// benchmark's density gets 12 and 59, of 256 17 and 84). At 0.75
    /// (11 / 54 and 16 / 76) a few 256-robot crowds needed thousands of
    /// iterations more (docs/BENCHMARKS.md).
    pub fn resolved_for_workspace(self) -> Self {
        let diagonal = self.workspace_diagonal();
        let allowed = self.samples as f64 * Self::MOVE_PER_SAMPLE * self.separation().0;
        let factor = diagonal / allowed;
        if factor.is_nan() || factor <= 1.0 {
            return self;
        }
        let grow = |x: usize| (x as f64 * factor).ceil() as usize;
        Self { degree: grow(self.degree), samples: grow(self.samples), ..self }
    }

    /// The workspace's diagonal (m) in the team's dimension: the farthest
    /// trip within it.
    pub fn workspace_diagonal(&self) -> f64 {
        (0..self.dim.axes()).map(|a| (self.workspace.max[a] - self.workspace.min[a]).powi(2)).sum::<f64>().sqrt()
    }

    /// Centre-to-centre separations `(a, b)` (horizontal, vertical): twice
    /// the robot's radius and half-height.
    pub fn separation(&self) -> (f64, f64) {
        (2.0 * self.robot.radius, 2.0 * self.robot.half_height)
    }

    /// Robot-obstacle separations `(a_o, b_o)`: the obstacle inflated by the
    /// robot.
    pub fn obstacle_separation(&self, obstacle: &Spheroid) -> (f64, f64) {
        (obstacle.radius + self.robot.radius, obstacle.half_height + self.robot.half_height)
    }

    /// The basis this team plans in.
    pub fn basis(&self) -> Result<Basis, BasisError> {
        Basis::new(self.degree, self.samples)
    }

    /// Checks the team's own parameters.
    pub fn validate(&self) -> Result<(), ProblemError> {
        if self.robots == 0 {
            return Err(ProblemError::NoRobots);
        }
        positive(self.robot.radius, Field::RobotRadius, 0)?;
        if self.dim == Dim::Three {
            positive(self.robot.half_height, Field::RobotHalfHeight, 0)?;
        }
        positive(self.horizon, Field::Horizon, 0)?;
        for a in 0..self.dim.axes() {
            finite(self.workspace.min[a], Field::Workspace, 0)?;
            finite(self.workspace.max[a], Field::Workspace, 1)?;
            if self.workspace.max[a] <= self.workspace.min[a] {
                return Err(ProblemError::EmptyWorkspace { axis: a });
            }
        }
        Basis::new(self.degree, self.samples)?;
        Ok(())
    }

    /// Scaled distance `||diag(a, a, b)^-1 d||` for a robot-robot offset `d`.
    pub fn scaled_distance(&self, d: &Vector3<f64>) -> f64 {
        let (a, b) = self.separation();
        scaled_norm(self.dim, d, a, b)
    }
}

/// `||diag(a, a, b)^-1 d||` in `dim` axes.
pub fn scaled_norm(dim: Dim, d: &Vector3<f64>, a: f64, b: f64) -> f64 {
    let h = (d.x / a).powi(2) + (d.y / a).powi(2);
    match dim {
        Dim::Two => h.sqrt(),
        Dim::Three => (h + (d.z / b).powi(2)).sqrt(),
    }
}

/// One planning instance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Problem {
    /// The team.
    pub team: Team,
    /// Measured start state per robot.
    pub starts: Vec<StartState>,
    /// Goal per robot, reached at rest at the horizon.
    pub goals: Vec<Vector3<f64>>,
    /// Static and moving obstacles.
    pub obstacles: Vec<Obstacle>,
}

/// Names of the inputs a [`ProblemError`] can point at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Field {
    /// A start position.
    StartPosition,
    /// A start velocity.
    StartVelocity,
    /// A start acceleration.
    StartAcceleration,
    /// A goal.
    Goal,
    /// An obstacle position.
    ObstaclePosition,
    /// An obstacle velocity.
    ObstacleVelocity,
    /// An obstacle size.
    ObstacleSize,
    /// The robot radius.
    RobotRadius,
    /// The robot half-height.
    RobotHalfHeight,
    /// The horizon.
    Horizon,
    /// A workspace corner.
    Workspace,
}

/// Why a problem is not plannable.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ProblemError {
    /// Only 2 and 3 dimensions exist.
    #[error("ProblemError::BadDimension: {0} (expected 2 or 3)")]
    BadDimension(usize),
    /// A team needs at least one robot.
    #[error("ProblemError::NoRobots: a team needs at least one robot")]
    NoRobots,
    /// An input is NaN or infinite.
    #[error("ProblemError::NonFinite: {field:?} #{index} is NaN or infinite")]
    NonFinite {
        /// Which input.
        field: Field,
        /// Robot or obstacle index.
        index: usize,
    },
    /// A size or duration is zero or negative.
    #[error("ProblemError::NonPositive: {field:?} #{index} must be positive")]
    NonPositive {
        /// Which input.
        field: Field,
        /// Obstacle index (0 for the team's own sizes).
        index: usize,
    },
    /// A list has the wrong length.
    #[error("ProblemError::WrongCount: {field:?} has {got} entries, expected {expected}")]
    WrongCount {
        /// Which list.
        field: Field,
        /// Length required by the team.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// The workspace box is empty along an axis.
    #[error("ProblemError::EmptyWorkspace: max <= min on axis {axis}")]
    EmptyWorkspace {
        /// Axis index.
        axis: usize,
    },
    /// Two starts overlap beyond the tolerance.
    #[error("ProblemError::StartsOverlap: robots {i} and {j} start at scaled distance {scaled:.3} < 1")]
    StartsOverlap {
        /// First robot.
        i: usize,
        /// Second robot.
        j: usize,
        /// Their scaled distance (1 = touching).
        scaled: f64,
    },
    /// Two goals overlap.
    #[error("ProblemError::GoalsOverlap: robots {i} and {j} have goals at scaled distance {scaled:.3} < 1")]
    GoalsOverlap {
        /// First robot.
        i: usize,
        /// Second robot.
        j: usize,
        /// Their scaled distance (1 = touching).
        scaled: f64,
    },
    /// A robot starts inside an obstacle.
    #[error("ProblemError::StartInObstacle: robot {robot} starts inside obstacle {obstacle}")]
    StartInObstacle {
        /// Robot index.
        robot: usize,
        /// Obstacle index.
        obstacle: usize,
    },
    /// A goal is inside an obstacle at the horizon.
    #[error("ProblemError::GoalInObstacle: robot {robot}'s goal is inside obstacle {obstacle} at the horizon")]
    GoalInObstacle {
        /// Robot index.
        robot: usize,
        /// Obstacle index.
        obstacle: usize,
    },
    /// A start lies outside the workspace box (beyond the tolerance).
    #[error("ProblemError::StartOutsideWorkspace: robot {0} starts outside the workspace")]
    StartOutsideWorkspace(usize),
    /// A goal lies outside the workspace box.
    #[error("ProblemError::GoalOutsideWorkspace: robot {0}'s goal is outside the workspace")]
    GoalOutsideWorkspace(usize),
    /// The basis cannot be built.
    #[error("ProblemError::Basis: {0}")]
    Basis(#[from] BasisError),
}

fn finite(v: f64, field: Field, index: usize) -> Result<(), ProblemError> {
    if v.is_finite() { Ok(()) } else { Err(ProblemError::NonFinite { field, index }) }
}

fn finite_vec(v: &Vector3<f64>, dim: Dim, field: Field, index: usize) -> Result<(), ProblemError> {
    (0..dim.axes()).try_for_each(|a| finite(v[a], field, index))
}

fn positive(v: f64, field: Field, index: usize) -> Result<(), ProblemError> {
    finite(v, field, index)?;
    if v > 0.0 { Ok(()) } else { Err(ProblemError::NonPositive { field, index }) }
}

impl Problem {
    /// Number of robots.
    pub fn robots(&self) -> usize {
        self.team.robots
    }

    /// The values of the boundary rows ([`crate::basis::Basis::boundary_rows`])
    /// per axis and robot, `[axis][robot][6]`: start position, velocity and
    /// acceleration, goal, and rest, in normalised time.
    pub fn boundary_values(&self) -> Vec<f64> {
        let t = &self.team;
        let n = t.robots;
        let mut b = vec![0.0; t.dim.axes() * n * BOUNDARY_ROWS];
        for (row, chunk) in b.chunks_exact_mut(BOUNDARY_ROWS).enumerate() {
            let (a, i) = (row / n, row % n);
            let s = &self.starts[i];
            chunk.copy_from_slice(&[
                s.position[a],
                s.velocity[a] * t.horizon,
                s.acceleration[a] * t.horizon * t.horizon,
                self.goals[i][a],
                0.0,
                0.0,
            ]);
        }
        b
    }

    /// Checks every input: counts, finiteness, sizes, overlaps and the
    /// workspace. Starts may be within [`FEASIBILITY_TOLERANCE`] of touching
    /// (they are measurements); goals must be strictly clear.
    pub fn validate(&self) -> Result<(), ProblemError> {
        let team = &self.team;
        team.validate()?;
        let dim = team.dim;
        let n = team.robots;
        if self.starts.len() != n {
            return Err(ProblemError::WrongCount { field: Field::StartPosition, expected: n, got: self.starts.len() });
        }
        if self.goals.len() != n {
            return Err(ProblemError::WrongCount { field: Field::Goal, expected: n, got: self.goals.len() });
        }
        for (i, s) in self.starts.iter().enumerate() {
            finite_vec(&s.position, dim, Field::StartPosition, i)?;
            finite_vec(&s.velocity, dim, Field::StartVelocity, i)?;
            finite_vec(&s.acceleration, dim, Field::StartAcceleration, i)?;
        }
        for (i, g) in self.goals.iter().enumerate() {
            finite_vec(g, dim, Field::Goal, i)?;
        }
        for (m, o) in self.obstacles.iter().enumerate() {
            finite_vec(&o.position, dim, Field::ObstaclePosition, m)?;
            finite_vec(&o.velocity, dim, Field::ObstacleVelocity, m)?;
            positive(o.shape.radius, Field::ObstacleSize, m)?;
            if dim == Dim::Three {
                positive(o.shape.half_height, Field::ObstacleSize, m)?;
            }
        }
        let (a, _) = team.separation();
        let slack = FEASIBILITY_TOLERANCE * a;
        for (i, s) in self.starts.iter().enumerate() {
            if !team.workspace.contains(dim, &s.position, slack) {
                return Err(ProblemError::StartOutsideWorkspace(i));
            }
        }
        for (i, g) in self.goals.iter().enumerate() {
            if !team.workspace.contains(dim, g, 0.0) {
                return Err(ProblemError::GoalOutsideWorkspace(i));
            }
        }
        for i in 0..n {
            for j in i + 1..n {
                let scaled = team.scaled_distance(&(self.starts[i].position - self.starts[j].position));
                if scaled < 1.0 - FEASIBILITY_TOLERANCE {
                    return Err(ProblemError::StartsOverlap { i, j, scaled });
                }
                let scaled = team.scaled_distance(&(self.goals[i] - self.goals[j]));
                if scaled < 1.0 {
                    return Err(ProblemError::GoalsOverlap { i, j, scaled });
                }
            }
        }
        for (m, o) in self.obstacles.iter().enumerate() {
            let (ao, bo) = team.obstacle_separation(&o.shape);
            for i in 0..n {
                let d0 = self.starts[i].position - o.at(0.0);
                if scaled_norm(dim, &d0, ao, bo) < 1.0 - FEASIBILITY_TOLERANCE {
                    return Err(ProblemError::StartInObstacle { robot: i, obstacle: m });
                }
                // Where the plan ends, if the obstacle is still predicted then.
                let d1 = self.goals[i] - o.at(team.horizon);
                if team.horizon <= team.predicted_until(&o.velocity) && scaled_norm(dim, &d1, ao, bo) < 1.0 {
                    return Err(ProblemError::GoalInObstacle { robot: i, obstacle: m });
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_resolution_grows_with_the_workspace_past_the_default_crossing() {
        let team = Team::default_for(Dim::Two, 16);
        assert_eq!(team.clone().resolved_for_workspace(), team);
        let at = |half: f64| {
            let t = Team { workspace: Workspace::centred(half), ..team.clone() }.resolved_for_workspace();
            let diagonal = 2.0 * half * 2f64.sqrt();
            assert!(diagonal / t.samples as f64 <= Team::MOVE_PER_SAMPLE * t.separation().0 + 1e-12);
            (t.degree, t.samples)
        };
        assert_eq!(at(2.4), (10, 50));
        assert_eq!(at(2.0 * 2f64.sqrt()), (12, 59));
        assert_eq!(at(4.0), (17, 84));
        assert_eq!(Team::default_for(Dim::Three, 64).resolved_for_workspace().samples, 50);
    }

    fn two_robot_problem() -> Problem {
        let team = Team::default_for(Dim::Two, 2);
        Problem {
            team,
            starts: vec![
                StartState::at_rest(Vector3::new(-0.5, 0.0, 0.0)),
                StartState::at_rest(Vector3::new(0.5, 0.0, 0.0)),
            ],
            goals: vec![Vector3::new(0.5, 0.1, 0.0), Vector3::new(-0.5, -0.1, 0.0)],
            obstacles: vec![],
        }
    }

    #[test]
    fn a_valid_problem_passes() {
        two_robot_problem().validate().unwrap();
    }

    #[test]
    fn nan_start_is_rejected() {
        let mut p = two_robot_problem();
        p.starts[1].velocity.y = f64::NAN;
        assert_eq!(p.validate(), Err(ProblemError::NonFinite { field: Field::StartVelocity, index: 1 }));
    }

    #[test]
    fn infinite_goal_is_rejected() {
        let mut p = two_robot_problem();
        p.goals[0].x = f64::INFINITY;
        assert!(matches!(p.validate(), Err(ProblemError::NonFinite { field: Field::Goal, index: 0 })));
    }

    #[test]
    fn z_is_ignored_in_2d() {
        let mut p = two_robot_problem();
        p.goals[0].z = f64::NAN;
        p.validate().unwrap();
    }

    #[test]
    fn wrong_lengths_are_rejected() {
        let mut p = two_robot_problem();
        p.goals.pop();
        assert_eq!(p.validate(), Err(ProblemError::WrongCount { field: Field::Goal, expected: 2, got: 1 }));
    }

    #[test]
    fn overlapping_starts_and_goals_are_rejected() {
        let mut p = two_robot_problem();
        p.starts[1].position = Vector3::new(-0.35, 0.0, 0.0);
        assert!(matches!(p.validate(), Err(ProblemError::StartsOverlap { i: 0, j: 1, .. })));
        let mut p = two_robot_problem();
        p.goals[1] = p.goals[0] + Vector3::new(0.1, 0.0, 0.0);
        assert!(matches!(p.validate(), Err(ProblemError::GoalsOverlap { i: 0, j: 1, .. })));
    }

    #[test]
    fn starts_within_tolerance_of_touching_are_accepted() {
        let mut p = two_robot_problem();
        p.starts[1].position = Vector3::new(-0.5 + 0.2 * 0.995, 0.0, 0.0);
        p.validate().unwrap();
    }

    #[test]
    fn goals_outside_the_workspace_are_rejected() {
        let mut p = two_robot_problem();
        p.goals[1].x = 1.2;
        assert_eq!(p.validate(), Err(ProblemError::GoalOutsideWorkspace(1)));
    }

    #[test]
    fn non_positive_sizes_are_rejected() {
        let mut p = two_robot_problem();
        p.team.robot.radius = 0.0;
        assert_eq!(p.validate(), Err(ProblemError::NonPositive { field: Field::RobotRadius, index: 0 }));
        let mut p = two_robot_problem();
        p.obstacles.push(Obstacle {
            position: Vector3::new(0.0, 0.6, 0.0),
            velocity: Vector3::zeros(),
            shape: Spheroid::ball(-0.1),
        });
        assert_eq!(p.validate(), Err(ProblemError::NonPositive { field: Field::ObstacleSize, index: 0 }));
        let mut p = two_robot_problem();
        p.team.horizon = -1.0;
        assert_eq!(p.validate(), Err(ProblemError::NonPositive { field: Field::Horizon, index: 0 }));
    }

    #[test]
    fn starts_and_goals_inside_obstacles_are_rejected() {
        let mut p = two_robot_problem();
        p.obstacles.push(Obstacle {
            position: Vector3::new(-0.45, 0.0, 0.0),
            velocity: Vector3::zeros(),
            shape: Spheroid::ball(0.1),
        });
        assert_eq!(p.validate(), Err(ProblemError::StartInObstacle { robot: 0, obstacle: 0 }));
        // A moving obstacle that ends on a goal.
        let mut p = two_robot_problem();
        p.obstacles.push(Obstacle {
            position: Vector3::new(0.0, 0.1, 0.0),
            velocity: Vector3::new(0.1, 0.0, 0.0),
            shape: Spheroid::ball(0.1),
        });
        assert_eq!(p.validate(), Err(ProblemError::GoalInObstacle { robot: 0, obstacle: 0 }));
    }

    #[test]
    fn dimension_parses_from_integers_only_2_or_3() {
        assert_eq!(Dim::try_from(3u8), Ok(Dim::Three));
        assert_eq!(Dim::try_from(4u8), Err(ProblemError::BadDimension(4)));
    }
}
