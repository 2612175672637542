"""Plan evaluation (against the Rust client's) and the followability contract."""

from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest

from flowopt_client import (
    Follower,
    JointTrajectory,
    MessageError,
    Plan,
    PlanStatus,
    Reason,
    Sent,
    bernstein_rows,
    coeff_array,
    write_team,
)
from flowopt_client.plan import SENT_REMEMBERED

#: Times (s) around a 5 s horizon: before the origin, inside, at and past the end.
TIMES = [-1.0, 0.0, 1e-4, 0.37, 1.25, 2.5, 4.999, 5.0, 7.5]


def synthetic(dim: int, robots: int, degree: int, seed: int, status=PlanStatus.OK) -> JointTrajectory:
    """A plan message with seeded random coefficients and every header field set."""
    rng = np.random.default_rng(seed)
    msg = JointTrajectory()
    msg.version, msg.status, msg.reason, msg.reason_index = 2, status, Reason.LIMITS, 7
    write_team(msg, "lab-b")
    msg.dim, msg.robots, msg.degree, msg.iterations = dim, robots, degree, 123
    msg.answers_sequence, msg.state_timestamp_ns, msg.plan_sequence = 41, 10**12 + 5, 40
    msg.plan_origin_ns, msg.received_ns, msg.published_ns = 10**12, 10**12 + 9, 10**12 + 11
    msg.horizon, msg.primal_residual, msg.smoothness = 5.0, 1e-7, 12.5
    msg.max_speed, msg.max_acceleration, msg.warm_started, msg.candidates = 1.25, 2.75, 1, 3
    msg.timings.total_us = 999
    coeff_array(msg)[:robots, :dim, : degree + 1] = rng.uniform(-1.0, 1.0, (robots, dim, degree + 1))
    return msg


def assert_same_as_rust(msg: JointTrajectory, rust: dict, times=TIMES) -> None:
    """Header fields and kinematics of ``Plan.from_message(msg)`` equal Rust's."""
    plan = Plan.from_message(msg)
    header = {
        k: rust[k]
        for k in (
            "status",
            "reason",
            "dim",
            "robots",
            "answers_sequence",
            "state_timestamp_ns",
            "plan_sequence",
            "plan_origin_ns",
            "received_ns",
            "published_ns",
            "horizon",
            "max_speed",
            "max_acceleration",
            "iterations",
            "candidates",
            "team",
        )
    }
    assert header == {k: getattr(plan, k) for k in header}
    assert rust["reason_index"] == (0xFFFF_FFFF if plan.reason_index is None else plan.reason_index)
    assert rust["warm_started"] == int(plan.warm_started) and rust["total_us"] == plan.timings_us["total_us"]
    assert rust["degree"] == plan.trajectory.degree
    ours = plan.at(np.array(times))  # vectorised over the times
    assert [s["t"] for s in rust["samples"]] == times
    for order, name in enumerate(("position", "velocity", "acceleration")):
        theirs = np.array([s[name] for s in rust["samples"]])
        assert theirs.shape == ours[order].shape == (len(times), plan.robots, plan.dim)
        np.testing.assert_allclose(ours[order], theirs, rtol=1e-12, atol=1e-12, err_msg=name)
        for k, t in enumerate(times):  # one time at a time gives the same
            np.testing.assert_allclose(plan.at(t)[order], theirs[k], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(("dim", "robots", "degree"), [(2, 16, 10), (3, 5, 15), (2, 256, 1), (3, 1, 2)])
def test_evaluation_matches_the_rust_client(evaluate_in_rust, dim, robots, degree):
    msg = synthetic(dim, robots, degree, seed=dim * 1000 + degree)
    assert_same_as_rust(msg, evaluate_in_rust(msg, TIMES))


@pytest.mark.skipif(
    not os.environ.get("FLOWOPT_CPP_CHECK"),
    reason="FLOWOPT_CPP_CHECK names no compiled clients/cpp/check.cpp (.ci/run sets it)",
)
@pytest.mark.parametrize(("dim", "robots", "degree"), [(2, 16, 10), (3, 5, 15), (2, 256, 1)])
def test_the_cpp_header_evaluates_as_the_rust_client(evaluate_in_rust, dim, robots, degree):
    msg = synthetic(dim, robots, degree, seed=dim * 1000 + degree + 1)
    result = subprocess.run(
        [os.environ["FLOWOPT_CPP_CHECK"], "-", *map(repr, TIMES)], input=bytes(msg), capture_output=True, check=False
    )
    assert result.returncode == 0, result.stderr.decode(errors="replace")
    cpp, rust = json.loads(result.stdout), evaluate_in_rust(msg, TIMES)
    for key in ("status", "reason", "dim", "robots", "degree", "plan_origin_ns", "horizon"):
        assert cpp[key] == rust[key], key
    assert len(cpp["samples"]) == len(rust["samples"]) == len(TIMES)
    for ours, theirs in zip(cpp["samples"], rust["samples"], strict=True):
        assert ours["t"] == theirs["t"]
        for name in ("position", "velocity", "acceleration"):
            np.testing.assert_allclose(ours[name], theirs[name], rtol=1e-12, atol=1e-12, err_msg=name)


def test_a_message_without_a_plan_has_nothing_to_evaluate_in_either_client(evaluate_in_rust):
    msg = synthetic(2, 4, 10, seed=1, status=PlanStatus.NO_PLAN)
    rust = evaluate_in_rust(msg, [1.0])
    assert rust["samples"] == [] and "NoPlan" in rust["error"]
    plan = Plan.from_message(msg)
    assert plan.trajectory is None
    with pytest.raises(MessageError):
        plan.at(1.0)


def test_bernstein_rows_are_a_partition_of_unity_with_matching_derivatives():
    tau = np.linspace(0.0, 1.0, 41)
    for degree in (1, 2, 10, 15):
        assert np.allclose(bernstein_rows(degree, 0, tau).sum(-1), 1.0)
        assert np.allclose(bernstein_rows(degree, 1, tau).sum(-1), 0.0, atol=1e-9)
        assert np.allclose(bernstein_rows(degree, 2, tau).sum(-1), 0.0, atol=1e-6)
    coeffs = np.random.default_rng(3).normal(size=11)
    inner, h = np.linspace(0.05, 0.95, 7), 1e-6
    f = lambda order, t: bernstein_rows(10, order, t) @ coeffs  # noqa: E731
    np.testing.assert_allclose((f(0, inner + h) - f(0, inner - h)) / (2 * h), f(1, inner), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose((f(1, inner + h) - f(1, inner - h)) / (2 * h), f(2, inner), rtol=1e-5, atol=1e-5)
    # The ends: B(0) = e_0, B'(0) = N (e_1 - e_0), B(1) = e_N.
    assert bernstein_rows(10, 0, 0.0).tolist() == [1.0] + [0.0] * 10
    assert bernstein_rows(10, 1, 0.0)[:3].tolist() == [-10.0, 10.0, 0.0]
    assert bernstein_rows(10, 0, 1.0).tolist() == [0.0] * 10 + [1.0]
    assert not bernstein_rows(2, 3, tau).any()


def controller() -> Follower:
    """A controller's follower that published the snapshot ``synthetic`` answers."""
    sent = Sent()
    sent.record(41, 10**12 + 5)
    return Follower(sent)


def test_followable_messages_replace_the_trajectory_and_others_leave_none():
    follower = controller()
    assert follower.current is None
    for status in (PlanStatus.OK, PlanStatus.HELD, PlanStatus.STOPPING):
        msg = synthetic(2, 3, 10, seed=int(status), status=status)
        follower.take(msg)
        followed = follower.current
        assert (followed.status, followed.plan_sequence) == (status, 40)
        # Evaluated against plan_origin_ns, not the answered snapshot's time.
        np.testing.assert_array_equal(
            followed.at_ns(10**12 + 500_000_000).position, Plan.from_message(msg).at(0.5).position
        )
    follower.take(synthetic(2, 3, 10, seed=9, status=PlanStatus.NO_PLAN))
    assert follower.current is None, "NoPlan leaves nothing to follow, even with coefficients"
    follower.take(synthetic(2, 3, 10, seed=9))
    bad = synthetic(2, 3, 10, seed=9)
    bad.status = 77
    with pytest.raises(MessageError):
        follower.take(bad)
    assert follower.current is None, "an unreadable message leaves nothing to follow"


def test_only_answers_to_the_controllers_own_snapshots_are_followed():
    follower = controller()
    for sequence, timestamp in ((41, 10**12 + 6), (40, 10**12 + 5)):
        other = synthetic(2, 3, 10, seed=2)
        other.answers_sequence, other.state_timestamp_ns = sequence, timestamp
        follower.take(other)
        assert follower.current is None, f"an answer to another snapshot ({sequence}, {timestamp})"
    follower.take(synthetic(2, 3, 10, seed=2, status=PlanStatus.HELD))
    assert follower.current.status is PlanStatus.HELD
    other = synthetic(2, 3, 10, seed=2, status=PlanStatus.NO_PLAN)
    other.answers_sequence = 40
    follower.take(other)
    assert follower.current is not None, "someone else's NoPlan changes nothing"
    watcher = Follower()
    watcher.take(synthetic(2, 3, 10, seed=2))
    assert watcher.current is None, "a watcher follows nothing"


def test_a_controller_remembers_its_last_snapshots():
    sent = Sent()
    for k in range(SENT_REMEMBERED + 1):
        sent.record(k, 1000 + k)
    assert (0, 1000) not in sent
    assert (1, 1001) in sent and (SENT_REMEMBERED, 1000 + SENT_REMEMBERED) in sent


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("dim", 4),
        ("robots", 0),
        ("robots", 257),
        ("degree", 0),
        ("degree", 16),
        ("horizon", 0.0),
        ("horizon", float("nan")),
        ("status", 4),
    ],
)
def test_impossible_messages_give_errors(field, value):
    """As the Rust follower: a status or shape no daemon writes is an error."""
    msg = synthetic(2, 3, 10, seed=4)
    setattr(msg, field, value)
    with pytest.raises(MessageError):
        Plan.from_message(msg)


def test_an_unknown_reason_is_kept_as_its_code_and_does_not_stop_following():
    msg = synthetic(2, 3, 10, seed=4)
    msg.reason = 99
    plan = Plan.from_message(msg)
    assert plan.reason == 99 and not isinstance(plan.reason, Reason) and plan.trajectory is not None
