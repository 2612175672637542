//! Why the bridge or the simulated team stopped.

use thiserror::Error;

/// Why the bridge stopped.
#[derive(Debug, Error)]
pub enum BridgeError {
    /// A ROS 2 entity could not be created.
    #[error("ROS 2: {0}")]
    Ros(String),
    /// The daemon's ports.
    #[error(transparent)]
    Port(#[from] flowopt_client::PortError),
}
