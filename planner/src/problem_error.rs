//! Why a problem is not plannable: [`ProblemError`], and the [`Field`]
//! an error points at ([`crate::problem::Problem::validate`]).

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::basis::BasisError;

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
    /// The start recovery time.
    StartRecovery,
    /// The robots' largest acceleration.
    MaxAcceleration,
    /// The robots' top speed.
    MaxSpeed,
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
    /// A robot inside the box moves towards a side faster than any plan
    /// it can follow (acceleration within the team's largest,
    /// [`crate::problem::Team::max_acceleration`]) stops before it: every
    /// such plan leaves the box ([`crate::braking`]).
    #[error(
        "ProblemError::CannotBrake: robot {robot} moving {speed:.3} m/s towards the box's {} side on axis {axis} cannot stop inside it: {overshoot:.4} m out at the least within the largest acceleration",
        if *upper { "upper" } else { "lower" }
    )]
    CannotBrake {
        /// Robot index.
        robot: usize,
        /// The axis.
        axis: usize,
        /// Whether the side is the upper one.
        upper: bool,
        /// Its speed towards the side (m/s).
        speed: f64,
        /// How far past the side its least excursion ends (m).
        overshoot: f64,
    },
    /// Two robots, apart, close on each other faster than both can brake
    /// or swerve (accelerations within the team's largest,
    /// [`crate::problem::Team::max_acceleration`]): every pair of
    /// trajectories they can follow touches ([`crate::closing`]).
    #[error(
        "ProblemError::CannotAvoid: robots {i} and {j} cannot keep apart: {scaled:.3} of their separation at {at:.3} s at the most within the largest acceleration"
    )]
    CannotAvoid {
        /// The lower robot index.
        i: usize,
        /// The higher robot index.
        j: usize,
        /// The largest scaled distance they can keep there (below 1).
        scaled: f64,
        /// When (s after the start).
        at: f64,
    },
    /// A goal lies outside the workspace box.
    #[error("ProblemError::GoalOutsideWorkspace: robot {0}'s goal is outside the workspace")]
    GoalOutsideWorkspace(usize),
    /// The basis cannot be built.
    #[error("ProblemError::Basis: {0}")]
    Basis(#[from] BasisError),
}
