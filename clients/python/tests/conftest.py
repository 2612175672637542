"""Fixtures: the binaries under test, a daemon on a prefix of its own, and
the controller ports opened against it.

The binaries are found through environment variables, else in the
repository's release build (``cargo build --release`` and
``cargo build --release -p flowopt-client --example evaluate_plan``):

- ``FLOWOPT_BIN``: the ``flowopt`` command line (``target/release/flowopt``);
- ``FLOWOPT_EVALUATE_PLAN``: the Rust client's plan evaluator
  (``target/release/examples/evaluate_plan``);
- ``FLOWOPT_CONFIG``: the daemon configuration (``config/default.toml``).

A missing binary fails the tests that need it (with the command that builds
it): the tests never pass without having talked to the Rust side.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from flowopt_client import Endpoint, JointTrajectory, Plan, TeamChannel, monotonic_ns, robot_array
from flowopt_client.example import TeamSpec

REPO = Path(__file__).resolve().parents[3]


def _binary(variable: str, default: Path, build: str) -> Path:
    path = Path(os.environ.get(variable, default))
    if not path.is_file():
        pytest.fail(f"{path} not found: build it with `{build}` or point {variable} at it", pytrace=False)
    return path


@pytest.fixture(scope="session")
def flowopt_bin() -> Path:
    """The daemon's command line."""
    return _binary("FLOWOPT_BIN", REPO / "target/release/flowopt", "cargo build --release")


@pytest.fixture(scope="session")
def evaluate_plan_bin() -> Path:
    """The Rust client's evaluator (``client-lib/examples/evaluate_plan.rs``)."""
    return _binary(
        "FLOWOPT_EVALUATE_PLAN",
        REPO / "target/release/examples/evaluate_plan",
        "cargo build --release -p flowopt-client --example evaluate_plan",
    )


class Daemon:
    """A running ``flowopt serve`` on a unique prefix."""

    def __init__(self, binary: Path, config: Path, prefix: str, log: Path):
        """Starts it and waits until it logs that it is ready."""
        with open(config, "rb") as f:
            self.config = tomllib.load(f)
        self.spec, _ = TeamSpec.from_config(str(config), None)
        self.prefix, self.log, self.config_path = prefix, log, config
        self.channel = TeamChannel(prefix, self.spec.name)
        with open(log, "wb") as out:
            self.process = subprocess.Popen(
                [str(binary), "serve", "--config", str(config), "--ipc-prefix", prefix],
                stdout=out,
                stderr=subprocess.STDOUT,
                env={**os.environ, "NO_COLOR": "1"},
            )
        deadline = time.monotonic() + 60.0
        while b"ready" not in log.read_bytes():
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                pytest.fail(f"flowopt serve did not get ready:\n{log.read_text(errors='replace')}", pytrace=False)
            time.sleep(0.02)

    def stop(self) -> int | None:
        """SIGTERM, then SIGKILL if it lingers; returns the exit status."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode


@pytest.fixture(scope="module")
def daemon(flowopt_bin: Path, tmp_path_factory: pytest.TempPathFactory):
    """One daemon per test module, on its own prefix, stopped afterwards."""
    config = Path(os.environ.get("FLOWOPT_CONFIG", REPO / "config/default.toml"))
    prefix = f"flowopt-pytest-{os.getpid()}-{time.monotonic_ns()}"
    d = Daemon(flowopt_bin, config, prefix, tmp_path_factory.mktemp("daemon") / "serve.log")
    yield d
    status = d.stop()
    assert status == 0, f"flowopt serve exited with {status}:\n{d.log.read_text(errors='replace')}"


@pytest.fixture
def lone_daemon(flowopt_bin: Path, tmp_path_factory: pytest.TempPathFactory):
    """A daemon of its own for one test (no other controller on its team:
    a team has one state source)."""
    config = Path(os.environ.get("FLOWOPT_CONFIG", REPO / "config/default.toml"))
    prefix = f"flowopt-pytest-lone-{os.getpid()}-{time.monotonic_ns()}"
    d = Daemon(flowopt_bin, config, prefix, tmp_path_factory.mktemp("daemon") / "serve.log")
    yield d
    status = d.stop()
    assert status == 0, f"flowopt serve exited with {status}:\n{d.log.read_text(errors='replace')}"


class Controller:
    """The controller ports of one test module, and snapshot helpers."""

    def __init__(self, daemon: Daemon):
        """Opens a publisher and a subscriber on the daemon's team."""
        self.spec, self.channel = daemon.spec, daemon.channel
        self.endpoint = Endpoint(f"flowopt-pytest-{os.getpid()}")
        self.states = self.endpoint.state_publisher(daemon.channel)
        self.plans = self.endpoint.plan_subscriber(daemon.channel, self.states)
        self.starts = self.spec.cells()
        self.goals = self.starts[::-1].copy()

    def publish(self, position=None, velocity=None, edit=None) -> tuple[int, int]:
        """Publishes the team at ``position`` (default: the grid cells) with
        ``velocity`` (default: at rest) towards the mirrored cells; ``edit``
        may change the snapshot last. Returns (sequence, timestamp_ns)."""
        n, dim = self.spec.robots, self.spec.dim
        position = self.starts if position is None else position
        velocity = np.zeros((n, dim)) if velocity is None else velocity
        stamp = monotonic_ns()

        def fill(s):
            s.timestamp_ns = stamp
            s.dim, s.robots = dim, n
            robots = robot_array(s)
            robots[:n, 0, :dim], robots[:n, 1, :dim], robots[:n, 2, :dim] = position, velocity, self.goals
            if edit is not None:
                edit(s)

        return self.states.publish_with(fill), stamp

    def answer_to(self, sequence: int, timeout_s: float = 5.0) -> Plan:
        """The daemon's answer to snapshot ``sequence``."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            plan = self.plans.wait(left)
            if plan is not None and plan.answers_sequence == sequence:
                return plan
        raise AssertionError(f"no answer to snapshot {sequence} within {timeout_s} s")


@pytest.fixture(scope="module")
def controller(daemon: Daemon) -> Controller:
    """The controller ports on the module's daemon."""
    return Controller(daemon)


@pytest.fixture(scope="session")
def evaluate_in_rust(evaluate_plan_bin: Path):
    """A function: (plan message, times) -> the Rust client's JSON for them."""

    def evaluate(msg: JointTrajectory, times) -> dict:
        result = subprocess.run(
            [str(evaluate_plan_bin), "-", *(repr(float(t)) for t in times)],
            input=bytes(msg),
            capture_output=True,
            check=False,
        )
        assert result.returncode == 0, result.stderr.decode(errors="replace")
        return json.loads(result.stdout)

    return evaluate
