//! A snapshot checked against its team and turned into a planning problem,
//! or a rejection carrying the reason code the plan message reports.
//!
//! The checks run in a fixed order, the first failure giving the reason:
//! the header ([`check_header`]: version, team, dimension, counts), then
//! the clock and the sequence ([`crate::admission`]), then the values
//! ([`measured`]: finite, positive sizes, plausible speeds of robots and
//! obstacles), then the task (workspace, overlaps, obstacles). A snapshot
//! rejected before the task is not a measurement and changes nothing; one
//! whose task alone is rejected still reports the world as it is.

use flowopt_client::{MAX_ROBOTS, Reason, StateSnapshot, WIRE_VERSION};
use flowopt_planner::problem::{Field, Obstacle, Problem, ProblemError, Spheroid, StartState, Team};
use nalgebra::Vector3;

/// Why a snapshot cannot be planned for, as written into the plan message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rejection {
    /// Reason code.
    pub reason: Reason,
    /// The robot (or `MAX_ROBOTS + obstacle`) at fault; `u32::MAX` if none.
    pub index: u32,
}

impl Rejection {
    /// A rejection that points at no robot or obstacle.
    pub fn new(reason: Reason) -> Self {
        Self { reason, index: u32::MAX }
    }

    /// A rejection that points at robot (or `MAX_ROBOTS + obstacle`) `index`.
    pub fn at(reason: Reason, index: usize) -> Self {
        Self { reason, index: index as u32 }
    }
}

/// The checks of a snapshot's header, in order: [`Reason::Version`],
/// [`Reason::Team`] (the name, NUL-padded, nothing after its NUL),
/// [`Reason::Dimension`], [`Reason::RobotCount`], [`Reason::ObstacleCount`].
/// They come first: a snapshot that fails one is not read any further.
pub fn check_header(snapshot: &StateSnapshot, team: &Team, name: &str, max_obstacles: usize) -> Result<(), Rejection> {
    if snapshot.version != WIRE_VERSION {
        return Err(Rejection::new(Reason::Version));
    }
    if snapshot.team_name().ok() != Some(name) {
        return Err(Rejection::new(Reason::Team));
    }
    if snapshot.dim as usize != team.dim.axes() {
        return Err(Rejection::new(Reason::Dimension));
    }
    if snapshot.robots as usize != team.robots {
        return Err(Rejection::new(Reason::RobotCount));
    }
    if snapshot.obstacles as usize > max_obstacles {
        return Err(Rejection::new(Reason::ObstacleCount));
    }
    Ok(())
}

/// The speeds above which a measured robot or obstacle is implausible.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausible {
    /// Robots (m/s).
    pub robot_speed: f64,
    /// Obstacles (m/s).
    pub obstacle_speed: f64,
}

/// A snapshot whose measurement was accepted: the world it reports, and
/// whether its task (the goals, from where the robots are) can be planned.
#[derive(Debug, Clone, PartialEq)]
pub struct Measured {
    /// The problem it describes (start accelerations zero).
    pub problem: Problem,
    /// `Err` when the task cannot be planned: a start or goal outside the
    /// workspace, overlapping starts or goals, a start or goal in an
    /// obstacle. The robots and obstacles are still what was measured.
    pub task: Result<(), Rejection>,
    /// The robot of the first start violation the plans recover from (a
    /// robot touching another or an obstacle, or outside the box, within
    /// what the team recovers from: [`flowopt_planner::recovery`]),
    /// reported with the answer as [`Reason::Recovering`].
    pub recovering: Option<usize>,
}

/// Reads a snapshot whose header passed [`check_header`]: the values
/// ([`Reason::NonFinite`], [`Reason::NonPositiveSize`]), then their
/// plausibility ([`Reason::Implausible`]: a robot or obstacle faster than
/// `plausible`), then the task. A rejection here means the snapshot is not
/// a measurement; a task that cannot be planned is reported in
/// [`Measured::task`].
pub fn measured(snapshot: &StateSnapshot, team: &Team, plausible: Plausible) -> Result<Measured, Rejection> {
    let v = |a: &[f64; 3]| Vector3::from(*a);
    let robots = &snapshot.robot[..team.robots];
    let obstacles = (snapshot.obstacles as usize).min(snapshot.obstacle.len());
    let mut problem = Problem {
        team: team.clone(),
        starts: robots
            .iter()
            .map(|r| StartState { position: v(&r.position), velocity: v(&r.velocity), acceleration: Vector3::zeros() })
            .collect(),
        goals: robots.iter().map(|r| v(&r.goal)).collect(),
        obstacles: snapshot.obstacle[..obstacles]
            .iter()
            .map(|o| Obstacle {
                position: v(&o.position),
                velocity: v(&o.velocity),
                shape: Spheroid { radius: o.radius, half_height: o.half_height },
            })
            .collect(),
    };
    if team.dim.axes() == 2 {
        // The third entries are ignored in 2D; keep them out of the plan.
        for s in &mut problem.starts {
            s.position.z = 0.0;
            s.velocity.z = 0.0;
        }
        problem.goals.iter_mut().for_each(|g| g.z = 0.0);
        for o in &mut problem.obstacles {
            o.position.z = 0.0;
            o.velocity.z = 0.0;
            o.shape.half_height = o.shape.radius;
        }
    }
    let task = match problem.validate() {
        Ok(()) => Ok(()),
        Err(e) if is_task(&e) => Err(rejection_of(&e)),
        Err(e) => return Err(rejection_of(&e)),
    };
    if let Some(i) = problem.starts.iter().position(|s| s.velocity.norm() > plausible.robot_speed) {
        return Err(Rejection::at(Reason::Implausible, i));
    }
    if let Some(m) = problem.obstacles.iter().position(|o| o.velocity.norm() > plausible.obstacle_speed) {
        return Err(Rejection::at(Reason::Implausible, MAX_ROBOTS + m));
    }
    let recovering = match task {
        Ok(()) => problem.start_violations().first().map(|v| v.robot),
        Err(_) => None,
    };
    Ok(Measured { problem, task, recovering })
}

/// Whether a validation error is about the task (where the robots are and
/// where they are to go) rather than about the values themselves.
fn is_task(error: &ProblemError) -> bool {
    use ProblemError as E;
    matches!(
        error,
        E::StartsOverlap { .. }
            | E::GoalsOverlap { .. }
            | E::StartInObstacle { .. }
            | E::GoalInObstacle { .. }
            | E::StartOutsideWorkspace(_)
            | E::CannotBrake { .. }
            | E::CannotAvoid { .. }
            | E::GoalOutsideWorkspace(_)
    )
}

/// The reason code of a validation error.
pub fn rejection_of(error: &ProblemError) -> Rejection {
    use ProblemError as E;
    match *error {
        E::NonFinite { field, index } => match field {
            Field::ObstaclePosition | Field::ObstacleVelocity | Field::ObstacleSize => {
                Rejection::at(Reason::NonFinite, MAX_ROBOTS + index)
            }
            _ => Rejection::at(Reason::NonFinite, index),
        },
        E::NonPositive { field: Field::ObstacleSize, index } => {
            Rejection::at(Reason::NonPositiveSize, MAX_ROBOTS + index)
        }
        E::NonPositive { .. } => Rejection::new(Reason::NonPositiveSize),
        E::StartsOverlap { i, .. } => Rejection::at(Reason::StartsOverlap, i),
        E::GoalsOverlap { i, .. } => Rejection::at(Reason::GoalsOverlap, i),
        E::StartInObstacle { robot, .. } => Rejection::at(Reason::StartInObstacle, robot),
        E::GoalInObstacle { robot, .. } => Rejection::at(Reason::GoalInObstacle, robot),
        E::StartOutsideWorkspace(i) => Rejection::at(Reason::StartOutsideWorkspace, i),
        E::CannotBrake { robot, .. } => Rejection::at(Reason::CannotBrake, robot),
        E::CannotAvoid { i, .. } => Rejection::at(Reason::CannotAvoid, i),
        E::GoalOutsideWorkspace(i) => Rejection::at(Reason::GoalOutsideWorkspace, i),
        E::WrongCount { .. } | E::NoRobots => Rejection::new(Reason::RobotCount),
        E::BadDimension(_) => Rejection::new(Reason::Dimension),
        E::EmptyWorkspace { .. } | E::Basis(_) => Rejection::new(Reason::Solver),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::Dim;
    use flowopt_planner::scenario::RandomScenario;

    const PLAUSIBLE: Plausible = Plausible { robot_speed: 3.0, obstacle_speed: 3.0 };

    /// A valid snapshot of a random 4-robot instance, with one obstacle.
    fn valid() -> (Team, StateSnapshot) {
        let team = Team::default_for(Dim::Two, 4);
        let p = RandomScenario::new(team.clone()).with_obstacles(1).generate(2).unwrap();
        let mut s = StateSnapshot::new();
        s.set_team("t").unwrap();
        s.write_problem(&p).unwrap();
        (team, s)
    }

    /// The header checks, then the measurement: the rejection of the
    /// snapshot, or of its task.
    fn check(s: &StateSnapshot, team: &Team) -> Result<Problem, Rejection> {
        check_header(s, team, "t", 2)?;
        let m = measured(s, team, PLAUSIBLE)?;
        m.task.map(|()| m.problem)
    }

    #[test]
    fn a_valid_snapshot_becomes_its_problem() {
        let (team, s) = valid();
        let p = check(&s, &team).unwrap();
        assert_eq!(p.starts[3].position, Vector3::from(s.robot[3].position));
        assert_eq!(p.obstacles.len(), 1);
    }

    #[test]
    fn every_malformed_kind_gets_its_reason() {
        let (team, good) = valid();
        type Edit = Box<dyn Fn(&mut StateSnapshot)>;
        let cases: Vec<(Edit, Reason, u32)> = vec![
            (Box::new(|s| s.version = 99), Reason::Version, u32::MAX),
            (Box::new(|s| s.set_team("other").unwrap()), Reason::Team, u32::MAX),
            (Box::new(|s| s.team[2..6].copy_from_slice(b"junk")), Reason::Team, u32::MAX),
            (Box::new(|s| s.dim = 3), Reason::Dimension, u32::MAX),
            (Box::new(|s| s.robots = MAX_ROBOTS as u32 + 1), Reason::RobotCount, u32::MAX),
            (Box::new(|s| s.obstacles = 3), Reason::ObstacleCount, u32::MAX),
            (Box::new(|s| s.robot[2].velocity[1] = f64::NAN), Reason::NonFinite, 2),
            (Box::new(|s| s.obstacle[0].position[0] = f64::INFINITY), Reason::NonFinite, MAX_ROBOTS as u32),
            (Box::new(|s| s.obstacle[0].radius = 0.0), Reason::NonPositiveSize, MAX_ROBOTS as u32),
            (Box::new(|s| s.obstacle[0].radius = -0.1), Reason::NonPositiveSize, MAX_ROBOTS as u32),
            (Box::new(|s| s.robot[1].velocity = [1e6, 0.0, 0.0]), Reason::Implausible, 1),
            (Box::new(|s| s.robot[3].velocity = [0.0, 3.5, 9.0]), Reason::Implausible, 3),
            (Box::new(|s| s.obstacle[0].velocity = [1e300, 0.0, 0.0]), Reason::Implausible, MAX_ROBOTS as u32),
            (Box::new(|s| s.obstacle[0].velocity = [0.0, 3.1, 0.0]), Reason::Implausible, MAX_ROBOTS as u32),
            (Box::new(|s| s.robot[1].position = s.robot[0].position), Reason::StartsOverlap, 0),
            (Box::new(|s| s.robot[1].goal = s.robot[0].goal), Reason::GoalsOverlap, 0),
            (Box::new(|s| s.robot[3].goal = [0.0, 5.0, 0.0]), Reason::GoalOutsideWorkspace, 3),
            (Box::new(|s| s.robot[3].position = [-3.0, 0.0, 0.0]), Reason::StartOutsideWorkspace, 3),
            (Box::new(|s| s.obstacle[0].position = s.robot[2].position), Reason::StartInObstacle, 2),
        ];
        for (break_it, reason, index) in cases {
            let mut s = good;
            break_it(&mut s);
            assert_eq!(check(&s, &team).unwrap_err(), Rejection { reason, index }, "{reason:?}");
        }
    }

    #[test]
    fn the_header_is_checked_first_and_an_all_zero_snapshot_is_the_wrong_version() {
        let team = Team::default_for(Dim::Two, 4);
        let zero = StateSnapshot { version: 0, ..StateSnapshot::new() };
        assert_eq!(check(&zero, &team).unwrap_err().reason, Reason::Version);
    }

    #[test]
    fn a_task_that_cannot_be_planned_is_still_a_measurement() {
        let (team, mut s) = valid();
        s.obstacle[0].position = s.robot[2].goal;
        let m = measured(&s, &team, PLAUSIBLE).unwrap();
        assert_eq!(m.task, Err(Rejection::at(Reason::GoalInObstacle, 2)));
        assert_eq!(m.problem.obstacles[0].position, Vector3::from(s.robot[2].goal));
        // A bad value is not.
        s.robot[0].position[0] = f64::NAN;
        assert_eq!(measured(&s, &team, PLAUSIBLE).unwrap_err().reason, Reason::NonFinite);
    }

    #[test]
    fn a_start_in_shallow_contact_is_planned_in_a_team_that_recovers_and_reported() {
        let (team, mut s) = valid();
        let recovering = Team { start_recovery: Some(1.0), ..team.clone() };
        // Robot 3 measured 5 mm outside the box's left side.
        s.robot[3].position = [-1.005, 0.0, 0.0];
        let m = measured(&s, &recovering, PLAUSIBLE).unwrap();
        assert_eq!((m.task, m.recovering), (Ok(()), Some(3)));
        let strict = measured(&s, &team, PLAUSIBLE).unwrap();
        assert_eq!((strict.task, strict.recovering), (Err(Rejection::at(Reason::StartOutsideWorkspace, 3)), None));
        // Deeper than half a separation: rejected in either team without
        // an acceleration limit; with one, planned back from where a plan
        // can bring it back within half the horizon.
        s.robot[3].position = [-1.2, 0.0, 0.0];
        assert_eq!(
            measured(&s, &recovering, PLAUSIBLE).unwrap().task,
            Err(Rejection::at(Reason::StartOutsideWorkspace, 3))
        );
        let limited = Team { max_acceleration: Some(3.0), ..recovering.clone() };
        assert_eq!(measured(&s, &limited, PLAUSIBLE).unwrap().recovering, Some(3));
        s.robot[3].position = [-4.0, 0.0, 0.0];
        assert_eq!(
            measured(&s, &limited, PLAUSIBLE).unwrap().task,
            Err(Rejection::at(Reason::StartOutsideWorkspace, 3))
        );
        let (_, clear) = valid();
        assert_eq!(measured(&clear, &recovering, PLAUSIBLE).unwrap().recovering, None);
    }

    #[test]
    fn a_pair_that_cannot_keep_apart_is_rejected_as_cannot_avoid_only_without_recovery() {
        let (team, mut s) = valid();
        let braking = Team { max_acceleration: Some(3.0), ..team.clone() };
        let recovering = Team { start_recovery: Some(1.0), ..braking.clone() };
        // Robots 1 and 2 head past each other at 1 m/s each, 0.35 m apart
        // along x and 0.1 m across: within 0.9 of their separation
        // whatever they do at 3 m/s^2.
        (s.robot[1].position, s.robot[1].velocity) = ([-0.175, -0.55, 0.0], [1.0, 0.0, 0.0]);
        (s.robot[2].position, s.robot[2].velocity) = ([0.175, -0.45, 0.0], [-1.0, 0.0, 0.0]);
        let strict = measured(&s, &braking, PLAUSIBLE).unwrap();
        assert_eq!(strict.task, Err(Rejection::at(Reason::CannotAvoid, 1)));
        assert!(Reason::CannotAvoid.is_rejection());
        // A recovering team plans them as any other pair; so does one of
        // unknown acceleration.
        assert_eq!(measured(&s, &recovering, PLAUSIBLE).unwrap().task, Ok(()));
        assert_eq!(measured(&s, &team, PLAUSIBLE).unwrap().task, Ok(()));
    }

    #[test]
    fn a_robot_that_cannot_brake_inside_the_box_is_recovered_or_rejected_as_cannot_brake() {
        let (team, mut s) = valid();
        let braking = Team { max_acceleration: Some(3.0), ..team.clone() };
        let recovering = Team { start_recovery: Some(1.0), ..braking.clone() };
        // Robot 3, 2 cm inside the box's left side, moving at it at 1 m/s.
        s.robot[3].position = [-0.98, 0.0, 0.0];
        s.robot[3].velocity = [-1.0, 0.0, 0.0];
        let m = measured(&s, &recovering, PLAUSIBLE).unwrap();
        assert_eq!((m.task, m.recovering), (Ok(()), Some(3)));
        let strict = measured(&s, &braking, PLAUSIBLE).unwrap();
        assert_eq!((strict.task, strict.recovering), (Err(Rejection::at(Reason::CannotBrake, 3)), None));
        assert!(Reason::CannotBrake.is_rejection());
        // Without a known acceleration, or moving inwards, it is a start like any other.
        assert_eq!(measured(&s, &team, PLAUSIBLE).unwrap().task, Ok(()));
        s.robot[3].velocity = [1.0, 0.0, 0.0];
        assert_eq!(measured(&s, &braking, PLAUSIBLE).unwrap().task, Ok(()));
    }

    #[test]
    fn the_third_entries_are_ignored_in_2d() {
        let (team, mut s) = valid();
        s.robot[0].position[2] = f64::NAN;
        s.robot[0].goal[2] = 7.0;
        let p = check(&s, &team).unwrap();
        assert_eq!((p.starts[0].position.z, p.goals[0].z), (0.0, 0.0));
    }
}
