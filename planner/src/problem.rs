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

use crate::basis::{BOUNDARY_ROWS, Basis, BasisError, DENSE_FACTOR};
use crate::closing;
pub use crate::problem_error::{Field, ProblemError};
pub use crate::start_violation::{Against, BrakingExcess, RECOVERABLE_DEPTH, RETURN_FACTOR, StartViolation};

/// Relative tolerance on every clearance: a plan is feasible when every
/// scaled distance is at least `1 - FEASIBILITY_TOLERANCE` (1% of the
/// separation) on a dense re-sampling, and robot centres stay within
/// `FEASIBILITY_TOLERANCE * separation` of the workspace box.
pub const FEASIBILITY_TOLERANCE: f64 = 0.01;

/// Start speed (m/s) and acceleration (m/s^2) at or below which a robot
/// counts as at rest ([`Problem::at_rest`]).
pub const AT_REST: f64 = 0.02;

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
    /// Seconds a robot whose measured start violates a constraint
    /// (in an obstacle; touching another robot by at most
    /// [`RECOVERABLE_DEPTH`]; outside the box where
    /// [`StartViolation::recoverable`]) has to clear it, at the least (a
    /// robot far out of the box is given longer:
    /// [`StartViolation::return_time`]); see [`crate::recovery`]. `None`:
    /// such starts are rejected.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_recovery: Option<f64>,
    /// The robots' largest acceleration (m/s^2), if known: a robot inside
    /// the box moving towards a side faster than it can stop before it
    /// ([`Against::Braking`]) is then rejected ([`ProblemError::CannotBrake`])
    /// or, with [`Team::start_recovery`], recovered from like a start
    /// outside the box; without [`Team::start_recovery`], two robots closing
    /// on each other faster than both can brake or swerve
    /// ([`Against::Closing`]) are rejected ([`ProblemError::CannotAvoid`]).
    /// `None`: no such check.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_acceleration: Option<f64>,
    /// The robots' top speed (m/s), if known: kept by engines that hold it
    /// in their iteration ([`crate::am::AmSettings::limit_speed`]). `None`:
    /// plans are checked against a speed limit, if any, after the fact.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_speed: Option<f64>,
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
            start_recovery: None,
            max_acceleration: None,
            max_speed: None,
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
        let allowed = self.samples as f64 * Self::MOVE_PER_SAMPLE * self.separation().0;
        let factor = self.workspace_diagonal() / allowed;
        self.resolved_by(factor)
    }

    /// Samples per obstacle a straight crossing of the workspace's
    /// horizontal diagonal passes, for [`Team::resolved_for_obstacles`].
    pub const SAMPLES_PER_OBSTACLE: f64 = 13.0;

    /// This team with its degree and sample count raised for static
    /// obstacles spread over its workspace `pitch` apart (a pillar forest):
    /// a plan weaves around every obstacle it passes, so K is kept at
    /// least [`Team::SAMPLES_PER_OBSTACLE`] per obstacle a straight
    /// crossing of the horizontal diagonal passes, the degree raised in
    /// the same proportion (at most [`Team::MAX_RESOLVED_DEGREE`]). 2D
    /// pillar forests of 16 robots (pitch 0.48-0.68 m in a 2 m box) get
    /// degree 11-16 and K = 55-76, of 32 robots degree 16-20 and K = 78-100:
    /// at degree 10 and K = 50, 3 and 4 of 10 of the 32-robot forests
    /// verified (seeds 100 and 200), at this resolution 10 and 8; in 3D 3
    /// and 6, then 9 and 9
    /// (docs/experiments/2026-11-29-restarts-through-narrow-passages.md).
    pub fn resolved_for_obstacles(self, pitch: f64) -> Self {
        let (dx, dy) = (self.workspace.max.x - self.workspace.min.x, self.workspace.max.y - self.workspace.min.y);
        let passes = dx.hypot(dy) / pitch;
        let factor = passes * Self::SAMPLES_PER_OBSTACLE / self.samples as f64;
        self.resolved_by(factor)
    }

    /// The highest degree [`Team::resolved_for_workspace`] and
    /// [`Team::resolved_for_obstacles`] raise a team to: plans of 3D pillar
    /// forests at degree 22-23 (K = 109-114) missed the boundary conditions
    /// by 1.2-2.5e-6 (the success verdict allows 1e-6), at degree 17-21 by
    /// at most 3.5e-7.
    pub const MAX_RESOLVED_DEGREE: usize = 20;

    /// Degree and sample count both grown by `factor` (rounded up) where it
    /// is over 1, the degree to at most [`Team::MAX_RESOLVED_DEGREE`].
    fn resolved_by(self, factor: f64) -> Self {
        // NaN first: `min` would turn it into the cap.
        if factor.is_nan() {
            return self;
        }
        let factor = factor.min(Self::MAX_RESOLVED_DEGREE as f64 / self.degree as f64);
        if factor <= 1.0 {
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

    /// How far past the workspace box a robot may be and still count as
    /// inside it (m): [`FEASIBILITY_TOLERANCE`] of the horizontal
    /// separation.
    pub fn box_tolerance(&self) -> f64 {
        FEASIBILITY_TOLERANCE * self.separation().0
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
        if let Some(t) = self.start_recovery {
            positive(t, Field::StartRecovery, 0)?;
        }
        if let Some(a) = self.max_acceleration {
            positive(a, Field::MaxAcceleration, 0)?;
        }
        if let Some(v) = self.max_speed {
            positive(v, Field::MaxSpeed, 0)?;
        }
        for a in 0..self.dim.axes() {
            finite(self.workspace.min[a], Field::Workspace, 0)?;
            finite(self.workspace.max[a], Field::Workspace, 1)?;
            if self.workspace.max[a] <= self.workspace.min[a] {
                return Err(ProblemError::EmptyWorkspace { axis: a });
            }
        }
        Basis::check(self.degree, self.samples)?;
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
    scaled(dim, d, a, b).norm()
}

/// `diag(a, a, b)^-1 d` in `dim` axes (the third entry 0 in 2D).
pub(crate) fn scaled(dim: Dim, d: &Vector3<f64>, a: f64, b: f64) -> Vector3<f64> {
    Vector3::new(d.x / a, d.y / a, if dim == Dim::Three { d.z / b } else { 0.0 })
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

/// The depth and closing rate of a body at offset `d` from another (scaled
/// by `(a, a, b)`), at relative velocity `v`, if closer than tolerated.
fn overlap(dim: Dim, d: Vector3<f64>, v: Vector3<f64>, a: f64, b: f64) -> Option<(f64, f64)> {
    let (ds, vs) = (scaled(dim, &d, a, b), scaled(dim, &v, a, b));
    let d0 = ds.norm();
    (d0 < 1.0 - FEASIBILITY_TOLERANCE).then_some((1.0 - d0, closing::closing_rate(&ds, &vs)))
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

    /// Whether every robot starts at rest (speed and acceleration, [`AT_REST`]).
    pub fn at_rest(&self) -> bool {
        self.starts.iter().all(|s| s.velocity.norm() <= AT_REST && s.acceleration.norm() <= AT_REST)
    }

    /// Whether a plan can be stretched in time to bring its speed and
    /// acceleration within limits without changing what was verified: every
    /// robot at rest and every obstacle static (the paths, and so the
    /// clearances, stay). A plan from motion, or among moving obstacles,
    /// over the team's acceleration limit cannot be followed.
    pub fn stretchable(&self) -> bool {
        self.at_rest() && self.obstacles.iter().all(|o| o.velocity.norm() == 0.0)
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

    /// Every constraint the starts violate beyond [`FEASIBILITY_TOLERANCE`]:
    /// the box robot by robot (outside it, then, with
    /// [`Team::max_acceleration`], unable to stop inside it), robot pairs
    /// (overlapping, or, with [`Team::max_acceleration`] and without
    /// [`Team::start_recovery`], closing faster than both can brake or
    /// swerve, [`crate::closing`]), then obstacles. Allocates only
    /// when there is one.
    pub fn start_violations(&self) -> Vec<StartViolation> {
        self.each_start_violation().collect()
    }

    /// [`Self::start_violations`] one at a time, each found when asked for
    /// (a validation stops at the first: the pairs' programs,
    /// [`Self::unavoidable_pair`], are not solved after a box
    /// violation).
    fn each_start_violation(&self) -> impl Iterator<Item = StartViolation> + '_ {
        let team = &self.team;
        let (a, b) = team.separation();
        let slack = team.box_tolerance();
        let n = self.starts.len();
        let boxes = self
            .starts
            .iter()
            .enumerate()
            .filter(move |(_, s)| !team.workspace.contains(team.dim, &s.position, slack))
            .flat_map(move |(i, s)| {
                (0..team.dim.axes()).filter_map(move |axis| {
                    let (lo, hi, p, v) =
                        (team.workspace.min[axis], team.workspace.max[axis], s.position[axis], s.velocity[axis]);
                    (p < lo - slack || p > hi + slack).then(|| {
                        let upper = p > hi;
                        let (depth, closing) = if upper { (p - hi, v) } else { (lo - p, -v) };
                        let against = Against::Box { axis, upper };
                        StartViolation { robot: i, against, depth: depth / a, closing: closing.max(0.0) }
                    })
                })
            });
        let braking = self.braking_excesses().filter(|e| !e.tolerated).map(move |e| {
            let against = Against::Braking { axis: e.axis, upper: e.upper };
            let closing = self.starts[e.robot].velocity[e.axis].abs();
            StartViolation { robot: e.robot, against, depth: e.excess / a, closing }
        });
        // The verification's instants, from its first dense one on.
        let window = (team.horizon / (DENSE_FACTOR * team.samples - 1) as f64, team.horizon);
        let pairs = (0..n).flat_map(move |i| {
            (i + 1..n).filter_map(move |j| {
                let (si, sj) = (&self.starts[i], &self.starts[j]);
                let (d, w) = (si.position - sj.position, si.velocity - sj.velocity);
                if let Some((depth, closing)) = overlap(team.dim, d, w, a, b) {
                    return Some(StartViolation { robot: i, against: Against::Robot(j), depth, closing });
                }
                let touching = 1.0 - FEASIBILITY_TOLERANCE;
                let (most, at) = team
                    .max_acceleration
                    .filter(|_| team.start_recovery.is_none())
                    .and_then(|m| self.unavoidable_pair((i, j), m, window, touching))?;
                Some(StartViolation { robot: i, against: Against::Closing(j), depth: 1.0 - most, closing: at })
            })
        });
        let obstacles = self.obstacles.iter().enumerate().flat_map(move |(m, o)| {
            let (ao, bo) = team.obstacle_separation(&o.shape);
            self.starts.iter().enumerate().filter_map(move |(i, s)| {
                let (depth, closing) = overlap(team.dim, s.position - o.position, s.velocity - o.velocity, ao, bo)?;
                Some(StartViolation { robot: i, against: Against::Obstacle(m), depth, closing })
            })
        });
        boxes.chain(braking).chain(pairs).chain(obstacles)
    }

    /// Checks every input: counts, finiteness, sizes, overlaps and the
    /// workspace. Starts may be within [`FEASIBILITY_TOLERANCE`] of touching
    /// (they are measurements), or further in a team that recovers from
    /// such starts ([`Team::start_recovery`], [`crate::recovery`]); goals
    /// must be strictly clear.
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
        if let Some(v) = self.each_start_violation().find(|v| {
            team.start_recovery.is_none() || !v.recoverable(team.separation().0, team.horizon, team.max_acceleration)
        }) {
            return Err(v.error(team.separation().0));
        }
        for (i, g) in self.goals.iter().enumerate() {
            if !team.workspace.contains(dim, g, 0.0) {
                return Err(ProblemError::GoalOutsideWorkspace(i));
            }
        }
        for i in 0..n {
            for j in i + 1..n {
                let scaled = team.scaled_distance(&(self.goals[i] - self.goals[j]));
                if scaled < 1.0 {
                    return Err(ProblemError::GoalsOverlap { i, j, scaled });
                }
            }
        }
        for (m, o) in self.obstacles.iter().enumerate() {
            let (ao, bo) = team.obstacle_separation(&o.shape);
            for i in 0..n {
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
        // Past the highest degree the growth stops.
        let huge = Team { workspace: Workspace::centred(8.0), ..team.clone() }.resolved_for_workspace();
        assert_eq!((huge.degree, huge.samples), (Team::MAX_RESOLVED_DEGREE, 100));
        // A box with no size leaves the team as it is.
        let unsized_box = Team { workspace: Workspace::centred(f64::NAN), ..team.clone() };
        let kept = unsized_box.resolved_for_workspace();
        assert_eq!((kept.degree, kept.samples), (team.degree, team.samples));
    }

    #[test]
    fn obstacles_spread_over_the_workspace_raise_the_resolution_per_obstacle_passed() {
        let team = Team::default_for(Dim::Two, 16); // a 2 m box: 2.83 m across
        let at = |pitch: f64| {
            let t = team.clone().resolved_for_obstacles(pitch);
            (t.degree, t.samples)
        };
        // Sparse obstacles leave the default: 2.83 / 1.0 * 13 < 50.
        assert_eq!(at(1.0), (10, 50));
        // A forest 0.5 m apart: 5.66 obstacles passed, 73.5 samples.
        assert_eq!(at(0.5), (15, 74));
        // Dense ones stop at the highest degree.
        assert_eq!(at(0.2), (Team::MAX_RESOLVED_DEGREE, 100));
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
