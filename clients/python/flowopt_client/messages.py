"""The two wire messages (version 2) as ctypes structures.

The layout is the one in ``docs/MESSAGES.md`` (``#[repr(C)]`` Rust structs in
``client-lib/src/messages.rs``, little-endian x86-64). Importing this module
checks every documented offset and size and raises ``ImportError`` if ctypes
laid a structure out differently, so a client never sends or reads a message
of another shape.

The payload structures carry a ``type_name()`` classmethod returning the
Rust type name: iceoryx2 compares it (with the size and alignment) when a
service is opened, so without it the daemon's services refuse the client
(``IncompatibleTypes``).
"""

from __future__ import annotations

import ctypes
import enum

import numpy as np

#: Layout version written into every message.
WIRE_VERSION = 2
#: Robots per team a message can carry.
MAX_ROBOTS = 256
#: Obstacles a snapshot can carry.
MAX_OBSTACLES = 16
#: Bernstein coefficients per robot and axis (degree at most 15).
MAX_COEFFS = 16
#: Bytes of the team name (UTF-8, NUL-padded).
TEAM_NAME_LEN = 32
#: ``reason_index`` when the reason points at no robot or obstacle.
NO_INDEX = 0xFFFF_FFFF

_Vec3 = ctypes.c_double * 3
_Name = ctypes.c_uint8 * TEAM_NAME_LEN


class PlanStatus(enum.IntEnum):
    """What a plan message tells the controllers to follow (``status``)."""

    NO_PLAN = 0
    OK = 1
    HELD = 2
    STOPPING = 3

    @property
    def followable(self) -> bool:
        """Whether a message with this status carries a verified trajectory."""
        return self is not PlanStatus.NO_PLAN

    @property
    def label(self) -> str:
        """The name ``docs/MESSAGES.md`` gives it (``Ok``, ``NoPlan``...)."""
        return _doc_name(self.name)


class Reason(enum.IntEnum):
    """Why a plan message is not a new plan (``reason``)."""

    NONE = 0
    VERSION = 1
    TEAM = 2
    DIMENSION = 3
    ROBOT_COUNT = 4
    OBSTACLE_COUNT = 5
    NON_FINITE = 6
    NON_POSITIVE_SIZE = 7
    STARTS_OVERLAP = 8
    GOALS_OVERLAP = 9
    START_IN_OBSTACLE = 10
    GOAL_IN_OBSTACLE = 11
    START_OUTSIDE_WORKSPACE = 12
    GOAL_OUTSIDE_WORKSPACE = 13
    STALE_STATE = 14
    SOLVER = 15
    CLOCK = 16
    SEQUENCE = 17
    IMPLAUSIBLE = 18
    DEADLINE_MISSED = 19
    NOT_VERIFIED = 20
    NOT_FOLLOWING = 21
    LIMITS = 22
    WORLD_CHANGED = 23
    RECOVERING = 24
    CANNOT_BRAKE = 25
    CANNOT_AVOID = 26

    @property
    def is_rejection(self) -> bool:
        """Whether the answered snapshot was rejected: its task was not
        planned. Rejected by a header, clock, sequence or value check (1-7,
        16-18) it changed nothing; rejected for its task (8-13, 25, 26) its
        robots and obstacles are still the world every followable answer is
        checked against."""
        return 1 <= self <= 13 or 16 <= self <= 18 or self in (25, 26)

    @property
    def label(self) -> str:
        """The name ``docs/MESSAGES.md`` gives it (``NonFinite``,
        ``DeadlineMissed``...)."""
        return _doc_name(self.name)


def _doc_name(name: str) -> str:
    """``NO_PLAN`` as the documentation writes it: ``NoPlan``."""
    return "".join(word.capitalize() for word in name.split("_"))


class RobotState(ctypes.Structure):
    """One robot's measured position and velocity, and its goal (72 bytes)."""

    _fields_ = [("position", _Vec3), ("velocity", _Vec3), ("goal", _Vec3)]

    @classmethod
    def type_name(cls) -> str:
        """The Rust type name."""
        return "flowopt::RobotState"


class ObstacleState(ctypes.Structure):
    """A spheroid moving at constant velocity from ``position`` (64 bytes)."""

    _fields_ = [
        ("position", _Vec3),
        ("velocity", _Vec3),
        ("radius", ctypes.c_double),
        ("half_height", ctypes.c_double),
    ]

    @classmethod
    def type_name(cls) -> str:
        """The Rust type name."""
        return "flowopt::ObstacleState"


class StateSnapshot(ctypes.Structure):
    """Controller to daemon: the measured state of a whole team (19520 bytes)."""

    _fields_ = [
        ("version", ctypes.c_uint32),
        ("dim", ctypes.c_uint32),
        ("team", _Name),
        ("sequence", ctypes.c_uint64),
        ("timestamp_ns", ctypes.c_uint64),
        ("robots", ctypes.c_uint32),
        ("obstacles", ctypes.c_uint32),
        ("obstacle", ObstacleState * MAX_OBSTACLES),
        ("robot", RobotState * MAX_ROBOTS),
    ]

    @classmethod
    def type_name(cls) -> str:
        """The Rust type name (iceoryx2 checks it when a service is opened)."""
        return "flowopt::StateSnapshot"


class StageTimings(ctypes.Structure):
    """Microseconds per planning stage (40 bytes)."""

    _fields_ = [
        (name, ctypes.c_uint32)
        for name in (
            "queue_us",
            "validate_us",
            "warm_start_us",
            "sample_us",
            "rank_us",
            "init_us",
            "filter_us",
            "optimise_us",
            "select_us",
            "total_us",
        )
    ]

    @classmethod
    def type_name(cls) -> str:
        """The Rust type name."""
        return "flowopt::StageTimings"

    def as_dict(self) -> dict[str, int]:
        """The timings by field name."""
        return {name: getattr(self, name) for name, _ in self._fields_}


class JointTrajectory(ctypes.Structure):
    """Daemon to controllers: the answer to one snapshot (98504 bytes)."""

    _fields_ = [
        ("version", ctypes.c_uint32),
        ("status", ctypes.c_uint32),
        ("reason", ctypes.c_uint32),
        ("reason_index", ctypes.c_uint32),
        ("team", _Name),
        ("dim", ctypes.c_uint32),
        ("robots", ctypes.c_uint32),
        ("degree", ctypes.c_uint32),
        ("iterations", ctypes.c_uint32),
        ("answers_sequence", ctypes.c_uint64),
        ("state_timestamp_ns", ctypes.c_uint64),
        ("plan_sequence", ctypes.c_uint64),
        ("plan_origin_ns", ctypes.c_uint64),
        ("received_ns", ctypes.c_uint64),
        ("published_ns", ctypes.c_uint64),
        ("horizon", ctypes.c_double),
        ("primal_residual", ctypes.c_double),
        ("smoothness", ctypes.c_double),
        ("max_speed", ctypes.c_double),
        ("max_acceleration", ctypes.c_double),
        ("warm_started", ctypes.c_uint32),
        ("candidates", ctypes.c_uint32),
        ("timings", StageTimings),
        ("coeffs", ctypes.c_double * MAX_COEFFS * 3 * MAX_ROBOTS),
    ]

    @classmethod
    def type_name(cls) -> str:
        """The Rust type name (iceoryx2 checks it when a service is opened)."""
        return "flowopt::JointTrajectory"


#: The documented layout: (structure, size, {field: offset}).
LAYOUT = (
    (RobotState, 72, {"position": 0, "velocity": 24, "goal": 48}),
    (ObstacleState, 64, {"position": 0, "velocity": 24, "radius": 48, "half_height": 56}),
    (
        StateSnapshot,
        19520,
        {
            "version": 0,
            "dim": 4,
            "team": 8,
            "sequence": 40,
            "timestamp_ns": 48,
            "robots": 56,
            "obstacles": 60,
            "obstacle": 64,
            "robot": 1088,
        },
    ),
    (StageTimings, 40, {"queue_us": 0, "total_us": 36}),
    (
        JointTrajectory,
        98504,
        {
            "version": 0,
            "status": 4,
            "reason": 8,
            "reason_index": 12,
            "team": 16,
            "dim": 48,
            "robots": 52,
            "degree": 56,
            "iterations": 60,
            "answers_sequence": 64,
            "state_timestamp_ns": 72,
            "plan_sequence": 80,
            "plan_origin_ns": 88,
            "received_ns": 96,
            "published_ns": 104,
            "horizon": 112,
            "primal_residual": 120,
            "smoothness": 128,
            "max_speed": 136,
            "max_acceleration": 144,
            "warm_started": 152,
            "candidates": 156,
            "timings": 160,
            "coeffs": 200,
        },
    ),
)


def layout_errors(layout=LAYOUT) -> list[str]:
    """Every difference between the ctypes structures and ``layout``
    (``(structure, size, {field: offset})`` triples; none: [])."""
    errors = []
    for struct, size, offsets in layout:
        name = struct.type_name()
        if ctypes.sizeof(struct) != size:
            errors.append(f"{name}: size {ctypes.sizeof(struct)}, documented {size}")
        for field, offset in offsets.items():
            actual = getattr(struct, field).offset
            if actual != offset:
                errors.append(f"{name}.{field}: offset {actual}, documented {offset}")
    return errors


def _check_layout() -> None:
    errors = layout_errors()
    for struct in (StateSnapshot, JointTrajectory):
        if ctypes.alignment(struct) != 8:
            errors.append(f"{struct.type_name()}: alignment {ctypes.alignment(struct)}, documented 8")
    if errors:
        raise ImportError("flowopt_client: the wire layout differs from docs/MESSAGES.md: " + "; ".join(errors))


_check_layout()


def check_team_name(name: str) -> bytes:
    """The UTF-8 bytes of a valid team name: 1-32 bytes without '/' or NUL.

    Raises ``ValueError`` otherwise.
    """
    raw = name.encode("utf-8")
    if not 1 <= len(raw) <= TEAM_NAME_LEN or "/" in name or "\0" in name:
        raise ValueError(f"the team name {name!r} must be 1-{TEAM_NAME_LEN} bytes of UTF-8 without '/' or NUL")
    return raw


def write_team(message: StateSnapshot | JointTrajectory, name: str) -> None:
    """Writes ``name`` NUL-padded into ``message.team``."""
    raw = check_team_name(name)
    ctypes.memmove(ctypes.addressof(message.team), raw.ljust(TEAM_NAME_LEN, b"\0"), TEAM_NAME_LEN)


def read_team(message: StateSnapshot | JointTrajectory) -> str:
    """The NUL-padded team name of ``message`` (``ValueError`` if not UTF-8)."""
    return bytes(message.team).split(b"\0", 1)[0].decode("utf-8")


def _doubles(address: int, shape: tuple[int, ...]) -> np.ndarray:
    """A writable float64 numpy view of ``shape`` at ``address``."""
    return np.ctypeslib.as_array(ctypes.cast(address, ctypes.POINTER(ctypes.c_double)), shape=shape)


def robot_array(snapshot: StateSnapshot) -> np.ndarray:
    """A writable ``(MAX_ROBOTS, 3, 3)`` float64 view of ``snapshot.robot``.

    Axis 1 is position, velocity, goal; axis 2 is x, y, z. Writing to the
    view writes the snapshot in place (in shared memory for a loaned one).
    """
    return _doubles(ctypes.addressof(snapshot.robot), (MAX_ROBOTS, 3, 3))


def obstacle_array(snapshot: StateSnapshot) -> np.ndarray:
    """A writable ``(MAX_OBSTACLES, 8)`` float64 view of ``snapshot.obstacle``.

    Columns: position x y z, velocity x y z, radius, half_height.
    """
    return _doubles(ctypes.addressof(snapshot.obstacle), (MAX_OBSTACLES, 8))


def coeff_array(message: JointTrajectory) -> np.ndarray:
    """A ``(MAX_ROBOTS, 3, MAX_COEFFS)`` float64 view of ``message.coeffs``."""
    return _doubles(ctypes.addressof(message.coeffs), (MAX_ROBOTS, 3, MAX_COEFFS))
