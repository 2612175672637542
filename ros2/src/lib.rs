//! flowopt's ROS 2 bridge (`flowopt ros2`), on ros2-client over RustDDS:
//! no ROS install is needed to build, test or run it.
//!
//! - [`msgs`]: the ROS 2 messages it speaks, field for field;
//! - [`settings`]: topics, frames, QoS and rates, with their defaults;
//! - [`convert`]: plans to paths and trajectories on the ROS clock, poses
//!   to states with an estimated velocity, the obstacles array;
//! - `node`: opening topics with the QoS the settings name;
//! - [`error`]: why it stopped;
//! - [`bridge`]: the loop, a controller of the daemon like any other;
//! - [`mocap`]: a simulated team on ROS 2 (poses out, paths in), for
//!   demonstrations and tests without robots.

pub mod bridge;
pub mod convert;
pub mod error;
pub mod mocap;
pub mod msgs;
mod node;
pub mod settings;

pub use bridge::{BridgeReport, BridgeTeam, run};
pub use error::BridgeError;
pub use settings::BridgeSettings;
