//! The messages as plain records (serde; JSON in recordings, the live view
//! and the ROS 2 bridge's status topic; schemas `flowopt.Snapshot` and
//! `flowopt.Answer`, docs/RECORDING.md): a snapshot, and an answer with its
//! plan's Bernstein coefficients, so that a reader rebuilds the plans
//! without this project's code.

use crate::{JointTrajectory, StateSnapshot};
use serde::{Deserialize, Serialize};

/// One robot in a snapshot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotRecord {
    /// Measured position (m).
    pub position: [f64; 3],
    /// Measured velocity (m/s).
    pub velocity: [f64; 3],
    /// Goal (m).
    pub goal: [f64; 3],
}

/// One obstacle in a snapshot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObstacleRecord {
    /// Centre (m).
    pub position: [f64; 3],
    /// Velocity (m/s).
    pub velocity: [f64; 3],
    /// Radius (m).
    pub radius: f64,
    /// Half height (m; 3D teams).
    pub half_height: f64,
}

/// A snapshot the team's controller published (`flowopt.Snapshot`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SnapshotRecord {
    /// The team.
    pub team: String,
    /// Its sequence.
    pub sequence: u64,
    /// Its measurement time (ns, the controller's monotonic clock).
    pub timestamp_ns: u64,
    /// 2 or 3.
    pub dim: u32,
    /// The robots.
    pub robots: Vec<RobotRecord>,
    /// The obstacles it reported.
    pub obstacles: Vec<ObstacleRecord>,
}

/// A plan: Bernstein coefficients over `[0, horizon]` from its origin.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanRecord {
    /// The sequence of the snapshot it was made from.
    pub sequence: u64,
    /// Its time origin `t = 0` (ns, the controller's clock).
    pub origin_ns: u64,
    /// Horizon T (s).
    pub horizon: f64,
    /// Bernstein degree.
    pub degree: u32,
    /// 2 or 3.
    pub dim: u32,
    /// `[robot][axis][coefficient]`: `dim` axes, `degree + 1` coefficients.
    pub coefficients: Vec<Vec<Vec<f64>>>,
}

/// An answer the daemon gave (`flowopt.Answer`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnswerRecord {
    /// The team.
    pub team: String,
    /// The snapshot it answers.
    pub answers_sequence: u64,
    /// That snapshot's measurement time (ns).
    pub state_timestamp_ns: u64,
    /// Its status (docs/MESSAGES.md), `unreadable` if out of range.
    pub status: String,
    /// Its reason (`None` for none).
    pub reason: String,
    /// The robot or obstacle the reason points at.
    pub reason_index: Option<u32>,
    /// Whether the contract says to follow the carried plan.
    pub followable: bool,
    /// The carried plan's sequence (0: none).
    pub plan_sequence: u64,
    /// Arrival of the snapshot at the daemon to this answer (ms).
    pub answer_ms: f64,
    /// Optimiser iterations spent.
    pub iterations: u32,
    /// Warm-started from the previous plan.
    pub warm_started: bool,
    /// The carried plan, the first time it is carried (later answers that
    /// carry it again name it by `plan_sequence` only).
    pub plan: Option<PlanRecord>,
}

impl SnapshotRecord {
    /// The record of `s`.
    pub fn of(s: &StateSnapshot) -> Self {
        let robots = (s.robots as usize).min(s.robot.len());
        let obstacles = (s.obstacles as usize).min(s.obstacle.len());
        Self {
            team: s.team_name().unwrap_or("").to_string(),
            sequence: s.sequence,
            timestamp_ns: s.timestamp_ns,
            dim: s.dim,
            robots: s.robot[..robots]
                .iter()
                .map(|r| RobotRecord { position: r.position, velocity: r.velocity, goal: r.goal })
                .collect(),
            obstacles: s.obstacle[..obstacles]
                .iter()
                .map(|o| ObstacleRecord {
                    position: o.position,
                    velocity: o.velocity,
                    radius: o.radius,
                    half_height: o.half_height,
                })
                .collect(),
        }
    }
}

impl AnswerRecord {
    /// The record of `msg`, with its plan when `new_plan`.
    pub fn of(msg: &JointTrajectory, new_plan: bool) -> Self {
        let status = msg.status();
        let followable = status.as_ref().is_ok_and(|s| s.followable());
        let plan = (followable && new_plan).then(|| PlanRecord::of(msg)).flatten();
        Self {
            team: msg.team_name().unwrap_or("").to_string(),
            answers_sequence: msg.answers_sequence,
            state_timestamp_ns: msg.state_timestamp_ns,
            status: status.map(|s| format!("{s:?}")).unwrap_or_else(|_| "unreadable".into()),
            reason: msg.reason().map(|r| format!("{r:?}")).unwrap_or_else(|_| "unreadable".into()),
            reason_index: (msg.reason_index != u32::MAX).then_some(msg.reason_index),
            followable,
            plan_sequence: if followable { msg.plan_sequence } else { 0 },
            answer_ms: msg.published_ns.saturating_sub(msg.received_ns) as f64 * 1e-6,
            iterations: msg.iterations,
            warm_started: msg.warm_started == 1,
            plan,
        }
    }
}

impl PlanRecord {
    /// The plan `msg` carries, if its shape is readable.
    pub fn of(msg: &JointTrajectory) -> Option<Self> {
        let plan = msg.plan().ok()?;
        let axes = plan.dim.axes();
        let coefficients =
            (0..plan.robots).map(|i| (0..axes).map(|a| plan.coefficients(a, i).to_vec()).collect()).collect();
        Some(Self {
            sequence: msg.plan_sequence,
            origin_ns: msg.plan_origin_ns,
            horizon: plan.horizon,
            degree: plan.degree as u32,
            dim: axes as u32,
            coefficients,
        })
    }
}

#[cfg(test)]
mod tests {
    use flowopt_planner::plan::JointPlan;
    use flowopt_planner::problem::Dim;

    use super::*;
    use crate::PlanStatus;

    /// Robot `robot`'s position `t` s after the origin of `plan` (clamped
    /// to `[0, T]`), by de Casteljau's algorithm on the record alone: what
    /// a reader without this project's code computes.
    fn position(plan: &PlanRecord, robot: usize, t: f64) -> [f64; 3] {
        let s = (t / plan.horizon).clamp(0.0, 1.0);
        let mut out = [0.0; 3];
        for (a, c) in plan.coefficients[robot].iter().enumerate() {
            let mut points = c.clone();
            for level in (1..points.len()).rev() {
                for k in 0..level {
                    points[k] = (1.0 - s) * points[k] + s * points[k + 1];
                }
            }
            out[a] = points[0];
        }
        out
    }

    #[test]
    fn a_plan_record_rebuilds_the_plan_it_was_made_from() {
        // A 3-robot 2D plan of degree 5 with arbitrary coefficients.
        let (robots, nx) = (3, 6);
        let coeffs: Vec<f64> = (0..2 * robots * nx).map(|k| ((k * 37 % 11) as f64 - 5.0) * 0.1).collect();
        let plan = JointPlan { dim: Dim::Two, robots, degree: nx - 1, horizon: 4.0, coeffs };
        let mut msg = JointTrajectory::new();
        msg.set_status(PlanStatus::Ok);
        msg.write_plan(&plan).unwrap();
        msg.plan_sequence = 7;
        msg.plan_origin_ns = 123;
        let record = AnswerRecord::of(&msg, true);
        assert!(record.followable && record.plan_sequence == 7);
        let again: AnswerRecord = serde_json::from_str(&serde_json::to_string(&record).unwrap()).unwrap();
        let rebuilt = again.plan.expect("a new plan is carried");
        assert_eq!((rebuilt.sequence, rebuilt.origin_ns, rebuilt.degree, rebuilt.dim), (7, 123, 5, 2));
        for t in [0.0, 0.3, 1.7, 4.0, 9.0] {
            let at = plan.at(t);
            for i in 0..robots {
                let p = position(&rebuilt, i, t);
                assert!((p[0] - at[i].position.x).abs() < 1e-12 && (p[1] - at[i].position.y).abs() < 1e-12);
            }
        }
        // A plan carried again is named, not repeated.
        assert!(AnswerRecord::of(&msg, false).plan.is_none());
        msg.set_status(PlanStatus::NoPlan);
        let none = AnswerRecord::of(&msg, true);
        assert!(!none.followable && none.plan.is_none() && none.plan_sequence == 0);
    }
}
