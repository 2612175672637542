//! A simulated team on ROS 2, standing in for mocap and robots: it
//! publishes each robot's `geometry_msgs/PoseStamped` and goal on the
//! bridge's input topics, and moves each robot along the newest
//! `nav_msgs/Path` the bridge published for it (interpolated on the poses'
//! stamps; an empty path: it stops where it is). When every robot is at
//! its goal the team gets new goals. Everything goes through DDS, so a run
//! exercises the bridge as a lab would.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use ros2_client::{Context, ContextOptions, NodeName, NodeOptions, Publisher, Subscription};
use serde::Serialize;

use crate::convert::Clocks;
use crate::error::BridgeError;
use crate::msgs::{Header, Path, Pose, PoseStamped, Quaternion, Vector3, types};
use crate::node::{advertise, qos, ros, subscribe};
use crate::settings::{BridgeSettings, topic};

/// Goals are re-published every this many ticks (they are best effort).
const GOAL_EVERY: u64 = 10;

/// What a simulated run saw.
#[derive(Debug, Clone, Default, Serialize)]
pub struct MocapReport {
    /// Pose messages published.
    pub poses_published: u64,
    /// Paths received, per robot.
    pub paths_received: Vec<u64>,
    /// Of those, empty (brake).
    pub empty_paths: u64,
    /// Goal sets the whole team reached.
    pub goal_sets_reached: u64,
}

/// One robot: where it is and the path it follows (monotonic ns, position).
struct Robot {
    position: [f64; 3],
    path: Vec<(u64, [f64; 3])>,
}

impl Robot {
    /// Where the path puts it at `now` (holding where it is without one).
    fn at(&self, now: u64) -> [f64; 3] {
        let Some(last) = self.path.last() else { return self.position };
        if now >= last.0 {
            return last.1;
        }
        match self.path.windows(2).find(|w| now < w[1].0) {
            Some(w) if now >= w[0].0 => {
                let s = (now - w[0].0) as f64 / (w[1].0 - w[0].0).max(1) as f64;
                std::array::from_fn(|a| w[0].1[a] + s * (w[1].1[a] - w[0].1[a]))
            }
            _ => self.path[0].1,
        }
    }
}

/// Simulates team `team` from `starts` until `stop`; `goals` draws each
/// new goal set; a robot is at its goal within `arrived_m`.
pub fn run(
    s: &BridgeSettings,
    team: &str,
    starts: Vec<[f64; 3]>,
    goals: &mut dyn FnMut() -> Vec<[f64; 3]>,
    arrived_m: f64,
    stop: &AtomicBool,
) -> Result<MocapReport, BridgeError> {
    let context =
        Context::with_options(ContextOptions::new().domain_id(s.domain_id)).map_err(ros("simulated mocap, DDS"))?;
    let name = NodeName::new("/flowopt", "simulated_mocap").map_err(ros("simulated mocap, node name"))?;
    let mut node = context
        .new_node(name, NodeOptions::new().enable_rosout(false).start_parameter_services(false))
        .map_err(ros("simulated mocap, node"))?;
    let n = starts.len();
    let (input, output) = (qos(s.input_reliability, 10), qos(s.output_reliability, 10));
    let mut poses: Vec<Publisher<PoseStamped>> = Vec::new();
    let mut goal_pubs: Vec<Publisher<PoseStamped>> = Vec::new();
    let mut paths: Vec<Subscription<Path>> = Vec::new();
    for i in 0..n {
        poses.push(advertise(&mut node, &topic(&s.pose_topic, team, Some(i)), types::pose_stamped(), &input)?);
        goal_pubs.push(advertise(&mut node, &topic(&s.goal_topic, team, Some(i)), types::pose_stamped(), &input)?);
        paths.push(subscribe(&mut node, &topic(&s.path_topic, team, Some(i)), types::path(), &output)?);
    }
    let mut robots: Vec<Robot> = starts.into_iter().map(|p| Robot { position: p, path: Vec::new() }).collect();
    let mut goal = goals();
    let mut report = MocapReport { paths_received: vec![0; n], ..MocapReport::default() };
    let period = Duration::from_secs_f64(1.0 / s.rate_hz);
    let mut next = Instant::now();
    let mut tick = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let clocks = Clocks::now();
        for (i, sub) in paths.iter().enumerate() {
            while let Ok(Some((path, _))) = sub.take() {
                report.paths_received[i] += 1;
                report.empty_paths += u64::from(path.poses.is_empty());
                robots[i].position = robots[i].at(clocks.monotonic_ns);
                robots[i].path =
                    path.poses.iter().map(|p| (clocks.monotonic(p.header.stamp), p.pose.position.array())).collect();
            }
        }
        let header = Header { stamp: clocks.ros(clocks.monotonic_ns), frame_id: s.frame_id.clone() };
        for (i, robot) in robots.iter_mut().enumerate() {
            robot.position = robot.at(clocks.monotonic_ns);
            let pose = Pose { position: Vector3::of(robot.position), orientation: Quaternion::default() };
            if poses[i].publish(PoseStamped { header: header.clone(), pose }).is_ok() {
                report.poses_published += 1;
            }
            if tick.is_multiple_of(GOAL_EVERY) {
                let pose = Pose { position: Vector3::of(goal[i]), orientation: Quaternion::default() };
                let _ = goal_pubs[i].publish(PoseStamped { header: header.clone(), pose });
            }
        }
        let distance = |a: [f64; 3], b: [f64; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
        if robots.iter().zip(&goal).all(|(r, g)| distance(r.position, *g) <= arrived_m) {
            report.goal_sets_reached += 1;
            goal = goals();
            tick = 0;
        } else {
            tick += 1;
        }
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
    }
    Ok(report)
}
