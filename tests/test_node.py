"""Each UAV its own process (or thread) over Zenoh on 127.0.0.1: end to end, robustness, keys."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("zenoh")

from waiting import wait_until

from uavmpc import scenarios
from uavmpc.comms.auth import sign
from uavmpc.comms.message import SCHEMA_VERSION, PredictionMessage, encode
from uavmpc.comms.state import NodeState
from uavmpc.comms.zenoh_link import ZenohTransport
from uavmpc.drivers.node import Node
from uavmpc.drivers.summary import RunStatus
from uavmpc.drivers.swarm import free_ports, run_swarm
from uavmpc.plant import Airframe
from uavmpc.reference import Reference
from uavmpc.scenarios.run import RunSpec

pytestmark = pytest.mark.realtime  # flies on the wall clock

HORIZON = np.cumsum(np.r_[0.01, np.full(39, 0.2)])
KEY = b"0123456789abcdef0123456789abcdef"


def _prediction(uav: str, priority: int, positions: np.ndarray, cooperative: bool) -> bytes:
    now = time.time()
    return encode(PredictionMessage(SCHEMA_VERSION, uav, priority, now, now + HORIZON, positions,
                                    cooperative))


def _on_path(x: float = 0.0) -> np.ndarray:
    """A non-cooperative intruder hovering right where the node hovers."""
    return np.tile([x, 0.0, 5.0], (40, 1))


class _Flight:
    """A node flying in a thread of this process, and a second transport to talk to it."""

    def __init__(self, *, key: bytes | None = None, duration_s: float = 6.0) -> None:
        ports = free_ports(2)
        self.swarm = f"t{ports[0]}"
        eps = [f"tcp/127.0.0.1:{p}" for p in ports]
        self.node_tx = ZenohTransport("uav1", swarm=self.swarm, listen=[eps[0]])
        self.other = ZenohTransport("intruder", swarm=self.swarm, listen=[eps[1]],
                                    connect=[eps[0]])
        self.node = Node("uav1", 5, Airframe.packaged("f550"), self.node_tx,
                         start_m=(0.0, 0.0, 5.0), key=key)
        self.states = self.other.subscribe("uav1/state", maxlen=100_000)
        self.thread = threading.Thread(target=self.node.run, args=(duration_s,), daemon=True)

    def __enter__(self) -> _Flight:
        self.thread.start()
        deadline = time.time() + 5.0  # wait for discovery: the node's state reaches us
        while not self.states.drain() and time.time() < deadline:
            time.sleep(0.05)
        return self

    def __exit__(self, *exc: object) -> None:
        self.node.stop()
        self.thread.join(timeout=10)
        self.other.close()
        self.node_tx.close()

    def max_offset(self) -> float:
        return max((NodeState.decode(p).z_offset_m for _, p in self.states.drain()), default=0.0)


# The same swap with avoidance, as three node processes, is flown (and watched live) in
# tests/test_live.py: one flight for both.


def test_the_same_swap_without_avoidance_collides(tmp_path) -> None:
    s = run_swarm(RunSpec(scenarios.load("swap_through_static"), avoidance=False,
                          duration_s=10.0), tmp_path)
    assert s.collisions, "the network path must be what carries the avoidance"
    assert s.status is RunStatus.COLLISION


def test_a_killed_node_is_no_longer_avoided_once_its_vehicle_can_only_have_landed(
        tmp_path, hover_pair) -> None:
    # uav1 is killed at 5 s. uav2 counts it silent, then (3 s unheard) dead: where a PX4
    # failsafe could take it, descending from 5 m at ≥ 0.6 m/s, on the ground by about 1 +
    # 8.3 s later; it is then no obstacle to a UAV at 5 m.
    s = run_swarm(RunSpec(scenarios.load(hover_pair), duration_s=26.0), tmp_path / "out",
                  kill_at_s={"uav1": 5.0})
    uav2 = s.uavs["uav2"]
    assert uav2.max_z_offset_m >= 3.0  # it yielded while uav1 was there
    assert "uav1" in uav2.details["node"]["assumptions"]["dead_peers"]
    # …held it until uav1's vehicle could only be on the ground, then released it at
    # 2 m/s
    last = uav2.details["last_state"]
    assert last["z_offset_m"] == 0.0 and not last["avoiding"]
    assert uav2.reached_goal
    # the killed node printed no report: the summary says how it ended instead
    assert s.uavs["uav1"].details["node"]["exit_code"] == -9
    assert isinstance(s.uavs["uav1"].details["node"]["stderr_tail"], list)
    assert s.status is RunStatus.VEHICLE_STOPPED


def test_forged_or_unsigned_predictions_are_ignored_with_a_key() -> None:
    with _Flight(key=KEY) as f:
        forged = bytearray(sign(_prediction("intruder", 0, _on_path(), False), KEY))
        forged[30] ^= 0xFF  # tampered after signing
        for _ in range(20):
            f.other.publish(_prediction("intruder", 0, _on_path(), False), "intruder", 0.0)
            f.other.publish(bytes(forged), "intruder", 0.0)
            time.sleep(0.1)
        assert f.max_offset() == 0.0
        assert f.node.stack.inbox.rejected_total >= 20
        for _ in range(20):  # the same prediction, properly signed, does make it climb
            f.other.publish(sign(_prediction("intruder", 0, _on_path(), False), KEY),
                            "intruder", 0.0)
            time.sleep(0.1)
        assert f.max_offset() >= 3.0


def test_fuzzed_messages_never_crash_or_move_a_flying_node() -> None:
    far = np.tile([500.0, 500.0, 5.0], (40, 1))  # a valid base message, far from the node
    base = _prediction("fuzzer", 1, far, True)
    sent = []

    @settings(max_examples=3_000, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(st.one_of(st.binary(max_size=2000),
                     st.tuples(st.integers(0, len(base) - 1), st.integers(0, 255)).map(
                         lambda m: base[:m[0]] + bytes([m[1]]) + base[m[0] + 1:]),
                     st.integers(0, len(base)).map(lambda n: base[:n])))
    def blast(data: bytes) -> None:
        sent.append(len(data))
        f.other.publish(data, "intruder", 0.0)

    # The flight lasts until the context stops it: the fuzz takes a few seconds on a free
    # machine and several times that on a loaded one (a node that had simply finished its run
    # would read as a crash).
    with _Flight(duration_s=300.0) as f:
        f.node.set_mission(Reference.goto(10.0, 0.0, 5.0, 0.0, start_s=time.time()))
        blast()
        wait_until(lambda: np.linalg.norm(
            f.node.vehicle.plant.state().position_m - [10.0, 0.0, 5.0]) < 0.5, 60.0,
            "the node to reach its goal 10 m away through the fuzz")
        assert f.thread.is_alive()  # no crash
        assert f.max_offset() == 0.0  # no change of flight
    assert len(sent) >= 3_000
    assert f.node.stack.inbox.rejected_total > 300  # most of the fuzz is malformed and counted


def test_a_flood_does_not_starve_the_control_loop() -> None:
    with _Flight(duration_s=8.0) as f:
        far = np.tile([500.0, 500.0, 5.0], (40, 1))
        t_end = time.time() + 5.0
        n = 0
        while time.time() < t_end:  # 1000 messages/s from one sender, bounded in time
            for _ in range(10):
                f.other.publish(_prediction("flooder", 1, far, True), "intruder", 0.0)
                n += 1
            time.sleep(0.01)
        f.thread.join(timeout=10)
    s = f.node.stats
    assert n >= 3000
    # The flood reached the node and was judged (far away: never avoided), and the node flew
    # its run to the end. Its tick period under a flood is a timing, measured by
    # benchmarks/bench_node_flood.py against the same node unflooded.
    assert not f.thread.is_alive() and s.accepted > 0
    assert s.max_z_offset_m == 0.0 and s.ticks > 100


def test_missions_over_the_network_are_validated() -> None:
    import json

    with _Flight(duration_s=12.0) as f:
        bad = [b"not json", b"[]", json.dumps({"goto": [1, 2]}).encode(),
               b'{"goto": [1, 2, NaN, 0]}', json.dumps({"points": [[0, 0, 5, 0]]}).encode(),
               json.dumps({"trajectory": {"points": [[0, 0, 0]]}}).encode()]
        for payload in bad:
            f.other.send("uav1", "mission", payload)
        wait_until(lambda: f.node.stats.missions_rejected == len(bad), 5.0,
                   "every bad mission to be refused and counted")
        f.other.send("uav1", "mission", json.dumps({"goto": [3.0, 0.0, 5.0, 0.0]}).encode())
        wait_until(lambda: np.linalg.norm(
            f.node.vehicle.plant.state().position_m - [3.0, 0.0, 5.0]) < 0.3, 10.0,
            "the node to fly the valid mission to its goal")
        assert f.node.stats.missions_rejected == len(bad)


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_node_process_shuts_down_cleanly_on_signal(sig: str) -> None:
    import json
    import signal
    import subprocess
    import sys

    port, ours = free_ports(2)
    proc = subprocess.Popen(
        [sys.executable, "-m", "uavmpc.apps.cli", "node", "--id", "solo", "--priority", "1",
         "--listen", f"tcp/127.0.0.1:{port}", "--goto", "3", "0", "5", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    watcher = ZenohTransport("watcher", swarm="default", listen=[f"tcp/127.0.0.1:{ours}"],
                             connect=[f"tcp/127.0.0.1:{port}"])
    try:
        states = watcher.subscribe("solo/state", maxlen=10_000)
        heard: list = []
        wait_until(lambda: heard.extend(states.drain()) or len(heard) >= 5, 120.0,
                   "the node to fly (its state heard over Zenoh)")
        assert proc.poll() is None  # still flying
        proc.send_signal(getattr(signal, sig))
        out, err = proc.communicate(timeout=10)
    finally:
        watcher.close()
        proc.kill()
    assert proc.returncode == 0, err
    stats = json.loads(out.strip().splitlines()[-1])
    assert stats["uav_id"] == "solo" and stats["ticks"] > 0
    assert stats["status"] == RunStatus.INTERRUPTED.value  # stopped before its time (none)


def test_a_node_that_flies_its_time_says_complete() -> None:
    flight = _Flight(duration_s=2.0)
    with flight:
        wait_until(lambda: not flight.thread.is_alive(), 60.0, "the node to end its 2 s")
    assert flight.node.stats.run_status is RunStatus.COMPLETE
    assert flight.node.stats.ticks > 0


def test_a_follower_node_flies_its_slot_and_changes_shape_on_command() -> None:
    """A formation follower in a node: its slot along the leader's plans received over Zenoh,
    then a shape change sent while it flies (bad commands refused and counted)."""
    import json

    from uavmpc.missions.formation import FormationFollower, FormationSpec

    spec = FormationSpec(leader="lead", followers=("f1",), spacing_m=6.0, transition_s=2.0)
    ports = free_ports(2)
    swarm = f"t{ports[0]}"
    eps = [f"tcp/127.0.0.1:{p}" for p in ports]
    node_tx = ZenohTransport("f1", swarm=swarm, listen=[eps[0]])
    lead = ZenohTransport("lead", swarm=swarm, listen=[eps[1]], connect=[eps[0]])
    node = Node("f1", 2, Airframe.packaged("f550"), node_tx, start_m=(0.0, -6.0, 5.0),
                mission=FormationFollower(spec, "f1"), pair_radius_m=spec.pair_radii("f1"))
    thread = threading.Thread(target=node.run, args=(14.0,), daemon=True)
    thread.start()

    def leader_at(t: float) -> np.ndarray:  # east at 1 m/s from x = 0 at t0
        return np.array([max(t - t0, 0.0) * 1.0, 0.0, 5.0])

    def slot_now() -> np.ndarray:  # on the node's own clock (it may lag the wall clock)
        t = node.stack.tracker.time_s
        return node.stack.tracker.reference.sample(np.array([t]))[0, :3] - leader_at(t)

    try:
        t0 = time.time() + 1.0
        next_send = time.time()
        sent_bad = sent_square = False
        seen: dict[str, np.ndarray] = {}
        while time.time() < t0 + 11.0:
            now = time.time()
            if now >= next_send:  # the leader's plan, at 2 Hz
                times = now + np.concatenate([[0.01], 0.01 + 0.2 * np.arange(1, 40)])
                pos = np.array([leader_at(t) for t in times])
                msg = PredictionMessage(SCHEMA_VERSION, "lead", 1, now, times, pos, True)
                lead.publish(encode(msg), "lead", now)
                next_send += 0.5
            if now > t0 + 4.0 and "line" not in seen:
                seen["line"] = slot_now()
            if now > t0 + 4.5 and not sent_bad:
                for bad in (b"{", b'{"shape": "vee"}', b'{"shape": "square", "at_s": "x"}'):
                    lead.put("formation", bad)
                sent_bad = True
            if now > t0 + 5.0 and not sent_square:
                cmd = json.dumps({"shape": "square", "at_s": now}).encode()
                lead.put("formation", cmd)
                lead.put("formation", cmd)  # a repeat is ignored
                sent_square = True
            if now > t0 + 10.0 and "square" not in seen:
                seen["square"] = slot_now()
            time.sleep(0.01)
    finally:
        node.stop()
        thread.join(timeout=10)
        lead.close()
        node_tx.close()
    # In the line: 6 m to the leader's right (heading east: −y); in the square (two deep):
    # 6 m behind it.
    assert np.allclose(seen["line"][:2], [0.0, -6.0], atol=0.3), seen
    assert np.allclose(seen["square"][:2], [-6.0, 0.0], atol=0.3), seen
    assert node.stats.missions_rejected == 3
    assert node.mission.spec.changes[-1][1] == "square" and len(node.mission.spec.changes) == 1
