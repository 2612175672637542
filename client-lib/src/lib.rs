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
//! - [`follow`]: the followability contract on the controller's side:
//!   which verified trajectory to follow now ([`Follower`]);
//! - [`codes`]: a plan message's [`PlanStatus`] and [`Reason`] codes, and
//!   [`MessageError`];
//! - [`clock`]: the monotonic clock every timestamp is read from;
//! - [`records`]: the messages as plain serde records (recordings, the
//!   live view, the ROS 2 bridge's status).
//!
//! A controller publishes its measured state, takes the newest plan message
//! and follows what the contract says (a verified trajectory, or none:
//! bring the robots to rest):
//!
//! ```no_run
//! use std::time::Duration;
//! use flowopt_client::{Endpoint, TeamChannel};
//!
//! # fn main() -> Result<(), flowopt_client::ClientError> {
//! let endpoint = Endpoint::new("my-controller")?;
//! let channel = TeamChannel::new("flowopt", "default")?;
//! let mut states = endpoint.state_publisher(&channel)?;
//! let mut plans = endpoint.plan_subscriber(&channel, &states)?;
//! states.publish_with(|s| {
//!     s.dim = 2;
//!     s.robots = 1;
//!     s.robot[0].position = [-0.5, 0.0, 0.0];
//!     s.robot[0].goal = [0.5, 0.0, 0.0];
//! })?;
//! if let Some(msg) = plans.wait(Duration::from_millis(100))? {
//!     println!("status {:?}, reason {:?}", msg.status(), msg.reason());
//! }
//! match plans.to_follow() {
//!     Some(followed) => {
//!         let now = followed.at(flowopt_client::clock::monotonic_ns());
//!         println!("robot 0 should be at {:?}", now[0].position);
//!     }
//!     None => println!("no verified plan: bring the robots to rest"),
//! }
//! # Ok(())
//! # }
//! ```

pub mod clock;
pub mod codes;
pub mod follow;
pub mod messages;
pub mod pieces;
pub mod ports;
pub mod records;

use thiserror::Error;

pub use follow::{Followed, Follower, Sent};
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
