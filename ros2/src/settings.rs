//! The bridge's settings, declared once with their defaults: the `[ros2]`
//! table of a bridge file (`flowopt ros2 --bridge FILE`), every key
//! optional. Topic names take `{team}` and `{robot}` (the robot's index).

use std::path::Path;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// What a robot's pose topic carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseKind {
    /// `geometry_msgs/PoseStamped`: velocity estimated from successive poses.
    PoseStamped,
    /// `nav_msgs/Odometry`: velocity from its twist.
    Odometry,
}

/// Reliability of a subscription or publication.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Reliability {
    /// Best effort (ROS 2's sensor-data profile; what mocap bridges use).
    BestEffort,
    /// Reliable (ROS 2's default profile).
    Reliable,
}

/// The bridge's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BridgeSettings {
    /// DDS domain (`ROS_DOMAIN_ID`).
    pub domain_id: u16,
    /// Frame of every published message and expected of every input.
    pub frame_id: String,
    /// Each robot's pose (mocap).
    pub pose_topic: String,
    /// Its message type.
    pub pose_kind: PoseKind,
    /// Reliability of the pose and goal subscriptions.
    pub input_reliability: Reliability,
    /// Each robot's goal (`geometry_msgs/PoseStamped`); until one arrives
    /// a robot's goal is where it first was seen.
    pub goal_topic: String,
    /// Obstacles (`std_msgs/Float64MultiArray`, one row of x, y, z, vx,
    /// vy, vz, radius, half_height per obstacle); empty: none.
    pub obstacles_topic: String,
    /// Each robot's plan to follow (`nav_msgs/Path`); an empty path: no
    /// verified plan, brake.
    pub path_topic: String,
    /// The team's plan (`trajectory_msgs/MultiDOFJointTrajectory`).
    pub trajectory_topic: String,
    /// Every answer's status (`std_msgs/String`, JSON, docs/ROS2.md).
    pub status_topic: String,
    /// Each robot's plan as Crazyswarm polynomial pieces
    /// (`std_msgs/Float64MultiArray`, one row of 33 per piece: duration,
    /// then x, y, z, yaw coefficients of ascending powers); empty: none.
    pub pieces_topic: String,
    /// Reliability of the published topics.
    pub output_reliability: Reliability,
    /// Points of a published path or trajectory (over the plan's horizon).
    pub path_points: usize,
    /// Rate of the snapshots sent to the daemon (Hz).
    pub rate_hz: f64,
    /// A robot whose pose is older than this is stale: no snapshot is sent
    /// (the daemon's plans stop being fresh; the controller brakes).
    pub pose_timeout_s: f64,
}

impl Default for BridgeSettings {
    fn default() -> Self {
        Self {
            domain_id: 0,
            frame_id: "world".into(),
            pose_topic: "/{team}/robot{robot}/pose".into(),
            pose_kind: PoseKind::PoseStamped,
            input_reliability: Reliability::BestEffort,
            goal_topic: "/{team}/robot{robot}/goal".into(),
            obstacles_topic: "/{team}/obstacles".into(),
            path_topic: "/flowopt/{team}/robot{robot}/path".into(),
            trajectory_topic: "/flowopt/{team}/trajectory".into(),
            status_topic: "/flowopt/{team}/status".into(),
            pieces_topic: "/flowopt/{team}/robot{robot}/pieces".into(),
            output_reliability: Reliability::Reliable,
            path_points: 50,
            rate_hz: 50.0,
            pose_timeout_s: 0.25,
        }
    }
}

/// Why the settings cannot be used.
#[derive(Debug, Error)]
pub enum SettingsError {
    /// The file cannot be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The file is not valid.
    #[error("{path}: {source}")]
    Parse {
        /// The file.
        path: String,
        /// Why.
        source: toml::de::Error,
    },
    /// A value is out of range.
    #[error("ros2.{key}: {why}")]
    Invalid {
        /// The key.
        key: &'static str,
        /// Why.
        why: String,
    },
}

/// A bridge file: its `[ros2]` table.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    ros2: BridgeSettings,
}

impl BridgeSettings {
    /// The settings in `path`'s `[ros2]` table.
    pub fn load(path: &Path) -> Result<Self, SettingsError> {
        let name = path.display().to_string();
        let text =
            std::fs::read_to_string(path).map_err(|source| SettingsError::Read { path: name.clone(), source })?;
        let file: File = toml::from_str(&text).map_err(|source| SettingsError::Parse { path: name, source })?;
        file.ros2.checked()
    }

    /// These settings, checked.
    pub fn checked(self) -> Result<Self, SettingsError> {
        let invalid = |key, why: &str| Err(SettingsError::Invalid { key, why: why.to_string() });
        if !(self.rate_hz > 0.0 && self.rate_hz <= 1000.0) {
            return invalid("rate_hz", "must be in (0, 1000]");
        }
        if self.path_points < 2 {
            return invalid("path_points", "must be at least 2");
        }
        if self.pose_timeout_s.is_nan() || self.pose_timeout_s <= 0.0 {
            return invalid("pose_timeout_s", "must be positive");
        }
        if self.domain_id > 232 {
            return invalid("domain_id", "must be at most 232");
        }
        for (key, topic) in
            [("pose_topic", &self.pose_topic), ("goal_topic", &self.goal_topic), ("path_topic", &self.path_topic)]
        {
            if !topic.contains("{robot}") {
                return invalid(key, "needs {robot}: one topic per robot");
            }
        }
        Ok(self)
    }
}

/// `template` with `{team}` and `{robot}` filled in.
pub fn topic(template: &str, team: &str, robot: Option<usize>) -> String {
    let named = template.replace("{team}", team);
    match robot {
        Some(i) => named.replace("{robot}", &i.to_string()),
        None => named,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_overrides_only_what_it_names_and_bad_values_are_named() {
        let dir = std::env::temp_dir().join(format!("flowopt-ros2-settings-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bridge.toml");
        std::fs::write(&path, "[ros2]\ndomain_id = 7\npose_kind = \"odometry\"\n").unwrap();
        let s = BridgeSettings::load(&path).unwrap();
        assert_eq!((s.domain_id, s.pose_kind), (7, PoseKind::Odometry));
        assert_eq!(s.path_topic, BridgeSettings::default().path_topic);
        std::fs::write(&path, "[ros2]\nrate_hz = 0\n").unwrap();
        let err = BridgeSettings::load(&path).unwrap_err().to_string();
        assert!(err.contains("ros2.rate_hz"), "{err}");
        std::fs::write(&path, "[ros2]\npath_topic = \"/plans\"\n").unwrap();
        assert!(BridgeSettings::load(&path).unwrap_err().to_string().contains("{robot}"));
        std::fs::write(&path, "[ros2]\nno_such_key = 1\n").unwrap();
        assert!(BridgeSettings::load(&path).unwrap_err().to_string().contains("no_such_key"));
        assert_eq!(topic("/{team}/robot{robot}/pose", "alpha", Some(3)), "/alpha/robot3/pose");
    }

    #[test]
    fn the_shipped_bridge_file_shows_the_defaults() {
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/ros2.toml");
        assert_eq!(BridgeSettings::load(&shipped).unwrap(), BridgeSettings::default());
    }
}
