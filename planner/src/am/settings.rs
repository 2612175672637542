//! Penalty schedule, stopping rules and the other knobs of an AM run.

use serde::{Deserialize, Serialize};

/// Penalty schedule: `rho_l = min(max, initial * factor^(l / every))`,
/// with stages of `big_team_every` iterations instead for teams of more than
/// `big_team` robots ([`Self::for_team`]; the engine resolves it).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RhoSchedule {
    /// Penalty at iteration 0.
    pub initial: f64,
    /// Growth factor per stage (1 = constant).
    pub factor: f64,
    /// Iterations per stage.
    pub every: usize,
    /// Ceiling.
    pub max: f64,
    /// Teams of more than this many robots use `big_team_every` (0: every
    /// team uses `every`).
    #[serde(default)]
    pub big_team: usize,
    /// Iterations per stage for teams of more than `big_team` robots.
    #[serde(default)]
    pub big_team_every: usize,
}

impl RhoSchedule {
    /// A constant penalty.
    pub fn constant(rho: f64) -> Self {
        Self { initial: rho, factor: 1.0, every: usize::MAX, max: rho, big_team: 0, big_team_every: 0 }
    }

    /// The schedule a team of `robots` runs: stages of `big_team_every`
    /// iterations for a team of more than `big_team` robots, else `every`.
    pub fn for_team(self, robots: usize) -> Self {
        if self.big_team > 0 && robots > self.big_team { Self { every: self.big_team_every, ..self } } else { self }
    }

    /// The distinct penalty values, in order (at most 64).
    pub fn levels(&self) -> Vec<f64> {
        let mut levels = vec![self.initial.min(self.max)];
        if self.factor > 1.0 && self.every > 0 {
            while let Some(&last) = levels.last() {
                if last >= self.max || levels.len() >= 64 {
                    break;
                }
                levels.push((last * self.factor).min(self.max));
            }
        }
        levels
    }

    /// Index into [`Self::levels`] (of length `count`) used at iteration `l`.
    pub fn level_at(&self, l: usize, count: usize) -> usize {
        if self.every == 0 || self.every == usize::MAX {
            return 0;
        }
        (l / self.every).min(count - 1)
    }
}

/// Stopping rules, penalty schedule, safety margin and starts.
///
/// Without dense verification (`verify_every = 0`, the paper's rule) a run
/// stops when the primal residual (inflated sizes, at the K samples) is at or
/// below `tolerance` ([`Stop::Tolerance`]).
///
/// With it, the iterate is checked on the dense re-sampling of
/// [`crate::metrics::Metrics`] against the true sizes and box, with no
/// overlap allowed (stricter than the success verdict's tolerance), every
/// `verify_every` iterations once the primal residual is at or below
/// `verify_below`, and whenever it is at or below `tolerance`; the run stops
/// when the check passes ([`Stop::Verified`]). A plan that meets the samples
/// but dips between them keeps iterating.
///
/// Either way `max_iterations` ends the run ([`Stop::IterationCap`], after a
/// last verification).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmSettings {
    /// Penalty schedule.
    pub rho: RhoSchedule,
    /// Stop when the primal residual is at or below this (m).
    pub tolerance: f64,
    /// Iteration cap (shared by all attempts of a restarted solve).
    pub max_iterations: usize,
    /// Relative inflation of every separation (and shrinking of the box by
    /// `margin` robot radii) used by the constraints.
    pub margin: f64,
    /// Verify on the dense grid every this many iterations (0: never).
    pub verify_every: usize,
    /// Only verify once the primal residual is at or below this (m).
    pub verify_below: f64,
    /// Optimiser only: further attempts from perturbed cold starts when an
    /// attempt hits its share of the iteration cap (fewer for big teams:
    /// `Engine::attempts`).
    pub restarts: usize,
    /// Optimiser only, where its cold start routed robots around static
    /// obstacles: an attempt ends once its primal residual has not fallen
    /// by [`super::STALL_PROGRESS`] for this many iterations (or
    /// [`super::ATTEMPT_ITERATIONS_PER_ROBOT`] per robot, whichever is
    /// more), and the next starts from the routes with each routed robot
    /// passing its route's narrowest point at another seeded time
    /// (`am/passages.rs`); attempts go on while the iteration cap lasts,
    /// in place of `restarts`' fixed shares. 0: off (docs/ENGINE.md,
    /// "Restarts through narrow passages").
    #[serde(default)]
    pub stall: usize,
    /// Optimiser only: start a robot whose straight segment crosses a static
    /// obstacle from a route around the obstacles ([`crate::route`]) instead
    /// of the smoothest curve (the paper's cold start).
    pub routed_start: bool,
    /// Record the per-iteration residuals.
    pub record_history: bool,
    /// Relative inflation of every separation in the dense verification
    /// (0: the true sizes). A buffer for robots that track plans imperfectly.
    #[serde(default)]
    pub verify_margin: f64,
    /// Dense instants right after the start held only to the success
    /// verdict's tolerance (1% of the separation) instead of the buffered
    /// true sizes: a measured start can be in near-contact, and with a
    /// `verify_margin` it could not be verified at the very next instants.
    #[serde(default)]
    pub verify_skip: usize,
    /// Inflate each instant's separation (constraints and verification) by
    /// the chord to its neighbouring instants, so that the straight motion
    /// between instants clears it too, however long or fast the paths
    /// (`false`: the fixed `margin` alone, which fast pairs of big
    /// workspaces dip through between samples).
    #[serde(default)]
    pub chord: bool,
    /// Check only the robot pairs a sweep-and-prune over per-segment
    /// bounding boxes finds (teams of 24 or more; the same iteration as all
    /// pairs, in near-linear time).
    #[serde(default)]
    pub broad_phase: bool,
    /// Optimiser only: robots whose straight segments meet head-on start
    /// veering to the same side (`Engine`'s cold start; breaks the deadlock
    /// of symmetric scenes such as antipodal swaps).
    #[serde(default)]
    pub veer: bool,
    /// Cut each of the [`super::engine::START_INTERVALS`] intervals after
    /// the first constrained sample into this many (0 and 1: the even grid;
    /// at most [`super::engine::MAX_START_REFINE`]): a plan from motion
    /// turns hardest right after its start, and between two even samples
    /// it can leave the box the samples keep it in.
    #[serde(default)]
    pub start_refine: usize,
    /// Threads a run of a team of [`super::CREW_MIN_ROBOTS`] robots or more
    /// iterates on (0 and 1: the calling thread alone), the calling one
    /// among them: the same iterates, bit for bit, for every count. Not a
    /// settings key of its own: the planner settings' `threads` sets it.
    #[serde(skip)]
    pub threads: usize,
    /// Keep each robot's acceleration within the team's `max_acceleration`
    /// (where it has one) at every constrained instant, and verify it on
    /// the dense grid after the start ([`super::rates`]; a run that does
    /// not verify, `verify_every` 0, only keeps it to its tolerance);
    /// `false`: plans are checked against the limit after the fact.
    #[serde(default)]
    pub limit_acceleration: bool,
    /// Keep each robot's speed within the team's `max_speed` (where it has
    /// one) in the same way as [`Self::limit_acceleration`] keeps its
    /// acceleration.
    #[serde(default)]
    pub limit_speed: bool,
}

impl AmSettings {
    /// Defaults for the from-scratch optimiser. The penalty doubles every 25
    /// iterations up to 100 for teams of up to 32 robots, every 50 for
    /// bigger ones. Plans from motion end just after the penalty reaches its
    /// top: doubling every 25 instead of 50 took the median of 16 robots
    /// starting at up to 1.0 m/s from 390 to 240 iterations, and from rest
    /// 0-30% fewer up to 32 robots, verified as often, random and moving
    /// teams as smooth within 5% (clutter 8-37% rougher). Bigger teams keep
    /// 50: at 64 robots it saved iterations but plans were 15-36% less
    /// smooth, at 128 it took more (from motion 520 -> 590) and one
    /// 256-robot crowd twice as many
    /// (docs/experiments/2026-11-28-penalty-schedule-by-team-size.md).
    pub fn optimiser() -> Self {
        Self {
            rho: RhoSchedule { initial: 1.0, factor: 2.0, every: 25, max: 100.0, big_team: 32, big_team_every: 50 },
            tolerance: 0.01,
            max_iterations: 10_000,
            margin: 0.05,
            verify_every: 10,
            verify_below: 0.1,
            restarts: 3,
            stall: 300,
            routed_start: true,
            record_history: false,
            verify_margin: 0.0,
            verify_skip: 0,
            chord: true,
            broad_phase: true,
            veer: true,
            start_refine: 4,
            threads: 0,
            limit_acceleration: false,
            limit_speed: false,
        }
    }

    /// Defaults for the safety filter. The penalty starts at 5 and doubles
    /// every 25 iterations up to 80: a sample far inside an obstacle is
    /// pulled back towards it by the cost, and a constant penalty let the
    /// multiplier grow too slowly to win (16 robots, 8 obstacles, rerouted
    /// flow samples, 16 candidates, top 4: 85% success at a constant 5, 97%
    /// with this schedule; docs/LEARNED.md).
    pub fn safety_filter() -> Self {
        Self {
            rho: RhoSchedule { initial: 5.0, factor: 2.0, every: 25, max: 80.0, big_team: 0, big_team_every: 0 },
            tolerance: 0.01,
            max_iterations: 500,
            margin: 0.05,
            verify_every: 10,
            verify_below: 0.1,
            restarts: 0,
            stall: 0,
            routed_start: false,
            record_history: false,
            verify_margin: 0.0,
            verify_skip: 0,
            chord: true,
            broad_phase: true,
            veer: false,
            start_refine: 1,
            threads: 0,
            limit_acceleration: false,
            limit_speed: false,
        }
    }

    /// The same settings run to a fixed primal tolerance with no dense
    /// verification and no restarts: for residual-decay studies.
    pub fn residual_study(mut self, tolerance: f64) -> Self {
        self.tolerance = tolerance;
        self.verify_every = 0;
        self.restarts = 0;
        self.stall = 0;
        self.record_history = true;
        self
    }
}

/// Why a run stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Stop {
    /// The primal residual reached the tolerance.
    Tolerance,
    /// The iterate passed the dense verification at the true sizes.
    Verified,
    /// The iteration cap was hit without either.
    IterationCap,
    /// The caller's deadline passed first.
    Deadline,
    /// The caller cancelled the run.
    Cancelled,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_levels_grow_to_the_ceiling() {
        let s = RhoSchedule { initial: 1.0, factor: 2.0, every: 100, max: 10.0, big_team: 0, big_team_every: 0 };
        assert_eq!(s.levels(), vec![1.0, 2.0, 4.0, 8.0, 10.0]);
        assert_eq!(s.level_at(0, 5), 0);
        assert_eq!(s.level_at(250, 5), 2);
        assert_eq!(s.level_at(10_000, 5), 4);
        assert_eq!(RhoSchedule::constant(3.0).levels(), vec![3.0]);
        assert_eq!(RhoSchedule::constant(3.0).level_at(1_000_000, 1), 0);
    }

    #[test]
    fn teams_of_more_than_big_team_robots_step_at_their_own_pace() {
        let s = AmSettings::optimiser().rho;
        assert_eq!([s.for_team(16).every, s.for_team(32).every], [25, 25]);
        assert_eq!([s.for_team(33).every, s.for_team(256).every], [50, 50]);
        let one = RhoSchedule { big_team: 0, ..s };
        assert_eq!(one.for_team(256).every, 25, "big_team 0: one pace for every team");
        assert_eq!(s.for_team(256).levels(), s.levels(), "the same penalties, reached at another pace");
    }
}
