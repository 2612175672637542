//! Stops: stretches in which the team is not on a plan to its goals (it
//! follows a stopping plan, or nothing and brakes), and whether it came to
//! rest off its goals before the next plan to them: what a lab sees as the
//! team stalling, beside the `Stopping` answers counted per message.

use flowopt_client::{Followed, PlanStatus};

/// One stretch off a plan to the goals.
#[derive(Debug, Clone, Copy)]
struct Stretch {
    /// When it began (s into the run).
    since_s: f64,
    /// Whether every robot came to rest during it while one was off its goal.
    halted: bool,
}

/// Follows the stops of one run, tick by tick.
#[derive(Debug, Default)]
pub struct Stops {
    /// The plan sequence of the stopping plan followed now (a later `Held`
    /// answer keeps it).
    stopping_plan: Option<u64>,
    current: Option<Stretch>,
    /// Whether a plan to the goals has been followed yet (the stretch
    /// before the first is not a stop).
    started: bool,
}

/// A stop that ended: when it began, how long it took (s) and whether the
/// team came to rest in it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ended {
    /// When it began (s into the run).
    pub since_s: f64,
    /// Its length (s).
    pub lasted_s: f64,
    /// Whether the team came to rest off its goals in it.
    pub halted: bool,
}

impl Stops {
    /// One tick at `t` s: what is followed, whether every robot is at rest
    /// and whether every robot is at its goal. Returns the stop that ended
    /// at this tick, if one did.
    pub fn tick(&mut self, t: f64, followed: Option<&Followed>, at_rest: bool, arrived: bool) -> Option<Ended> {
        if let Some(f) = followed {
            match f.status {
                PlanStatus::Stopping => self.stopping_plan = Some(f.plan_sequence),
                PlanStatus::Ok => self.stopping_plan = None,
                _ => {}
            }
        }
        let to_goals = followed.is_some_and(|f| self.stopping_plan != Some(f.plan_sequence));
        if to_goals {
            self.started = true;
            return self.end(t);
        }
        if !self.started {
            return None;
        }
        let stretch = self.current.get_or_insert(Stretch { since_s: t, halted: false });
        stretch.halted |= at_rest && !arrived;
        None
    }

    /// Ends the stop under way at `t` (the run's end), if there is one.
    pub fn end(&mut self, t: f64) -> Option<Ended> {
        self.current.take().map(|s| Ended { since_s: s.since_s, lasted_s: t - s.since_s, halted: s.halted })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::plan::JointPlan;
    use flowopt_planner::problem::{Dim, Team};

    fn followed(status: PlanStatus, plan_sequence: u64) -> Followed {
        let team = Team::default_for(Dim::Two, 2);
        let plan = JointPlan::new(&team, vec![0.0; 2 * 2 * (team.degree + 1)]);
        Followed { plan, origin_ns: 0, plan_sequence, status }
    }

    #[test]
    fn a_stop_lasts_from_the_stopping_plan_to_the_next_plan_to_the_goals() {
        let mut stops = Stops::default();
        // Nothing before the first plan is a stop.
        assert_eq!(stops.tick(0.0, None, true, false), None);
        assert_eq!(stops.tick(0.1, Some(&followed(PlanStatus::Ok, 1)), false, false), None);
        assert_eq!(stops.tick(0.2, Some(&followed(PlanStatus::Held, 1)), false, false), None);
        // A stopping plan, then held: one stop, moving all along.
        assert_eq!(stops.tick(0.3, Some(&followed(PlanStatus::Stopping, 2)), false, false), None);
        assert_eq!(stops.tick(0.4, Some(&followed(PlanStatus::Held, 2)), false, false), None);
        let ended = stops.tick(0.6, Some(&followed(PlanStatus::Ok, 3)), false, false);
        assert_eq!(ended.map(|e| (e.since_s, e.halted)), Some((0.3, false)));
        assert!((ended.map_or(0.0, |e| e.lasted_s) - 0.3).abs() < 1e-12);
        // Nothing to follow, the team at rest off its goals: a halt, ended
        // by the run's end.
        assert_eq!(stops.tick(1.0, None, false, false), None);
        assert_eq!(stops.tick(1.1, None, true, false), None);
        assert_eq!(stops.end(1.5).map(|e| e.halted), Some(true));
        // At rest at the goals is no halt.
        assert_eq!(stops.tick(2.0, Some(&followed(PlanStatus::Stopping, 4)), true, true), None);
        assert_eq!(stops.end(2.5).map(|e| e.halted), Some(false));
    }
}
