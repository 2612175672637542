//! What the simulator counts, over the whole run and per fault window.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Counters of one window of a run.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Tally {
    /// Plan messages received.
    pub plans: u64,
    /// Messages by status (`Ok`, `Held`, `Stopping`, `NoPlan`).
    pub statuses: BTreeMap<String, u64>,
    /// Messages by reason (rejections and failures).
    pub reasons: BTreeMap<String, u64>,
    /// Robot-robot contacts begun on the executed motion (pairs closer than
    /// their separation, checked every integration substep).
    pub contacts: u64,
    /// Robot-obstacle contacts begun on the executed motion (a robot closer
    /// to an obstacle than their radii, every substep).
    pub obstacle_contacts: u64,
    /// Closest robot-robot distance over the separation (1 = touching);
    /// `None` before any motion.
    pub closest_approach: Option<f64>,
    /// Closest robot-obstacle distance over their separation; `None`
    /// without obstacles.
    pub closest_obstacle_approach: Option<f64>,
    /// Farthest any robot left the workspace (m; 0 inside).
    pub workspace_excess_m: f64,
    /// Plans taken up whose independent check failed: not collision-free
    /// on the dense grid, not starting where the robots were, or crossing
    /// an obstacle the controller had reported.
    pub followed_unverified: u64,
    /// Of those, the plans that cross a reported obstacle.
    pub followed_through_obstacle: u64,
    /// Answers published after their snapshot's deadline (from the
    /// daemon's receipt of the snapshot to its publication).
    pub late_answers: u64,
    /// The longest any answer took from receipt to publication (ms).
    pub answer_max_ms: f64,
    /// Longest stretch with no trajectory to follow (ms).
    pub longest_without_plan_ms: f64,
    /// Stops: stretches off a plan to the goals (on a stopping plan, or
    /// none), from the first plan on ([`super::stops`]).
    pub stops: u64,
    /// Stops in which the whole team came to rest with a robot off its
    /// goal before the next plan to the goals: the team stalled.
    pub halts: u64,
    /// The longest stop (ms).
    pub longest_stop_ms: f64,
    /// All stops together (ms).
    pub stopped_ms: f64,
    /// Bad snapshots injected.
    pub injected: u64,
    /// Injected snapshots whose answer was seen with the expected rejection
    /// reason.
    pub rejected_as_expected: u64,
}

impl Tally {
    /// Counts a message of `status` and `reason`.
    pub fn message(&mut self, status: &str, reason: Option<&str>) {
        self.plans += 1;
        *self.statuses.entry(status.to_string()).or_default() += 1;
        if let Some(r) = reason {
            *self.reasons.entry(r.to_string()).or_default() += 1;
        }
    }

    /// Records a period of motion: closest approaches and contacts begun.
    pub fn motion(&mut self, closest: f64, contacts: u64, closest_obstacle: f64, obstacle_contacts: u64) {
        self.closest_approach = Some(self.closest_approach.map_or(closest, |c| c.min(closest)));
        self.contacts += contacts;
        if closest_obstacle.is_finite() {
            let c = self.closest_obstacle_approach.map_or(closest_obstacle, |c| c.min(closest_obstacle));
            self.closest_obstacle_approach = Some(c);
        }
        self.obstacle_contacts += obstacle_contacts;
    }

    /// Records an answer that took `ms` from receipt to publication
    /// against a deadline of `deadline_ms`.
    pub fn answered_in(&mut self, ms: f64, deadline_ms: f64) {
        self.answer_max_ms = self.answer_max_ms.max(ms);
        self.late_answers += u64::from(ms > deadline_ms);
    }

    /// Records a stop that ended.
    pub fn stop(&mut self, ended: &super::stops::Ended) {
        let ms = ended.lasted_s * 1e3;
        self.stops += 1;
        self.halts += u64::from(ended.halted);
        self.longest_stop_ms = self.longest_stop_ms.max(ms);
        self.stopped_ms += ms;
    }

    /// Records a stretch without a trajectory to follow.
    pub fn without_plan(&mut self, ms: f64) {
        self.longest_without_plan_ms = self.longest_without_plan_ms.max(ms);
    }
}
