"""The ctypes layout is the documented one, and the checks can fail."""

from __future__ import annotations

import ctypes
import re

import numpy as np
import pytest
from conftest import REPO

from flowopt_client import messages as m


def documented_table(title: str) -> dict[str, int]:
    """``{field: offset}`` of the table under the ``## `title` `` heading of
    docs/MESSAGES.md."""
    text = (REPO / "docs/MESSAGES.md").read_text()
    section = text.split(f"## `{title}`", 1)[1].split("\n## ", 1)[0]
    return {field: int(offset) for offset, field in re.findall(r"^\| (\d+) \| `(\w+)` \|", section, re.M)}


def test_the_import_time_check_finds_no_difference():
    assert m.layout_errors() == []
    assert ctypes.sizeof(m.StateSnapshot) == 19520 and ctypes.alignment(m.StateSnapshot) == 8
    assert ctypes.sizeof(m.JointTrajectory) == 98504 and ctypes.alignment(m.JointTrajectory) == 8


@pytest.mark.parametrize(
    ("struct", "title"), [(m.StateSnapshot, "flowopt::StateSnapshot"), (m.JointTrajectory, "flowopt::JointTrajectory")]
)
def test_every_documented_offset_is_the_ctypes_one(struct, title):
    table = documented_table(title)
    assert len(table) == len(struct._fields_), "docs/MESSAGES.md lists every field"
    assert {field: getattr(struct, field).offset for field, _ in struct._fields_} == table
    checked = next(offsets for s, _, offsets in m.LAYOUT if s is struct)
    assert checked == table, "the import-time check uses the documented offsets"


def test_the_check_reports_a_layout_that_differs():
    class Shifted(ctypes.Structure):
        _fields_ = [("version", ctypes.c_uint32), ("dim", ctypes.c_uint64)]

        @classmethod
        def type_name(cls):
            return "test::Shifted"

    errors = m.layout_errors([(Shifted, 12, {"version": 0, "dim": 4})])
    assert errors == ["test::Shifted: size 16, documented 12", "test::Shifted.dim: offset 8, documented 4"]


def test_payloads_carry_the_rust_type_names():
    assert m.StateSnapshot.type_name() == "flowopt::StateSnapshot"
    assert m.JointTrajectory.type_name() == "flowopt::JointTrajectory"


def test_numpy_views_write_the_structures_in_place():
    s = m.StateSnapshot()
    robots = m.robot_array(s)
    robots[3, 0] = [1.0, 2.0, 3.0]
    robots[3, 2, :2] = [-4.0, 5.0]
    assert list(s.robot[3].position) == [1.0, 2.0, 3.0] and list(s.robot[3].goal) == [-4.0, 5.0, 0.0]
    m.obstacle_array(s)[15, 6:] = [0.2, 0.3]
    assert (s.obstacle[15].radius, s.obstacle[15].half_height) == (0.2, 0.3)
    j = m.JointTrajectory()
    m.coeff_array(j)[255, 2, 15] = 7.5
    assert j.coeffs[255][2][15] == 7.5
    assert np.count_nonzero(m.coeff_array(j)) == 1


def test_team_names_round_trip_and_bad_ones_are_refused():
    s = m.StateSnapshot()
    m.write_team(s, "lab-a")
    assert bytes(s.team) == b"lab-a" + b"\0" * 27
    assert m.read_team(s) == "lab-a"
    for bad in ("", "x" * 33, "a/b", "a\0b"):
        with pytest.raises(ValueError):
            m.write_team(s, bad)


def test_reason_codes_are_the_documented_ones():
    assert (m.Reason.NON_FINITE, m.Reason.CLOCK, m.Reason.LIMITS, m.Reason.WORLD_CHANGED) == (6, 16, 22, 23)
    assert m.Reason.RECOVERING == 24 and not m.Reason.RECOVERING.is_rejection
    assert m.Reason.CANNOT_BRAKE == 25 and m.Reason.CANNOT_BRAKE.label == "CannotBrake"
    assert m.Reason.CANNOT_AVOID == 26 and m.Reason.CANNOT_AVOID.label == "CannotAvoid"
    assert (m.PlanStatus.NO_PLAN.label, m.Reason.DEADLINE_MISSED.label) == ("NoPlan", "DeadlineMissed")
    rejections = {r for r in m.Reason if r.is_rejection}
    assert rejections == set(m.Reason(v) for v in [*range(1, 14), 16, 17, 18, 25, 26])
    assert [s.followable for s in m.PlanStatus] == [False, True, True, True]
