//! What one answer says: what the controllers are to follow ([`Follow`]),
//! why it is not a new plan ([`Why`]), and what it cost ([`Answer`]).

use flowopt_planner::method::Stages;

/// What the controllers are to follow after an answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Follow {
    /// A new verified plan (now the held plan).
    New,
    /// The held plan, re-issued unchanged.
    Held,
    /// A new verified stopping plan (now the held plan).
    Stopping,
    /// Nothing: there is no verified trajectory.
    Nothing,
}

/// Why an answer is not a new plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Why {
    /// It is one.
    None,
    /// No plan verified within the deadline.
    DeadlineMissed,
    /// The planners' plans did not verify.
    NotVerified,
    /// The robots had left the held plan.
    NotFollowing,
    /// The verified plan exceeds the speed or acceleration limits.
    Limits,
    /// The held plan no longer clears the newest snapshot's obstacles.
    WorldChanged,
}

/// What kind of plan is held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A plan to the goals.
    Goals,
    /// A plan bringing the robots to rest.
    Stopping,
}

/// What one snapshot (or a late cold plan) produced.
#[derive(Debug, Clone, PartialEq)]
pub struct Answer {
    /// What to follow: for `New`, `Held` and `Stopping`, [`TeamPlanner::held`].
    pub follow: Follow,
    /// Why it is not a new plan.
    pub why: Why,
    /// Iterations spent on this answer.
    pub iterations: usize,
    /// Whether the new plan came from the warm start.
    pub warm: bool,
    /// Candidates refined for it.
    pub candidates: usize,
    /// Stage times of this answer.
    pub stages: Stages,
    /// The cold planner whose plan this answer adopted (`None`: no cold
    /// plan was adopted).
    pub by: Option<&'static str>,
}

impl Answer {
    /// An answer saying `follow` for `why`, with nothing spent yet.
    pub(crate) fn new(follow: Follow, why: Why) -> Self {
        Self { follow, why, iterations: 0, warm: false, candidates: 0, stages: Stages::default(), by: None }
    }
}
