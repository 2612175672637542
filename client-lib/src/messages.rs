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

pub use crate::codes::{MessageError, PlanStatus, Reason};

/// Robots per team a message can carry.
pub const MAX_ROBOTS: usize = 256;
/// Obstacles a snapshot can carry.
pub const MAX_OBSTACLES: usize = 16;
/// Bernstein coefficients per robot and axis a plan can carry (degree <= 15).
pub const MAX_COEFFS: usize = 16;
/// Bytes of the team name (UTF-8, NUL-padded).
pub const TEAM_NAME_LEN: usize = 32;
/// Layout version written into every message; bumped on any layout change.
pub const WIRE_VERSION: u32 = 2;

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
    /// Obstacles `0..obstacles`.
    pub obstacle: [ObstacleState; MAX_OBSTACLES],
    /// Robots `0..robots` (last, so that a message's used part is a prefix).
    pub robot: [RobotState; MAX_ROBOTS],
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

/// Daemon to controllers: the answer to one snapshot, carrying the
/// trajectory to follow from now on (the followability contract,
/// `docs/MESSAGES.md`): when [`PlanStatus::followable`], the coefficients
/// with their time origin `plan_origin_ns` were verified by the daemon;
/// otherwise there is none.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("flowopt::JointTrajectory")]
pub struct JointTrajectory {
    /// [`WIRE_VERSION`] of the writer.
    pub version: u32,
    /// [`PlanStatus`] as a `u32`: what to follow ([`Self::status`]).
    pub status: u32,
    /// [`Reason`] as a `u32`: why this is not a new plan ([`Self::reason`]).
    pub reason: u32,
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
    /// Safety-filter / optimiser iterations spent on this answer.
    pub iterations: u32,
    /// `sequence` of the snapshot this message answers.
    pub answers_sequence: u64,
    /// `timestamp_ns` of that snapshot.
    pub state_timestamp_ns: u64,
    /// `sequence` of the snapshot the carried plan was made from (equal to
    /// `answers_sequence` for [`PlanStatus::Ok`]).
    pub plan_sequence: u64,
    /// The carried plan's time origin: its `t = 0` (the `timestamp_ns` of
    /// the snapshot it was made from).
    pub plan_origin_ns: u64,
    /// When the daemon received the answered snapshot.
    pub received_ns: u64,
    /// When the daemon published this message.
    pub published_ns: u64,
    /// Horizon T (s): robots reach their goals at rest at
    /// `plan_origin_ns + T`.
    pub horizon: f64,
    /// Primal residual of the plan at the (inflated) constraint samples (m).
    pub primal_residual: f64,
    /// Smoothness: mean over robots of the summed squared acceleration at
    /// the K samples (m^2/s^4), as `flowopt_planner::metrics`.
    pub smoothness: f64,
    /// Largest speed of any robot along the plan (m/s).
    pub max_speed: f64,
    /// Largest acceleration of any robot along the plan (m/s^2).
    pub max_acceleration: f64,
    /// 1 when warm-started from the previous plan, 0 for a cold plan.
    pub warm_started: u32,
    /// Candidates refined (1 for the optimiser and warm starts).
    pub candidates: u32,
    /// Per-stage timings of this answer.
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

/// Reads a NUL-padded name: UTF-8 up to the first NUL and only NULs after
/// it (`default\0junk` is not the name `default`).
fn read_name(bytes: &[u8; TEAM_NAME_LEN]) -> Result<&str, MessageError> {
    let bad = || MessageError::TeamName(String::from_utf8_lossy(bytes).into());
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(TEAM_NAME_LEN);
    if bytes[end..].iter().any(|&b| b != 0) {
        return Err(bad());
    }
    std::str::from_utf8(&bytes[..end]).map_err(|_| bad())
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
            obstacle: [ObstacleState::default(); MAX_OBSTACLES],
            robot: [RobotState::default(); MAX_ROBOTS],
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

impl JointTrajectory {
    /// An empty message of the current version: no plan.
    pub fn new() -> Self {
        Self {
            version: WIRE_VERSION,
            status: PlanStatus::NoPlan as u32,
            reason: Reason::None as u32,
            reason_index: u32::MAX,
            team: [0; TEAM_NAME_LEN],
            dim: 0,
            robots: 0,
            degree: 0,
            iterations: 0,
            answers_sequence: 0,
            state_timestamp_ns: 0,
            plan_sequence: 0,
            plan_origin_ns: 0,
            received_ns: 0,
            published_ns: 0,
            horizon: 0.0,
            primal_residual: 0.0,
            smoothness: 0.0,
            max_speed: 0.0,
            max_acceleration: 0.0,
            warm_started: 0,
            candidates: 0,
            timings: StageTimings::default(),
            coeffs: [[[0.0; MAX_COEFFS]; 3]; MAX_ROBOTS],
        }
    }

    /// What to follow; an error for a value no daemon writes.
    pub fn status(&self) -> Result<PlanStatus, MessageError> {
        PlanStatus::from_wire(self.status)
    }

    /// Why this is not a new plan; an error for a value no daemon writes.
    pub fn reason(&self) -> Result<Reason, MessageError> {
        Reason::from_wire(self.reason)
    }

    /// Sets the status.
    pub fn set_status(&mut self, status: PlanStatus) {
        self.status = status as u32;
    }

    /// Sets the reason.
    pub fn set_reason(&mut self, reason: Reason) {
        self.reason = reason as u32;
    }

    /// Sets the team name.
    pub fn set_team(&mut self, name: &str) -> Result<(), MessageError> {
        write_name(&mut self.team, name)
    }

    /// The team name.
    pub fn team_name(&self) -> Result<&str, MessageError> {
        read_name(&self.team)
    }

    /// Seconds from the carried plan's time origin (`plan_origin_ns`) to
    /// `now_ns` ([`crate::clock::monotonic_ns`]); negative if `now_ns` is
    /// earlier.
    pub fn elapsed_s(&self, now_ns: u64) -> f64 {
        (now_ns as i128 - self.plan_origin_ns as i128) as f64 * 1e-9
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
        let status = self.status()?;
        if !status.followable() {
            return Err(MessageError::NoPlan(status));
        }
        let dim = match self.dim {
            2 => Dim::Two,
            3 => Dim::Three,
            _ => return Err(MessageError::Shape("dim")),
        };
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
    use flowopt_planner::scenario::RandomScenario;

    /// The offsets documented in docs/MESSAGES.md.
    #[test]
    fn the_byte_layout_is_the_documented_one() {
        assert_eq!(size_of::<RobotState>(), 72);
        assert_eq!(size_of::<ObstacleState>(), 64);
        assert_eq!(offset_of!(StateSnapshot, dim), 4);
        assert_eq!(offset_of!(StateSnapshot, team), 8);
        assert_eq!(offset_of!(StateSnapshot, sequence), 40);
        assert_eq!(offset_of!(StateSnapshot, timestamp_ns), 48);
        assert_eq!(offset_of!(StateSnapshot, robots), 56);
        assert_eq!(offset_of!(StateSnapshot, obstacles), 60);
        assert_eq!(offset_of!(StateSnapshot, obstacle), 64);
        assert_eq!(offset_of!(StateSnapshot, robot), 1088);
        assert_eq!(size_of::<StateSnapshot>(), 1088 + 72 * MAX_ROBOTS);
        assert_eq!(size_of::<StateSnapshot>(), 19520);

        assert_eq!(size_of::<StageTimings>(), 40);
        assert_eq!(offset_of!(JointTrajectory, status), 4);
        assert_eq!(offset_of!(JointTrajectory, reason), 8);
        assert_eq!(offset_of!(JointTrajectory, reason_index), 12);
        assert_eq!(offset_of!(JointTrajectory, team), 16);
        assert_eq!(offset_of!(JointTrajectory, dim), 48);
        assert_eq!(offset_of!(JointTrajectory, robots), 52);
        assert_eq!(offset_of!(JointTrajectory, degree), 56);
        assert_eq!(offset_of!(JointTrajectory, iterations), 60);
        assert_eq!(offset_of!(JointTrajectory, answers_sequence), 64);
        assert_eq!(offset_of!(JointTrajectory, state_timestamp_ns), 72);
        assert_eq!(offset_of!(JointTrajectory, plan_sequence), 80);
        assert_eq!(offset_of!(JointTrajectory, plan_origin_ns), 88);
        assert_eq!(offset_of!(JointTrajectory, received_ns), 96);
        assert_eq!(offset_of!(JointTrajectory, published_ns), 104);
        assert_eq!(offset_of!(JointTrajectory, horizon), 112);
        assert_eq!(offset_of!(JointTrajectory, primal_residual), 120);
        assert_eq!(offset_of!(JointTrajectory, smoothness), 128);
        assert_eq!(offset_of!(JointTrajectory, max_speed), 136);
        assert_eq!(offset_of!(JointTrajectory, max_acceleration), 144);
        assert_eq!(offset_of!(JointTrajectory, warm_started), 152);
        assert_eq!(offset_of!(JointTrajectory, candidates), 156);
        assert_eq!(offset_of!(JointTrajectory, timings), 160);
        assert_eq!(offset_of!(JointTrajectory, coeffs), 200);
        assert_eq!(size_of::<JointTrajectory>(), 200 + 384 * MAX_ROBOTS);
        assert_eq!(size_of::<JointTrajectory>(), 98504);
    }

    #[test]
    fn zeroed_messages_say_no_plan() {
        // SAFETY: checking the module's claim that all-zero bytes are a
        // valid value of both messages.
        let plan: JointTrajectory = unsafe { core::mem::zeroed() };
        assert_eq!(plan.status(), Ok(PlanStatus::NoPlan));
        assert_eq!(plan.reason(), Ok(Reason::None));
        assert!(plan.sample(0.0).is_err());
    }

    #[test]
    fn a_written_plan_samples_like_the_planner_plan() {
        let team = Team::default_for(Dim::Three, 3);
        let nx = team.degree + 1;
        let coeffs: Vec<f64> = (0..3 * 3 * nx).map(|k| ((k * 7) % 11) as f64 * 0.1 - 0.5).collect();
        let plan = JointPlan::new(&team, coeffs);
        let mut msg = JointTrajectory::new();
        msg.set_status(PlanStatus::Ok);
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
        msg.status = 9;
        assert!(matches!(msg.sample(0.0), Err(MessageError::Field("status"))));
        msg.set_status(PlanStatus::Held);
        msg.dim = 4;
        assert!(matches!(msg.sample(0.0), Err(MessageError::Shape("dim"))));
        msg.dim = 258;
        assert!(matches!(msg.sample(0.0), Err(MessageError::Shape("dim"))), "no truncation to 2");
        msg.dim = 2;
        msg.robots = MAX_ROBOTS as u32 + 1;
        assert!(matches!(msg.sample(0.0), Err(MessageError::Shape("robots"))));
        msg.robots = 2;
        msg.degree = MAX_COEFFS as u32;
        assert!(matches!(msg.sample(0.0), Err(MessageError::Shape("degree"))));
    }

    #[test]
    fn a_problem_written_into_a_snapshot_keeps_every_field() {
        let team = Team::default_for(Dim::Three, 5);
        let problem = RandomScenario::new(team).with_obstacles(2).with_start_speed(0.3).generate(4).unwrap();
        let mut s = StateSnapshot::new();
        s.write_problem(&problem).unwrap();
        assert_eq!((s.dim, s.robots, s.obstacles), (3, 5, 2));
        for (i, start) in problem.starts.iter().enumerate() {
            assert_eq!(s.robot[i].position, <[f64; 3]>::from(start.position));
            assert_eq!(s.robot[i].velocity, <[f64; 3]>::from(start.velocity));
            assert_eq!(s.robot[i].goal, <[f64; 3]>::from(problem.goals[i]));
        }
        let o = &problem.obstacles[1];
        assert_eq!(s.obstacle[1].position, <[f64; 3]>::from(o.position));
        assert_eq!((s.obstacle[1].radius, s.obstacle[1].half_height), (o.shape.radius, o.shape.half_height));
        let mut big = problem.clone();
        big.obstacles = vec![*o; MAX_OBSTACLES + 1];
        assert!(matches!(s.write_problem(&big), Err(MessageError::Capacity { obstacles: 17, .. })));
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
        // Bytes after the name's NUL make it another name.
        s.set_team("default").unwrap();
        s.team[8..12].copy_from_slice(b"junk");
        assert!(s.team_name().is_err());
        s.team[TEAM_NAME_LEN - 1] = 0;
        assert!(s.team_name().is_err());
    }
}
