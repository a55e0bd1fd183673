"""The live view on the emulated bench: `rakectl view` as its own process, read by a
Foxglove WebSocket client (the SDK's protocol, foxglove.sdk.v1, over the websockets
package; tier 3).

Rates are printed and only bounded loosely (at least a quarter of the one asked for):
these machines are shared and noisy.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import websockets

from rakectl.sim.rig import emulated_bench, namespaces_unavailable
from rakectl.view.topics import JSON_SCHEMAS

CONFIG = Path(__file__).resolve().parents[2] / "config"
EMULATOR = CONFIG / "emulator-demo.yaml"
DAEMON = CONFIG / "rakectl-emulated.yaml"
RATE_HZ = 50.0
LISTEN_S = 3.0

_reason = namespaces_unavailable()
pytestmark = [pytest.mark.crossprocess,
              pytest.mark.skipif(_reason is not None, reason=f"no network namespace: {_reason}")]


def _start_viewer(socket: Path, truth: Path, log: Path) -> tuple[subprocess.Popen[bytes], int]:
    """`rakectl view` on a free port; the port it printed."""
    process = subprocess.Popen(
        [sys.executable, "-m", "rakectl", "view", "--socket", str(socket), "--port", "0",
         "--rate-hz", str(RATE_HZ), "--truth", str(truth), "--emulator-config", str(EMULATOR),
         "--lane", "0.92", "1.25"], stderr=log.open("wb"))
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        found = re.search(r"ws://127\.0\.0\.1:(\d+)", log.read_text())
        if found:
            return process, int(found.group(1))
        if process.poll() is not None:
            raise AssertionError(f"rakectl view ended: {log.read_text()}")
        time.sleep(0.1)
    process.kill()
    raise AssertionError(f"rakectl view did not start: {log.read_text()}")


async def _listen(port: int, topics: tuple[str, ...], seconds: float
                  ) -> tuple[dict[str, list[tuple[int, bytes]]], dict[str, Any]]:
    """Subscribe to ``topics`` and collect (log time, payload) per topic."""
    async with websockets.connect(f"ws://127.0.0.1:{port}",
                                  subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]
                                  ) as ws:
        channels: dict[str, dict[str, Any]] = {}
        info: dict[str, Any] = {}
        while not set(topics) <= set(channels):
            message = json.loads(await asyncio.wait_for(ws.recv(), 10.0))
            if message["op"] == "serverInfo":
                info = message
            elif message["op"] == "advertise":
                channels.update({c["topic"]: c for c in message["channels"]})
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": k, "channelId": channels[t]["id"]} for k, t in enumerate(topics)]}))
        got: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics}
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                frame = await asyncio.wait_for(ws.recv(), left)
            except TimeoutError:
                break
            if isinstance(frame, bytes) and frame[0] == 0x01:  # messageData
                sub, t_ns = struct.unpack_from("<IQ", frame, 1)
                got[topics[sub]].append((t_ns, frame[13:]))
        return got, {"server": info, "channels": channels}


def test_the_live_view_streams_a_running_bench(tmp_path: Path) -> None:
    with emulated_bench(tmp_path, EMULATOR, DAEMON) as bench:
        bench.wait_for_state(["disarmed"], 60.0)
        viewer, port = _start_viewer(bench.socket, tmp_path / "truth.csv",
                                     tmp_path / "view.log")
        try:
            bench.request("arm")
            bench.wait_for_state(["armed"], 15.0)
            topics = ("/force", "/state", "/rake", "/voltage", "/timing", "/ground", "/truth")
            got, meta = asyncio.run(_listen(port, topics, LISTEN_S))
        finally:
            viewer.terminate()
            assert viewer.wait(10.0) == 0, (tmp_path / "view.log").read_text()
    rates = {t: len(v) / LISTEN_S for t, v in got.items()}
    print(f"\nlive view, messages per second over {LISTEN_S:g} s: "
          + ", ".join(f"{t} {r:.0f}" for t, r in rates.items()))
    assert meta["channels"]["/force"]["encoding"] == "json"
    assert meta["channels"]["/rake"]["schemaName"] == "foxglove.SceneUpdate"
    for topic in ("/force", "/state", "/rake", "/voltage", "/timing", "/ground"):
        assert rates[topic] >= 0.25 * RATE_HZ, (topic, rates)
    assert got["/truth"], "the emulator's truth streams too"
    states = {json.loads(p)["state"] for _, p in got["/state"]}
    assert states <= {"armed", "checking"} and "armed" in states
    force = json.loads(got["/force"][-1][1])
    assert set(force) == set(JSON_SCHEMAS["/force"]["properties"])  # each field its schema's
    assert force["clamp_limit_n"] == pytest.approx(72.0)
    assert 0.0 < force["clamp_budget_n"] <= 0.5 * force["clamp_limit_n"]
    assert all(math.isfinite(force[k]) for k in ("f_hat_n", "f_current_n"))
    volts = json.loads(got["/voltage"][-1][1])
    assert all(abs(volts[k]) <= 24.0 for k in volts)  # holding the rake: within the supply
    truth = json.loads(got["/truth"][-1][1])
    assert truth["force_down_n"] < 90.0 and truth["mine_activated"] is False
    times = [t for t, _ in got["/force"]]
    assert times == sorted(times) and abs(times[-1] * 1e-9 - time.time()) < 60.0
