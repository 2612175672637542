//! What the simulator counts, over the whole run and per fault window.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Counters of one window of a run.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Tally {
    /// Plan messages received.
    pub plans: u64,
    /// Messages by status (`ok`, `held`, `stopping`, `no_plan`).
    pub statuses: BTreeMap<String, u64>,
    /// Messages by reason (rejections and failures).
    pub reasons: BTreeMap<String, u64>,
    /// Robot-robot contacts begun on the executed motion (pairs closer than
    /// their separation, checked every integration substep).
    pub contacts: u64,
    /// Closest robot-robot distance over the separation (1 = touching);
    /// `None` before any motion.
    pub closest_approach: Option<f64>,
    /// Farthest any robot left the workspace (m; 0 inside).
    pub workspace_excess_m: f64,
    /// Plans taken up whose independent check failed: not collision-free
    /// on the dense grid, or not starting where the robots were.
    pub followed_unverified: u64,
    /// Longest stretch with no trajectory to follow (ms).
    pub longest_without_plan_ms: f64,
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

    /// Records a robot-robot distance (scaled) and whether a contact began.
    pub fn distance(&mut self, scaled: f64, contact_began: bool) {
        self.closest_approach = Some(self.closest_approach.map_or(scaled, |c| c.min(scaled)));
        self.contacts += u64::from(contact_began);
    }

    /// Records a stretch without a trajectory to follow.
    pub fn without_plan(&mut self, ms: f64) {
        self.longest_without_plan_ms = self.longest_without_plan_ms.max(ms);
    }
}
