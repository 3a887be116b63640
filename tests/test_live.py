"""The live view, seen by an independent client: a WebSocket client of our own speaking
Foxglove's protocol (subprotocol ``foxglove.sdk.v1``: JSON ``advertise``/``subscribe``, binary
message data) on loopback, while a simulated world flies."""

from __future__ import annotations

import asyncio
import json
import struct
import subprocess
import sys
import time
from collections.abc import Callable

import jsonschema
import numpy as np
import pytest
import websockets

from uavmpc import scenarios
from uavmpc.drivers.summary import RunStatus, RunSummary
from uavmpc.drivers.swarm import free_ports
from uavmpc.drivers.world import World
from uavmpc.scenarios.run import RunSpec
from uavmpc.view.live import LiveView

pytestmark = pytest.mark.realtime  # flies on the wall clock

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode: u32 subscription id, u64 log time [ns], payload


async def _watch(url: str, seconds: float, *, leave_abruptly: bool = False,
                 until: Callable[[dict], bool] | None = None) -> dict:
    """Connect, subscribe to every advertised channel, and decode what arrives for
    ``seconds``, or until ``until(got)`` holds."""
    got: dict[str, list[tuple[int, dict]]] = {}
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        channels: dict[int, dict] = {}
        while {c["topic"] for c in channels.values()} < {"/scene", "/metrics"}:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 10.0))
            if msg["op"] == "advertise":
                channels.update({c["id"]: c for c in msg["channels"]})
        subs = {i + 1: c for i, c in enumerate(channels.values())}
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": sid, "channelId": c["id"]} for sid, c in subs.items()]}))
        validators = {sid: jsonschema.Draft202012Validator(json.loads(c["schema"]))
                      for sid, c in subs.items()}
        checked: list[tuple[int, dict]] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                frame = await asyncio.wait_for(ws.recv(), max(0.01, end - time.monotonic()))
            except TimeoutError:
                break
            if isinstance(frame, str) or frame[0] != MESSAGE_DATA:
                continue
            sid, log_ns = struct.unpack_from("<IQ", frame, 1)
            payload = json.loads(frame[13:])
            got.setdefault(subs[sid]["topic"], []).append((log_ns, payload))
            checked.append((sid, payload))
            if until is not None and until(got):
                break
        if leave_abruptly:  # no close handshake: the socket just goes away
            ws.transport.abort()
    # Validated once the client has left: a client that validates as it reads is slow on a
    # loaded machine, and the server drops a client that does not keep up.
    for sid, payload in checked:
        validators[sid].validate(payload)
    return got


def test_a_client_receives_the_scene_while_a_run_flies_and_clients_do_not_disturb_it(
        tmp_path) -> None:
    port = free_ports(1)[0]
    run = subprocess.Popen([sys.executable, "-m", "uavmpc.apps.cli", "run",
                            "swap_through_static", "--duration", "12", "--realtime", "1",
                            "--out", str(tmp_path), "--live", str(port)],
                           stdout=subprocess.PIPE, text=True)
    try:
        assert run.stdout is not None
        first = run.stdout.readline()
        assert f"live view on ws://127.0.0.1:{port}" in first, first
        # a client that connects once the flight is under way (its kernels may compile
        # first, on a cold cache: it watches until 2 s of the flight have come, or 90 s)…
        got = asyncio.run(_watch(f"ws://127.0.0.1:{port}", 90.0, until=lambda g: min(
            len(g.get("/scene", [])), len(g.get("/metrics", []))) >= 20))
        # …one that leaves without a word, and one more after it
        asyncio.run(_watch(f"ws://127.0.0.1:{port}", 0.5, leave_abruptly=True))
        late = asyncio.run(_watch(f"ws://127.0.0.1:{port}", 0.5))
        assert run.wait(120) == 0
    finally:
        run.kill()
    scenes = got["/scene"]
    # 2 s of a flight: 20 updates at 10 Hz of its clock, consecutive, each decoded and valid
    assert len(scenes) >= 20 and len(got["/metrics"]) >= 20
    t = np.array([ns for ns, _ in scenes]) * 1e-9
    assert np.all(np.diff(t) > 0) and np.median(np.diff(t)) == pytest.approx(0.1, abs=1e-6)
    ids = {e["id"] for e in scenes[-1][1]["entities"]}
    assert {"ground", "uav1/body", "uav2/plan", "uav3/cylinder", "uav3/desired"} <= ids
    assert late["/scene"]
    # The flight is the one flown without anyone watching.
    summary = RunSummary.read(tmp_path / "summary.json")
    reference = World(RunSpec(scenarios.load("swap_through_static"), seed=0)).run(12.0).summary()
    assert summary.min_distance_m == reference.min_distance_m
    assert summary.uavs == reference.uavs


def test_a_busy_port_and_a_missing_extra_are_one_line_errors(tmp_path) -> None:
    with LiveView(port=0) as live:
        with pytest.raises(OSError, match=f"cannot serve on 127.0.0.1:{live.port}"):
            LiveView(port=live.port)
        # the CLI says the same in one line, before flying
        run = subprocess.run([sys.executable, "-m", "uavmpc.apps.cli", "run",
                              "swap_through_static", "--duration", "1", "--out",
                              str(tmp_path), "--live", str(live.port)],
                             capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert f"cannot serve on 127.0.0.1:{live.port}" in run.stderr
    with pytest.raises(ValueError, match="port: must be an integer"):
        LiveView(port=70000)
    # without the extra: the import fails with what to install
    code = ("import sys; sys.modules['foxglove'] = None\n"
            "from uavmpc.view.live import LiveView\n"
            "try:\n    LiveView(port=0)\nexcept ImportError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60)
    assert "pip install 'uavmpc[viz]'" in out.stdout


def _yielding(scene: dict, entity: str) -> bool:
    return any(e["id"] == entity and e["metadata"][0]["value"] == "yielding"
               for e in scene["entities"] if e["cylinders"])


def test_a_swap_of_three_node_processes_is_collision_free_and_watched_live(tmp_path) -> None:
    """``uavmpc swarm --live``: three node processes swap through one point over Zenoh,
    without collision, each to its goal, and the live view shows what the monitor hears."""
    port = free_ports(1)[0]
    swarm = subprocess.Popen([sys.executable, "-m", "uavmpc.apps.cli", "swarm",
                              "swap_through_static", "--duration", "28", "--out", str(tmp_path),
                              "--live", str(port)], stdout=subprocess.PIPE, text=True)
    try:
        assert swarm.stdout is not None
        assert f"ws://127.0.0.1:{port}" in swarm.stdout.readline()
        # the nodes start (compiling first, on a cold cache) and are heard by the monitor
        deadline = time.monotonic() + 90.0
        while time.monotonic() < deadline:
            first = asyncio.run(_watch(f"ws://127.0.0.1:{port}", 1.0))
            if any(e["cylinders"] for _, m in first.get("/scene", [])
                   for e in m["entities"]):
                break
        # they meet from ~2 s after the start on: watch until uav3 climbs over both (in
        # spells, while the swarm flies: on a loaded machine one spell may see nothing)
        got: dict[str, list[tuple[int, dict]]] = {}

        def seen(g: dict) -> bool:
            # (the nodes preview the mission over their horizon: uav3 may yield before the
            # epoch, while every scene is still stamped 0; wait for the mission's clock too)
            scenes = got.get("/scene", []) + g.get("/scene", [])
            return (len(scenes) >= 10 and scenes[-1][0] > scenes[0][0]
                    and _yielding(scenes[-1][1], "uav3/cylinder"))

        while swarm.poll() is None and not seen({}):
            try:
                spell = asyncio.run(_watch(f"ws://127.0.0.1:{port}", 5.0, until=seen))
            except OSError:  # the swarm ended between two spells
                break
            for topic, msgs in spell.items():
                got.setdefault(topic, []).extend(msgs)
        assert swarm.wait(120) == 0
        assert got.get("/scene"), "no scene reached the live view while the swarm flew"
    finally:
        swarm.kill()
    scenes = [m for _, m in got["/scene"]]
    assert len(scenes) >= 10
    t = np.array([ns for ns, _ in got["/scene"]]) * 1e-9
    # stamped in order (several at 0 before the mission's epoch; their pace is the wall
    # clock's, a benchmark's business, not a test's)
    assert np.all(np.diff(t) >= 0.0) and t[-1] > t[0]
    cylinders = [{e["id"]: e["metadata"][0]["value"] for e in s["entities"] if e["cylinders"]}
                 for s in scenes]
    assert set(cylinders[-1]) == {"uav1/cylinder", "uav2/cylinder", "uav3/cylinder"}
    assert any(c.get("uav3/cylinder") == "yielding" for c in cylinders)  # it climbs over both
    s = RunSummary.read(tmp_path / "summary.json")
    assert s.collisions == (), s.collisions
    assert s.driver == "swarm" and s.status is RunStatus.COMPLETE, s.status
    assert s.min_distance_m is not None and s.min_distance_m > 1.0
    for uav, u in s.uavs.items():
        assert u.reached_goal, (uav, u.final_position_m)
        # it flew (at what pace: benchmarks/bench_node_flood.py)
        assert u.details["node"]["ticks"] > 0
    assert s.uavs["uav1"].max_z_offset_m == 0.0
    assert s.uavs["uav3"].max_z_offset_m > 0.0
    assert s.messages.delivered > 0.8 * s.messages.sent
    assert (tmp_path / "flight.mcap").stat().st_size > 1000
