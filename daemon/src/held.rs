//! The plans the contract is about: the held plan (what the controllers
//! follow), a verified candidate not yet published, and the newest world
//! they are checked against.

use flowopt_planner::metrics::DENSE_FACTOR;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::Problem;
use nalgebra::Vector3;

use crate::answer::Kind;

/// Goals closer than this (m) count as unchanged.
const SAME_GOAL: f64 = 1e-9;

/// The last verified plan published: what the controllers follow.
#[derive(Debug, Clone)]
pub struct Held {
    /// The plan.
    pub plan: JointPlan,
    /// Its time origin (ns, the clock of the snapshots).
    pub origin_ns: u64,
    /// The snapshot it was made from.
    pub sequence: u64,
    /// To the goals, or to rest.
    pub kind: Kind,
    /// Its primal residual (m).
    pub primal: f64,
    /// Its smoothness.
    pub smoothness: f64,
    /// Its largest speed (m/s).
    pub max_speed: f64,
    /// Its largest acceleration (m/s^2).
    pub max_acceleration: f64,
    pub(crate) goals: Vec<Vector3<f64>>,
}

impl Held {
    /// How far (m) the robots of `problem`, measured at `origin_ns`, are from
    /// this plan.
    pub(crate) fn deviation(&self, problem: &Problem, origin_ns: u64) -> f64 {
        self.plan.deviation(seconds(self.origin_ns, origin_ns), &problem.starts)
    }

    /// `world` with each robot measured within `tolerance` (m) of this
    /// plan where the plan has it at its time (position, velocity and
    /// acceleration), the others as measured: the start of a plan that
    /// takes over from this one. A robot that follows it (within the follow
    /// tolerance, which every plan is verified to keep) then joins the new
    /// plan without a jump; started from the measurement instead, it would
    /// start off this one by the tracking error and the mocap noise, and,
    /// tracking this one while the new one is made, leave its start by up
    /// to twice that. One robot knocked off the plan (a gust at 64 robots,
    /// every half second) leaves every other robot on it, so that a warm
    /// replan has one robot to move, not the whole team.
    pub(crate) fn anchored(&self, world: &World, tolerance: f64) -> World {
        let mut problem = world.problem.clone();
        let elapsed = seconds(self.origin_ns, world.origin_ns).max(0.0);
        for (s, k) in problem.starts.iter_mut().zip(self.plan.at(elapsed)) {
            if k.deviation(s) <= tolerance {
                *s = k.into();
            }
        }
        World { problem, ..world.clone() }
    }
}

/// Seconds from `from_ns` to `to_ns` (negative if earlier).
pub(crate) fn seconds(from_ns: u64, to_ns: u64) -> f64 {
    (to_ns as i128 - from_ns as i128) as f64 * 1e-9
}

/// Whether `goals` are `problem`'s goals.
pub(crate) fn same_goals(goals: &[Vector3<f64>], problem: &Problem) -> bool {
    goals.len() == problem.goals.len() && goals.iter().zip(&problem.goals).all(|(a, b)| (a - b).norm() <= SAME_GOAL)
}

impl Held {
    /// The held plan `candidate` becomes (of a team planned at `samples`
    /// samples).
    pub(crate) fn of(candidate: Candidate, kind: Kind, samples: usize) -> Held {
        let (max_speed, max_acceleration) = candidate.plan.peak_rates(DENSE_FACTOR * samples);
        let smoothness = candidate.plan.smoothness(samples);
        Held {
            smoothness,
            max_speed,
            max_acceleration,
            origin_ns: candidate.origin_ns,
            sequence: candidate.sequence,
            kind,
            primal: candidate.primal,
            goals: candidate.problem.goals,
            plan: candidate.plan,
        }
    }
}

/// A verified plan made from some state, not yet published.
#[derive(Debug, Clone)]
pub(crate) struct Candidate {
    /// The plan.
    pub(crate) plan: JointPlan,
    /// The problem it starts from (with the start accelerations it has).
    pub(crate) problem: Problem,
    /// Its time origin: the measurement it starts from.
    pub(crate) origin_ns: u64,
    /// That measurement's snapshot.
    pub(crate) sequence: u64,
    /// Its primal residual (m).
    pub(crate) primal: f64,
}

/// The newest accepted measurement: every followable answer is checked
/// against it.
#[derive(Debug, Clone)]
pub(crate) struct World {
    /// The robots, their goals (which may not be plannable) and the obstacles.
    pub(crate) problem: Problem,
    /// When it was measured.
    pub(crate) origin_ns: u64,
    /// Its snapshot.
    pub(crate) sequence: u64,
}
