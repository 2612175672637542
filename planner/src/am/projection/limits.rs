//! What one projection checks against: the separations (scaled), the
//! box, and the obstacles' centres at the grid's instants.

use super::grid::SampleGrid;
use crate::problem::Problem;

/// Sizes, box and obstacle tracks one projection checks against.
#[derive(Debug, Clone)]
pub struct Limits {
    /// Robot-robot separations per axis.
    pub(super) robot_sep: [f64; 3],
    /// Per obstacle: robot-obstacle separations per axis.
    pub(super) obstacle_sep: Vec<[f64; 3]>,
    /// Box per axis.
    pub(super) lo: [f64; 3],
    pub(super) hi: [f64; 3],
    /// Obstacle centres at the grid instants, `[obstacle][axis][count]`.
    pub(super) tracks: Vec<f64>,
    /// Per obstacle, the instants it is kept clear at: `0..until` (a moving
    /// obstacle's prediction ends, [`crate::problem::Team::obstacle_prediction`]).
    pub(super) until: Vec<usize>,
    /// Inflate each instant's separation by the chord to its neighbours.
    pub(super) chord: bool,
    /// Find the robot pairs to check by sweep-and-prune (large teams).
    pub(super) broad_phase: bool,
}

impl Limits {
    /// Robot-robot separations per axis (m).
    pub fn robot_separation(&self) -> [f64; 3] {
        self.robot_sep
    }

    /// Robot-obstacle separations per axis, per obstacle (m).
    pub fn obstacle_separations(&self) -> &[[f64; 3]] {
        &self.obstacle_sep
    }

    /// The box positions are clamped into, `(lower, upper)` per axis (m).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.lo, self.hi)
    }

    /// Obstacle centres at the grid's instants, `[obstacle][axis][sample]` (m).
    pub fn tracks(&self) -> &[f64] {
        &self.tracks
    }

    /// The limits of `problem` on `grid`: every separation scaled by
    /// `scale`, the box moved inwards by `inset` (per axis; negative grows it).
    pub(crate) fn new(problem: &Problem, grid: &SampleGrid, scale: f64, inset: [f64; 3]) -> Self {
        let times: Vec<f64> = grid.taus.iter().map(|tau| tau * problem.team.horizon).collect();
        Self::at_times(problem, &times, scale, inset)
    }

    /// The same limits with the obstacles tracked at `times` (seconds from
    /// the obstacles' reported positions), one per grid instant.
    pub(crate) fn at_times(problem: &Problem, times: &[f64], scale: f64, inset: [f64; 3]) -> Self {
        let team = &problem.team;
        let dim = team.dim.axes();
        let (a, b) = team.separation();
        let count = times.len();
        let mut tracks = vec![0.0; problem.obstacles.len() * dim * count];
        let mut obstacle_sep = Vec::with_capacity(problem.obstacles.len());
        let mut until = Vec::with_capacity(problem.obstacles.len());
        for (m, o) in problem.obstacles.iter().enumerate() {
            let predicted = team.predicted_until(&o.velocity);
            until.push(times.iter().take_while(|t| **t <= predicted).count());
            for ax in 0..dim {
                for (k, t) in times.iter().enumerate() {
                    tracks[(m * dim + ax) * count + k] = o.position[ax] + o.velocity[ax] * t;
                }
            }
            let (ao, bo) = team.obstacle_separation(&o.shape);
            obstacle_sep.push([ao * scale, ao * scale, bo * scale]);
        }
        Self {
            robot_sep: [a * scale, a * scale, b * scale],
            obstacle_sep,
            lo: [0, 1, 2].map(|ax| team.workspace.min[ax] + inset[ax]),
            hi: [0, 1, 2].map(|ax| team.workspace.max[ax] - inset[ax]),
            tracks,
            until,
            chord: false,
            broad_phase: false,
        }
    }

    /// The same limits checked with `chord` inflation (see [`Projection`])
    /// and, for teams of [`BROAD_PHASE_MIN_ROBOTS`] or more, with the
    /// `broad_phase`.
    pub(crate) fn with_rules(self, chord: bool, broad_phase: bool) -> Self {
        Self { chord, broad_phase, ..self }
    }
}
