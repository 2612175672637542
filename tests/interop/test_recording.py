"""`flowopt demo --record`: the MCAP read back by the Python ``mcap``
package (not this project's code), every channel's schema named, and the
run's plans rebuilt from their Bernstein coefficients: each new plan starts
where the snapshot it answers measured the robots."""

from __future__ import annotations

import json
import subprocess

import pytest

mcap_reader = pytest.importorskip("mcap.reader")


def bernstein(c, s):
    p = list(c)
    for level in range(len(p) - 1, 0, -1):
        for k in range(level):
            p[k] = (1 - s) * p[k] + s * p[k + 1]
    return p[0]


def test_a_recording_holds_the_run_and_its_plans(flowopt_bin, config, prefix, tmp_path):
    path = tmp_path / "run.mcap"
    run = subprocess.run(
        [str(flowopt_bin), "demo", "--config", str(config), "--ipc-prefix", prefix, "--seconds", "6",
         "--record", str(path), "--json"],
        capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads(run.stdout)
    answered = sum(report["statuses"].values())
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f)
        summary = reader.get_summary()
        kinds = {c.topic: (c.message_encoding, summary.schemas[c.schema_id].name) for c in summary.channels.values()}
        assert kinds == {
            "/flowopt/default/snapshot": ("json", "flowopt.Snapshot"),
            "/flowopt/default/answer": ("json", "flowopt.Answer"),
            "/flowopt/default/scene": ("protobuf", "foxglove.SceneUpdate"),
        }
        snapshots, plans, answers = {}, {}, []
        for _, channel, message in reader.iter_messages(topics=["/flowopt/default/snapshot", "/flowopt/default/answer"]):
            record = json.loads(message.data)
            if channel.topic.endswith("/snapshot"):
                snapshots[record["sequence"]] = record
            else:
                answers.append(record)
                if record["plan"]:
                    plans[record["plan"]["sequence"]] = record["plan"]
    # The watcher sees the newest message, as any viewer: nearly all of them.
    assert len(answers) >= 0.9 * answered, (len(answers), answered)
    assert len({a["status"] for a in answers} - {"Ok", "Held", "Stopping", "NoPlan", "Rejected"}) == 0
    errors = []
    for a in answers:
        if a["status"] != "Ok" or a["answers_sequence"] not in snapshots:
            continue
        plan, snapshot = plans[a["plan_sequence"]], snapshots[a["answers_sequence"]]
        assert len(plan["coefficients"]) == len(snapshot["robots"]) == report["robots"]
        s = min(max((snapshot["timestamp_ns"] - plan["origin_ns"]) * 1e-9 / plan["horizon"], 0.0), 1.0)
        errors.append(max(
            max(abs(bernstein(axis, s) - robot["position"][k]) for k, axis in enumerate(c))
            for c, robot in zip(plan["coefficients"], snapshot["robots"])))
    assert len(errors) >= 0.5 * report["statuses"].get("Ok", 0)
    errors.sort()
    # Ok plans start where the robots were measured: within the follow
    # tolerance (10 mm; a plan made while the robots follow the held one
    # starts on that one), a late plan adopted while the team was still
    # near its start within the warm tolerance.
    assert errors[len(errors) // 2] < 0.010 + 1e-9 and errors[-1] < 0.05, errors[-5:]


def test_an_existing_recording_is_never_overwritten(flowopt_bin, config, prefix, tmp_path):
    path = tmp_path / "kept.mcap"
    path.write_bytes(b"keep me")
    run = subprocess.run(
        [str(flowopt_bin), "sim", "--config", str(config), "--ipc-prefix", prefix, "--seconds", "1",
         "--record", str(path)],
        capture_output=True, text=True, timeout=60)
    assert run.returncode != 0
    assert "never overwritten" in run.stderr and run.stderr.count("\n") == 1, run.stderr
    assert path.read_bytes() == b"keep me"
