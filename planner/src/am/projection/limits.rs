//! What one projection checks against: the separations (scaled), the
//! box, and the obstacles' centres at the grid's instants.

use super::grid::SampleGrid;
use crate::problem::Against;
use crate::problem::Problem;
use crate::recovery::{Recovery, Violation, box_bounds};

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
    /// obstacle's prediction ends, [`crate::problem::Team::obstacle_prediction`]),
    /// the first instant past the prediction's end included, so that the
    /// constrained instants cover the whole prediction (without it, the
    /// dense verification refused the 64-robot lab's warm replans near a
    /// walker's prediction end at a primal residual of 0: `Ok` 77.5% ->
    /// 99.3% in a 40 s run, docs/experiments/2026-11-28-moving-obstacles-to-the-prediction-end.md).
    pub(super) until: Vec<usize>,
    /// Inflate each instant's separation by the chord to its neighbours.
    pub(super) chord: bool,
    /// Find the robot pairs to check by sweep-and-prune (large teams).
    pub(super) broad_phase: bool,
    /// The start's violations with their floors on this grid (a side of
    /// the box moved by its inset; empty without any).
    pub(super) floors: Vec<Violation>,
    /// The instants `0..floors_until` the floors hold at.
    pub(super) floors_until: usize,
    /// Per robot, whether it is in a pair with a floor (empty without any).
    pub(super) pair_floors: Vec<bool>,
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
            until.push((times.iter().take_while(|t| **t <= predicted).count() + 1).min(count));
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
            floors: Vec::new(),
            floors_until: 0,
            pair_floors: Vec::new(),
        }
    }

    /// The same limits with the floors of `recovery` (the start violations
    /// of `problem`) at `grid`'s instants ([`crate::recovery`]; none
    /// without any). A side of the box keeps this limit's inset from its
    /// floor, as from the box, but no more than the floor's slack
    /// ([`Violation::slack`]): further inside, no plan the robot can follow
    /// keeps to the limit.
    pub(crate) fn with_recovery(mut self, problem: &Problem, recovery: &Recovery, grid: &SampleGrid) -> Self {
        if recovery.violations.is_empty() || recovery.until <= 0.0 {
            return self;
        }
        self.floors_until = grid.taus.iter().take_while(|tau| **tau * problem.team.horizon < recovery.until).count();
        let inset = |axis: usize| self.lo[axis] - problem.team.workspace.min[axis];
        self.floors = recovery
            .violations
            .iter()
            .map(|v| {
                let floor = match v.against.side() {
                    Some((axis, true)) => v.floor - inset(axis).min(v.slack),
                    Some((axis, false)) => v.floor + inset(axis).min(v.slack),
                    None => v.floor,
                };
                Violation { floor, ..*v }
            })
            .collect();
        if recovery.violations.iter().any(|v| matches!(v.against, Against::Robot(_))) {
            self.pair_floors = vec![false; problem.team.robots];
            for v in &recovery.violations {
                if let Against::Robot(j) = v.against {
                    (self.pair_floors[v.robot], self.pair_floors[j]) = (true, true);
                }
            }
        }
        self
    }

    /// Whether robots `i` and `j` have a floor (and are checked against it
    /// with the obstacles, skipped among the candidate pairs).
    #[inline(always)]
    pub(super) fn pair_has_floor(&self, i: usize, j: usize) -> bool {
        !self.pair_floors.is_empty()
            && self.pair_floors[i]
            && self.pair_floors[j]
            && self.floors.iter().any(|f| f.robot == i.min(j) && f.against == Against::Robot(i.max(j)))
    }

    /// Whether robot `i` has a floor against obstacle `m`.
    pub(super) fn obstacle_has_floor(&self, i: usize, m: usize) -> bool {
        self.floors.iter().any(|f| f.robot == i && f.against == Against::Obstacle(m))
    }

    /// Robot `i`'s box on `axis` at the first [`Self::floors_until`]
    /// instants, if it recovers from outside the box there.
    pub(super) fn box_floor(&self, i: usize, axis: usize) -> Option<(f64, f64)> {
        box_bounds(&self.floors, i, axis, (self.lo[axis], self.hi[axis]))
    }

    /// The same limits checked with `chord` inflation (see [`Projection`])
    /// and, for teams of [`BROAD_PHASE_MIN_ROBOTS`] or more, with the
    /// `broad_phase`.
    pub(crate) fn with_rules(self, chord: bool, broad_phase: bool) -> Self {
        Self { chord, broad_phase, ..self }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::problem::{Dim, Obstacle, Spheroid, Team};
    use crate::scenario::RandomScenario;

    #[test]
    fn a_moving_obstacle_is_kept_clear_up_to_the_first_instant_past_its_prediction() {
        let team = Team { obstacle_prediction: Some(1.2), ..Team::default_for(Dim::Two, 2) };
        let mut problem = RandomScenario::new(team).generate(0).unwrap();
        let walker = |v: f64| Obstacle {
            position: Vector3::new(0.0, 0.9, 0.0),
            velocity: Vector3::new(v, 0.0, 0.0),
            shape: Spheroid::ball(0.1),
        };
        problem.obstacles = vec![walker(0.5), walker(0.0)];
        let times = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5];
        let limits = Limits::at_times(&problem, &times, 1.0, [0.0; 3]);
        // 0, 0.5 and 1.0 within the prediction, and 1.5 past its end; a
        // static obstacle at every instant.
        assert_eq!(limits.until, [4, 6]);
        // A prediction past the grid's last instant: no instant beyond it.
        let longer = Team { obstacle_prediction: Some(3.0), ..problem.team.clone() };
        let limits = Limits::at_times(&Problem { team: longer, ..problem }, &times, 1.0, [0.0; 3]);
        assert_eq!(limits.until, [6, 6], "no instant past the grid");
    }
}
