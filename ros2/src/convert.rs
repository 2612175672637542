//! Between ROS 2 messages and flowopt's: the plan to follow as a
//! `nav_msgs/Path` per robot and a `MultiDOFJointTrajectory` for the team,
//! stamped on the ROS clock; poses with an estimated velocity; the
//! obstacles array. Pure functions, tested here.

use flowopt_client::Followed;
use flowopt_client::clock::monotonic_ns;
use flowopt_client::pieces::{COEFFICIENTS, DEFAULT_PIECE_S, Pieces};
use flowopt_planner::plan::Kinematics;

use crate::msgs::{
    Float64MultiArray, Header, MultiArrayDimension, MultiArrayLayout, MultiDofJointTrajectory,
    MultiDofJointTrajectoryPoint, Path, Pose, PoseStamped, Quaternion, Time, Transform, Twist, Vector3,
};

/// Numbers per obstacle on the obstacles topic: x, y, z, vx, vy, vz,
/// radius, half_height.
pub const OBSTACLE_FIELDS: usize = 8;

/// Weight of a new finite difference in the estimated velocity (a first
/// order low-pass against mocap noise).
const VELOCITY_SMOOTHING: f64 = 0.5;

/// The monotonic clock flowopt stamps with, against ROS time (the Unix
/// epoch), read together.
#[derive(Debug, Clone, Copy)]
pub struct Clocks {
    /// `flowopt_client::clock::monotonic_ns`.
    pub monotonic_ns: u64,
    /// Unix time (ns).
    pub unix_ns: i64,
}

impl Clocks {
    /// Both clocks now.
    pub fn now() -> Self {
        let unix_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as i64)
            .unwrap_or(0);
        Self { monotonic_ns: monotonic_ns(), unix_ns }
    }

    /// ROS time of monotonic instant `ns`.
    pub fn ros(&self, ns: u64) -> Time {
        Time::from_ns(self.unix_ns + (ns as i64 - self.monotonic_ns as i64))
    }

    /// Monotonic instant of ROS time `t` (one before the monotonic clock's
    /// start is its start).
    pub fn monotonic(&self, t: Time) -> u64 {
        (self.monotonic_ns as i64 + (t.ns() - self.unix_ns)).max(1) as u64
    }

    /// When a measurement stamped `t` was made: a stamp from the future
    /// (another machine's clock ahead of this one) counts as now.
    pub fn measured(&self, t: Time) -> u64 {
        self.monotonic(t).min(self.monotonic_ns)
    }
}

/// The plan to follow at `points` instants `k T / (points - 1)` after its
/// origin: every robot at each instant, evaluated once for all the paths
/// and the trajectory published from it.
#[derive(Debug, Clone)]
pub struct Sampled {
    /// The plan's origin (monotonic ns).
    origin_ns: u64,
    /// `(seconds after the origin, every robot there)`.
    instants: Vec<(f64, Vec<Kinematics>)>,
}

impl Sampled {
    /// `followed` at `points` instants (at least 2) over its horizon.
    pub fn of(followed: &Followed, points: usize) -> Self {
        let last = (points.max(2) - 1) as f64;
        let instants = (0..points.max(2))
            .map(|k| {
                let t = followed.plan.horizon * k as f64 / last;
                (t, followed.plan.at(t))
            })
            .collect();
        Self { origin_ns: followed.origin_ns, instants }
    }
}

fn header(stamp: Time, frame: &str) -> Header {
    Header { stamp, frame_id: frame.to_string() }
}

/// Robot `robot`'s path on the sampled plan (a pose per instant, each
/// stamped with the ROS time to be there); `None`: an empty path, which
/// tells the robot to brake.
pub fn path(sampled: Option<&Sampled>, robot: usize, frame: &str, clocks: &Clocks) -> Path {
    let Some(f) = sampled else {
        return Path { header: header(clocks.ros(clocks.monotonic_ns), frame), poses: Vec::new() };
    };
    let poses = f
        .instants
        .iter()
        .map(|(t, at)| {
            let k = &at[robot];
            let stamp = clocks.ros(f.origin_ns + (t * 1e9) as u64);
            PoseStamped {
                header: header(stamp, frame),
                pose: Pose {
                    position: Vector3 { x: k.position.x, y: k.position.y, z: k.position.z },
                    orientation: Quaternion::default(),
                },
            }
        })
        .collect();
    Path { header: header(clocks.ros(f.origin_ns), frame), poses }
}

/// The team's sampled plan as one trajectory: a point per instant with
/// every robot's position, velocity and acceleration; `names` names the
/// robots.
pub fn trajectory(
    sampled: Option<&Sampled>,
    names: &[String],
    frame: &str,
    clocks: &Clocks,
) -> MultiDofJointTrajectory {
    let Some(f) = sampled else {
        return MultiDofJointTrajectory {
            header: header(clocks.ros(clocks.monotonic_ns), frame),
            joint_names: names.to_vec(),
            points: Vec::new(),
        };
    };
    let points = f
        .instants
        .iter()
        .map(|(t, at)| {
            let vector = |v: &nalgebra::Vector3<f64>| Vector3 { x: v.x, y: v.y, z: v.z };
            MultiDofJointTrajectoryPoint {
                transforms: at
                    .iter()
                    .map(|k| Transform { translation: vector(&k.position), rotation: Quaternion::default() })
                    .collect(),
                velocities: at.iter().map(|k| Twist { linear: vector(&k.velocity), ..Default::default() }).collect(),
                accelerations: at
                    .iter()
                    .map(|k| Twist { linear: vector(&k.acceleration), ..Default::default() })
                    .collect(),
                time_from_start: Time::from_ns((t * 1e9) as i64),
            }
        })
        .collect();
    MultiDofJointTrajectory { header: header(clocks.ros(f.origin_ns), frame), joint_names: names.to_vec(), points }
}

/// Numbers per Crazyswarm piece: the duration, then x, y, z and yaw.
pub const PIECE_FIELDS: usize = 1 + 4 * COEFFICIENTS;

/// Robot `robot`'s plan as Crazyswarm pieces (`flowopt_client::pieces`,
/// [`DEFAULT_PIECE_S`] long): one row of [`PIECE_FIELDS`] per piece, the
/// columns of Crazyswarm's CSV; no rows: no plan to follow.
pub fn pieces(followed: Option<&Followed>, robot: usize) -> Float64MultiArray {
    let rows =
        followed.and_then(|f| Pieces::of(&f.plan, robot, DEFAULT_PIECE_S).ok()).map(|p| p.pieces).unwrap_or_default();
    let data = rows.iter().flat_map(|p| std::iter::once(p.duration).chain(p.axes.iter().flatten().copied())).collect();
    let dimension = |label: &str, size: usize, stride: usize| MultiArrayDimension {
        label: label.into(),
        size: size as u32,
        stride: stride as u32,
    };
    Float64MultiArray {
        layout: MultiArrayLayout {
            dim: vec![
                dimension("piece", rows.len(), rows.len() * PIECE_FIELDS),
                dimension("duration_x_y_z_yaw", PIECE_FIELDS, PIECE_FIELDS),
            ],
            data_offset: 0,
        },
        data,
    }
}

/// One robot as mocap reports it: the newest pose, its time, and a
/// velocity (given, or estimated from successive poses).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Tracked {
    /// Position (m).
    pub position: [f64; 3],
    /// Velocity (m/s).
    pub velocity: [f64; 3],
    /// When it was measured (monotonic ns; 0: never).
    pub at_ns: u64,
}

impl Tracked {
    /// Takes a pose measured at `at_ns` with its velocity if the message
    /// had one; otherwise the velocity is estimated. A pose no newer than
    /// the last is ignored (returns false).
    pub fn update(&mut self, position: [f64; 3], velocity: Option<[f64; 3]>, at_ns: u64) -> bool {
        if !position.iter().all(|x| x.is_finite()) || (self.at_ns != 0 && at_ns <= self.at_ns) {
            return false;
        }
        self.velocity = match velocity {
            Some(v) => v,
            None if self.at_ns == 0 => [0.0; 3],
            None => {
                let dt = (at_ns - self.at_ns) as f64 * 1e-9;
                std::array::from_fn(|a| {
                    let raw = (position[a] - self.position[a]) / dt;
                    VELOCITY_SMOOTHING * raw + (1.0 - VELOCITY_SMOOTHING) * self.velocity[a]
                })
            }
        };
        self.position = position;
        self.at_ns = at_ns;
        true
    }
}

/// An obstacle from the obstacles topic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleRow {
    /// Centre (m).
    pub position: [f64; 3],
    /// Velocity (m/s).
    pub velocity: [f64; 3],
    /// Radius (m).
    pub radius: f64,
    /// Half height (m).
    pub half_height: f64,
}

/// The obstacles of an obstacles message, or why it cannot be read.
pub fn obstacles(msg: &Float64MultiArray) -> Result<Vec<ObstacleRow>, String> {
    if !msg.data.len().is_multiple_of(OBSTACLE_FIELDS) {
        return Err(format!(
            "{} numbers is not a whole number of obstacles of {OBSTACLE_FIELDS} (x, y, z, vx, vy, vz, radius, half_height)",
            msg.data.len()
        ));
    }
    if !msg.data.iter().all(|x| x.is_finite()) {
        return Err("a number is not finite".into());
    }
    Ok(msg
        .data
        .chunks_exact(OBSTACLE_FIELDS)
        .map(|r| ObstacleRow {
            position: [r[0], r[1], r[2]],
            velocity: [r[3], r[4], r[5]],
            radius: r[6],
            half_height: r[7],
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use flowopt_client::PlanStatus;
    use flowopt_planner::plan::JointPlan;
    use flowopt_planner::problem::Dim;

    use super::*;

    /// A 2-robot plan whose coefficients are straight lines.
    fn followed() -> Followed {
        let nx = 4;
        let mut coeffs = Vec::new();
        for a in 0..2 {
            for i in 0..2 {
                let (from, to) = if a == 0 { (i as f64, i as f64 + 3.0) } else { (0.0, 0.0) };
                coeffs.extend((0..nx).map(|k| from + (to - from) * k as f64 / (nx - 1) as f64));
            }
        }
        Followed {
            plan: JointPlan { dim: Dim::Two, robots: 2, degree: nx - 1, horizon: 3.0, coeffs },
            origin_ns: 5_000_000_000,
            plan_sequence: 9,
            status: PlanStatus::Ok,
        }
    }

    #[test]
    fn paths_and_trajectories_follow_the_plan_on_the_ros_clock() {
        let clocks = Clocks { monotonic_ns: 6_000_000_000, unix_ns: 1_700_000_000_000_000_000 };
        let f = followed();
        let sampled = Sampled::of(&f, 4);
        let p = path(Some(&sampled), 1, "world", &clocks);
        assert_eq!(p.poses.len(), 4);
        // Robot 1 goes from x = 1 to 4 in 3 s at 1 m/s; the origin is 1 s
        // before the clocks were read.
        for (k, pose) in p.poses.iter().enumerate() {
            assert!((pose.pose.position.x - (1.0 + k as f64)).abs() < 1e-12);
            assert_eq!(pose.header.stamp.ns(), 1_700_000_000_000_000_000 - 1_000_000_000 + k as i64 * 1_000_000_000);
        }
        assert_eq!(p.header.frame_id, "world");
        assert!(path(None, 0, "world", &clocks).poses.is_empty());
        let names = vec!["robot0".to_string(), "robot1".to_string()];
        let t = trajectory(Some(&sampled), &names, "world", &clocks);
        assert_eq!(t.points.len(), 4);
        assert_eq!(t.points[2].transforms.len(), 2);
        assert!((t.points[2].transforms[0].translation.x - 2.0).abs() < 1e-12);
        assert!((t.points[2].velocities[1].linear.x - 1.0).abs() < 1e-12);
        assert_eq!(t.points[3].time_from_start, Time { sec: 3, nanosec: 0 });
        assert!(trajectory(None, &names, "world", &clocks).points.is_empty());
        assert_eq!(clocks.monotonic(clocks.ros(5_500_000_000)), 5_500_000_000);
        assert_eq!(clocks.monotonic(clocks.ros(7_000_000_000)), 7_000_000_000);
        assert_eq!(clocks.measured(clocks.ros(7_000_000_000)), 6_000_000_000, "a measurement is never in the future");
    }

    #[test]
    fn pieces_are_rows_of_crazyswarm_columns_from_the_plan() {
        let f = followed();
        let msg = pieces(Some(&f), 1);
        assert_eq!(msg.layout.dim[1].size as usize, PIECE_FIELDS);
        let rows: Vec<&[f64]> = msg.data.chunks_exact(PIECE_FIELDS).collect();
        // 3 s in pieces of at most 0.5 s.
        assert_eq!(rows.len(), 6);
        assert_eq!(msg.layout.dim[0].size, 6);
        assert!(rows.iter().all(|r| (r[0] - 0.5).abs() < 1e-12));
        // Robot 1 starts at x = 1 moving at 1 m/s: x^0 and x^1 of the first.
        assert!((rows[0][1] - 1.0).abs() < 1e-9 && (rows[0][2] - 1.0).abs() < 1e-9, "{:?}", &rows[0][..4]);
        assert!(pieces(None, 0).data.is_empty());
    }

    #[test]
    fn velocities_are_estimated_from_poses_and_stale_poses_ignored() {
        let mut r = Tracked::default();
        assert!(r.update([0.0; 3], None, 1_000_000_000));
        assert_eq!(r.velocity, [0.0; 3]);
        assert!(r.update([0.1, 0.0, 0.0], None, 1_100_000_000));
        assert!((r.velocity[0] - 0.5).abs() < 1e-9, "half of the 1 m/s difference: {:?}", r.velocity);
        assert!(!r.update([5.0, 0.0, 0.0], None, 1_100_000_000), "a pose no newer is ignored");
        assert!(!r.update([f64::NAN, 0.0, 0.0], None, 1_200_000_000));
        assert!(r.update([0.2, 0.0, 0.0], Some([2.0, 0.0, 0.0]), 1_200_000_000));
        assert_eq!(r.velocity, [2.0, 0.0, 0.0]);
    }

    #[test]
    fn obstacle_rows_are_read_and_bad_ones_refused() {
        let msg = Float64MultiArray { data: vec![1.0, 2.0, 0.0, 0.1, 0.0, 0.0, 0.2, 0.5], ..Default::default() };
        let rows = obstacles(&msg).unwrap();
        assert_eq!(rows[0].radius, 0.2);
        assert_eq!(rows[0].velocity, [0.1, 0.0, 0.0]);
        assert!(obstacles(&Float64MultiArray { data: vec![1.0; 7], ..Default::default() }).unwrap_err().contains("8"));
        let mut bad = msg.clone();
        bad.data[6] = f64::INFINITY;
        assert!(obstacles(&bad).is_err());
    }
}
