"""Plans: evaluating the Bernstein trajectories of a plan message, and the
followability contract (``docs/MESSAGES.md``) on the controller's side.

- ``bernstein_rows`` evaluates the Bernstein polynomials of a degree, or
  their derivatives, at many normalised times at once;
- ``Trajectory`` is one verified joint trajectory (coefficients, horizon,
  time origin) and gives every robot's position, velocity and acceleration
  at any times, vectorised with numpy;
- ``Plan`` is a plan message copied out of shared memory: its header, and
  the ``Trajectory`` it carries when its status says to follow it;
- ``Follower`` keeps, from the newest message taken, the trajectory to
  follow now (or none: bring the robots to rest).
"""

from __future__ import annotations

import collections
import dataclasses
from math import comb
from typing import NamedTuple

import numpy as np

from .messages import MAX_COEFFS, MAX_ROBOTS, JointTrajectory, PlanStatus, Reason, coeff_array, read_team


class MessageError(ValueError):
    """A plan message with a value or shape no daemon writes."""


def bernstein_rows(degree: int, order: int, tau: np.ndarray | float) -> np.ndarray:
    """The ``order``-th derivative (in normalised time) of the ``degree + 1``
    Bernstein polynomials of ``degree`` at every ``tau`` in ``[0, 1]``.

    Returns shape ``tau.shape + (degree + 1,)``. Uses
    ``d^r/dtau^r B_{i,N} = N!/(N-r)! sum_j (-1)^(r-j) C(r,j) B_{i-j,N-r}``.
    """
    tau = np.asarray(tau, dtype=np.float64)[..., None]
    rows = np.zeros(tau.shape[:-1] + (degree + 1,))
    if order > degree:
        return rows
    low = degree - order
    i = np.arange(low + 1)
    binomials = np.array([comb(low, k) for k in range(low + 1)], dtype=np.float64)
    lower = binomials * tau**i * (1.0 - tau) ** (low - i)
    falling = float(np.prod(np.arange(degree, degree - order, -1, dtype=np.float64)))
    for j in range(order + 1):
        sign = 1.0 if (order - j) % 2 == 0 else -1.0
        rows[..., j : j + low + 1] += sign * comb(order, j) * lower
    return falling * rows


class Kinematics(NamedTuple):
    """Positions, velocities and accelerations, each ``(..., robots, dim)``."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """A joint trajectory: robot ``i``'s position on axis ``a`` at ``t``
    seconds after ``origin_ns`` is ``sum_c coeffs[i, a, c] B_c(t / horizon)``.
    """

    #: ``(robots, dim, degree + 1)`` Bernstein coefficients (m).
    coeffs: np.ndarray
    #: Horizon T (s): the goals are reached at rest at ``origin_ns + T``.
    horizon: float
    #: The time origin (``CLOCK_MONOTONIC`` ns): the trajectory's t = 0.
    origin_ns: int

    @property
    def robots(self) -> int:
        """Robots in the trajectory."""
        return self.coeffs.shape[0]

    @property
    def dim(self) -> int:
        """2 or 3."""
        return self.coeffs.shape[1]

    @property
    def degree(self) -> int:
        """The Bernstein degree."""
        return self.coeffs.shape[2] - 1

    def at(self, t: np.ndarray | float) -> Kinematics:
        """Every robot's kinematics ``t`` seconds after the origin (a scalar
        or an array of times; clamped to ``[0, horizon]``: before the
        trajectory its start, after it the goals at rest).

        For a scalar ``t`` each array is ``(robots, dim)``; for times of
        shape ``S``, ``S + (robots, dim)``.
        """
        tau = np.clip(np.asarray(t, dtype=np.float64) / self.horizon, 0.0, 1.0)
        scale = (1.0, 1.0 / self.horizon, 1.0 / self.horizon**2)
        values = [
            np.einsum("...c,iac->...ia", bernstein_rows(self.degree, order, tau), self.coeffs) * scale[order]
            for order in range(3)
        ]
        return Kinematics(*values)

    def at_ns(self, now_ns: np.ndarray | int) -> Kinematics:
        """Every robot's kinematics at ``CLOCK_MONOTONIC`` time ``now_ns``."""
        return self.at(self.elapsed_s(now_ns))

    def elapsed_s(self, now_ns: np.ndarray | int) -> np.ndarray | float:
        """Seconds from the origin to ``now_ns`` (negative before it)."""
        if isinstance(now_ns, (int, np.integer)):
            return (int(now_ns) - self.origin_ns) * 1e-9
        return (np.asarray(now_ns, dtype=np.int64) - np.int64(self.origin_ns)) * 1e-9


@dataclasses.dataclass(frozen=True)
class Plan:
    """One plan message, copied out of shared memory.

    ``trajectory`` is the verified trajectory to follow when ``status`` is
    followable (``Ok``, ``Held``, ``Stopping``), and ``None`` for ``NoPlan``.
    """

    status: PlanStatus
    #: A ``Reason``, or the bare code if this client does not know it.
    reason: Reason | int
    #: The robot (or 256 + obstacle) the reason points at; ``None``: none.
    reason_index: int | None
    team: str
    dim: int
    robots: int
    iterations: int
    answers_sequence: int
    state_timestamp_ns: int
    plan_sequence: int
    plan_origin_ns: int
    received_ns: int
    published_ns: int
    horizon: float
    primal_residual: float
    smoothness: float
    max_speed: float
    max_acceleration: float
    warm_started: bool
    candidates: int
    timings_us: dict[str, int]
    trajectory: Trajectory | None

    @classmethod
    def from_message(cls, msg: JointTrajectory) -> Plan:
        """Copies ``msg`` (which may live in shared memory).

        Raises ``MessageError`` for a status no daemon writes, and for a
        followable message whose shape is impossible (dim not 2 or 3,
        no robots or more than 256, degree not in 1..15, horizon not
        positive and finite): such a message gives nothing to follow.
        """
        try:
            status = PlanStatus(msg.status)
        except ValueError:
            raise MessageError(f"the message's status {msg.status} is no daemon's") from None
        reason = Reason(msg.reason) if msg.reason in Reason._value2member_map_ else int(msg.reason)
        trajectory = None
        if status.followable:
            if msg.dim not in (2, 3):
                raise MessageError(f"the plan message has an invalid dim {msg.dim}")
            if not 1 <= msg.robots <= MAX_ROBOTS:
                raise MessageError(f"the plan message has an invalid robot count {msg.robots}")
            if not 1 <= msg.degree < MAX_COEFFS:
                raise MessageError(f"the plan message has an invalid degree {msg.degree}")
            if not (np.isfinite(msg.horizon) and msg.horizon > 0.0):
                raise MessageError(f"the plan message has an invalid horizon {msg.horizon}")
            coeffs = coeff_array(msg)[: msg.robots, : msg.dim, : msg.degree + 1].copy()
            trajectory = Trajectory(coeffs=coeffs, horizon=float(msg.horizon), origin_ns=int(msg.plan_origin_ns))
        try:
            team = read_team(msg)
        except UnicodeDecodeError:
            raise MessageError("the message's team name is not UTF-8") from None
        return cls(
            status=status,
            reason=reason,
            reason_index=None if msg.reason_index == 0xFFFF_FFFF else int(msg.reason_index),
            team=team,
            dim=int(msg.dim),
            robots=int(msg.robots),
            iterations=int(msg.iterations),
            answers_sequence=int(msg.answers_sequence),
            state_timestamp_ns=int(msg.state_timestamp_ns),
            plan_sequence=int(msg.plan_sequence),
            plan_origin_ns=int(msg.plan_origin_ns),
            received_ns=int(msg.received_ns),
            published_ns=int(msg.published_ns),
            horizon=float(msg.horizon),
            primal_residual=float(msg.primal_residual),
            smoothness=float(msg.smoothness),
            max_speed=float(msg.max_speed),
            max_acceleration=float(msg.max_acceleration),
            warm_started=bool(msg.warm_started),
            candidates=int(msg.candidates),
            timings_us=msg.timings.as_dict(),
            trajectory=trajectory,
        )

    def at(self, t: np.ndarray | float) -> Kinematics:
        """The carried trajectory at ``t`` seconds after ``plan_origin_ns``
        (``Trajectory.at``); ``MessageError`` if the message carries none."""
        if self.trajectory is None:
            raise MessageError(f"the message carries no plan (status {self.status.name})")
        return self.trajectory.at(t)


@dataclasses.dataclass(frozen=True)
class Followed:
    """The trajectory being followed, and the message it came from."""

    trajectory: Trajectory
    status: PlanStatus
    #: The snapshot the trajectory was made from.
    plan_sequence: int

    def at_ns(self, now_ns: int) -> Kinematics:
        """Every robot's kinematics at ``now_ns`` (``CLOCK_MONOTONIC``)."""
        return self.trajectory.at_ns(now_ns)


SENT_REMEMBERED = 1024
"""Snapshots a controller remembers having published (at 1 kHz, the last second)."""


class Sent:
    """The snapshots a controller published most recently, by sequence and
    timestamp: its ``StatePublisher`` records them, its ``Follower`` reads
    them to recognise the answers to them."""

    def __init__(self) -> None:
        """Nothing published yet."""
        self._sent: collections.deque[tuple[int, int]] = collections.deque(maxlen=SENT_REMEMBERED)

    def record(self, sequence: int, timestamp_ns: int) -> None:
        """Remembers a published snapshot (forgetting the oldest beyond ``SENT_REMEMBERED``)."""
        self._sent.append((sequence, timestamp_ns))

    def __contains__(self, snapshot: tuple[int, int]) -> bool:
        """Whether ``(sequence, timestamp_ns)`` is one of the remembered snapshots."""
        return snapshot in self._sent


class Follower:
    """The followability contract: which verified trajectory to follow now.

    Only answers to the controller's own snapshots count (their
    ``answers_sequence`` and ``state_timestamp_ns`` are those of a snapshot
    in ``sent``): never an answer to another process's snapshot, nor the
    message a service keeps for late joiners. Among those the newest
    decides: a followable one (``Ok``, ``Held``, ``Stopping``) replaces the
    trajectory, evaluated against its own ``plan_origin_ns``; ``NoPlan``, or
    a message that cannot be read, leaves none (bring the robots to rest by
    your own means). Without ``sent`` (a watcher) nothing is ever followed.
    """

    def __init__(self, sent: Sent | None = None):
        """Nothing to follow yet; answers to the snapshots in ``sent`` count."""
        self.sent = sent
        self._current: Followed | None = None

    def take(self, msg: JointTrajectory | Plan) -> Plan:
        """Takes the newest message and returns it as a ``Plan``.

        An answer to another snapshot than the controller's own changes
        nothing. Otherwise a followable message becomes the trajectory to
        follow and any other leaves none; a message that cannot be read
        leaves none too, and its ``MessageError`` is raised.
        """
        if self.sent is None or (msg.answers_sequence, msg.state_timestamp_ns) not in self.sent:
            return msg if isinstance(msg, Plan) else Plan.from_message(msg)
        self._current = None
        plan = msg if isinstance(msg, Plan) else Plan.from_message(msg)
        if plan.trajectory is not None:
            self._current = Followed(plan.trajectory, plan.status, plan.plan_sequence)
        return plan

    @property
    def current(self) -> Followed | None:
        """The trajectory to follow now, or ``None``: bring the robots to rest."""
        return self._current
