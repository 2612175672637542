"""An example controller: flies a simulated team against a running daemon.

Start the daemon, then the controller::

    flowopt serve --config config/default.toml &
    python -m flowopt_client.example --seconds 10 --json

Every tick (50 Hz by default) the controller reads the clock, moves its
simulated robots along the trajectory the followability contract says to
follow (an ideal tracker; with none, every robot brakes at the team's
acceleration limit), publishes the measured state and takes the daemon's
answers until the next tick. The robots start on a grid of cells over the
workspace and go to the mirrored cells; each time all of them are at rest on
their goals, they get a new permutation of the cells (seeded). Robot-robot
distances are checked on the executed motion at substeps of every tick.

It prints a summary (``--json``: one JSON object): plans received, their
statuses and reasons, the latency from a snapshot's timestamp to its answer
being taken (percentiles), the closest approach over the robots' separation
(1 = touching) and the contacts begun. The exit status is 1 when no plan was
received or a contact occurred.

A robot counts as on its goal within 2 cm and below 5 cm/s: every answer
re-plans from the measured state over the full horizon, so the team
approaches its goals and is never exactly on them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tomllib
from collections import Counter

import numpy as np

from .messages import Reason, StateSnapshot, robot_array
from .plan import Followed, Plan
from .ports import Endpoint, TeamChannel, monotonic_ns

#: Substeps per tick at which robot-robot distances are checked.
SUBSTEPS = 4
#: A robot is on its goal within this distance (m) and below ``ARRIVED_SPEED``
#: (m/s), as in the daemon's simulator (``flowopt sim``).
ARRIVED_DISTANCE, ARRIVED_SPEED = 0.02, 0.05


@dataclasses.dataclass
class TeamSpec:
    """What the controller must know of the daemon's team (its config)."""

    name: str = "default"
    dim: int = 2
    robots: int = 16
    radius: float = 0.1
    half_height: float = 0.1
    workspace_min: tuple[float, ...] = (-1.0, -1.0)
    workspace_max: tuple[float, ...] = (1.0, 1.0)
    max_acceleration: float = 3.0

    @classmethod
    def from_config(cls, path: str, team: str | None) -> tuple[TeamSpec, str]:
        """The team named ``team`` (or the first) of a daemon configuration
        file, and the file's IPC prefix."""
        with open(path, "rb") as f:
            config = tomllib.load(f)
        teams = config.get("team", [])
        chosen = next((t for t in teams if team is None or t.get("name") == team), None)
        if chosen is None:
            raise SystemExit(f"{path}: no team named {team!r}")
        robot = chosen.get("robot", {})
        radius = float(robot.get("radius", cls.radius))
        spec = cls(
            name=chosen["name"],
            dim=int(chosen.get("dim", cls.dim)),
            robots=int(chosen.get("robots", cls.robots)),
            radius=radius,
            half_height=float(robot.get("half_height", radius)),
            workspace_min=tuple(chosen["workspace"]["min"]),
            workspace_max=tuple(chosen["workspace"]["max"]),
            max_acceleration=float(chosen.get("max_acceleration", cls.max_acceleration)),
        )
        return spec, config.get("ipc", {}).get("prefix", "flowopt")

    def separation(self) -> np.ndarray:
        """Per-axis separation of two robots' centres: ``2r, 2r (, 2h)``."""
        return np.array([2 * self.radius] * 2 + [2 * self.half_height] * (self.dim - 2))

    def cells(self) -> np.ndarray:
        """``(robots, dim)`` centres of a grid of cells over the workspace.

        Raises ``SystemExit`` if the cells are too small for the robots.
        """
        lo, hi = np.array(self.workspace_min, float), np.array(self.workspace_max, float)
        side = math.ceil(self.robots ** (1 / self.dim) - 1e-9)
        pitch = (hi - lo) / side
        if np.any(pitch < 1.1 * self.separation()):
            raise SystemExit(f"{self.robots} robots do not fit a grid of {side}^{self.dim} cells in the workspace")
        index = np.array(np.unravel_index(np.arange(self.robots), (side,) * self.dim)).T[:, ::-1]
        return lo + (index + 0.5) * pitch


class Tally:
    """What the controller counts."""

    def __init__(self) -> None:
        """Nothing yet."""
        self.snapshots = 0
        self.plans = 0
        self.statuses: Counter[str] = Counter()
        self.reasons: Counter[str] = Counter()
        self.latencies_ms: list[float] = []
        self.closest = math.inf
        self.contacts = 0
        self.touching: set[tuple[int, int]] = set()
        self.workspace_excess_m = 0.0
        self.missions = 0
        self.longest_without_plan_ms = 0.0
        self._without_plan_since: int | None = None

    def following(self, following: bool, now_ns: int) -> None:
        """Records whether there is a trajectory to follow at ``now_ns``."""
        if not following:
            self._without_plan_since = self._without_plan_since or now_ns
        elif self._without_plan_since is not None:
            gap_ms = (now_ns - self._without_plan_since) / 1e6
            self.longest_without_plan_ms = max(self.longest_without_plan_ms, gap_ms)
            self._without_plan_since = None

    def answer(self, plan: Plan, taken_ns: int, sent_ns: int | None) -> None:
        """Counts a plan message taken at ``taken_ns``, answering a snapshot
        sent at ``sent_ns`` (``None``: not one of this run's)."""
        self.plans += 1
        self.statuses[plan.status.label] += 1
        if plan.reason != Reason.NONE:
            self.reasons[getattr(plan.reason, "label", str(plan.reason))] += 1
        if sent_ns is not None:
            self.latencies_ms.append((taken_ns - sent_ns) / 1e6)

    def distances(self, positions: np.ndarray, separation: np.ndarray) -> None:
        """Records the robots' scaled distances at ``(substeps, robots, dim)``
        positions; a contact begins when a pair first comes closer than 1."""
        n = positions.shape[1]
        i, j = np.triu_indices(n, 1)
        scaled = np.linalg.norm((positions[:, i] - positions[:, j]) / separation, axis=-1)
        self.closest = min(self.closest, float(scaled.min()))
        for s in scaled:
            now = {(int(a), int(b)) for a, b in zip(i[s < 1.0], j[s < 1.0], strict=True)}
            self.contacts += len(now - self.touching)
            self.touching = now

    def summary(self, args: argparse.Namespace, spec: TeamSpec, prefix: str) -> dict:
        """The run as a JSON-ready dictionary."""
        lat = np.array(self.latencies_ms)
        pct = {f"p{q}": round(float(np.percentile(lat, q)), 3) for q in (50, 90, 99)} if lat.size else {}
        return {
            "prefix": prefix,
            "team": spec.name,
            "robots": spec.robots,
            "dim": spec.dim,
            "seconds": args.seconds,
            "rate_hz": args.rate_hz,
            "snapshots": self.snapshots,
            "plans_received": self.plans,
            "answered": len(self.latencies_ms),
            "statuses": dict(sorted(self.statuses.items())),
            "reasons": dict(sorted(self.reasons.items())),
            "latency_ms": {**pct, "max": round(float(lat.max()), 3)} if lat.size else None,
            "closest_approach_ratio": round(self.closest, 4) if math.isfinite(self.closest) else None,
            "contacts": self.contacts,
            "workspace_excess_m": round(self.workspace_excess_m, 6),
            "missions_completed": self.missions,
            "longest_without_plan_ms": round(self.longest_without_plan_ms, 1),
        }


def brake(position: np.ndarray, velocity: np.ndarray, dt: float, a_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Every robot decelerating at ``a_max`` along its velocity for ``dt`` s."""
    speed = np.linalg.norm(velocity, axis=1, keepdims=True)
    stop = np.minimum(dt, speed / a_max)
    direction = np.divide(velocity, speed, out=np.zeros_like(velocity), where=speed > 0)
    position = position + velocity * stop - 0.5 * a_max * direction * stop**2
    return position, velocity - a_max * direction * stop


class SimulatedTeam:
    """The robots: an ideal tracker of the trajectory to follow."""

    def __init__(self, spec: TeamSpec, seed: int):
        """At rest on the grid cells, going to the mirrored cells."""
        self.spec, self.rng = spec, np.random.default_rng(seed)
        self.cells = spec.cells()
        self.position, self.velocity = self.cells.copy(), np.zeros_like(self.cells)
        self.goal = self.cells[::-1].copy()

    def advance(self, followed: Followed | None, last_ns: int, now_ns: int) -> np.ndarray:
        """Moves the robots from ``last_ns`` to ``now_ns`` along ``followed``
        (braking without it); returns the positions at the substeps,
        ``(SUBSTEPS, robots, dim)``."""
        if followed is not None:
            times = last_ns + (now_ns - last_ns) * np.arange(1, SUBSTEPS + 1, dtype=np.int64) // SUBSTEPS
            k = followed.at_ns(times)
            self.position, self.velocity = k.position[-1], k.velocity[-1]
            return k.position
        path = []
        for _ in range(SUBSTEPS):
            dt = (now_ns - last_ns) / 1e9 / SUBSTEPS
            self.position, self.velocity = brake(self.position, self.velocity, dt, self.spec.max_acceleration)
            path.append(self.position)
        return np.array(path)

    def new_goals_if_arrived(self) -> bool:
        """When every robot is at rest on its goal, draws new goals (a
        permutation of the cells); returns whether it did."""
        on_goal = np.linalg.norm(self.position - self.goal, axis=1) < ARRIVED_DISTANCE
        at_rest = np.linalg.norm(self.velocity, axis=1) < ARRIVED_SPEED
        if not np.all(on_goal & at_rest):
            return False
        self.goal = self.cells[self.rng.permutation(self.spec.robots)]
        return True

    def fill(self, snapshot: StateSnapshot, measured_ns: int) -> None:
        """Writes the measured state into ``snapshot``."""
        n, dim = self.spec.robots, self.spec.dim
        snapshot.timestamp_ns = measured_ns
        snapshot.dim, snapshot.robots = dim, n
        robots = robot_array(snapshot)
        robots[:n, 0, :dim], robots[:n, 1, :dim], robots[:n, 2, :dim] = self.position, self.velocity, self.goal


def run(args: argparse.Namespace, spec: TeamSpec, prefix: str) -> dict:
    """Flies the team for ``args.seconds`` and returns the summary."""
    endpoint = Endpoint(f"flowopt-py-example-{args.seed}")
    channel = TeamChannel(prefix, spec.name)
    states = endpoint.state_publisher(channel)
    plans = endpoint.plan_subscriber(channel, states)
    team, tally = SimulatedTeam(spec, args.seed), Tally()
    lo, hi = np.array(spec.workspace_min), np.array(spec.workspace_max)
    sent_ns: dict[int, int] = {}
    period_ns = int(1e9 / args.rate_hz)
    start = last = monotonic_ns()
    tally.distances(team.position[None], spec.separation())
    for tick in range(1, math.ceil(args.seconds * args.rate_hz) + 1):
        # Move the robots along what the contract says to follow; measure.
        now = monotonic_ns()
        followed = plans.to_follow()
        tally.following(followed is not None, now)
        path = team.advance(followed, last, now)
        tally.distances(path, spec.separation())
        tally.workspace_excess_m = max(tally.workspace_excess_m, float(np.maximum(lo - path, path - hi).max()))
        tally.missions += team.new_goals_if_arrived()
        sequence = states.publish_with(lambda s, now=now: team.fill(s, now))
        sent_ns[sequence] = now
        tally.snapshots += 1
        last = now
        # Take the answers until the next tick.
        while (left := start + tick * period_ns - monotonic_ns()) > 0:
            plan = plans.wait(left / 1e9)
            if plan is not None:
                tally.answer(plan, monotonic_ns(), sent_ns.pop(plan.answers_sequence, None))
    tally.following(True, monotonic_ns())
    return tally.summary(args, spec, prefix)


def parse(argv: list[str] | None) -> tuple[argparse.Namespace, TeamSpec, str]:
    """The command line, the team and the prefix."""
    defaults = TeamSpec()
    p = argparse.ArgumentParser(prog="python -m flowopt_client.example", description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=10.0, help="how long to fly (default 10)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--config", help="take the team (and prefix) from this daemon configuration file")
    p.add_argument("--prefix", help="service prefix (default: the config's, else flowopt)")
    p.add_argument("--team", help=f"team name (default: the config's first, else {defaults.name})")
    p.add_argument("--robots", type=int, help=f"robots in the team (default {defaults.robots})")
    p.add_argument("--dim", type=int, choices=(2, 3), help=f"2 or 3 (default {defaults.dim})")
    p.add_argument("--radius", type=float, help=f"robot radius (default {defaults.radius})")
    p.add_argument("--half-height", type=float, help="robot half-height in 3D (default: the radius)")
    p.add_argument("--workspace", type=float, nargs=2, metavar=("MIN", "MAX"), help="a cube workspace [MIN, MAX]^dim")
    p.add_argument("--max-acceleration", type=float, help=f"braking limit (default {defaults.max_acceleration})")
    p.add_argument("--rate-hz", type=float, default=50.0, help="snapshots per second (default 50)")
    p.add_argument("--seed", type=int, default=7, help="seed of the goal permutations (default 7)")
    args = p.parse_args(argv)
    if args.config:
        spec, prefix = TeamSpec.from_config(args.config, args.team)
    else:
        spec, prefix = TeamSpec(name=args.team or defaults.name), "flowopt"
    for field in ("robots", "dim", "radius", "half_height", "max_acceleration"):
        if getattr(args, field) is not None:
            setattr(spec, field, getattr(args, field))
    if args.radius is not None and args.half_height is None and not args.config:
        spec.half_height = args.radius
    if args.workspace is not None:
        spec.workspace_min, spec.workspace_max = (args.workspace[0],) * spec.dim, (args.workspace[1],) * spec.dim
    elif len(spec.workspace_min) != spec.dim:
        spec.workspace_min = (spec.workspace_min[0],) * spec.dim
        spec.workspace_max = (spec.workspace_max[0],) * spec.dim
    if args.seconds <= 0 or args.rate_hz <= 0:
        p.error("--seconds and --rate-hz must be positive")
    return args, spec, args.prefix or prefix


def main(argv: list[str] | None = None) -> int:
    """Runs the example; 0 when plans came and no contact occurred."""
    import iceoryx2 as iox2

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    args, spec, prefix = parse(argv)
    try:
        summary = run(args, spec, prefix)
    except KeyboardInterrupt:
        return 130
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:26} {value}")
    if summary["plans_received"] == 0:
        print(f"no plan received: is `flowopt serve` running on prefix {prefix!r}?", file=sys.stderr)
    return 0 if summary["plans_received"] > 0 and summary["contacts"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
