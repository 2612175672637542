//! Planning from a start that already violates a constraint: a robot
//! measured touching another robot or an obstacle (a walker bumped it), or
//! outside the box (a gust pushed it out while it braked).
//!
//! A plan cannot meet at its first instants a constraint its measured
//! start violates, so without this such a start makes the whole team's
//! task unplannable, and every robot stops while the one in contact waits
//! for the contact to go away by itself. With a team's
//! [`crate::problem::Team::start_recovery`] set, [`Problem::validate`] accepts starts in
//! an obstacle however deep (a walker is where it is reported), starts
//! touching another robot by at most [`crate::problem::RECOVERABLE_DEPTH`]
//! (deeper is more likely a wrong measurement) and starts outside the box
//! that a plan can bring back within half the horizon
//! ([`crate::problem::StartViolation::recoverable`]), and every planner
//! holds that constraint, for that robot (that pair) alone, to a floor
//! until the recovery time has passed (longer for a robot far out of the
//! box: [`crate::problem::StartViolation::return_time`]) and in full from
//! then on:
//!
//! - a pair or a robot and an obstacle at measured scaled distance `d0`,
//!   closing at scaled speed `u`, keep at least
//!   `(1 - RECOVERY_SLACK) d0 - u T_r / 4` (what braking within half the
//!   recovery time `T_r` allows), never below 0;
//! - a robot `e` outside the box on an axis, moving outwards at `u`, keeps
//!   within `e (1 + RECOVERY_SLACK) + u T_r / 4` of that side, and at
//!   least `1 + RECOVERY_SLACK` times the least excursion of a plan it can
//!   follow ([`crate::braking`]) from where it is;
//! - a robot inside the box moving towards a side faster than any plan it
//!   can follow stops before it ([`crate::braking`]) keeps within
//!   `1 + RECOVERY_SLACK` times that plan's least excursion of where it is.
//!
//! - in every team (with or without start recovery), a robot within the
//!   tolerance of the box moving towards a side whose least excursion takes
//!   it past that side by no more than the tolerance
//!   ([`Problem::braking_excesses`]: not a start violation, but no plan
//!   keeps it inside) keeps within `1 + RECOVERY_SLACK` times that
//!   excursion of where it is, never further out than the tolerance; without
//!   start recovery, for the whole plan. Without this, such a start (a robot
//!   measured at a side with some speed towards it) ran to the iteration
//!   cap: the optimiser and its verification held the exact box;
//! - likewise, a robot whose least excursion stops it less than
//!   [`crate::braking::GOAL_CHECK_NEAR`] inside a side keeps within the
//!   side, or, where that leaves it under [`RECOVERY_SLACK`] of the
//!   excursion, within `1 + RECOVERY_SLACK` times it, never further out
//!   than the tolerance.
//!
//! Each floor of a side carries its slack ([`Violation::slack`]), the room
//! between it and the least excursion: the optimiser's projection keeps
//! its box inset from a floor only up to that, since inside it no plan the
//! robot can follow exists.
//!
//! Every other constraint holds in full from the first instant. The
//! optimiser's projection, its dense verification ([`crate::am::Limits`])
//! and [`crate::metrics::Metrics`] read the floors from here.
//!
//! ```
//! use flowopt_planner::problem::{Against, Dim, Problem, StartState, Team};
//! use flowopt_planner::recovery::Recovery;
//! use nalgebra::Vector3;
//!
//! // Robot 1 is measured 4 mm outside the box's right side, at rest.
//! let team = Team { start_recovery: Some(1.0), ..Team::default_for(Dim::Two, 2) };
//! let problem = Problem {
//!     team,
//!     starts: vec![StartState::at_rest(Vector3::new(0.0, 0.0, 0.0)), StartState::at_rest(Vector3::new(1.004, 0.0, 0.0))],
//!     goals: vec![Vector3::new(0.0, 0.5, 0.0), Vector3::new(0.5, 0.0, 0.0)],
//!     obstacles: vec![],
//! };
//! problem.validate().unwrap();
//! let recovery = Recovery::of(&problem);
//! assert_eq!(recovery.violations[0].against, Against::Box { axis: 0, upper: true });
//! // For its first second it may stay where it is (and a little further out); then in the box.
//! let (_, hi) = recovery.bounds(1, 0, 0.5, (-1.0, 1.0));
//! assert!(hi > 1.004 && hi < 1.005);
//! assert_eq!(recovery.bounds(1, 0, 1.0, (-1.0, 1.0)), (-1.0, 1.0));
//! ```

use crate::problem::{Against, Problem};

/// How much deeper than measured a violation may become during recovery,
/// as a share of the measured distance (or excess): room for the plan,
/// which starts at the measured state, to turn.
pub const RECOVERY_SLACK: f64 = 0.1;

/// One constraint a measured start violates
/// ([`crate::problem::StartViolation`]) and its floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Violation {
    /// The robot (the lower index of a pair).
    pub robot: usize,
    /// What it violates.
    pub against: Against,
    /// What holds until the recovery time: the least scaled distance for a
    /// pair or an obstacle, the coordinate the robot stays within for a
    /// side of the box.
    pub floor: f64,
    /// How far inside its floor a robot may still be held (m): for a side
    /// of the box, from the floor back to the least excursion of a plan it
    /// can follow ([`crate::braking`]); infinite for a pair or an obstacle.
    /// A limit tighter than the floor by more leaves no plan.
    pub slack: f64,
}

/// Every start violation of a problem and how long its floors hold.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Recovery {
    /// Seconds from the start the floors hold for: the team's
    /// [`crate::problem::Team::start_recovery`], or longer where a robot
    /// outside the box needs longer to come back
    /// ([`crate::problem::StartViolation::return_time`]); without it, the horizon
    /// where a start's braking takes it past a side within the tolerance,
    /// else 0.
    pub until: f64,
    /// The violations, in the order [`Problem::validate`] reports them:
    /// the box robot by robot, pairs, then obstacles.
    pub violations: Vec<Violation>,
}

impl Recovery {
    /// The start violations of `problem`
    /// ([`Problem::start_violations`]) with their floors, in a team with
    /// start recovery (in any other they make the problem invalid), and in
    /// every team the starts whose braking takes them past a side within
    /// the tolerance ([`Problem::braking_excesses`]). Does not allocate
    /// when there are none.
    pub fn of(problem: &Problem) -> Self {
        let team = &problem.team;
        let slack = team.box_tolerance();
        // Starts that cannot stop before a side but past it by no more than
        // the tolerance (not violations, but no plan keeps them in the box),
        // and starts that stop just inside it.
        let tolerated = problem.braking_excesses().filter(|e| e.tolerated).map(|e| {
            // Past the side: its least excursion with the slack, never past
            // the tolerance. Inside: the side itself.
            let room = e.least - e.excess;
            let out = room.max(((1.0 + RECOVERY_SLACK) * e.least).min(room + slack));
            let p = problem.starts[e.robot].position[e.axis];
            let floor = if e.upper { p + out } else { p - out };
            let against = Against::Braking { axis: e.axis, upper: e.upper };
            Violation { robot: e.robot, against, floor, slack: out - e.least }
        });
        let mut tolerated = tolerated.peekable();
        let quarter = team.start_recovery.unwrap_or(0.0) / 4.0;
        // Only a team that recovers from its starts has floors for them (in
        // any other, a start violation makes the problem invalid, and its
        // floor must not last the tolerated ones' whole plan).
        let measured = if team.start_recovery.is_some() { problem.start_violations() } else { Vec::new() };
        // Without start recovery the tolerated floors hold for the whole
        // plan; with it, until the recovery time, or as long as a robot
        // far out of the box needs to come back.
        let until = match team.start_recovery {
            Some(recovery) => {
                let back = measured
                    .iter()
                    .filter_map(|v| v.return_time(team.separation().0, team.max_acceleration))
                    .fold(0.0, f64::max);
                // A longer time ends just before a constrained instant: the
                // box holds there and at every later one, on the
                // constraints' grid as on the verification's.
                let step = team.horizon / (team.samples.max(2) - 1) as f64;
                if back > recovery { (back / step).ceil() * step - 1e-9 } else { recovery }
            }
            None if tolerated.peek().is_some() => team.horizon,
            None => 0.0,
        };
        let violations = measured
            .into_iter()
            .map(|v| {
                let (floor, slack) = match v.against {
                    Against::Box { axis, upper } | Against::Braking { axis, upper } => {
                        // At least the least excursion of a plan it can
                        // follow (with the slack), from where it is.
                        let least =
                            team.max_acceleration.map_or(0.0, |a| problem.least_excursion(v.robot, axis, upper, a));
                        let room = match v.against {
                            Against::Box { .. } => RECOVERY_SLACK * v.depth * team.separation().0 + v.closing * quarter,
                            _ => 0.0,
                        };
                        let out = room.max((1.0 + RECOVERY_SLACK) * least);
                        let p = problem.starts[v.robot].position[axis];
                        (if upper { p + out } else { p - out }, out - least)
                    }
                    Against::Robot(_) | Against::Obstacle(_) => {
                        (((1.0 - RECOVERY_SLACK) * (1.0 - v.depth) - v.closing * quarter).max(0.0), f64::INFINITY)
                    }
                    // Never recovered from (a recovering team does not
                    // check it): the separation.
                    Against::Closing(_) => (1.0, f64::INFINITY),
                };
                Violation { robot: v.robot, against: v.against, floor, slack }
            })
            .chain(tolerated)
            .collect();
        Self { until, violations }
    }

    /// The least scaled distance robots `i < j` keep `t` s after the start
    /// (1: the separation).
    pub fn pair_floor(&self, i: usize, j: usize, t: f64) -> f64 {
        self.floor(i, Against::Robot(j), t)
    }

    /// The least scaled distance robot `i` keeps from obstacle `m` `t` s
    /// after the start.
    pub fn obstacle_floor(&self, i: usize, m: usize, t: f64) -> f64 {
        self.floor(i, Against::Obstacle(m), t)
    }

    /// The bounds `(lo, hi)` robot `i` stays within on `axis` `t` s after
    /// the start: `box_` unless it recovers from outside it.
    pub fn bounds(&self, i: usize, axis: usize, t: f64, box_: (f64, f64)) -> (f64, f64) {
        if t < self.until { box_bounds(&self.violations, i, axis, box_).unwrap_or(box_) } else { box_ }
    }

    fn floor(&self, i: usize, against: Against, t: f64) -> f64 {
        if t >= self.until {
            return 1.0;
        }
        self.violations.iter().find(|v| v.robot == i && v.against == against).map_or(1.0, |v| v.floor.min(1.0))
    }
}

/// The box `box_` robot `i` stays within on `axis` while it recovers from
/// outside one of its sides (`violations`' floors there), if it does.
pub(crate) fn box_bounds(violations: &[Violation], i: usize, axis: usize, box_: (f64, f64)) -> Option<(f64, f64)> {
    let mut out = None;
    for v in violations.iter().filter(|v| v.robot == i) {
        if let Some((x, upper)) = v.against.side()
            && x == axis
        {
            let (lo, hi) = out.get_or_insert(box_);
            if upper {
                *hi = hi.max(v.floor);
            } else {
                *lo = lo.min(v.floor);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::am::{AmSettings, Engine, Objective, Stop};
    use crate::basis::DENSE_FACTOR;
    use crate::metrics::Metrics;
    use crate::plan::JointPlan;
    use crate::problem::{Dim, FEASIBILITY_TOLERANCE, ProblemError, RETURN_FACTOR, Team};
    use crate::problem::{Obstacle, Spheroid, StartState};

    /// Four robots at rest in the default 2D box, going to the opposite
    /// corners' side; `with` moves things before the team recovers in 1 s.
    fn four(with: impl FnOnce(&mut Problem)) -> Problem {
        let team = Team { start_recovery: Some(1.0), ..Team::default_for(Dim::Two, 4) };
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        let mut problem = Problem {
            team,
            starts: [at(-0.5, -0.5), at(0.5, -0.5), at(0.5, 0.5), at(-0.5, 0.5)].map(StartState::at_rest).to_vec(),
            goals: vec![at(0.5, 0.5), at(-0.5, 0.5), at(-0.5, -0.5), at(0.5, -0.5)],
            obstacles: vec![],
        };
        with(&mut problem);
        problem
    }

    /// The verified plan of `problem` (one thread, and the same on two).
    fn planned(problem: &Problem) -> JointPlan {
        let solve = |threads| {
            let settings = AmSettings { threads, ..AmSettings::optimiser() };
            let engine =
                Engine::new(&problem.team, problem.obstacles.len(), Objective::smoothness(), settings).unwrap();
            let outcome = engine.solve(problem).unwrap();
            assert_eq!(outcome.stop, Stop::Verified, "{:?}", Recovery::of(problem));
            engine.plan(outcome.state.xi)
        };
        let one = solve(1);
        assert_eq!(solve(2).coeffs, one.coeffs, "the same plan on every crew");
        let m = Metrics::measure(problem, &one);
        assert!(m.success(problem.team.separation().0), "{m:?}");
        one
    }

    #[test]
    fn a_robot_measured_outside_the_box_is_planned_back_in_within_the_recovery_time() {
        let problem = four(|p| {
            p.starts[1] = StartState {
                velocity: Vector3::new(0.2, 0.0, 0.0),
                ..StartState::at_rest(Vector3::new(1.01, -0.5, 0.0))
            }
        });
        let strict = Problem { team: Team { start_recovery: None, ..problem.team.clone() }, ..problem.clone() };
        assert_eq!(strict.validate(), Err(ProblemError::StartOutsideWorkspace(1)));
        let plan = planned(&problem);
        // Out of the box at first (it was moving outwards), then inside.
        let x = |t: f64| plan.at(t)[1].position.x;
        assert!(x(0.1) > 1.01, "{}", x(0.1));
        for k in 0..=40 {
            let t = 1.0 + k as f64 * 0.1;
            assert!(x(t) <= 1.0 + FEASIBILITY_TOLERANCE * 0.2, "x({t}) = {}", x(t));
        }
        assert!(Metrics::measure(&strict, &plan).workspace_excess > 0.01, "it did start outside");
    }

    #[test]
    fn a_robot_far_out_of_the_box_is_planned_back_in_where_a_plan_can_bring_it() {
        // Robot 1 pushed 0.3 m (1.5 separations) past the right side, still
        // moving out at 0.5 m/s.
        let problem = four(|p| {
            p.team.max_acceleration = Some(3.0);
            p.starts[1] = StartState {
                velocity: Vector3::new(0.5, 0.0, 0.0),
                ..StartState::at_rest(Vector3::new(1.3, -0.5, 0.0))
            };
        });
        problem.validate().unwrap();
        // Its floor holds for twice the shortest return (0.5 / 3 s to
        // brake, then 0.342 m at 3 m/s^2), to the next constrained instant.
        let recovery = Recovery::of(&problem);
        let expected = RETURN_FACTOR * (0.5 / 3.0 + 2.0 * ((0.3 + 0.25 / 6.0) / 3.0_f64).sqrt());
        let step = problem.team.horizon / (problem.team.samples - 1) as f64;
        assert!(expected > 1.0 && recovery.until >= expected && recovery.until < expected + step, "{recovery:?}");
        let plan = planned(&problem);
        let x = |t: f64| plan.at(t)[1].position.x;
        assert!(x(0.1) > 1.3, "it goes on out first: {}", x(0.1));
        // Inside from then on, at the verification's instants.
        let dense = DENSE_FACTOR * problem.team.samples;
        let instants = (0..dense).map(|j| j as f64 * problem.team.horizon / (dense - 1) as f64);
        for t in instants.filter(|t| *t >= recovery.until) {
            assert!(x(t) <= 1.0 + FEASIBILITY_TOLERANCE * 0.2, "x({t}) = {}", x(t));
        }
        // Without an acceleration limit the depth rule holds: rejected.
        let unlimited = Problem { team: Team { max_acceleration: None, ..problem.team.clone() }, ..problem.clone() };
        assert_eq!(unlimited.validate(), Err(ProblemError::StartOutsideWorkspace(1)));
        // Too far to come back within half the horizon: rejected.
        let far = four(|p| {
            p.team.max_acceleration = Some(3.0);
            p.starts[1] = StartState::at_rest(Vector3::new(3.0, -0.5, 0.0));
        });
        assert_eq!(far.validate(), Err(ProblemError::StartOutsideWorkspace(1)));
    }

    #[test]
    fn a_pair_closing_faster_than_it_can_swerve_is_certified_unless_the_team_recovers() {
        // Robots 0 and 1 head past each other at 1 m/s each, 0.35 m apart
        // along x and 0.1 m across: at 3 m/s^2 each they come within 0.9
        // of the separation whatever they do.
        let problem = four(|p| {
            p.team.max_acceleration = Some(3.0);
            p.starts[0] = StartState {
                velocity: Vector3::new(1.0, 0.0, 0.0),
                ..StartState::at_rest(Vector3::new(-0.175, -0.55, 0.0))
            };
            p.starts[1] = StartState {
                velocity: Vector3::new(-1.0, 0.0, 0.0),
                ..StartState::at_rest(Vector3::new(0.175, -0.45, 0.0))
            };
        });
        let strict = Problem { team: Team { start_recovery: None, ..problem.team.clone() }, ..problem.clone() };
        match strict.validate() {
            Err(ProblemError::CannotAvoid { i: 0, j: 1, scaled, at }) => {
                assert!(scaled > 0.85 && scaled < 0.95 && at > 0.05 && at < 0.2, "{scaled} at {at}");
            }
            other => panic!("{other:?}"),
        }
        // A team that recovers from its starts holds the pair to the
        // separation, as any other; so does one of unknown acceleration.
        assert_eq!(problem.validate(), Ok(()));
        assert!(Recovery::of(&problem).violations.is_empty());
        let unknown = Problem { team: Team { max_acceleration: None, ..strict.team.clone() }, ..strict.clone() };
        assert_eq!(unknown.validate(), Ok(()));
        // Slower, they swerve in time.
        let slow = Problem {
            starts: strict.starts.iter().map(|s| StartState { velocity: s.velocity * 0.3, ..*s }).collect(),
            ..strict.clone()
        };
        assert_eq!(slow.validate(), Ok(()));
    }

    #[test]
    fn a_robot_that_cannot_brake_inside_the_box_brakes_past_its_side_and_comes_back() {
        // Robot 1, 5 cm from the right side at 1 m/s outwards: at 3 m/s^2
        // its shortest stop is 16.7 cm, a plan's (from zero acceleration)
        // longer.
        let moving =
            StartState { velocity: Vector3::new(1.0, 0.0, 0.0), ..StartState::at_rest(Vector3::new(0.95, -0.5, 0.0)) };
        let problem = four(|p| {
            p.team.max_acceleration = Some(3.0);
            p.starts[1] = moving;
        });
        let v = Recovery::of(&problem).violations;
        assert_eq!(
            v.iter().map(|v| (v.robot, v.against)).collect::<Vec<_>>(),
            [(1, Against::Braking { axis: 0, upper: true })]
        );
        // Its least excursion: the table's, and with its goal (behind it)
        // more.
        let table = crate::braking::least_excursion(10, 50, 5.0, 3.0, 0.0, 1.0);
        let least = problem.least_excursion(1, 0, true, 3.0);
        assert!(table > 1.0 / 6.0 && least > table, "{table} {least}");
        assert!((v[0].floor - (0.95 + 1.1 * least)).abs() < 1e-12, "its stop with the slack: {}", v[0].floor);
        let strict = Problem { team: Team { start_recovery: None, ..problem.team.clone() }, ..problem.clone() };
        match strict.validate() {
            Err(ProblemError::CannotBrake { robot: 1, axis: 0, upper: true, speed, overshoot }) => {
                assert_eq!(speed, 1.0);
                assert!((overshoot - (least - 0.05)).abs() < 1e-9, "{overshoot}");
            }
            other => panic!("{other:?}"),
        }
        // Slower, or without a known acceleration, it is a start like any other.
        let slow = four(|p| {
            p.team.max_acceleration = Some(3.0);
            p.starts[1] = StartState { velocity: Vector3::new(0.3, 0.0, 0.0), ..moving };
        });
        // At 0.3 m/s it turns within 3 cm: no violation, and a floor at
        // the side itself, whose inset the projection keeps within what its
        // stop leaves it.
        assert_eq!(Problem { team: strict.team.clone(), ..slow.clone() }.validate(), Ok(()));
        let near = Recovery::of(&slow).violations;
        assert_eq!(
            near.iter().map(|v| (v.robot, v.against)).collect::<Vec<_>>(),
            [(1, Against::Braking { axis: 0, upper: true })]
        );
        let least = slow.least_excursion(1, 0, true, 3.0);
        assert!(least < 0.03 && near[0].floor == 1.0, "{least} {near:?}");
        assert!((near[0].slack - (0.05 - least)).abs() < 1e-12, "{near:?}");
        let unknown = Problem { team: Team { max_acceleration: None, ..strict.team.clone() }, ..strict.clone() };
        assert_eq!(unknown.validate(), Ok(()));
        let plan = planned(&problem);
        let x = |t: f64| plan.at(t)[1].position.x;
        assert!((0..=10).any(|k| x(k as f64 * 0.1) > 1.0 + 0.05), "it does leave the box");
        for k in 0..=50 {
            let t = k as f64 * 0.1;
            let bound = if t < 1.0 { v[0].floor } else { 1.0 + FEASIBILITY_TOLERANCE * 0.2 };
            assert!(x(t) <= bound, "x({t}) = {}", x(t));
        }
    }

    #[test]
    fn a_robot_that_must_brake_past_its_side_within_the_tolerance_is_planned_there() {
        // Robot 1 at 0.3 m/s outwards, placed so that its least excursion
        // (with its goal) ends 1 mm past the right side: within the 2 mm
        // tolerance, so not a violation, but no plan keeps it in the box.
        let at = |x0: f64| {
            four(|p| {
                p.team = Team { start_recovery: None, max_acceleration: Some(3.0), ..p.team.clone() };
                p.starts[1] = StartState {
                    velocity: Vector3::new(0.3, 0.0, 0.0),
                    ..StartState::at_rest(Vector3::new(x0, -0.5, 0.0))
                };
            })
        };
        let mut x0 = 1.0 - crate::braking::least_excursion(10, 50, 5.0, 3.0, 0.0, 0.3) + 0.001;
        for _ in 0..20 {
            x0 -= at(x0).least_excursion(1, 0, true, 3.0) - (1.0 - x0) - 0.001;
        }
        let problem = at(x0);
        let least = problem.least_excursion(1, 0, true, 3.0);
        assert_eq!(problem.validate(), Ok(()));
        let excess: Vec<_> = problem.braking_excesses().collect();
        assert_eq!(excess.len(), 1);
        assert!((excess[0].excess - 0.001).abs() < 1e-9, "{excess:?}");
        let recovery = Recovery::of(&problem);
        assert_eq!(recovery.until, problem.team.horizon, "held for the whole plan");
        let v = recovery.violations;
        assert_eq!(
            v.iter().map(|v| (v.robot, v.against)).collect::<Vec<_>>(),
            [(1, Against::Braking { axis: 0, upper: true })]
        );
        let slack = FEASIBILITY_TOLERANCE * problem.team.separation().0;
        assert!((v[0].floor - (x0 + (1.1 * least).min(least - 0.001 + slack))).abs() < 1e-12, "{}", v[0].floor);
        assert!(v[0].floor > 1.001 && v[0].floor <= 1.0 + slack + 1e-12);
        // Verified, past the side and never past its floor at the
        // verification's dense instants; between them by micrometres at
        // most (the projection holds it 1 mm inside the floor, all its
        // least excursion leaves, at the samples).
        let plan = planned(&problem);
        let x = |t: f64| plan.at(t)[1].position.x;
        assert!((0..=20).any(|k| x(k as f64 * 0.05) > 1.0), "it does leave the box");
        let dense = DENSE_FACTOR * problem.team.samples - 1;
        for k in 0..=dense {
            let t = k as f64 * problem.team.horizon / dense as f64;
            assert!(x(t) <= v[0].floor, "x({t}) = {}", x(t));
        }
        for k in 0..=1000 {
            let t = k as f64 * 0.005;
            assert!(x(t) <= v[0].floor + 1e-5, "x({t}) = {}", x(t));
        }
        // An obstacle reported on robot 2 makes the problem invalid for a
        // team without start recovery: no floor for it (it would have been
        // held for the whole plan, with the tolerated one).
        let bumped = Problem {
            obstacles: vec![Obstacle {
                position: problem.starts[2].position,
                velocity: Vector3::zeros(),
                shape: Spheroid::ball(0.15),
            }],
            ..problem.clone()
        };
        assert!(matches!(bumped.validate(), Err(ProblemError::StartInObstacle { robot: 2, obstacle: 0 })));
        assert_eq!(Recovery::of(&bumped), Recovery::of(&problem));
        // Slower, it stops inside: its floor is the side itself.
        let slow = Problem {
            starts: problem.starts.iter().map(|s| StartState { velocity: s.velocity * 0.5, ..*s }).collect(),
            ..problem.clone()
        };
        let v = Recovery::of(&slow).violations;
        assert_eq!(v.iter().map(|v| (v.robot, v.floor)).collect::<Vec<_>>(), [(1, 1.0)]);
        assert!(v[0].slack > 0.0);
    }

    #[test]
    fn two_robots_measured_in_contact_part_and_are_never_pushed_deeper() {
        let problem = four(|p| p.starts[1].position = Vector3::new(-0.31, -0.5, 0.0));
        let recovery = Recovery::of(&problem);
        assert_eq!(recovery.violations.len(), 1);
        let v = recovery.violations[0];
        assert_eq!((v.robot, v.against), (0, Against::Robot(1)));
        assert!((v.floor - 0.9 * 0.95).abs() < 1e-12, "at rest: 90% of the measured 0.95");
        let plan = planned(&problem);
        let scaled = |t: f64| {
            let at = plan.at(t);
            problem.team.scaled_distance(&(at[0].position - at[1].position))
        };
        for k in 1..=50 {
            let t = k as f64 * 0.1;
            let least = if t < 1.0 { v.floor } else { 1.0 - FEASIBILITY_TOLERANCE };
            assert!(scaled(t) >= least, "{} at {t} s", scaled(t));
        }
    }

    #[test]
    fn a_robot_a_walker_bumps_gets_out_of_its_way() {
        // A walker of radius 0.15 m 3% into robot 2, walking at it at
        // 0.4 m/s.
        let problem = four(|p| {
            let r = p.starts[2].position;
            let d = 0.97 * 0.25;
            p.obstacles = vec![Obstacle {
                position: r + Vector3::new(-d, 0.0, 0.0),
                velocity: Vector3::new(0.4, 0.0, 0.0),
                shape: Spheroid::ball(0.15),
            }];
            p.goals[0] = Vector3::new(0.0, 0.0, 0.0);
        });
        let recovery = Recovery::of(&problem);
        assert_eq!(
            recovery.violations.iter().map(|v| (v.robot, v.against)).collect::<Vec<_>>(),
            [(2, Against::Obstacle(0))]
        );
        let plan = planned(&problem);
        let o = &problem.obstacles[0];
        let (a, b) = problem.team.obstacle_separation(&o.shape);
        let floor = recovery.violations[0].floor;
        for k in 1..=50 {
            let t = k as f64 * 0.1;
            let d = crate::problem::scaled_norm(Dim::Two, &(plan.at(t)[2].position - o.at(t)), a, b);
            let least = if t < 1.0 { floor } else { 1.0 - FEASIBILITY_TOLERANCE };
            assert!(d >= least, "{d} at {t} s");
        }
    }

    #[test]
    fn a_walker_reported_on_a_robot_is_planned_around_within_the_recovery_time() {
        let problem = four(|p| {
            p.obstacles = vec![Obstacle {
                position: p.starts[2].position + Vector3::new(-0.02, 0.0, 0.0),
                velocity: Vector3::new(0.4, 0.0, 0.0),
                shape: Spheroid::ball(0.15),
            }];
            p.goals[0] = Vector3::new(0.0, 0.0, 0.0);
        });
        let v = Recovery::of(&problem).violations[0];
        assert_eq!((v.robot, v.against, v.floor), (2, Against::Obstacle(0), 0.0));
        let plan = planned(&problem);
        let o = &problem.obstacles[0];
        let (a, b) = problem.team.obstacle_separation(&o.shape);
        for k in 10..=50 {
            let t = k as f64 * 0.1;
            let d = crate::problem::scaled_norm(Dim::Two, &(plan.at(t)[2].position - o.at(t)), a, b);
            assert!(d >= 1.0 - FEASIBILITY_TOLERANCE, "{d} at {t} s");
        }
    }

    #[test]
    fn deeper_violations_and_teams_without_a_recovery_time_are_rejected() {
        let deep = four(|p| p.starts[1].position = Vector3::new(-0.45, -0.5, 0.0));
        assert!(matches!(deep.validate(), Err(ProblemError::StartsOverlap { i: 0, j: 1, .. })));
        let out = four(|p| p.starts[1].position = Vector3::new(1.2, -0.5, 0.0));
        assert_eq!(out.validate(), Err(ProblemError::StartOutsideWorkspace(1)));
        let touching = four(|p| p.starts[1].position = Vector3::new(-0.31, -0.5, 0.0));
        touching.validate().unwrap();
        let strict = Problem { team: Team { start_recovery: None, ..touching.team.clone() }, ..touching };
        assert!(matches!(strict.validate(), Err(ProblemError::StartsOverlap { i: 0, j: 1, .. })));
        let bad = Team { start_recovery: Some(0.0), ..Team::default_for(Dim::Two, 2) };
        assert_eq!(
            bad.validate(),
            Err(ProblemError::NonPositive { field: crate::problem::Field::StartRecovery, index: 0 })
        );
    }
}
