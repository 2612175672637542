//! The followability contract on the controller's side: from the newest
//! plan message, which trajectory to follow now.
//!
//! A message whose status is followable ([`PlanStatus::Ok`], `Held`,
//! `Stopping`) carries a trajectory the daemon verified, with its own time
//! origin; it replaces whatever was followed before. Any other message
//! ([`PlanStatus::NoPlan`], or one that cannot be read) leaves nothing to
//! follow: the controller brings its robots to rest by its own means.

use flowopt_planner::plan::{JointPlan, Kinematics};

use crate::messages::{JointTrajectory, MessageError, PlanStatus};

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
    /// Messages answering snapshots measured before this are ignored.
    since_ns: u64,
}

impl Follower {
    /// Nothing to follow yet; every message counts.
    pub fn new() -> Self {
        Self::default()
    }

    /// Nothing to follow yet; messages answering snapshots measured before
    /// `since_ns` are ignored: a (re)started controller follows only
    /// answers to its own time, not the last message a service kept for
    /// late joiners (whose plan its robots may have left meanwhile).
    pub fn since(since_ns: u64) -> Self {
        Self { current: None, since_ns }
    }

    /// Takes the newest plan message: a followable one becomes the
    /// trajectory to follow, any other leaves none. A message that cannot be
    /// read leaves none too, and its error is returned. A message older
    /// than the follower ([`Follower::since`]) changes nothing.
    pub fn take(&mut self, msg: &JointTrajectory) -> Result<(), MessageError> {
        if msg.state_timestamp_ns < self.since_ns {
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
        msg
    }

    #[test]
    fn followable_messages_replace_the_trajectory_and_others_leave_none() {
        let mut follower = Follower::new();
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
    fn a_follower_ignores_answers_from_before_its_time() {
        let mut follower = Follower::since(2_000_000_000);
        let mut old = message(PlanStatus::Ok);
        old.state_timestamp_ns = 1_999_999_999;
        follower.take(&old).unwrap();
        assert!(follower.current().is_none(), "the message a service kept for late joiners");
        let mut new = message(PlanStatus::Held);
        new.state_timestamp_ns = 2_000_000_000;
        follower.take(&new).unwrap();
        assert_eq!(follower.current().map(|f| f.status), Some(PlanStatus::Held));
        follower.take(&old).unwrap();
        assert!(follower.current().is_some(), "an older message changes nothing");
    }
}
