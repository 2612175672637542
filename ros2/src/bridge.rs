//! The bridge's loop: a controller of the daemon like any other. It takes
//! each robot's pose (mocap) and goal and the obstacles from ROS 2, sends
//! the team's snapshot to the daemon over iceoryx2 at its rate, and
//! publishes what the followability contract says to follow: a
//! `nav_msgs/Path` per robot and the team's `MultiDOFJointTrajectory`
//! whenever that changes (empty when there is no verified plan: brake),
//! every answer's status, and the plan as Crazyswarm pieces.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use flowopt_client::clock::monotonic_ns;
use flowopt_client::records::AnswerRecord;
use flowopt_client::{Endpoint, Followed, MAX_OBSTACLES, StatePublisher, TeamChannel};
use flowopt_planner::problem::Dim;
use ros2_client::{Context, ContextOptions, Node, NodeName, NodeOptions, Publisher, Subscription};
use serde::Serialize;
use tracing::{info, warn};

use crate::convert::{self, Clocks, ObstacleRow, Tracked};
use crate::error::BridgeError;
use crate::msgs::{Float64MultiArray, MultiDofJointTrajectory, Odometry, Path, PoseStamped, StringMsg, types};
use crate::node::{advertise, qos, ros, subscribe};
use crate::settings::{BridgeSettings, PoseKind, topic};

/// The team the bridge serves.
#[derive(Debug, Clone)]
pub struct BridgeTeam {
    /// Its name in the daemon's configuration.
    pub name: String,
    /// Robots.
    pub robots: usize,
    /// 2 or 3 axes.
    pub dim: Dim,
}

/// What a run of the bridge did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct BridgeReport {
    /// Snapshots sent to the daemon.
    pub snapshots: u64,
    /// Ticks with a robot's pose missing or stale (no snapshot sent).
    pub stale_ticks: u64,
    /// Answers received (each published on the status topic).
    pub answers: u64,
    /// Times the plan to follow changed (paths and trajectory published).
    pub plans_published: u64,
    /// Of those, with no plan to follow (empty paths: brake).
    pub brakes_published: u64,
    /// Input messages ignored (wrong frame, not finite, bad obstacles).
    pub bad_inputs: u64,
    /// Publications that failed (a full reliable window).
    pub publish_failures: u64,
}

/// A robot's pose subscription, of either kind.
enum Poses {
    Stamped(Subscription<PoseStamped>),
    Odometry(Subscription<Odometry>),
}

/// The bridge's ROS 2 side.
struct Ros {
    poses: Vec<Poses>,
    goals: Vec<Subscription<PoseStamped>>,
    obstacles: Option<Subscription<Float64MultiArray>>,
    paths: Vec<Publisher<Path>>,
    trajectory: Publisher<MultiDofJointTrajectory>,
    status: Publisher<StringMsg>,
    pieces: Vec<Publisher<Float64MultiArray>>,
    // Dropped last: the publishers and subscriptions above belong to it.
    _node: Node,
    _context: Context,
}

impl Ros {
    fn open(s: &BridgeSettings, team: &BridgeTeam) -> Result<Self, BridgeError> {
        let context = Context::with_options(ContextOptions::new().domain_id(s.domain_id)).map_err(ros("DDS"))?;
        let node_name: String = team.name.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
        let node_name = NodeName::new("/flowopt", &format!("bridge_{node_name}")).map_err(ros("node name"))?;
        let options = NodeOptions::new().enable_rosout(false).start_parameter_services(false);
        let mut node = context.new_node(node_name, options).map_err(ros("node"))?;
        let input = qos(s.input_reliability, 1);
        let output = qos(s.output_reliability, 10);
        let t = |template: &str, robot| topic(template, &team.name, robot);
        let mut poses = Vec::new();
        let mut goals = Vec::new();
        let mut paths = Vec::new();
        let mut pieces = Vec::new();
        for i in 0..team.robots {
            let pose_topic = t(&s.pose_topic, Some(i));
            poses.push(match s.pose_kind {
                PoseKind::PoseStamped => {
                    Poses::Stamped(subscribe(&mut node, &pose_topic, types::pose_stamped(), &input)?)
                }
                PoseKind::Odometry => Poses::Odometry(subscribe(&mut node, &pose_topic, types::odometry(), &input)?),
            });
            goals.push(subscribe(&mut node, &t(&s.goal_topic, Some(i)), types::pose_stamped(), &input)?);
            paths.push(advertise(&mut node, &t(&s.path_topic, Some(i)), types::path(), &output)?);
            if !s.pieces_topic.is_empty() {
                pieces.push(advertise(&mut node, &t(&s.pieces_topic, Some(i)), types::float64_array(), &output)?);
            }
        }
        let obstacles = if s.obstacles_topic.is_empty() {
            None
        } else {
            Some(subscribe(&mut node, &t(&s.obstacles_topic, None), types::float64_array(), &input)?)
        };
        let trajectory = advertise(&mut node, &t(&s.trajectory_topic, None), types::trajectory(), &output)?;
        let status = advertise(&mut node, &t(&s.status_topic, None), types::string(), &output)?;
        Ok(Self { poses, goals, obstacles, paths, trajectory, status, pieces, _node: node, _context: context })
    }
}

/// The world as the bridge last heard it.
struct World {
    robots: Vec<Tracked>,
    goals: Vec<Option<[f64; 3]>>,
    obstacles: Vec<ObstacleRow>,
}

/// Runs the bridge for `team` of the daemon under iceoryx2 `prefix` until
/// `stop`.
pub fn run(
    s: &BridgeSettings,
    prefix: &str,
    team: &BridgeTeam,
    stop: &AtomicBool,
) -> Result<BridgeReport, BridgeError> {
    let ros = Ros::open(s, team)?;
    let channel = TeamChannel::new(prefix, &team.name)?;
    let endpoint = Endpoint::new(&format!("flowopt-ros2-{}", team.name))?;
    let mut states = endpoint.state_publisher(&channel)?;
    let mut plans = endpoint.plan_subscriber(&channel, &states)?;
    info!(
        team = team.name,
        robots = team.robots,
        domain = s.domain_id,
        "bridging ROS 2 poses {} to plans {}",
        topic(&s.pose_topic, &team.name, None),
        topic(&s.path_topic, &team.name, None)
    );
    let names: Vec<String> = (0..team.robots).map(|i| format!("robot{i}")).collect();
    let mut world =
        World { robots: vec![Tracked::default(); team.robots], goals: vec![None; team.robots], obstacles: vec![] };
    let mut report = BridgeReport::default();
    let period = Duration::from_secs_f64(1.0 / s.rate_hz);
    let timeout_ns = (s.pose_timeout_s * 1e9) as u64;
    let mut followed_key = None;
    let mut next = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        take_inputs(&ros, s, &mut world, &mut report);
        let now = monotonic_ns();
        if world.robots.iter().all(|r| r.at_ns > 0 && now.saturating_sub(r.at_ns) <= timeout_ns) {
            send(&mut states, team, &world)?;
            report.snapshots += 1;
        } else {
            report.stale_ticks += 1;
        }
        next += period;
        loop {
            let left = next.saturating_duration_since(Instant::now());
            let Some(msg) = plans.wait(left)? else { break };
            report.answers += 1;
            let status = serde_json::to_string(&AnswerRecord::of(&msg, false)).unwrap_or_default();
            publish(&ros.status, StringMsg { data: status }, &mut report);
            let followed = plans.to_follow();
            let key = followed.map(|f| (f.plan_sequence, f.origin_ns));
            if key != followed_key {
                followed_key = key;
                publish_plan(&ros, s, followed, &names, &mut report);
            }
        }
        if next + period < Instant::now() {
            next = Instant::now();
        }
    }
    Ok(report)
}

/// Drains every input topic into `world`.
fn take_inputs(ros: &Ros, s: &BridgeSettings, world: &mut World, report: &mut BridgeReport) {
    let clocks = Clocks::now();
    let frame_ok = |frame: &str| frame.is_empty() || frame == s.frame_id;
    for (i, poses) in ros.poses.iter().enumerate() {
        loop {
            let (header, position, velocity) = match poses {
                Poses::Stamped(sub) => match sub.take() {
                    Ok(Some((m, _))) => (m.header, m.pose.position.array(), None),
                    _ => break,
                },
                Poses::Odometry(sub) => match sub.take() {
                    Ok(Some((m, _))) => (m.header, m.pose.pose.position.array(), Some(m.twist.twist.linear.array())),
                    _ => break,
                },
            };
            let at = if header.stamp.ns() > 0 { clocks.measured(header.stamp) } else { clocks.monotonic_ns };
            if !frame_ok(&header.frame_id) || !world.robots[i].update(position, velocity, at) {
                report.bad_inputs += 1;
            }
        }
    }
    for (i, goals) in ros.goals.iter().enumerate() {
        while let Ok(Some((m, _))) = goals.take() {
            let goal = m.pose.position.array();
            if frame_ok(&m.header.frame_id) && goal.iter().all(|x| x.is_finite()) {
                world.goals[i] = Some(goal);
            } else {
                report.bad_inputs += 1;
            }
        }
    }
    if let Some(sub) = &ros.obstacles {
        while let Ok(Some((m, _))) = sub.take() {
            match convert::obstacles(&m) {
                Ok(rows) if rows.len() <= MAX_OBSTACLES => world.obstacles = rows,
                Ok(rows) => {
                    warn!("{} obstacles, more than a snapshot carries ({MAX_OBSTACLES}): ignored", rows.len());
                    report.bad_inputs += 1;
                }
                Err(why) => {
                    warn!("obstacles ignored: {why}");
                    report.bad_inputs += 1;
                }
            }
        }
    }
}

/// Sends the team's snapshot, stamped with its oldest pose's time.
fn send(states: &mut StatePublisher, team: &BridgeTeam, world: &World) -> Result<u64, BridgeError> {
    let oldest = world.robots.iter().map(|r| r.at_ns).min().unwrap_or(0);
    Ok(states.publish_with(|snap| {
        snap.timestamp_ns = oldest;
        snap.dim = team.dim.axes() as u32;
        snap.robots = team.robots as u32;
        for (i, r) in world.robots.iter().enumerate() {
            snap.robot[i].position = r.position;
            snap.robot[i].velocity = r.velocity;
            // Until a goal arrives, a robot's goal is where it is.
            snap.robot[i].goal = world.goals[i].unwrap_or(r.position);
        }
        snap.obstacles = world.obstacles.len() as u32;
        for (k, o) in world.obstacles.iter().enumerate() {
            snap.obstacle[k].position = o.position;
            snap.obstacle[k].velocity = o.velocity;
            snap.obstacle[k].radius = o.radius;
            snap.obstacle[k].half_height = o.half_height;
        }
    })?)
}

fn publish<M: Serialize>(publisher: &Publisher<M>, msg: M, report: &mut BridgeReport) {
    if publisher.publish(msg).is_err() {
        report.publish_failures += 1;
    }
}

/// Publishes the plan to follow (or empty ones: brake).
fn publish_plan(
    ros: &Ros,
    s: &BridgeSettings,
    followed: Option<&Followed>,
    names: &[String],
    report: &mut BridgeReport,
) {
    let clocks = Clocks::now();
    report.plans_published += 1;
    report.brakes_published += u64::from(followed.is_none());
    let sampled = followed.map(|f| convert::Sampled::of(f, s.path_points));
    for (i, publisher) in ros.paths.iter().enumerate() {
        publish(publisher, convert::path(sampled.as_ref(), i, &s.frame_id, &clocks), report);
    }
    publish(&ros.trajectory, convert::trajectory(sampled.as_ref(), names, &s.frame_id, &clocks), report);
    for (i, publisher) in ros.pieces.iter().enumerate() {
        publish(publisher, convert::pieces(followed, i), report);
    }
}
