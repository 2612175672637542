"""The ROS 2 bridge against Eclipse Cyclone DDS (the DDS of
``rmw_cyclonedds_cpp``), which shares no code with the bridge's RustDDS:
it receives every robot's ``nav_msgs/Path`` and the answers' statuses while
a simulated team flies, and it can be the mocap itself."""

from __future__ import annotations

import json
import subprocess
import time

import pytest

cyclonedds = pytest.importorskip("cyclonedds")

from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.qos import Policy, Qos  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from ros2_types import (  # noqa: E402
    Header, MultiDOFJointTrajectory, Odometry, Path, Point, Pose, PoseStamped, PoseWithCovariance, String, Time, Twist,
    TwistWithCovariance, Vector3)

ROBOTS = 16  # config/default.toml
# How far a verified plan's centres may leave the 2 m box
# (`flowopt_planner::problem::FEASIBILITY_TOLERANCE` of the 0.2 m separation); a plan
# starts at the measured state, which the daemon accepts that far out.
BOX_TOLERANCE = 0.01 * 0.2
RELIABLE = Qos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepLast(10))
# A viewer's subscription: best effort, the newest only. (A slow reliable
# reader holds the bridge's send window full, and its publications then
# fail for every reader, the robots' controller included: this process
# decodes in Python beside the daemon, the bridge and the simulated team.)
NEWEST = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(1))
BEST_EFFORT = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(1))


def readers(participant, kind, topics, qos=RELIABLE):
    return [DataReader(participant, Topic(participant, "rt" + t, kind, qos=RELIABLE), qos=qos) for t in topics]


def take(reader, kind):
    """The valid samples waiting (an ending writer leaves invalid ones)."""
    return [s for s in reader.take(N=100) if isinstance(s, kind)]


def bridge(flowopt_bin, config, prefix, domain, *extra):
    return subprocess.Popen(
        [str(flowopt_bin), "ros2", "--config", str(config), "--ipc-prefix", prefix, "--domain", str(domain),
         "--with-daemon", "--json", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def test_every_robot_path_reaches_a_cyclone_participant_while_a_simulated_team_flies(flowopt_bin, config, prefix, domain):
    participant = DomainParticipant(domain)
    paths = readers(participant, Path, [f"/flowopt/default/robot{i}/path" for i in range(ROBOTS)], NEWEST)
    (status,) = readers(participant, String, ["/flowopt/default/status"])
    (trajectory,) = readers(participant, MultiDOFJointTrajectory, ["/flowopt/default/trajectory"], NEWEST)
    run = bridge(flowopt_bin, config, prefix, domain, "--simulate", "--seconds", "12")
    received = [[] for _ in range(ROBOTS)]
    statuses, trajectories = [], []
    while run.poll() is None:
        for i, reader in enumerate(paths):
            received[i] += take(reader, Path)
        statuses += [json.loads(s.data) for s in take(status, String)]
        trajectories += take(trajectory, MultiDOFJointTrajectory)
        time.sleep(0.2)
    out, _ = run.communicate()
    assert run.returncode == 0, out
    report = json.loads(out)
    for i, got in enumerate(received):
        flown = [p for p in got if p.poses]
        assert flown, f"robot {i}: no path with poses ({len(got)} received)"
        spans = []
        for path in flown:
            assert path.header.frame_id == "world"
            stamps = [p.header.stamp.sec * 10**9 + p.header.stamp.nanosec for p in path.poses]
            assert stamps == sorted(stamps) and len(stamps) == 50
            spans.append(stamps[-1] - stamps[0])
            excess = max(max(abs(p.pose.position.x), abs(p.pose.position.y)) - 1.0 for p in path.poses)
            assert excess <= BOX_TOLERANCE, f"robot {i}: {excess * 1e3:.2f} mm outside the box"
        # Plans over the 5 s horizon (stopping plans are shorter).
        assert max(spans) == pytest.approx(5e9, abs=1e6) and min(spans) > 0
    assert statuses and {s["status"] for s in statuses} <= {"Ok", "Held", "Stopping", "NoPlan", "Rejected"}
    # (How often it is Ok is measured by `flowopt demo`: this process's
    # decoding of every path competes with the daemon for the cores.)
    assert any(s["status"] == "Ok" for s in statuses)
    flown = [t for t in trajectories if t.points]
    assert flown and flown[-1].joint_names == [f"robot{i}" for i in range(ROBOTS)]
    assert len(flown[-1].points[0].transforms) == ROBOTS
    # The team flew: goal sets reached through poses and paths over DDS.
    assert report["simulated"]["goal_sets_reached"] >= 1, report


def test_a_cyclone_mocap_gets_plans_from_its_poses_to_its_goals(flowopt_bin, config, prefix, domain):
    participant = DomainParticipant(domain)
    writer = lambda topic: DataWriter(participant, Topic(participant, "rt" + topic, PoseStamped, qos=BEST_EFFORT), qos=BEST_EFFORT)  # noqa: E731
    poses = [writer(f"/default/robot{i}/pose") for i in range(ROBOTS)]
    goals = [writer(f"/default/robot{i}/goal") for i in range(ROBOTS)]
    paths = readers(participant, Path, [f"/flowopt/default/robot{i}/path" for i in range(ROBOTS)])
    # A 4 x 4 grid crossing to its mirror image.
    starts = [(-0.75 + 0.5 * (i % 4), -0.75 + 0.5 * (i // 4)) for i in range(ROBOTS)]
    ends = [(-x, -y) for x, y in starts]
    run = bridge(flowopt_bin, config, prefix, domain, "--seconds", "8")
    got = [None] * ROBOTS
    while run.poll() is None:
        now = time.time_ns()
        header = Header(stamp=Time(sec=now // 10**9, nanosec=now % 10**9), frame_id="world")
        for i in range(ROBOTS):
            poses[i].write(PoseStamped(header=header, pose=Pose(position=Point(x=starts[i][0], y=starts[i][1]))))
            goals[i].write(PoseStamped(header=header, pose=Pose(position=Point(x=ends[i][0], y=ends[i][1]))))
            for p in take(paths[i], Path):
                if p.poses:
                    got[i] = p
        time.sleep(0.02)
    out, _ = run.communicate()
    assert run.returncode == 0, out
    for i, path in enumerate(got):
        assert path is not None, f"robot {i}: no plan"
        first, last = path.poses[0].pose.position, path.poses[-1].pose.position
        # Within the follow tolerance (10 mm): a plan made while the robots
        # count as following the held one starts on that one.
        assert (first.x, first.y) == pytest.approx(starts[i], abs=10e-3 + 1e-9), f"robot {i} starts where mocap saw it"
        assert (last.x, last.y) == pytest.approx(ends[i], abs=1e-3), f"robot {i} ends at its goal"


def test_odometry_from_cyclone_gives_plans_that_start_at_its_velocity(flowopt_bin, config, prefix, domain, tmp_path):
    bridge_file = tmp_path / "bridge.toml"
    bridge_file.write_text('[ros2]\npose_kind = "odometry"\n')
    participant = DomainParticipant(domain)
    odometry = [DataWriter(participant, Topic(participant, f"rt/default/robot{i}/pose", Odometry, qos=BEST_EFFORT),
                           qos=BEST_EFFORT) for i in range(ROBOTS)]
    (trajectory,) = readers(participant, MultiDOFJointTrajectory, ["/flowopt/default/trajectory"])
    starts = [(-0.75 + 0.5 * (i % 4), -0.75 + 0.5 * (i // 4)) for i in range(ROBOTS)]
    velocity = (0.2, -0.1)
    run = bridge(flowopt_bin, config, prefix, domain, "--seconds", "6", "--bridge", str(bridge_file))
    got = None
    while run.poll() is None:
        now = time.time_ns()
        header = Header(stamp=Time(sec=now // 10**9, nanosec=now % 10**9), frame_id="world")
        for i in range(ROBOTS):
            pose = PoseWithCovariance(pose=Pose(position=Point(x=starts[i][0], y=starts[i][1])))
            twist = TwistWithCovariance(twist=Twist(linear=Vector3(x=velocity[0], y=velocity[1])))
            odometry[i].write(Odometry(header=header, child_frame_id="robot", pose=pose, twist=twist))
        got = next((t for t in reversed(take(trajectory, MultiDOFJointTrajectory)) if t.points), got)
        time.sleep(0.02)
    out, _ = run.communicate()
    assert run.returncode == 0, out
    assert got is not None, "no plan from odometry"
    first = got.points[0]
    for i in range(ROBOTS):
        assert (first.transforms[i].translation.x, first.transforms[i].translation.y) == pytest.approx(starts[i], abs=1e-3)
        assert (first.velocities[i].linear.x, first.velocities[i].linear.y) == pytest.approx(velocity, abs=1e-3)
