//! What a measured start violates ([`StartViolation`], found by
//! [`crate::problem::Problem::start_violations`]) and how deep a team that
//! recovers from its starts accepts it ([`RECOVERABLE_DEPTH`],
//! [`StartViolation::return_time`]).

use crate::problem_error::ProblemError;

/// The deepest overlap of two robots' starts a team with
/// [`crate::problem::Team::start_recovery`] plans from: half a separation
/// (scaled distance 0.5). Robots cannot be that deep in each other without
/// a wrong measurement. Outside the box the same depth (half the
/// horizontal separation) holds for a team without
/// [`crate::problem::Team::max_acceleration`]; with it, a robot is planned
/// back in from wherever a plan can bring it back within half the horizon
/// ([`StartViolation::return_time`]): a gust pushes a robot out of the box
/// as far as it likes, and a team that waited for it to come back by
/// itself stopped (103 s of a 120 s simulated run). An obstacle (a walker bumping a robot, walking
/// on through it) may be reported anywhere.
pub const RECOVERABLE_DEPTH: f64 = 0.5;

/// How many times the shortest return into the box at the acceleration
/// limit (the outward motion braked and the way back covered at full
/// acceleration and braking) a plan is given for it: plans are
/// polynomials, not bang-bang.
pub const RETURN_FACTOR: f64 = 2.0;

/// What a measured start violates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Against {
    /// Another robot (a higher index).
    Robot(usize),
    /// An obstacle.
    Obstacle(usize),
    /// A side of the box on an axis (`upper`: the maximum).
    Box {
        /// The axis.
        axis: usize,
        /// Whether it is the upper side.
        upper: bool,
    },
    /// A side of the box the robot, inside it, moves towards faster than
    /// any plan it can follow (acceleration within
    /// [`crate::problem::Team::max_acceleration`]) stops before it ([`crate::braking`]).
    Braking {
        /// The axis.
        axis: usize,
        /// Whether it is the upper side.
        upper: bool,
    },
    /// Another robot (a higher index) the robot, apart from it, closes
    /// on faster than both can brake or swerve (accelerations within
    /// [`crate::problem::Team::max_acceleration`]): they must touch,
    /// whatever the plan ([`crate::closing`]). Checked only in a team
    /// without [`crate::problem::Team::start_recovery`]: a team that
    /// recovers from its starts holds every pair to the separation, as
    /// before, and never recovers from this one.
    Closing(usize),
}

impl Against {
    /// The side of the box, `(axis, upper)`, for [`Against::Box`] and
    /// [`Against::Braking`].
    pub fn side(self) -> Option<(usize, bool)> {
        match self {
            Against::Box { axis, upper } | Against::Braking { axis, upper } => Some((axis, upper)),
            _ => None,
        }
    }
}

/// A robot moving towards a side of the box it cannot stop before, or
/// stops just inside ([`crate::problem::Problem::braking_excesses`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrakingExcess {
    /// The robot.
    pub robot: usize,
    /// The axis.
    pub axis: usize,
    /// Whether the side is the upper one.
    pub upper: bool,
    /// How far it goes towards the side at the least, from its start (m).
    pub least: f64,
    /// How far past the side that takes it (m; negative: how far inside
    /// the side it can stop).
    pub excess: f64,
    /// Whether that is within [`crate::problem::FEASIBILITY_TOLERANCE`]
    /// (a floor the plan keeps to, [`crate::recovery`]) rather than beyond
    /// it (a start violation, [`Against::Braking`]).
    pub tolerated: bool,
}

/// A constraint a measured start violates beyond [`crate::problem::FEASIBILITY_TOLERANCE`]
/// ([`crate::problem::Problem::start_violations`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StartViolation {
    /// The robot (the lower index of a pair).
    pub robot: usize,
    /// What it violates.
    pub against: Against,
    /// How deep: `1 - d0` for a pair or an obstacle at scaled distance
    /// `d0`; the excess over the horizontal separation for the box (for
    /// [`Against::Braking`], how far past the side its least excursion
    /// ends, [`crate::braking`]; for [`Against::Closing`], `1 - d` with
    /// `d` the most scaled distance the pair can keep, [`crate::closing`]).
    pub depth: f64,
    /// How fast it deepens: the rate the scaled distance shrinks at, or
    /// the outward speed (m/s) for the box; 0 when it does not. For
    /// [`Against::Closing`], the instant (s) the pair comes closest at the
    /// least.
    pub closing: f64,
}

impl StartViolation {
    /// Whether a team with [`crate::problem::Team::start_recovery`] plans
    /// from it: an obstacle at any depth, a robot to [`RECOVERABLE_DEPTH`],
    /// the box where a plan brings the robot back within half the horizon
    /// ([`Self::return_time`]; to [`RECOVERABLE_DEPTH`] without an
    /// acceleration limit), a robot that cannot stop inside the box however
    /// fast (it is inside); never a pair that must touch
    /// ([`Against::Closing`]). `separation`: the team's horizontal
    /// separation (the unit of a box depth); `horizon` (s) and
    /// `max_acceleration`: the team's.
    pub fn recoverable(&self, separation: f64, horizon: f64, max_acceleration: Option<f64>) -> bool {
        match self.against {
            Against::Obstacle(_) | Against::Braking { .. } => true,
            Against::Closing(_) => false,
            Against::Box { .. } => self
                .return_time(separation, max_acceleration)
                .map_or(self.depth <= RECOVERABLE_DEPTH, |t| t <= horizon / 2.0),
            Against::Robot(_) => self.depth <= RECOVERABLE_DEPTH,
        }
    }

    /// For a start outside the box of a team of horizontal `separation`
    /// with [`crate::problem::Team::max_acceleration`] `a`: the time (s) its plan
    /// is given to be back inside, [`RETURN_FACTOR`] times the shortest
    /// return (brake the outward speed `u` in `u / a`, then cover the excess
    /// `e` and the braking distance `u^2 / 2a` accelerating and braking at
    /// `a`: `2 sqrt((e + u^2 / 2a) / a)`). `None` for any other violation or
    /// without the limit.
    pub fn return_time(&self, separation: f64, max_acceleration: Option<f64>) -> Option<f64> {
        let a = max_acceleration.filter(|a| *a > 0.0)?;
        if !matches!(self.against, Against::Box { .. }) {
            return None;
        }
        let (e, u) = (self.depth * separation, self.closing);
        Some(RETURN_FACTOR * (u / a + 2.0 * ((e + u * u / (2.0 * a)) / a).sqrt()))
    }

    /// Its validation error (`separation`: the team's horizontal
    /// separation, the unit of a box depth).
    pub fn error(&self, separation: f64) -> ProblemError {
        match self.against {
            Against::Robot(j) => ProblemError::StartsOverlap { i: self.robot, j, scaled: 1.0 - self.depth },
            Against::Obstacle(m) => ProblemError::StartInObstacle { robot: self.robot, obstacle: m },
            Against::Box { .. } => ProblemError::StartOutsideWorkspace(self.robot),
            Against::Braking { axis, upper } => ProblemError::CannotBrake {
                robot: self.robot,
                axis,
                upper,
                speed: self.closing,
                overshoot: self.depth * separation,
            },
            Against::Closing(j) => {
                ProblemError::CannotAvoid { i: self.robot, j, scaled: 1.0 - self.depth, at: self.closing }
            }
        }
    }
}
