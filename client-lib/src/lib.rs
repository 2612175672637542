//! flowopt's client library: the messages the daemon and controllers
//! exchange over iceoryx2 shared memory, and the ports that carry them.
//!
//! - [`messages`]: [`StateSnapshot`] (controller to daemon) and
//!   [`JointTrajectory`] (daemon to controllers), `#[repr(C)]` with fixed
//!   capacities and stable iceoryx2 type names (byte layout in
//!   `docs/MESSAGES.md`);
//! - [`ports`]: [`Endpoint`] (one iceoryx2 node) and the four ports:
//!   [`StatePublisher`] and [`PlanSubscriber`] for controllers,
//!   [`StateSubscriber`] and [`PlanPublisher`] for the daemon;
//! - [`clock`]: the monotonic clock every timestamp is read from.
//!
//! A controller publishes its measured state and waits for the newest plan:
//!
//! ```no_run
//! use std::time::Duration;
//! use flowopt_client::{Endpoint, TeamChannel};
//!
//! # fn main() -> Result<(), flowopt_client::ClientError> {
//! let endpoint = Endpoint::new("my-controller")?;
//! let channel = TeamChannel::new("flowopt", "default")?;
//! let mut states = endpoint.state_publisher(&channel)?;
//! let plans = endpoint.plan_subscriber(&channel)?;
//! states.publish_with(|s| {
//!     s.dim = 2;
//!     s.robots = 1;
//!     s.robot[0].position = [-0.5, 0.0, 0.0];
//!     s.robot[0].goal = [0.5, 0.0, 0.0];
//! })?;
//! if let Some(plan) = plans.wait(Duration::from_millis(100))? {
//!     let now = plan.elapsed_s(flowopt_client::clock::monotonic_ns());
//!     let robot0 = plan.sample_robot(0, now)?;
//!     println!("{:?} -> {:?}", plan.status, robot0.position);
//! }
//! # Ok(())
//! # }
//! ```

pub mod clock;
pub mod messages;
pub mod ports;

use thiserror::Error;

pub use messages::{
    JointTrajectory, MAX_COEFFS, MAX_OBSTACLES, MAX_ROBOTS, MessageError, ObstacleState, PlanStatus, Reason,
    RobotState, StageTimings, StateSnapshot, TEAM_NAME_LEN, WIRE_VERSION,
};
pub use ports::{Endpoint, PlanPublisher, PlanSubscriber, PortError, StatePublisher, StateSubscriber, TeamChannel};

/// Either of the library's errors, for a controller that opens ports and
/// reads messages in one function.
#[derive(Debug, Error)]
pub enum ClientError {
    /// Opening or using a port failed.
    #[error(transparent)]
    Port(#[from] PortError),
    /// Writing or reading a message failed.
    #[error(transparent)]
    Message(#[from] MessageError),
}
