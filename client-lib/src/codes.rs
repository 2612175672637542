//! The wire's codes: what a plan message tells the controllers to do
//! ([`PlanStatus`]) and why ([`Reason`]), each a `u32` on the wire, and
//! what writing or reading a message refuses ([`MessageError`]). The
//! messages themselves are `crate::messages`; the codes' meanings,
//! `docs/MESSAGES.md`.

use thiserror::Error;

/// Why a message could not be written or read.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum MessageError {
    /// A team name that does not fit a message.
    #[error("MessageError::TeamName: the team name {0:?} must be 1-32 bytes of UTF-8 without '/' or NUL")]
    TeamName(String),
    /// Sampling a message that carries no plan.
    #[error("MessageError::NoPlan: the message carries no plan (status {0:?})")]
    NoPlan(PlanStatus),
    /// A plan message with an impossible shape.
    #[error("MessageError::Shape: the plan message has an invalid {0}")]
    Shape(&'static str),
    /// A status or reason value no daemon writes.
    #[error("MessageError::Field: the message's {0} has a value no daemon writes")]
    Field(&'static str),
    /// Sampling a robot the plan does not have.
    #[error("MessageError::RobotOutOfRange: robot {robot} out of range: the plan has {robots}")]
    RobotOutOfRange {
        /// Requested robot.
        robot: usize,
        /// Robots in the plan.
        robots: usize,
    },
    /// A plan or problem larger than the message capacity.
    #[error(
        "MessageError::Capacity: {robots} robots, {obstacles} obstacles and {coefficients} coefficients per axis exceed the message capacity"
    )]
    Capacity {
        /// Robots.
        robots: usize,
        /// Obstacles (0 for a plan).
        obstacles: usize,
        /// Coefficients per robot and axis (0 for a snapshot).
        coefficients: usize,
    },
}

/// Which trajectory a plan message tells the controllers to follow from
/// now on (the followability contract, `docs/MESSAGES.md`). On the wire it
/// is a `u32` (`JointTrajectory::status`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanStatus {
    /// There is no verified trajectory to follow: bring the robots to rest
    /// by your own means (`reason` says why).
    NoPlan = 0,
    /// A new plan, verified from the state this message answers.
    Ok = 1,
    /// The last verified plan, re-issued unchanged (same time origin): no
    /// new one could be made or accepted (`reason` says why).
    Held = 2,
    /// A verified plan that brings every robot to rest along its motion:
    /// the robots had left the held plan (`reason` says what else failed).
    Stopping = 3,
}

impl PlanStatus {
    /// The status with wire value `value`.
    pub fn from_wire(value: u32) -> Result<Self, MessageError> {
        Ok(match value {
            0 => Self::NoPlan,
            1 => Self::Ok,
            2 => Self::Held,
            3 => Self::Stopping,
            _ => return Err(MessageError::Field("status")),
        })
    }

    /// Whether a message with this status carries a verified trajectory
    /// to follow.
    pub fn followable(self) -> bool {
        matches!(self, Self::Ok | Self::Held | Self::Stopping)
    }
}

/// Why a message is not a new plan: the snapshot was rejected (codes 1-13,
/// 16-18, 25 and 26), or the plan could not be made or verified (14, 15, 19-23).
/// On the wire it is a `u32` (`JointTrajectory::reason`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reason {
    /// Nothing to report.
    None = 0,
    /// `version` is not `WIRE_VERSION`.
    Version = 1,
    /// `team` does not name this service's team.
    Team = 2,
    /// `dim` differs from the team's.
    Dimension = 3,
    /// `robots` differs from the team's (or exceeds `MAX_ROBOTS`).
    RobotCount = 4,
    /// `obstacles` exceeds the configured maximum.
    ObstacleCount = 5,
    /// A NaN or infinite number (`reason_index`: the robot, or
    /// `MAX_ROBOTS + obstacle`).
    NonFinite = 6,
    /// An obstacle size is not positive (`reason_index`: `MAX_ROBOTS +
    /// obstacle`).
    NonPositiveSize = 7,
    /// Two starts overlap (`reason_index`: the first robot).
    StartsOverlap = 8,
    /// Two goals overlap (`reason_index`: the first robot).
    GoalsOverlap = 9,
    /// A start overlaps an obstacle (`reason_index`: the robot).
    StartInObstacle = 10,
    /// A goal overlaps an obstacle (`reason_index`: the robot).
    GoalInObstacle = 11,
    /// A start lies outside the workspace (`reason_index`: the robot).
    StartOutsideWorkspace = 12,
    /// A goal lies outside the workspace (`reason_index`: the robot).
    GoalOutsideWorkspace = 13,
    /// No snapshot within the configured time.
    StaleState = 14,
    /// The planner failed internally.
    Solver = 15,
    /// `timestamp_ns` is outside the accepted window around the daemon's
    /// clock (older than the stale limit, or ahead by more than the skew).
    Clock = 16,
    /// `sequence` does not increase over the publisher's last accepted one
    /// (or is `u64::MAX`).
    Sequence = 17,
    /// A speed beyond what the robots can do (`reason_index`: the robot).
    Implausible = 18,
    /// No plan verified within the deadline (planning goes on).
    DeadlineMissed = 19,
    /// The planner's plan did not verify.
    NotVerified = 20,
    /// The measured state has left the held plan: it is no longer safe.
    NotFollowing = 21,
    /// The verified plan exceeds the robots' speed or acceleration limits.
    Limits = 22,
    /// The held plan no longer clears the newest snapshot's obstacles (one
    /// appeared, moved or changed course onto it).
    WorldChanged = 23,
    /// The plan was made from a start in contact (touching a robot or an
    /// obstacle, outside the box, or unable to brake inside it;
    /// `reason_index`: the robot, the first of a pair) and moves it out
    /// within `start_recovery_s` (docs/MESSAGES.md, "Starts in contact").
    Recovering = 24,
    /// A robot moves towards a side of the box too fast to stop before it
    /// within the team's `max_acceleration` (`reason_index`: the robot);
    /// sent with `start_recovery_s = 0`, else `Recovering` (docs/MESSAGES.md).
    CannotBrake = 25,
    /// Two robots close on each other faster than both can brake or swerve
    /// within the team's `max_acceleration`: they must touch
    /// (`reason_index`: the first of the pair); checked only with
    /// `start_recovery_s = 0` (docs/MESSAGES.md).
    CannotAvoid = 26,
}

impl Reason {
    /// The reason with wire value `value`.
    pub fn from_wire(value: u32) -> Result<Self, MessageError> {
        use Reason::*;
        const ALL: [Reason; 27] = [
            None,
            Version,
            Team,
            Dimension,
            RobotCount,
            ObstacleCount,
            NonFinite,
            NonPositiveSize,
            StartsOverlap,
            GoalsOverlap,
            StartInObstacle,
            GoalInObstacle,
            StartOutsideWorkspace,
            GoalOutsideWorkspace,
            StaleState,
            Solver,
            Clock,
            Sequence,
            Implausible,
            DeadlineMissed,
            NotVerified,
            NotFollowing,
            Limits,
            WorldChanged,
            Recovering,
            CannotBrake,
            CannotAvoid,
        ];
        ALL.get(value as usize).copied().ok_or(MessageError::Field("reason"))
    }

    /// Whether this reason rejects the snapshot: its task was not planned.
    /// Rejected by a header, clock, sequence or value check (1-7, 16-18) it
    /// changed nothing; rejected for its task (8-13, 25 and 26: overlaps,
    /// the workspace, obstacles, braking, closing pairs) its robots and
    /// obstacles are still the newest world every followable answer is
    /// checked against.
    pub fn is_rejection(self) -> bool {
        matches!(self as u32, 1..=13 | 16..=18 | 25 | 26)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_values_round_trip_and_unknown_ones_are_errors() {
        for value in 0..4 {
            assert_eq!(PlanStatus::from_wire(value).map(|s| s as u32), Ok(value));
        }
        for value in 0..27 {
            assert_eq!(Reason::from_wire(value).map(|r| r as u32), Ok(value));
        }
        assert_eq!(PlanStatus::from_wire(4), Err(MessageError::Field("status")));
        assert_eq!(Reason::from_wire(23), Ok(Reason::WorldChanged));
        assert_eq!(Reason::from_wire(24), Ok(Reason::Recovering));
        assert_eq!(Reason::from_wire(25), Ok(Reason::CannotBrake));
        assert_eq!(Reason::from_wire(26), Ok(Reason::CannotAvoid));
        assert_eq!(Reason::from_wire(27), Err(MessageError::Field("reason")));
        assert!(Reason::NonFinite.is_rejection() && Reason::Clock.is_rejection() && Reason::Implausible.is_rejection());
        assert!(!Reason::DeadlineMissed.is_rejection() && !Reason::StaleState.is_rejection());
        assert!(!Reason::WorldChanged.is_rejection() && !Reason::Recovering.is_rejection());
        assert!(Reason::CannotBrake.is_rejection() && Reason::CannotAvoid.is_rejection());
        assert!(PlanStatus::Held.followable() && PlanStatus::Stopping.followable() && !PlanStatus::NoPlan.followable());
    }
}
