"""`flowopt demo --live ADDR`: the page served at ADDR, the Foxglove
WebSocket protocol on the next port as a client written from the
protocol's description speaks it (the ``websockets`` package), and, where
Chromium is installed, the page rendered by a real browser."""

from __future__ import annotations

import base64
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
    """The page in headless Chromium, read through its DevTools protocol in
    real time (a DOM dump runs on virtual time, which the WebSocket's
    messages do not hold up)."""
    port, _ = live_demo
    devtools = port + 10001
    browser = subprocess.Popen(
        ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1200,720",
         f"--remote-debugging-port={devtools}", f"--user-data-dir={tmp_path / 'profile'}", f"http://127.0.0.1:{port}/"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30
        pages = []
        while not pages and time.monotonic() < deadline:
            try:
                targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{devtools}/json", timeout=2))
                pages = [t for t in targets if t["type"] == "page" and str(port) in t["url"]]
            except OSError:
                time.sleep(0.2)
        assert pages, "Chromium did not open the page"
        with ws_client.connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=10) as cdp:
            calls = iter(range(1, 1_000_000))

            def call(method, **params):
                n = next(calls)
                cdp.send(json.dumps({"id": n, "method": method, "params": params}))
                while True:
                    reply = json.loads(cdp.recv(timeout=20))
                    if reply.get("id") == n:
                        return reply["result"]

            shown = ""
            while time.monotonic() < deadline:
                shown = call("Runtime.evaluate", expression="document.querySelector('main').outerHTML",
                             returnByValue=True)["result"].get("value", "")
                if 'data-drawn="robots 16, paths 16"' in shown and "newest answer Ok" in shown:
                    break
                time.sleep(0.5)
            shot = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
    finally:
        browser.terminate()
        browser.wait(timeout=20)
    # The stats say what arrived; the canvas says what it drew: every robot,
    # and a path for each.
    assert "robots 16" in shown and "newest answer Ok" in shown, shown
    assert 'data-drawn="robots 16, paths 16"' in shown, shown
    assert shot.startswith(b"\x89PNG") and len(shot) > 10_000
