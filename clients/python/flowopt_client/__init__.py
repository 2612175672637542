"""flowopt's Python client: the wire messages and the controller's ports.

- ``messages``: ``StateSnapshot`` and ``JointTrajectory`` (with their
  sub-structures) as ctypes structures, laid out as ``docs/MESSAGES.md``
  says (checked at import), the status and reason codes;
- ``ports``: ``Endpoint`` (an iceoryx2 node), ``StatePublisher`` and
  ``PlanSubscriber``, opened with the daemon's service settings;
- ``plan``: ``Plan`` (a message copied out of shared memory),
  ``Trajectory`` (positions, velocities and accelerations at any times,
  vectorised) and ``Follower`` (the followability contract);
- ``example``: a controller flying a simulated team against a running
  daemon (``python -m flowopt_client.example --help``).

A controller publishes its measured state, takes the newest plan and follows
what the contract says::

    from flowopt_client import Endpoint, TeamChannel, robot_array

    endpoint = Endpoint("my-controller")
    channel = TeamChannel("flowopt", "default")
    states = endpoint.state_publisher(channel)
    plans = endpoint.plan_subscriber(channel, states)

    def fill(snapshot):
        snapshot.dim, snapshot.robots = 2, 16
        robot_array(snapshot)[:16] = ...  # position, velocity, goal per robot

    states.publish_with(fill)
    plan = plans.wait(0.1)
    followed = plans.to_follow()
    if followed is None:
        ...  # no verified plan: bring the robots to rest
    else:
        kinematics = followed.at_ns(monotonic_ns())
"""

from .messages import (
    MAX_COEFFS,
    MAX_OBSTACLES,
    MAX_ROBOTS,
    TEAM_NAME_LEN,
    WIRE_VERSION,
    JointTrajectory,
    ObstacleState,
    PlanStatus,
    Reason,
    RobotState,
    StageTimings,
    StateSnapshot,
    coeff_array,
    obstacle_array,
    read_team,
    robot_array,
    write_team,
)
from .plan import Followed, Follower, Kinematics, MessageError, Plan, Sent, Trajectory, bernstein_rows
from .ports import Endpoint, PlanSubscriber, StatePublisher, TeamChannel, monotonic_ns

__all__ = [
    "MAX_COEFFS",
    "MAX_OBSTACLES",
    "MAX_ROBOTS",
    "TEAM_NAME_LEN",
    "WIRE_VERSION",
    "Endpoint",
    "Followed",
    "Follower",
    "Sent",
    "JointTrajectory",
    "Kinematics",
    "MessageError",
    "ObstacleState",
    "Plan",
    "PlanStatus",
    "PlanSubscriber",
    "Reason",
    "RobotState",
    "StageTimings",
    "StatePublisher",
    "StateSnapshot",
    "TeamChannel",
    "Trajectory",
    "bernstein_rows",
    "coeff_array",
    "monotonic_ns",
    "obstacle_array",
    "read_team",
    "robot_array",
    "write_team",
]
