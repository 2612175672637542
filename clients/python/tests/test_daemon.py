"""Against a running daemon (``flowopt serve`` on a prefix of its own):
round trips, rejections, a real plan evaluated by both clients, and the
example controller."""

from __future__ import annotations

import ctypes
import os
import json
import subprocess
import sys
import time

import numpy as np
import pytest
from test_plan import assert_same_as_rust

from flowopt_client import Endpoint, JointTrajectory, PlanStatus, Reason, monotonic_ns, robot_array, write_team


def first_ok_answer(controller, timeout_s: float = 10.0):
    """Publishes the team at rest on its starts every 20 ms until the answer
    to one of them is a new plan (``Ok``); returns (sequence, stamp, plan)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        sequence, stamp = controller.publish()
        plan = controller.answer_to(sequence)
        if plan.status is PlanStatus.OK:
            return sequence, stamp, plan
        assert plan.status.followable, f"from rest on free starts: {plan.status.name} ({plan.reason.name})"
        time.sleep(0.02)
    raise AssertionError(f"no Ok plan within {timeout_s} s")


def test_a_snapshot_is_answered_with_a_verified_plan_from_it(controller):
    spec = controller.spec
    sequence, stamp, plan = first_ok_answer(controller)
    assert (plan.team, plan.dim, plan.robots) == (spec.name, spec.dim, spec.robots)
    assert (plan.answers_sequence, plan.state_timestamp_ns) == (sequence, stamp)
    # Ok: made from this snapshot, or a late plan adopted because the team
    # was still at the start of the snapshot it was made from.
    assert plan.plan_sequence <= sequence and plan.plan_origin_ns <= stamp
    assert (plan.plan_sequence == sequence) == (plan.plan_origin_ns == stamp)
    assert stamp <= plan.received_ns <= plan.published_ns <= monotonic_ns()
    assert plan.reason is Reason.NONE and plan.reason_index is None
    k = plan.at([0.0, plan.horizon])
    np.testing.assert_allclose(k.position[0], controller.starts, atol=1e-3)
    np.testing.assert_allclose(k.velocity[0], 0.0, atol=1e-3)
    np.testing.assert_allclose(k.position[1], controller.goals, atol=1e-3)
    np.testing.assert_allclose(k.velocity[1], 0.0, atol=1e-3)
    assert controller.plans.to_follow().plan_sequence == plan.plan_sequence


def test_a_non_finite_position_is_rejected_and_changes_nothing(controller):
    first_ok_answer(controller)

    def nan_robot_3(s):
        robot_array(s)[3, 0, 1] = np.nan

    sequence, _ = controller.publish(edit=nan_robot_3)
    plan = controller.answer_to(sequence)
    assert plan.status in (PlanStatus.HELD, PlanStatus.NO_PLAN)
    assert (plan.reason, plan.reason_index) == (Reason.NON_FINITE, 3)
    if plan.status is PlanStatus.HELD:
        assert plan.plan_sequence < sequence, "the held plan, not one made from the rejected snapshot"


def _version(s):
    s.version = 1


def _robot_count(s):
    s.robots -= 1


def _clock(s):
    s.timestamp_ns -= 2_000_000_000


def _team(s):
    write_team(s, "no-such-team")


def _speed(s):
    robot_array(s)[5, 1, 0] = 10.0


@pytest.mark.parametrize(
    ("edit", "reason", "index"),
    [
        (_version, Reason.VERSION, None),
        (_robot_count, Reason.ROBOT_COUNT, None),
        (_clock, Reason.CLOCK, None),
        (_team, Reason.TEAM, None),
        (_speed, Reason.IMPLAUSIBLE, 5),
    ],
)
def test_bad_snapshots_are_rejected_with_their_reason(controller, edit, reason, index):
    sequence, _ = controller.publish(edit=edit)
    plan = controller.answer_to(sequence)
    assert plan.status in (PlanStatus.HELD, PlanStatus.NO_PLAN)
    assert plan.reason is reason and plan.reason.is_rejection
    if index is not None:
        assert plan.reason_index == index


def test_a_real_plan_evaluates_as_in_the_rust_client(controller, evaluate_in_rust):
    subscriber = controller.endpoint.topic(controller.channel.plan, JointTrajectory).subscriber_builder().create()
    sequence, _, _ = first_ok_answer(controller)
    raw = None
    deadline = time.monotonic() + 5.0
    while raw is None and time.monotonic() < deadline:
        while (sample := subscriber.receive()) is not None:
            if sample.payload().contents.answers_sequence == sequence:
                raw = JointTrajectory.from_buffer_copy(bytes(sample.payload().contents))
            sample.delete()
        time.sleep(0.001)
    assert raw is not None, f"the raw subscriber did not see the answer to {sequence}"
    times = [0.0, 0.5, raw.horizon / 3, raw.horizon - 1e-3, raw.horizon]
    assert_same_as_rust(raw, evaluate_in_rust(raw, times), times)


def test_a_payload_of_another_type_name_is_refused(controller):
    class Impostor(ctypes.Structure):
        _fields_ = [("bytes", ctypes.c_uint64 * (ctypes.sizeof(JointTrajectory) // 8))]

        @classmethod
        def type_name(cls):
            return "flowopt::Impostor"

    with pytest.raises(RuntimeError, match="cannot open or create the service"):
        controller.endpoint.topic(controller.channel.plan, Impostor)


def test_a_second_controller_is_refused_naming_the_team(controller):
    other = Endpoint(f"flowopt-pytest-other-{os.getpid()}")
    with pytest.raises(RuntimeError, match=f"team {controller.channel.team!r}.*one state source"):
        other.state_publisher(controller.channel)
    sequence, _ = controller.publish()
    assert controller.answer_to(sequence).status.followable, "the first controller is still served"


def test_the_example_hints_at_the_prefix_when_no_plan_comes(daemon):
    prefix = f"{daemon.prefix}-nobody"
    result = subprocess.run(
        [sys.executable, "-m", "flowopt_client.example", "--seconds", "0.3", "--json", "--prefix", prefix],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 1
    assert json.loads(result.stdout)["plans_received"] == 0
    assert f"is `flowopt serve` running on prefix {prefix!r}" in result.stderr


def test_the_example_controller_flies_the_team_without_contact(lone_daemon):
    daemon = lone_daemon
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "flowopt_client.example",
            "--seconds",
            "3",
            "--json",
            "--config",
            str(daemon.config_path),
            "--prefix",
            daemon.prefix,
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    summary = json.loads(result.stdout)
    assert summary["plans_received"] > 0 and summary["answered"] > 0
    assert summary["contacts"] == 0 and summary["closest_approach_ratio"] >= 1.0
    assert set(summary["statuses"]) <= {"Ok", "Held", "Stopping", "NoPlan"}
    assert summary["latency_ms"]["p50"] > 0
