"""`flowopt demo --live ADDR`: the page served at ADDR, the Foxglove
WebSocket protocol on the next port as a client written from the
protocol's description speaks it (the ``websockets`` package), and, where
Chromium is installed, the page rendered by a real browser."""

from __future__ import annotations

import json
import random
import shutil
import struct
import subprocess
import time
import urllib.request

import pytest

ws_client = pytest.importorskip("websockets.sync.client")


@pytest.fixture
def live_demo(flowopt_bin, config, prefix):
    port = random.randrange(20000, 40000, 2)
    demo = subprocess.Popen(
        [str(flowopt_bin), "demo", "--config", str(config), "--ipc-prefix", prefix, "--seconds", "12",
         "--live", f"127.0.0.1:{port}", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    deadline = time.monotonic() + 20
    page = None
    while page is None and time.monotonic() < deadline and demo.poll() is None:
        try:
            page = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2).read().decode()
        except OSError:
            time.sleep(0.2)
    assert page is not None, "the live view's page was never served"
    yield port, page
    demo.wait(timeout=60)
    assert demo.returncode == 0


def test_the_page_and_the_foxglove_websocket_carry_the_team(live_demo):
    port, page = live_demo
    assert f'"ws_port":{port + 1}' in page and '"name":"default"' in page
    with ws_client.connect(f"ws://127.0.0.1:{port + 1}", subprotocols=["foxglove.sdk.v1"], open_timeout=10) as ws:
        channels = {}
        deadline = time.monotonic() + 10
        while len(channels) < 3 and time.monotonic() < deadline:
            m = json.loads(ws.recv(timeout=10))
            if m["op"] == "advertise":
                channels.update({c["id"]: c for c in m["channels"]})
        topics = {c["topic"]: c for c in channels.values()}
        assert topics["/flowopt/default/answer"]["encoding"] == "json"
        assert topics["/flowopt/default/answer"]["schemaName"] == "flowopt.Answer"
        assert topics["/flowopt/default/snapshot"]["schemaName"] == "flowopt.Snapshot"
        assert topics["/flowopt/default/scene"]["schemaName"] == "foxglove.SceneUpdate"
        wanted = {1: "/flowopt/default/answer", 2: "/flowopt/default/snapshot"}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": k, "channelId": topics[t]["id"]} for k, t in wanted.items()]}))
        got = {}
        while len(got) < 2 and time.monotonic() < deadline + 10:
            frame = ws.recv(timeout=10)
            if isinstance(frame, str):
                continue
            opcode, subscription, _ = struct.unpack_from("<BIQ", frame)
            assert opcode == 1
            got[wanted[subscription]] = json.loads(frame[13:])
    assert len(got["/flowopt/default/snapshot"]["robots"]) == 16
    assert got["/flowopt/default/answer"]["status"] in {"Ok", "Held", "Stopping", "NoPlan", "Rejected"}


@pytest.mark.skipif(shutil.which("chromium") is None, reason="Chromium is not installed (apt-get install chromium)")
def test_headless_chromium_draws_the_team(live_demo, tmp_path):
    port, _ = live_demo
    time.sleep(2)
    browser = ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=4000"]
    # Chromium's virtual time may run out before the first messages arrive
    # over the (real) socket: a few tries.
    for _ in range(8):
        dom = subprocess.run([*browser, "--dump-dom", f"http://127.0.0.1:{port}/"],
                             capture_output=True, text=True, timeout=60).stdout
        if "newest answer Ok" in dom and 'data-drawn="robots 16, paths 16"' in dom:
            break
    shown = dom[dom.find("<main"):dom.find("</main>")]
    assert "robots 16" in shown and "newest answer Ok" in shown, shown
    # The canvas says what it drew: every robot, and a path for each.
    assert 'data-drawn="robots 16, paths 16"' in shown, shown
    shot = tmp_path / "live.png"
    subprocess.run([*browser, "--window-size=1200,720", f"--screenshot={shot}", f"http://127.0.0.1:{port}/"],
                   capture_output=True, timeout=60)
    assert shot.stat().st_size > 10_000
