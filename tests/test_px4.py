"""The onboard stack flies PX4 over MAVLink: the stand-in autopilot, the node's life cycle and its
failsafes, an independent client (MAVSDK), and a swarm of node + stand-in pairs on loopback.

Faults are made by a real UDP hop between the stand-in and the node that drops chosen messages
(:class:`MavlinkHop`), not by reaching into either side.
"""

from __future__ import annotations

import json
import select
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymavlink")
pytest.importorskip("zenoh")

from waiting import wait_until

from uavmpc import scenarios
from uavmpc.comms.zenoh_link import ZenohTransport
from uavmpc.drivers.node import Node
from uavmpc.drivers.px4.dialect import HOLD, OFFBOARD, POSCTL, Px4Mode, mavlink
from uavmpc.drivers.px4.endpoint import InvalidAddressError, MavlinkEndpoint, parse_address
from uavmpc.drivers.px4.sitl import StandInPx4
from uavmpc.drivers.px4.vehicle import Px4Vehicle
from uavmpc.drivers.swarm import free_ports, run_swarm
from uavmpc.drivers.world import World
from uavmpc.plant import Airframe
from uavmpc.scenarios.run import RunSpec

pytestmark = pytest.mark.realtime  # flies on the wall clock

AF = Airframe.packaged("f550")
ODOMETRY = mavlink.MAVLINK_MSG_ID_ODOMETRY
SET_ATTITUDE_TARGET = mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET
SET_POSITION_TARGET = mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED


def _msgid(data: bytes) -> int:
    return data[7] | data[8] << 8 | data[9] << 16 if data[:1] == b"\xfd" else data[5]


class MavlinkHop:
    """A UDP hop: the stand-in sends to :attr:`port`, the hop forwards to the node's port and
    back. ``drop(direction, msgid, from_s, to_s)`` drops one message kind in a time window
    (``"to_node"`` or ``"to_sitl"``); :attr:`log` has (time, direction, msgid) of what passed."""

    def __init__(self, node_port: int) -> None:
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.bind(("127.0.0.1", 0))
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.back.bind(("127.0.0.1", 0))
        self.port = self.front.getsockname()[1]
        self.node = ("127.0.0.1", node_port)
        self.sitl: tuple[str, int] | None = None
        self.rules: list[tuple[str, int, float, float]] = []
        self.log: list[tuple[float, str, int]] = []
        self.dropped: list[tuple[float, str, int]] = []
        self._run = True
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def drop(self, direction: str, msgid: int, from_s: float = 0.0,
             to_s: float = float("inf")) -> None:
        self.rules.append((direction, msgid, from_s, to_s))

    def _pass(self, direction: str, data: bytes, now: float) -> bool:
        mid = _msgid(data) if len(data) > 9 else -1
        for d, m, t0, t1 in self.rules:
            if d == direction and m == mid and t0 <= now < t1:
                self.dropped.append((now, direction, mid))
                return False
        self.log.append((now, direction, mid))
        return True

    def _loop(self) -> None:
        while self._run:
            ready, _, _ = select.select([self.front, self.back], [], [], 0.05)
            for sock in ready:
                data, addr = sock.recvfrom(65535)
                now = time.time()
                if sock is self.front:
                    self.sitl = addr
                    if self._pass("to_node", data, now):
                        self.back.sendto(data, self.node)
                elif self.sitl is not None and self._pass("to_sitl", data, now):
                    self.front.sendto(data, self.sitl)

    def close(self) -> None:
        self._run = False
        self.thread.join(timeout=2)
        self.front.close()
        self.back.close()


class PxFlight:
    """A node flying a stand-in PX4 through a :class:`MavlinkHop`, all in this process:
    take-off to 3 m, hold, land after ``duration_s``."""

    def __init__(self, duration_s: float) -> None:
        node_port, zenoh_port = free_ports(2)
        self.hop = MavlinkHop(node_port)
        self.sitl = StandInPx4(AF, f"udpout://127.0.0.1:{self.hop.port}",
                               position_m=(2.0, -1.0, 0.0))
        self.transport = ZenohTransport("uav1", swarm=f"px{zenoh_port}",
                                        listen=[f"tcp/127.0.0.1:{zenoh_port}"])
        self.vehicle = Px4Vehicle(f"udp://127.0.0.1:{node_port}", AF, origin_m=(2.0, -1.0, 0.0))
        self.node = Node("uav1", 1, AF, self.transport, start_m=(2.0, -1.0, 3.0),
                         vehicle=self.vehicle)
        self.node_port = node_port
        self.duration_s = duration_s
        self.stats = None
        self.heights: list[tuple[float, float, str]] = []

    def __enter__(self) -> PxFlight:
        self.t0 = time.time()
        self.sitl_thread = threading.Thread(target=self.sitl.run, daemon=True)
        self.sitl_thread.start()
        self.node_thread = threading.Thread(target=self._fly, daemon=True)
        self.node_thread.start()
        self.watch_thread = threading.Thread(target=self._watch, daemon=True)
        self.watch_thread.start()
        return self

    def _fly(self) -> None:
        self.stats = self.node.run(self.duration_s)

    def _watch(self) -> None:
        while self.sitl_thread.is_alive():
            self.heights.append((time.time(), float(self.sitl.plant.state().position_m[2]),
                                 str(self.sitl.mode)))
            time.sleep(0.05)

    def wait_phase(self, phase: str, timeout_s: float = 20.0) -> float:
        t_end = time.time() + timeout_s
        while self.vehicle.phase.value != phase:
            assert time.time() < t_end, f"never reached {phase}: {self.vehicle.report()}"
            time.sleep(0.02)
        return time.time()

    def height_m(self) -> float:
        """The stand-in's true height [m]."""
        return float(self.sitl.plant.state().position_m[2])

    def join(self) -> None:
        self.node_thread.join(timeout=self.duration_s + 60)
        assert self.stats is not None, "the node did not finish"

    def __exit__(self, *exc: object) -> None:
        self.node.stop()
        self.node.stop()
        self.node_thread.join(timeout=10)
        self.sitl.stop()
        self.sitl_thread.join(timeout=5)
        self.hop.close()
        self.transport.close()


# ---------------------------------------------------------------------- small parts

def test_px4_modes_encode_as_px4_does() -> None:
    assert OFFBOARD.custom_mode == 393216 and HOLD.custom_mode == 50593792
    assert Px4Mode.decode(HOLD.custom_mode) == HOLD and str(HOLD) == "AUTO.LOITER"
    assert str(Px4Mode.decode(POSCTL.custom_mode)) == "POSCTL"


@pytest.mark.parametrize("url, why", [
    ("tcp://1.2.3.4:5", "expected udp://"), ("udp://:0", "port"), ("udp://host", "port"),
    ("udpout://:14540", "needs a host"), ("/dev/ttyACM0", "mavlink-router"),
])
def test_bad_mavlink_addresses_are_named(url: str, why: str) -> None:
    with pytest.raises(InvalidAddressError, match=why):
        parse_address(url)


def test_cli_errors_are_one_line(tmp_path: Path) -> None:
    def cli(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "uavmpc.apps.cli", *args],
                              capture_output=True, text=True, timeout=60)

    bad = cli("node", "--id", "a", "--priority", "1", "--mavlink", "serial:/dev/x",
              "--duration", "1")
    assert bad.returncode == 2 and "--mavlink" in bad.stderr and "Traceback" not in bad.stderr
    rate = cli("sitl", "--odometry-rate", "0", "--duration", "1")
    assert rate.returncode == 2 and "odometry_rate_hz" in rate.stderr
    # Without pymavlink installed: one line naming the extra.
    missing = subprocess.run(
        [sys.executable, "-c", "import sys; sys.modules['pymavlink'] = None; "
         "from uavmpc.apps.cli import main; sys.exit(main(['sitl', '--duration', '1']))"],
        capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2
    assert "pip install 'uavmpc[px4]'" in missing.stderr and "Traceback" not in missing.stderr


def test_a_node_with_no_autopilot_says_so(tmp_path: Path) -> None:
    (port,) = free_ports(1)
    v = Px4Vehicle(f"udp://127.0.0.1:{port}", AF)
    try:
        with pytest.raises(RuntimeError, match="no HEARTBEAT from an autopilot"):
            v.start(timeout_s=0.5)
    finally:
        v.close()


# ---------------------------------------------------------------------- the stand-in's protocol

def test_an_independent_client_mavsdk_drives_the_stand_in() -> None:
    pytest.importorskip("mavsdk")
    (port,) = free_ports(1)
    sitl = subprocess.Popen([sys.executable, "-m", "uavmpc.apps.cli", "sitl", "--connect",
                             f"udpout://127.0.0.1:{port}", "--duration", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        client = subprocess.run([sys.executable, str(Path(__file__).with_name("mavsdk_client.py")),
                                 f"udpin://0.0.0.0:{port}"],
                                capture_output=True, text=True, timeout=90)
    finally:
        sitl.terminate()
        out, _ = sitl.communicate(timeout=15)
    seen = json.loads(client.stdout.strip().splitlines()[-1])
    assert client.returncode == 0, seen
    assert seen["autopilot"] == "PX4" and seen["mode_at_connect"] == "HOLD"
    assert seen["offboard_height_m"] > 2.0  # it flew MAVSDK's offboard position setpoint
    assert seen["mode_after_hold"] == "HOLD" and seen["armed_in_hold"]
    assert abs(seen["hold_height_m"] - seen["offboard_height_m"]) < 0.5  # and held there
    events = json.loads(out.strip().splitlines()[-1])["events"]
    assert any("OFFBOARD → AUTO.LOITER" in e for e in events)


# ---------------------------------------------------------------------- the life cycle and faults

def test_a_node_takes_off_flies_lands_and_disarms_with_every_command_acknowledged() -> None:
    with PxFlight(duration_s=7.0) as f:
        f.join()
    rep = f.stats.vehicle
    assert rep["phase"] == "landed", rep
    assert [c["result"] for c in rep["commands"]] == ["MAV_RESULT_ACCEPTED"] * 3
    assert [c["command"] for c in rep["commands"]] == [
        "MAV_CMD_DO_SET_MODE", "MAV_CMD_COMPONENT_ARM_DISARM", "MAV_CMD_COMPONENT_ARM_DISARM"]
    assert rep["hover_thrust_source"] == "MPC_THR_HOVER"
    assert max(h for _, h, _ in f.heights) > 2.8  # took off to its start, 3 m
    assert f.heights[-1][1] < 0.05 and not f.sitl.armed
    # Setpoints went out at 100 Hz before the mode switch (PX4 needs the stream first).
    first_set = min(t for t, d, m in f.hop.log if d == "to_sitl" and m == SET_ATTITUDE_TARGET)
    mode_cmd = min(t for t, d, m in f.hop.log
                   if d == "to_sitl" and m == mavlink.MAVLINK_MSG_ID_COMMAND_LONG)
    assert mode_cmd - first_set > 1.0
    # (their period is a timing: `uavmpc bench px4` measures it)
    assert rep["setpoints_sent"] > 100 and rep["setpoint_period_p50_ms"] > 0


def test_a_node_that_trusts_only_the_heartbeat_fails_against_the_stand_in_as_against_px4(
        monkeypatch) -> None:
    """The node as it was before it met PX4 took the armed flag from the HEARTBEAT alone: the
    stand-in, whose HEARTBEAT is PX4's fixed 1 Hz stream, stops it right after the accepted
    arm, as the real PX4 did ("the autopilot disarmed"); the node of today flies on."""
    from uavmpc.drivers.px4 import vehicle as vehicle_module

    on_ack = vehicle_module._HANDLERS["COMMAND_ACK"]

    def ack_without_state(v: Px4Vehicle, msg, now_s: float) -> None:
        armed, mode = v.armed, v.mode
        on_ack(v, msg, now_s)
        v.armed, v.mode = armed, mode  # the ACK's news ignored, as before
        v._acked_armed = v._acked_mode = None

    monkeypatch.setitem(vehicle_module._HANDLERS, "COMMAND_ACK", ack_without_state)
    with PxFlight(duration_s=6.0) as f:
        f.join()
    rep = f.stats.vehicle
    assert rep["phase"] == "stopped" and rep["stop_reason"] == "the autopilot disarmed", rep
    assert max(h for _, h, _ in f.heights) < 1.0  # it never got up


def test_arming_refused_without_the_setpoint_stream_is_retried_until_it_flows() -> None:
    with PxFlight(duration_s=6.0) as f:
        f.hop.drop("to_sitl", SET_ATTITUDE_TARGET, 0.0, time.time() + 3.0)
        f.join()
    rep = f.stats.vehicle
    arms = [c for c in rep["commands"] if c["command"] == "MAV_CMD_COMPONENT_ARM_DISARM"]
    assert arms[0]["result"] == "MAV_RESULT_TEMPORARILY_REJECTED"
    assert any(a["result"] == "MAV_RESULT_ACCEPTED" for a in arms[1:])
    assert rep["phase"] == "landed", rep
    assert any("No offboard signal" in t for t in rep["status_texts"])


def test_lost_setpoints_make_the_stand_in_fail_safe_and_the_node_stop_and_say_so() -> None:
    with PxFlight(duration_s=30.0) as f:
        f.wait_phase("flying")
        wait_until(lambda: f.height_m() > 2.9, 20.0, "the climb to 3 m")
        cut = time.time()
        f.hop.drop("to_sitl", SET_ATTITUDE_TARGET, cut)
        stopped = f.wait_phase("stopped", timeout_s=5.0)

        def descending() -> bool:  # from 1.5 s after the cut (COM_OF_LOSS_T), by 0.3 m
            after = [h for t, h, _ in f.heights if t > cut + 1.5]
            return bool(after) and after[-1] < after[0] - 0.3

        wait_until(descending, 15.0, "the stand-in's failsafe descent")
        rep = f.vehicle.report()
        stack = f.node.stack
        assert not stack.cooperative  # its broadcasts now say: I will not yield
        # ... and what it will really do: hold where the stand-in holds it.
        plan = stack.tracker.prediction().position_m
        where = f.sitl.plant.state().position_m
        assert np.abs(plan - where).max() < 1.0, (plan[[0, -1]], where)
        sent_after = [t for t, d, m in f.hop.dropped if m == SET_ATTITUDE_TARGET
                      and t > stopped + 0.05]
    assert "left offboard (now POSCTL)" in rep["stop_reason"]
    assert 1.0 <= stopped - cut < 3.0  # COM_OF_LOSS_T, then the next HEARTBEAT
    assert not sent_after  # it stopped commanding
    # The stand-in fails safe as PX4 without RC does: position mode, descending (to land and
    # disarm by itself), never taken back by the node.
    after = [h for t, h, mode in f.heights if t > cut + 1.5]
    assert after and max(after) < 3.5 and after[-1] < after[0] - 0.3, after[::20]
    assert f.heights[-1][2] == "POSCTL"


def test_an_odometry_gap_is_flown_by_the_autopilot_on_position_setpoints_then_ours_again(
        ) -> None:
    """ODOMETRY stops reaching the node for 0.6 s in the air (what a loaded machine did to
    real PX4 for 0.2 s): from 0.2 s on the node does not fly its attitude on the old estimate
    but sends the tracker's position setpoints (the autopilot flies them on its own estimate),
    and flies attitude again once estimates return. The vehicle holds its height throughout and
    stays ours: no stop, no failsafe."""
    with PxFlight(duration_s=30.0) as f:
        f.wait_phase("flying")
        wait_until(lambda: f.height_m() > 2.9, 20.0, "the climb to 3 m")
        wait_until(lambda: abs(f.height_m() - 3.0) < 0.1, 10.0, "the hold at 3 m")
        cut = time.time()
        f.hop.drop("to_node", ODOMETRY, cut, cut + 0.6)
        wait_until(lambda: any(t > cut + 0.7 and m == SET_ATTITUDE_TARGET
                               for t, _, m in list(f.hop.log)), 5.0, "attitude setpoints again")
        wait_until(lambda: f.vehicle.report()["position_fallbacks"] >= 1
                   and f.vehicle.report()["position_fallback_s"] > 0.0, 5.0,
                   "the fallback spell to end")
        phase = f.vehicle.phase.value
        rep = f.vehicle.report()
        during = [(t, m) for t, d, m in list(f.hop.log)
                  if d == "to_sitl" and cut + 0.25 < t < cut + 0.55]
        heights = [h for t, h, _ in f.heights if cut <= t <= cut + 1.5]
    assert phase == "flying", rep["stop_reason"]
    assert rep["position_fallbacks"] == 1, rep
    assert 0.3 < rep["position_fallback_max_s"] < 0.7, rep
    kinds = {m for _, m in during}
    assert SET_POSITION_TARGET in kinds and SET_ATTITUDE_TARGET not in kinds, kinds
    assert heights and max(abs(h - 3.0) for h in heights) < 0.3, heights


def test_without_odometry_for_a_second_the_node_stops_commanding() -> None:
    """No estimate for longer than PX4's own offboard-loss timeout (1 s): the node stops; from
    0.2 s on, only position setpoints went out."""
    with PxFlight(duration_s=30.0) as f:
        f.wait_phase("flying")
        wait_until(lambda: f.height_m() > 2.9, 20.0, "the climb to 3 m")
        cut = time.time()
        f.hop.drop("to_node", ODOMETRY, cut)
        f.wait_phase("stopped", timeout_s=5.0)
        time.sleep(0.3)
        rep = f.vehicle.report()
        sent = [(t, m) for t, d, m in list(f.hop.log)
                if d == "to_sitl" and m in (SET_ATTITUDE_TARGET, SET_POSITION_TARGET)]
    assert "estimate lost" in rep["stop_reason"], rep["stop_reason"]
    last_attitude = max(t for t, m in sent if m == SET_ATTITUDE_TARGET)
    last_any = max(t for t, _ in sent)
    # The limits plus a tick and the hop's jitter (0.1 s: the thread's scheduling on a
    # loaded machine).
    assert last_attitude - cut < 0.2 + 0.1
    assert 0.2 < last_any - cut < 1.0 + 0.1


def test_garbage_and_other_systems_at_the_nodes_port_change_nothing() -> None:
    with PxFlight(duration_s=30.0) as f:
        f.wait_phase("flying")
        wait_until(lambda: f.height_m() > 2.9, 20.0, "the climb to 3 m")
        intruder = MavlinkEndpoint(f"udpout://127.0.0.1:{f.node_port}", system_id=7,
                                   component_id=1)
        rng = np.random.default_rng(3)
        for i in range(300):
            intruder.sock.sendto(rng.bytes(int(rng.integers(1, 300))), intruder.peer)
            if i % 30 == 0:  # well-formed MAVLink from a system that is not ours
                intruder.send(mavlink.MAVLink_heartbeat_message(
                    2, 12, 129, POSCTL.custom_mode, 4, 3))
                intruder.send(mavlink.MAVLink_odometry_message(
                    1, 1, 1, 50.0, 50.0, -40.0, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0,
                    [float("nan")] * 21, [float("nan")] * 21, 0, 8, 0))
                intruder.send(mavlink.MAVLink_command_ack_message(400, 0, 0, 0, 245, 191))
            time.sleep(0.005)
        intruder.close()
        time.sleep(1.0)
        rep = f.vehicle.report()
        assert f.vehicle.phase.value == "flying", rep
    assert rep["garbage"] > 100 and rep["foreign"] >= 30
    flying = [h for t, h, _ in f.heights if t > f.t0 + 6.0]
    assert flying and max(abs(h - 3.0) for h in flying) < 0.2  # undisturbed


# ---------------------------------------------------------------------- a swarm of PX4s



def test_nodes_flying_stand_ins_avoid_each_other_and_without_avoidance_collide(
        tmp_path: Path, head_on_pairs) -> None:
    """Four node + stand-in pairs in one swarm (the same two head-on pairs as the real-PX4
    test): the pair with avoidance keeps clear, the pair without collides, all land."""
    sc = scenarios.load(head_on_pairs("f550"))
    s = run_swarm(RunSpec(sc), tmp_path / "run", mavlink=True)
    closest = s.sections["closest_by_pair_m"]
    assert closest["a1-a2"] > 2.0, closest
    # Without avoidance they fly through each other; the stand-in's estimator drift (as EKF2's)
    # may offset the true paths by up to about a metre, so a collision is likely, not certain.
    assert closest["b1-b2"] < 1.5, closest
    assert {(c.a, c.b) for c in s.collisions} <= {("b1", "b2")}, s.collisions
    assert all(u.reached_goal for u in s.uavs.values()), s.uavs
    # Judged by the truth each stand-in sends as PX4's SIH does (HIL_STATE_QUATERNION), the
    # estimates' figures beside it: the stand-in's estimator drifts as EKF2's does, so the
    # two differ, and each UAV's estimator error is kept.
    assert s.sections["judged_by"].startswith("the simulator's ground truth")
    est = s.sections["estimate"]["closest_by_pair_m"]
    assert est.keys() == closest.keys() and est != closest
    for uav, u in s.uavs.items():
        err = u.details["estimator_error"]
        assert err["samples"] > 100 and 0.0 < err["horizontal_rms_m"] < 1.5, (uav, err)
        assert u.details["mission_end_estimate_m"] != u.details["mission_end_position_m"]
    for uav, u in s.uavs.items():  # a node without a report says why (exit code, errors)
        node = u.details["node"]
        assert node.get("vehicle", {}).get("phase") == "landed", (uav, node)
        assert node["status"] != "vehicle_stopped", (uav, node)
    # Tracking through MAVLink and the stand-in's attitude loop, against the built-in plant
    # (the same scenario in the simulated world, whose tracking equals the node's plant). The
    # stand-in's estimates come at PX4's 30 Hz and wander as EKF2's do, so the bound is
    # absolute: a decimetre-scale error, not a multiple of the ideal plant's centimetres.
    world = World(RunSpec(sc, seed=0)).run(sc.duration_s)
    for uav, u in s.uavs.items():
        built_in = world.per_uav[uav].tracking_rmse_m
        assert u.tracking_rmse_m is not None
        assert u.tracking_rmse_m < max(2.0 * built_in, 0.25), (uav, u.tracking_rmse_m,
                                                                built_in)
        # The stream never paused as long as PX4 allows before it leaves offboard (it needs
        # setpoints faster than 2 Hz); the tail of the period is the machine's, not ours.
        vehicle = u.details["node"]["vehicle"]
        assert vehicle["setpoint_period_max_ms"] < 500.0, vehicle

