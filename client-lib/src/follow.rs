//! The followability contract on the controller's side: from the newest
//! plan message, which trajectory to follow now.
//!
//! A controller follows only answers to snapshots it published itself
//! (the `answers_sequence` and `state_timestamp_ns` of one of its recent
//! snapshots, [`Sent`]): never the answer to another process's snapshot,
//! nor the message a service kept for late joiners. Among those, a message
//! whose status is followable ([`PlanStatus::Ok`], `Held`, `Stopping`)
//! carries a trajectory the daemon verified, with its own time origin; it
//! replaces whatever was followed before. Any other message
//! ([`PlanStatus::NoPlan`], or one that cannot be read) leaves nothing to
//! follow: the controller brings its robots to rest by its own means.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::rc::Rc;

use flowopt_planner::plan::{JointPlan, Kinematics};

use crate::messages::{JointTrajectory, MessageError, PlanStatus};

/// Snapshots a controller remembers having published, to recognise the
/// answers to them: at 1 kHz, the last second.
pub const SENT_REMEMBERED: usize = 1024;

/// The snapshots a controller published most recently, by sequence and
/// timestamp: its [`crate::ports::StatePublisher`] records them, its plan
/// subscriber's [`Follower`] reads them (one thread: ports are not `Send`).
#[derive(Debug, Clone, Default)]
pub struct Sent(Rc<RefCell<VecDeque<(u64, u64)>>>);

impl Sent {
    /// Remembers a published snapshot (forgetting the oldest beyond
    /// [`SENT_REMEMBERED`]).
    pub fn record(&self, sequence: u64, timestamp_ns: u64) {
        let mut sent = self.0.borrow_mut();
        if sent.len() == SENT_REMEMBERED {
            sent.pop_front();
        }
        sent.push_back((sequence, timestamp_ns));
    }

    /// Whether the snapshot of `sequence` stamped `timestamp_ns` is one of
    /// the remembered ones.
    pub fn contains(&self, sequence: u64, timestamp_ns: u64) -> bool {
        self.0.borrow().iter().rev().any(|&s| s == (sequence, timestamp_ns))
    }
}

/// A verified trajectory taken from a plan message.
#[derive(Debug, Clone, PartialEq)]
pub struct Followed {
    /// The plan.
    pub plan: JointPlan,
    /// Its time origin ([`crate::clock::monotonic_ns`]).
    pub origin_ns: u64,
    /// The snapshot it was made from.
    pub plan_sequence: u64,
    /// Why it is followed: a new plan, a held one or a stopping plan.
    pub status: PlanStatus,
}

impl Followed {
    /// Every robot's position, velocity and acceleration at `now_ns`
    /// (clamped to the plan: before it the start, after it the goal at rest).
    pub fn at(&self, now_ns: u64) -> Vec<Kinematics> {
        self.plan.at((now_ns as i128 - self.origin_ns as i128) as f64 * 1e-9)
    }
}

/// What a controller follows, kept from the plan messages it takes.
#[derive(Debug, Clone, Default)]
pub struct Follower {
    current: Option<Followed>,
    /// The controller's own snapshots; `None`: a watcher, which follows
    /// nothing.
    sent: Option<Sent>,
}

impl Follower {
    /// A watcher's: nothing is ever followed.
    pub fn watcher() -> Self {
        Self::default()
    }

    /// A controller's: follows answers to the snapshots in `sent` only.
    pub fn answering(sent: Sent) -> Self {
        Self { current: None, sent: Some(sent) }
    }

    /// Takes the newest plan message. An answer to another snapshot than
    /// this controller's own changes nothing. Otherwise a followable
    /// message becomes the trajectory to follow and any other leaves none;
    /// a message that cannot be read leaves none too, and its error is
    /// returned.
    pub fn take(&mut self, msg: &JointTrajectory) -> Result<(), MessageError> {
        if !self.sent.as_ref().is_some_and(|s| s.contains(msg.answers_sequence, msg.state_timestamp_ns)) {
            return Ok(());
        }
        self.current = None;
        let status = msg.status()?;
        if status.followable() {
            self.current = Some(Followed {
                plan: msg.plan()?,
                origin_ns: msg.plan_origin_ns,
                plan_sequence: msg.plan_sequence,
                status,
            });
        }
        Ok(())
    }

    /// The trajectory to follow now, or `None`: bring the robots to rest.
    pub fn current(&self) -> Option<&Followed> {
        self.current.as_ref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::{Dim, Team};

    fn message(status: PlanStatus) -> JointTrajectory {
        let team = Team::default_for(Dim::Two, 2);
        let coeffs = (0..2 * 2 * (team.degree + 1)).map(|k| k as f64 * 1e-2).collect();
        let mut msg = JointTrajectory::new();
        msg.set_status(status);
        msg.write_plan(&JointPlan::new(&team, coeffs)).unwrap();
        msg.plan_origin_ns = 1_000_000_000;
        msg.plan_sequence = 7;
        msg.answers_sequence = 9;
        msg.state_timestamp_ns = 2_000_000_000;
        msg
    }

    fn controller() -> Follower {
        let sent = Sent::default();
        sent.record(9, 2_000_000_000);
        Follower::answering(sent)
    }

    #[test]
    fn followable_messages_replace_the_trajectory_and_others_leave_none() {
        let mut follower = controller();
        assert!(follower.current().is_none());
        for status in [PlanStatus::Ok, PlanStatus::Held, PlanStatus::Stopping] {
            follower.take(&message(status)).unwrap();
            let followed = follower.current().unwrap();
            assert_eq!((followed.status, followed.origin_ns, followed.plan_sequence), (status, 1_000_000_000, 7));
            // Evaluated against its own origin: 0.5 s after it.
            assert_eq!(followed.at(1_500_000_000), followed.plan.at(0.5));
        }
        // A no-plan message leaves nothing to follow, even with coefficients.
        follower.take(&message(PlanStatus::NoPlan)).unwrap();
        assert!(follower.current().is_none());
        // So does a message that cannot be read.
        follower.take(&message(PlanStatus::Ok)).unwrap();
        let mut bad = message(PlanStatus::Ok);
        bad.status = 77;
        assert!(follower.take(&bad).is_err());
        assert!(follower.current().is_none());
    }

    #[test]
    fn only_answers_to_the_controllers_own_snapshots_are_followed() {
        let mut follower = controller();
        // Another controller's snapshot: the same sequence at another time,
        // or another sequence at the same time.
        for (sequence, timestamp) in [(9, 2_000_000_001), (8, 2_000_000_000)] {
            let mut other = message(PlanStatus::Ok);
            (other.answers_sequence, other.state_timestamp_ns) = (sequence, timestamp);
            follower.take(&other).unwrap();
            assert!(follower.current().is_none(), "answer to ({sequence}, {timestamp})");
        }
        follower.take(&message(PlanStatus::Held)).unwrap();
        assert_eq!(follower.current().map(|f| f.status), Some(PlanStatus::Held));
        // Someone else's no-plan answer changes nothing either.
        let mut other = message(PlanStatus::NoPlan);
        other.answers_sequence = 8;
        follower.take(&other).unwrap();
        assert!(follower.current().is_some());
        // A watcher follows nothing.
        let mut watcher = Follower::watcher();
        watcher.take(&message(PlanStatus::Ok)).unwrap();
        assert!(watcher.current().is_none());
    }

    #[test]
    fn a_controller_remembers_its_last_snapshots() {
        let sent = Sent::default();
        for k in 0..SENT_REMEMBERED as u64 + 1 {
            sent.record(k, 1000 + k);
        }
        assert!(!sent.contains(0, 1000), "the oldest is forgotten");
        assert!(sent.contains(1, 1001) && sent.contains(SENT_REMEMBERED as u64, 1000 + SENT_REMEMBERED as u64));
    }
}
