//! The ROS 2 messages the bridge speaks, laid out field for field as their
//! `.msg` definitions (CDR has no field names: the order is the contract).
//! ros2-client ships none of these; they are checked against the bytes a
//! ROS 2 peer puts on the wire in this module's tests.

use serde::{Deserialize, Serialize};
use serde_big_array::BigArray;

/// `builtin_interfaces/Time` (also the layout of `Duration`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds, below a second.
    pub nanosec: u32,
}

impl Time {
    /// `ns` nanoseconds (since the Unix epoch for a stamp).
    pub fn from_ns(ns: i64) -> Self {
        Self { sec: ns.div_euclid(1_000_000_000) as i32, nanosec: ns.rem_euclid(1_000_000_000) as u32 }
    }

    /// In nanoseconds.
    pub fn ns(self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }
}

/// `builtin_interfaces/Duration`.
pub type Duration = Time;

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Stamp (ROS time: the Unix epoch on a real clock).
    pub stamp: Time,
    /// Frame.
    pub frame_id: String,
}

/// `geometry_msgs/Point` and `geometry_msgs/Vector3`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

impl Vector3 {
    /// From an array.
    pub fn of(p: [f64; 3]) -> Self {
        Self { x: p[0], y: p[1], z: p[2] }
    }

    /// As an array.
    pub fn array(self) -> [f64; 3] {
        [self.x, self.y, self.z]
    }
}

/// `geometry_msgs/Point`.
pub type Point = Vector3;

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Default for Quaternion {
    /// The identity (the `.msg` default; CDR carries no defaults).
    fn default() -> Self {
        Self { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position.
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/PoseStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    /// Header.
    pub header: Header,
    /// Pose.
    pub pose: Pose,
}

/// `geometry_msgs/Twist`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity.
    pub linear: Vector3,
    /// Angular velocity.
    pub angular: Vector3,
}

/// `geometry_msgs/PoseWithCovariance`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// Pose.
    pub pose: Pose,
    /// Row-major 6x6 covariance.
    #[serde(with = "BigArray")]
    pub covariance: [f64; 36],
}

/// `geometry_msgs/TwistWithCovariance`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    /// Twist.
    pub twist: Twist,
    /// Row-major 6x6 covariance.
    #[serde(with = "BigArray")]
    pub covariance: [f64; 36],
}

/// `nav_msgs/Odometry`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Odometry {
    /// Header (the pose's frame).
    pub header: Header,
    /// The twist's frame.
    pub child_frame_id: String,
    /// Pose.
    pub pose: PoseWithCovariance,
    /// Twist (in `child_frame_id`; the bridge reads it as world-aligned).
    pub twist: TwistWithCovariance,
}

/// `nav_msgs/Path`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Path {
    /// Header.
    pub header: Header,
    /// Poses, each stamped with the time to be there.
    pub poses: Vec<PoseStamped>,
}

/// `geometry_msgs/Transform`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `trajectory_msgs/MultiDOFJointTrajectoryPoint`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiDofJointTrajectoryPoint {
    /// One transform per joint (robot).
    pub transforms: Vec<Transform>,
    /// One velocity per joint.
    pub velocities: Vec<Twist>,
    /// One acceleration per joint.
    pub accelerations: Vec<Twist>,
    /// From the header's stamp.
    pub time_from_start: Duration,
}

/// `trajectory_msgs/MultiDOFJointTrajectory`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiDofJointTrajectory {
    /// Header: the stamp is the plan's start.
    pub header: Header,
    /// The robots' names.
    pub joint_names: Vec<String>,
    /// Points.
    pub points: Vec<MultiDofJointTrajectoryPoint>,
}

/// `std_msgs/String`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct StringMsg {
    /// The text.
    pub data: String,
}

/// `std_msgs/MultiArrayDimension`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiArrayDimension {
    /// Label.
    pub label: String,
    /// Size.
    pub size: u32,
    /// Stride.
    pub stride: u32,
}

/// `std_msgs/MultiArrayLayout`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiArrayLayout {
    /// Dimensions.
    pub dim: Vec<MultiArrayDimension>,
    /// Offset of the first element.
    pub data_offset: u32,
}

/// `std_msgs/Float64MultiArray`: the obstacles topic, one row of
/// [`crate::convert::OBSTACLE_FIELDS`] numbers per obstacle.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Float64MultiArray {
    /// Layout (ignored on input).
    pub layout: MultiArrayLayout,
    /// Row-major data.
    pub data: Vec<f64>,
}

/// The ROS type names of the messages above.
pub mod types {
    use ros2_client::MessageTypeName;

    /// `geometry_msgs/PoseStamped`.
    pub fn pose_stamped() -> MessageTypeName {
        MessageTypeName::new("geometry_msgs", "PoseStamped")
    }
    /// `nav_msgs/Odometry`.
    pub fn odometry() -> MessageTypeName {
        MessageTypeName::new("nav_msgs", "Odometry")
    }
    /// `nav_msgs/Path`.
    pub fn path() -> MessageTypeName {
        MessageTypeName::new("nav_msgs", "Path")
    }
    /// `trajectory_msgs/MultiDOFJointTrajectory`.
    pub fn trajectory() -> MessageTypeName {
        MessageTypeName::new("trajectory_msgs", "MultiDOFJointTrajectory")
    }
    /// `std_msgs/String`.
    pub fn string() -> MessageTypeName {
        MessageTypeName::new("std_msgs", "String")
    }
    /// `std_msgs/Float64MultiArray`.
    pub fn float64_array() -> MessageTypeName {
        MessageTypeName::new("std_msgs", "Float64MultiArray")
    }
}
