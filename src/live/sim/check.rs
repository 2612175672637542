//! The simulator's own check of every trajectory it is told to follow,
//! independent of the daemon's: collision-free between robots and inside
//! the box on a dense grid (within the success tolerance; a contact the
//! robots were measured in held to its floor while they recover from it,
//! `flowopt_planner::recovery`), starting where
//! the robots are, and clear of the obstacles the controller reported in
//! the snapshot the message answers, along their reported motion, over the
//! rest of the plan (a moving obstacle within the window the daemon checks
//! followable answers over, `TeamConfig::obstacle_check_s`, passed as the
//! team's `obstacle_prediction`).

use flowopt_client::Followed;
use flowopt_planner::metrics::{DENSE_FACTOR, Metrics};
use flowopt_planner::problem::{FEASIBILITY_TOLERANCE, Obstacle, Problem, StartState, Team, scaled_norm};
use flowopt_planner::recovery::Recovery;
use nalgebra::Vector3;

/// How far (m) a trajectory taken up may start from the robots' true
/// positions before the check counts it as unverified.
const START_TOLERANCE: f64 = 0.05;

/// Why a followed trajectory fails the check.
#[derive(Debug, Clone, PartialEq)]
pub enum Failure {
    /// Robots touch, or one leaves the box, or it starts away from the robots.
    Unverified(String),
    /// It crosses a reported obstacle.
    ThroughObstacle(String),
}

/// Checks `f` taken up at `now_ns` with the robots at `positions`, against
/// `reported`: the obstacles of the snapshot the message answers, measured
/// at `reported_ns`.
pub fn check(
    team: &Team,
    f: &Followed,
    positions: &[Vector3<f64>],
    now_ns: u64,
    reported: &[Obstacle],
    reported_ns: u64,
) -> Result<(), Failure> {
    let start = f.at(f.origin_ns);
    let end = f.plan.at(f.plan.horizon);
    let problem = Problem {
        team: Team { horizon: f.plan.horizon, ..team.clone() },
        starts: start.into_iter().map(StartState::from).collect(),
        goals: end.iter().map(|k| k.position).collect(),
        obstacles: Vec::new(),
    };
    let m = Metrics::measure(&problem, &f.plan);
    if m.min_robot_scaled < 1.0 - FEASIBILITY_TOLERANCE {
        return Err(Failure::Unverified(format!("robots come within {:.4} of the separation", m.min_robot_scaled)));
    }
    if m.workspace_excess > team.box_tolerance() {
        return Err(Failure::Unverified(format!("a robot leaves the box by {:.4} m", m.workspace_excess)));
    }
    let off = f.at(now_ns).iter().zip(positions).map(|(k, p)| (k.position - p).norm()).fold(0.0, f64::max);
    if off > START_TOLERANCE {
        let age = (now_ns as f64 - f.origin_ns as f64) * 1e-6;
        return Err(Failure::Unverified(format!("it is {off:.4} m from the robots {age:.1} ms after its origin")));
    }
    // Where a robot was measured in contact with an obstacle of the
    // snapshot the plan was made from, the plan holds it to the contact's
    // floor while it recovers (a plan re-issued for a later snapshot is
    // checked against that one's obstacles in full).
    let reported_at = (reported_ns as f64 - f.origin_ns as f64) * 1e-9;
    let recovery = if reported_ns == f.origin_ns {
        Recovery::of(&Problem { obstacles: reported.to_vec(), ..problem })
    } else {
        Recovery::default()
    };
    // The rest of the plan, from now, against the reported obstacles.
    let steps = DENSE_FACTOR * team.samples;
    let dt = f.plan.horizon / (steps - 1) as f64;
    let elapsed = (now_ns as f64 - f.origin_ns as f64) * 1e-9;
    let mut t = elapsed.max(0.0);
    while t <= f.plan.horizon {
        let since_report = t - reported_at;
        for (i, k) in f.plan.at(t).iter().enumerate() {
            for (j, o) in reported.iter().enumerate() {
                if since_report > team.predicted_until(&o.velocity) {
                    // Past its prediction a moving obstacle is the next
                    // snapshot's to report (docs/MESSAGES.md).
                    continue;
                }
                let (a, b) = team.obstacle_separation(&o.shape);
                let d = scaled_norm(team.dim, &(k.position - o.at(since_report)), a, b);
                if d < recovery.obstacle_floor(i, j, t) * (1.0 - FEASIBILITY_TOLERANCE) {
                    return Err(Failure::ThroughObstacle(format!(
                        "robot {i} comes within {d:.3} of obstacle {j} {:.2} s after its origin",
                        t
                    )));
                }
            }
        }
        t += dt;
    }
    Ok(())
}
