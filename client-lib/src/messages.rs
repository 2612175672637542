//! The two messages on the wire, `#[repr(C)]` with fixed capacities so
//! they live in shared memory as they are and C++/Python iceoryx2 clients
//! can read them. The byte layout is in `docs/MESSAGES.md` (a test keeps it
//! honest). Every vector is 3D; in a 2D team the third entry is ignored and
//! written as 0.
//!
//! Every field of both messages is valid when all its bytes are zero, and a
//! zeroed message says "version 0, no plan": the ports zero each loan
//! before the caller fills it.

use flowopt_planner::plan::{InstantRows, JointPlan, Kinematics};
use flowopt_planner::problem::{Dim, Problem, Team};
use iceoryx2::prelude::ZeroCopySend;
use thiserror::Error;

/// Robots per team a message can carry.
pub const MAX_ROBOTS: usize = 64;
/// Obstacles a snapshot can carry.
pub const MAX_OBSTACLES: usize = 16;
/// Bernstein coefficients per robot and axis a plan can carry (degree <= 15).
pub const MAX_COEFFS: usize = 16;
/// Bytes of the team name (UTF-8, NUL-padded).
pub const TEAM_NAME_LEN: usize = 32;
/// Layout version written into every message; bumped on any layout change.
pub const WIRE_VERSION: u32 = 1;

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

/// One robot's measured state and goal.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("flowopt::RobotState")]
pub struct RobotState {
    /// Centre position (m).
    pub position: [f64; 3],
    /// Velocity (m/s).
    pub velocity: [f64; 3],
    /// Goal, to be reached at rest at the end of the horizon (m).
    pub goal: [f64; 3],
}

/// One obstacle: a spheroid moving at constant velocity from `position`
/// at the snapshot's timestamp.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("flowopt::ObstacleState")]
pub struct ObstacleState {
    /// Centre (m).
    pub position: [f64; 3],
    /// Velocity (m/s); zero for a static obstacle.
    pub velocity: [f64; 3],
    /// Radius in the plane (m).
    pub radius: f64,
    /// Half-height along z (m); ignored in 2D.
    pub half_height: f64,
}

/// Controller to daemon: the measured state of a whole team.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("flowopt::StateSnapshot")]
pub struct StateSnapshot {
    /// [`WIRE_VERSION`] of the writer.
    pub version: u32,
    /// 2 or 3.
    pub dim: u32,
    /// Team name (UTF-8, NUL-padded); must match the service's team.
    pub team: [u8; TEAM_NAME_LEN],
    /// Set by the publisher, increasing by one per snapshot; plans echo it.
    pub sequence: u64,
    /// When the state was measured, [`crate::clock::monotonic_ns`].
    pub timestamp_ns: u64,
    /// Robots in use, `1..=MAX_ROBOTS`; must equal the configured team's.
    pub robots: u32,
    /// Obstacles in use, `0..=MAX_OBSTACLES`.
    pub obstacles: u32,
    /// Robots `0..robots`.
    pub robot: [RobotState; MAX_ROBOTS],
    /// Obstacles `0..obstacles`.
    pub obstacle: [ObstacleState; MAX_OBSTACLES],
}

/// What a plan message carries.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("flowopt::PlanStatus")]
pub enum PlanStatus {
    /// No plan could be made (an internal failure; see `reason`).
    NoPlan = 0,
    /// A plan verified collision-free at the true sizes on a dense grid.
    Ok = 1,
    /// The solver's best iterate after its iteration cap: not verified.
    Degraded = 2,
    /// The deadline passed: the best iterate so far, not verified.
    DeadlineMissed = 3,
    /// The snapshot was invalid (`reason`, `reason_index`); no plan.
    RejectedInput = 4,
    /// No snapshot arrived within the configured time; the last plan is
    /// repeated unchanged.
    Stale = 5,
}

/// Why a snapshot was rejected (or why there is no plan).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("flowopt::Reason")]
pub enum Reason {
    /// Nothing to report.
    None = 0,
    /// `version` is not [`WIRE_VERSION`].
    Version = 1,
    /// `team` does not name this service's team.
    Team = 2,
    /// `dim` differs from the team's.
    Dimension = 3,
    /// `robots` differs from the team's (or exceeds [`MAX_ROBOTS`]).
    RobotCount = 4,
    /// `obstacles` exceeds the configured maximum.
    ObstacleCount = 5,
    /// A NaN or infinite number (`reason_index`: the robot, or
    /// `MAX_ROBOTS + obstacle`).
    NonFinite = 6,
    /// An obstacle size is not positive (`reason_index`: the obstacle).
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
}

/// Time spent in each planning stage (microseconds; 0 for a stage not run).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("flowopt::StageTimings")]
pub struct StageTimings {
    /// From the snapshot's arrival at the daemon to the start of planning.
    pub queue_us: u32,
    /// Checking and converting the snapshot.
    pub validate_us: u32,
    /// Shifting the previous plan to the new start and fitting it.
    pub warm_start_us: u32,
    /// Sampling candidates from the flow policy.
    pub sample_us: u32,
    /// Ranking candidates by primal residual.
    pub rank_us: u32,
    /// The initialisation network.
    pub init_us: u32,
    /// The safety filter.
    pub filter_us: u32,
    /// The from-scratch optimiser.
    pub optimise_us: u32,
    /// Choosing among refined candidates.
    pub select_us: u32,
    /// From the snapshot's arrival to the plan being written.
    pub total_us: u32,
}

/// Daemon to controllers: a joint plan answering one snapshot.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("flowopt::JointTrajectory")]
pub struct JointTrajectory {
    /// [`WIRE_VERSION`] of the writer.
    pub version: u32,
    /// What this message carries.
    pub status: PlanStatus,
    /// Why, for [`PlanStatus::RejectedInput`], [`PlanStatus::NoPlan`] and
    /// [`PlanStatus::Stale`].
    pub reason: Reason,
    /// The robot or obstacle the reason points at (`u32::MAX`: none).
    pub reason_index: u32,
    /// Team name (UTF-8, NUL-padded).
    pub team: [u8; TEAM_NAME_LEN],
    /// 2 or 3.
    pub dim: u32,
    /// Robots in the plan.
    pub robots: u32,
    /// Bernstein degree (coefficients per robot and axis: `degree + 1`).
    pub degree: u32,
    /// Safety-filter / optimiser iterations spent.
    pub iterations: u32,
    /// `sequence` of the snapshot this plan starts from.
    pub answers_sequence: u64,
    /// `timestamp_ns` of that snapshot: the plan's time origin.
    pub state_timestamp_ns: u64,
    /// When the daemon received that snapshot.
    pub received_ns: u64,
    /// When the daemon published this message.
    pub published_ns: u64,
    /// Horizon T (s): robots reach their goals at rest at
    /// `state_timestamp_ns + T`.
    pub horizon: f64,
    /// Primal residual of the plan at the (inflated) constraint samples (m).
    pub primal_residual: f64,
    /// Smoothness: mean over robots of the summed squared acceleration at
    /// the K samples (m^2/s^4), as `flowopt_planner::metrics`.
    pub smoothness: f64,
    /// 1 when warm-started from the previous plan, 0 for a cold plan.
    pub warm_started: u32,
    /// Candidates refined (1 for the optimiser and warm starts).
    pub candidates: u32,
    /// Per-stage timings.
    pub timings: StageTimings,
    /// Coefficients `[robot][axis][coef]`, the first `degree + 1` used.
    pub coeffs: [[[f64; MAX_COEFFS]; 3]; MAX_ROBOTS],
}

/// Checks that `name` can name a team: 1 to [`TEAM_NAME_LEN`] bytes, no
/// `/` (it is a segment of the service names) and no NUL (the padding).
pub fn check_team_name(name: &str) -> Result<(), MessageError> {
    if name.is_empty() || name.len() > TEAM_NAME_LEN || name.contains(['/', '\0']) {
        return Err(MessageError::TeamName(name.to_string()));
    }
    Ok(())
}

/// Writes `name` NUL-padded into `out`.
fn write_name(out: &mut [u8; TEAM_NAME_LEN], name: &str) -> Result<(), MessageError> {
    check_team_name(name)?;
    *out = [0; TEAM_NAME_LEN];
    out[..name.len()].copy_from_slice(name.as_bytes());
    Ok(())
}

/// Reads a NUL-padded name.
fn read_name(bytes: &[u8; TEAM_NAME_LEN]) -> Result<&str, MessageError> {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(TEAM_NAME_LEN);
    std::str::from_utf8(&bytes[..end]).map_err(|_| MessageError::TeamName(String::from_utf8_lossy(bytes).into()))
}

impl StateSnapshot {
    /// An empty snapshot of the current version.
    pub fn new() -> Self {
        Self {
            version: WIRE_VERSION,
            dim: 0,
            team: [0; TEAM_NAME_LEN],
            sequence: 0,
            timestamp_ns: 0,
            robots: 0,
            obstacles: 0,
            robot: [RobotState::default(); MAX_ROBOTS],
            obstacle: [ObstacleState::default(); MAX_OBSTACLES],
        }
    }

    /// Sets the team name.
    pub fn set_team(&mut self, name: &str) -> Result<(), MessageError> {
        write_name(&mut self.team, name)
    }

    /// The team name.
    pub fn team_name(&self) -> Result<&str, MessageError> {
        read_name(&self.team)
    }

    /// Writes `problem`'s shape, start states (position and velocity; the
    /// wire carries no acceleration), goals and obstacles. The team name,
    /// sequence and timestamp are the publisher's.
    pub fn write_problem(&mut self, problem: &Problem) -> Result<(), MessageError> {
        let (robots, obstacles) = (problem.robots(), problem.obstacles.len());
        if robots > MAX_ROBOTS || obstacles > MAX_OBSTACLES {
            return Err(MessageError::Capacity { robots, obstacles, coefficients: 0 });
        }
        self.dim = problem.team.dim.axes() as u32;
        self.robots = robots as u32;
        self.obstacles = obstacles as u32;
        for ((r, s), g) in self.robot.iter_mut().zip(&problem.starts).zip(&problem.goals) {
            r.position = s.position.into();
            r.velocity = s.velocity.into();
            r.goal = (*g).into();
        }
        for (o, m) in self.obstacle.iter_mut().zip(&problem.obstacles) {
            o.position = m.position.into();
            o.velocity = m.velocity.into();
            o.radius = m.shape.radius;
            o.half_height = m.shape.half_height;
        }
        Ok(())
    }
}

impl Default for StateSnapshot {
    fn default() -> Self {
        Self::new()
    }
}

impl PlanStatus {
    /// Whether a message with this status carries coefficients.
    pub fn has_plan(self) -> bool {
        matches!(self, Self::Ok | Self::Degraded | Self::DeadlineMissed | Self::Stale)
    }
}

impl JointTrajectory {
    /// An empty message of the current version: no plan.
    pub fn new() -> Self {
        Self {
            version: WIRE_VERSION,
            status: PlanStatus::NoPlan,
            reason: Reason::None,
            reason_index: u32::MAX,
            team: [0; TEAM_NAME_LEN],
            dim: 0,
            robots: 0,
            degree: 0,
            iterations: 0,
            answers_sequence: 0,
            state_timestamp_ns: 0,
            received_ns: 0,
            published_ns: 0,
            horizon: 0.0,
            primal_residual: 0.0,
            smoothness: 0.0,
            warm_started: 0,
            candidates: 0,
            timings: StageTimings::default(),
            coeffs: [[[0.0; MAX_COEFFS]; 3]; MAX_ROBOTS],
        }
    }

    /// Sets the team name.
    pub fn set_team(&mut self, name: &str) -> Result<(), MessageError> {
        write_name(&mut self.team, name)
    }

    /// The team name.
    pub fn team_name(&self) -> Result<&str, MessageError> {
        read_name(&self.team)
    }

    /// Seconds from the plan's time origin (the answered state's timestamp)
    /// to `now_ns` ([`crate::clock::monotonic_ns`]); negative if `now_ns` is
    /// earlier.
    pub fn elapsed_s(&self, now_ns: u64) -> f64 {
        (now_ns as i128 - self.state_timestamp_ns as i128) as f64 * 1e-9
    }

    /// Writes `plan`'s shape and coefficients.
    pub fn write_plan(&mut self, plan: &JointPlan) -> Result<(), MessageError> {
        let nx = plan.degree + 1;
        if plan.robots > MAX_ROBOTS || nx > MAX_COEFFS {
            return Err(MessageError::Capacity { robots: plan.robots, obstacles: 0, coefficients: nx });
        }
        self.dim = plan.dim.axes() as u32;
        self.robots = plan.robots as u32;
        self.degree = plan.degree as u32;
        self.horizon = plan.horizon;
        for i in 0..plan.robots {
            for a in 0..3 {
                let out = &mut self.coeffs[i][a];
                out.fill(0.0);
                if a < plan.dim.axes() {
                    out[..nx].copy_from_slice(plan.coefficients(a, i));
                }
            }
        }
        Ok(())
    }

    /// The plan this message carries, checked for shape.
    pub fn plan(&self) -> Result<JointPlan, MessageError> {
        let (dim, robots, nx) = self.shape()?;
        let mut coeffs = Vec::with_capacity(dim.axes() * robots * nx);
        for a in 0..dim.axes() {
            for i in 0..robots {
                coeffs.extend_from_slice(&self.coeffs[i][a][..nx]);
            }
        }
        Ok(JointPlan { dim, robots, degree: nx - 1, horizon: self.horizon, coeffs })
    }

    /// Every robot's position, velocity and acceleration `t` seconds after
    /// the plan's origin (clamped to `[0, T]`: before it the start, after
    /// it the goal at rest).
    pub fn sample(&self, t: f64) -> Result<Vec<Kinematics>, MessageError> {
        Ok(self.plan()?.at(t))
    }

    /// One robot's kinematics `t` seconds after the plan's origin (clamped
    /// to `[0, T]`), without building the whole plan.
    pub fn sample_robot(&self, robot: usize, t: f64) -> Result<Kinematics, MessageError> {
        let (dim, robots, nx) = self.shape()?;
        if robot >= robots {
            return Err(MessageError::RobotOutOfRange { robot, robots });
        }
        let rows = InstantRows::new(nx - 1, self.horizon, t);
        Ok(rows.kinematics(dim.axes(), |a| &self.coeffs[robot][a][..nx]))
    }

    /// Whether this message's shape fits `team`.
    pub fn fits(&self, team: &Team) -> bool {
        self.shape().is_ok_and(|(d, n, nx)| d == team.dim && n == team.robots && nx == team.degree + 1)
    }

    fn shape(&self) -> Result<(Dim, usize, usize), MessageError> {
        if !self.status.has_plan() {
            return Err(MessageError::NoPlan(self.status));
        }
        let dim = Dim::try_from(self.dim as u8).map_err(|_| MessageError::Shape("dim"))?;
        let robots = self.robots as usize;
        let nx = self.degree as usize + 1;
        if robots == 0 || robots > MAX_ROBOTS {
            return Err(MessageError::Shape("robots"));
        }
        if self.degree == 0 || nx > MAX_COEFFS {
            return Err(MessageError::Shape("degree"));
        }
        if !(self.horizon.is_finite() && self.horizon > 0.0) {
            return Err(MessageError::Shape("horizon"));
        }
        Ok((dim, robots, nx))
    }
}

impl Default for JointTrajectory {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{offset_of, size_of};
    use flowopt_planner::problem::Team;

    /// The offsets documented in docs/MESSAGES.md.
    #[test]
    fn the_byte_layout_is_the_documented_one() {
        assert_eq!(size_of::<RobotState>(), 72);
        assert_eq!(size_of::<ObstacleState>(), 64);
        assert_eq!(offset_of!(StateSnapshot, team), 8);
        assert_eq!(offset_of!(StateSnapshot, sequence), 40);
        assert_eq!(offset_of!(StateSnapshot, timestamp_ns), 48);
        assert_eq!(offset_of!(StateSnapshot, robots), 56);
        assert_eq!(offset_of!(StateSnapshot, obstacles), 60);
        assert_eq!(offset_of!(StateSnapshot, robot), 64);
        assert_eq!(offset_of!(StateSnapshot, obstacle), 4672);
        assert_eq!(size_of::<StateSnapshot>(), 5696);

        assert_eq!(size_of::<PlanStatus>(), 4);
        assert_eq!(size_of::<Reason>(), 4);
        assert_eq!(size_of::<StageTimings>(), 40);
        assert_eq!(offset_of!(JointTrajectory, status), 4);
        assert_eq!(offset_of!(JointTrajectory, reason), 8);
        assert_eq!(offset_of!(JointTrajectory, reason_index), 12);
        assert_eq!(offset_of!(JointTrajectory, team), 16);
        assert_eq!(offset_of!(JointTrajectory, dim), 48);
        assert_eq!(offset_of!(JointTrajectory, iterations), 60);
        assert_eq!(offset_of!(JointTrajectory, answers_sequence), 64);
        assert_eq!(offset_of!(JointTrajectory, published_ns), 88);
        assert_eq!(offset_of!(JointTrajectory, horizon), 96);
        assert_eq!(offset_of!(JointTrajectory, smoothness), 112);
        assert_eq!(offset_of!(JointTrajectory, warm_started), 120);
        assert_eq!(offset_of!(JointTrajectory, timings), 128);
        assert_eq!(offset_of!(JointTrajectory, coeffs), 168);
        assert_eq!(size_of::<JointTrajectory>(), 24744);
    }

    #[test]
    fn zeroed_messages_say_no_plan() {
        // SAFETY: checking the module's claim that all-zero bytes are a
        // valid value of both messages.
        let plan: JointTrajectory = unsafe { core::mem::zeroed() };
        assert_eq!(plan.status, PlanStatus::NoPlan);
        assert_eq!(plan.reason, Reason::None);
        assert!(plan.sample(0.0).is_err());
    }

    #[test]
    fn a_written_plan_samples_like_the_planner_plan() {
        let team = Team::default_for(Dim::Three, 3);
        let nx = team.degree + 1;
        let coeffs: Vec<f64> = (0..3 * 3 * nx).map(|k| ((k * 7) % 11) as f64 * 0.1 - 0.5).collect();
        let plan = JointPlan::new(&team, coeffs);
        let mut msg = JointTrajectory::new();
        msg.status = PlanStatus::Ok;
        msg.write_plan(&plan).unwrap();
        assert_eq!(msg.plan().unwrap(), plan);
        for t in [0.0, 1.3, 4.9, 7.0] {
            let whole = msg.sample(t).unwrap();
            assert_eq!(whole, plan.at(t));
            for (i, k) in whole.iter().enumerate() {
                let one = msg.sample_robot(i, t).unwrap();
                assert!((one.position - k.position).norm() < 1e-12);
                assert!((one.velocity - k.velocity).norm() < 1e-12);
                assert!((one.acceleration - k.acceleration).norm() < 1e-12);
            }
        }
        assert!(matches!(msg.sample_robot(3, 0.0), Err(MessageError::RobotOutOfRange { robot: 3, robots: 3 })));
    }

    #[test]
    fn malformed_plan_messages_give_typed_errors() {
        let mut msg = JointTrajectory::new();
        assert!(matches!(msg.sample(0.0), Err(MessageError::NoPlan(PlanStatus::NoPlan))));
        msg.status = PlanStatus::Ok;
        msg.dim = 4;
        assert!(matches!(msg.sample(0.0), Err(MessageError::Shape("dim"))));
        msg.dim = 2;
        msg.robots = MAX_ROBOTS as u32 + 1;
        assert!(matches!(msg.sample(0.0), Err(MessageError::Shape("robots"))));
        msg.robots = 2;
        msg.degree = MAX_COEFFS as u32;
        assert!(matches!(msg.sample(0.0), Err(MessageError::Shape("degree"))));
    }

    #[test]
    fn team_names_round_trip_and_bad_ones_are_refused() {
        let mut s = StateSnapshot::new();
        s.set_team("lab-a").unwrap();
        assert_eq!(s.team_name().unwrap(), "lab-a");
        assert!(s.set_team("").is_err());
        assert!(s.set_team(&"x".repeat(TEAM_NAME_LEN + 1)).is_err());
        s.team = [0xff; TEAM_NAME_LEN];
        assert!(s.team_name().is_err());
    }
}
