"""The node against the real PX4 firmware: PX4 v1.16 SITL with its SIH simulator.

Skipped with the reason where no PX4 SITL build is available (``UAVMPC_PX4_SITL``, set by
``.ci/run`` when the project's ``shared/px4-sitl`` archive sits beside the checkout). Each test
runs the real ``uavmpc node`` command against real PX4 processes on loopback; every wait is on
a condition, bounded.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np
import pytest
from waiting import wait_until

mavlink = pytest.importorskip("pymavlink.dialects.v20.common")

pytestmark = pytest.mark.realtime  # flies on the wall clock

_GOAL = (3.0, 0.0, 3.0)


def _node_command(uav_id: str, address: str, *extra: str) -> list[str]:
    return [sys.executable, "-m", "uavmpc.apps.cli", "node", "--id", uav_id, "--priority", "1",
            "--airframe", "x500", "--mavlink", address, "--swarm", f"px4real-{uav_id}",
            "--start", "0", "0", str(_GOAL[2]), *extra]


def _report(proc: subprocess.Popen[str], timeout_s: float) -> dict[str, Any]:
    """The node's last stdout line (its JSON report); its stderr in the failure message."""
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the node did not end within {timeout_s:g} s; stderr:\n{err[-3000:]}")
    lines = [line for line in out.splitlines() if line.startswith("{")]
    assert lines, f"no report (exit {proc.returncode}); stderr:\n{err[-3000:]}"
    return json.loads(lines[-1])


def _full_cycle_checks(rep: dict[str, Any], mode: str) -> None:
    px4 = rep["vehicle"]
    assert px4["setpoint_mode"] == mode
    # (what the failure message must show first: pytest cuts a long report short)
    why = (px4["stop_reason"], px4["phases"], px4["status_texts"], px4["landed_states"])
    assert px4["phase"] == "landed", why
    assert px4["stop_reason"] is None, why
    # When the mission ended the node asked for the goal, and PX4 held it by its own estimate
    # as closely as PX4 holds any setpoint in SITL: its estimate wanders about a fixed setpoint
    # (measured at the end of 15 s flights to this goal: 0.09–0.63 m in position mode, where
    # PX4's own controller holds it, 0.10–0.50 m in attitude mode, where ours does).
    def dist(p: list[float]) -> float:
        return sum((a - b) ** 2 for a, b in zip(p, _GOAL, strict=True)) ** 0.5
    assert dist(rep["mission_end_command_m"]) < 0.01, rep["mission_end_command_m"]
    end = rep["mission_end_position_m"]
    assert dist(end) < 1.0, (mode, end, px4["status_texts"])
    # PX4 itself accepted the disarm: its land detector said landed first.
    disarms = [c for c in px4["commands"] if c["command"] == "MAV_CMD_COMPONENT_ARM_DISARM"
               and c["params"][0] == 0.0]
    assert disarms and disarms[-1]["result"] == "MAV_RESULT_ACCEPTED", px4["commands"]
    assert px4["landed_states"][-1].endswith("ON_GROUND"), px4["landed_states"]
    # The clock map saw PX4's clock as it is (lockstep SITL: not the wall clock's rate).
    assert px4["clock_source"] == "TIMESYNC round trips"
    assert 0.9 < px4["clock_rate"] < 1.1
    # PX4's texts reach us (we are a ground station to it): at least its arming text.
    assert any("Armed" in t or "armed" in t for t in px4["status_texts"]), px4["status_texts"]


class _Relay:
    """A UDP relay between PX4 (which sends to ``px4_port``) and the node (listening on
    ``node_port``) that can cut the node → PX4 direction, hide PX4's ODOMETRY from the node,
    and reads what crosses."""

    def __init__(self, px4_port: int, node_port: int) -> None:
        self.px4_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.px4_side.bind(("127.0.0.1", px4_port))
        self.node_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.node_side.bind(("127.0.0.1", 0))
        self.node_addr = ("127.0.0.1", node_port)
        self.px4_addr: tuple[str, int] | None = None
        self.cut = threading.Event()
        self.hide_odometry = threading.Event()
        self.stop = threading.Event()
        self.heights: list[tuple[float, float]] = []  # (time, PX4's estimated height [m])
        self.setpoint_kinds: list[tuple[float, str]] = []  # (time, SET_* message name)
        self.setpoints_after_cut: list[float] = []
        self.modes: list[tuple[float, int, bool]] = []  # (time, PX4 main mode, armed)
        self.height_m = 0.0  # PX4's estimate, from its ODOMETRY (NED: up is −z)
        self.cut_at: float | None = None
        self.hidden = (0.0, 0.0)  # when ODOMETRY was hidden from the node
        self.restored_at: float | None = None
        self._parse_up = mavlink.MAVLink(None)
        self._parse_down = mavlink.MAVLink(None)
        self._threads = [threading.Thread(target=self._down, daemon=True),
                         threading.Thread(target=self._up, daemon=True)]
        for t in self._threads:
            t.start()

    def _down(self) -> None:  # PX4 → node
        self.px4_side.settimeout(0.1)
        while not self.stop.is_set():
            try:
                data, addr = self.px4_side.recvfrom(65535)
            except TimeoutError:
                continue
            self.px4_addr = addr
            msgs = self._parse_down.parse_buffer(data) or []
            for m in msgs:
                if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1:
                    self.modes.append((time.time(), (m.custom_mode >> 16) & 0xFF,
                                       bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)))
                elif m.get_type() == "ODOMETRY":
                    self.height_m = -float(m.z)
                    self.heights.append((time.time(), self.height_m))
            if self.hide_odometry.is_set() and any(m.get_type() == "ODOMETRY" for m in msgs):
                for m in msgs:
                    if m.get_type() != "ODOMETRY":
                        self.node_side.sendto(m.get_msgbuf(), self.node_addr)
                continue
            self.node_side.sendto(data, self.node_addr)

    def _up(self) -> None:  # node → PX4
        self.node_side.settimeout(0.1)
        while not self.stop.is_set():
            try:
                data, _ = self.node_side.recvfrom(65535)
            except TimeoutError:
                continue
            kinds = [m.get_type() for m in self._parse_up.parse_buffer(data) or []]
            now = time.time()
            self.setpoint_kinds.extend((now, k) for k in kinds if k.startswith("SET_"))
            if self.cut_at is not None and any(k.startswith("SET_") for k in kinds):
                self.setpoints_after_cut.append(time.time())
            if self.cut.is_set() or self.px4_addr is None:
                continue
            self.px4_side.sendto(data, self.px4_addr)

    def last_setpoint_s(self) -> float:
        """When the node's last setpoint crossed since the cut (the cut's time if none did)."""
        assert self.cut_at is not None
        return self.setpoints_after_cut[-1] if self.setpoints_after_cut else self.cut_at

    def close(self) -> None:
        self.stop.set()
        for t in self._threads:
            t.join(1.0)
        self.px4_side.close()
        self.node_side.close()


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _steady(heights: list[tuple[float, float]], goal_m: float) -> bool:
    """Over the last second the height stayed within 0.1 m of ``goal_m``."""
    now = time.time()
    recent = [h for t, h in list(heights) if t > now - 1.0]
    return len(recent) >= 5 and max(abs(h - goal_m) for h in recent) < 0.1


@pytest.fixture(scope="module")
def flights(px4_sitl_build, tmp_path_factory) -> dict[str, Any]:
    """Three real PX4 instances flown at once, each by its own ``uavmpc node`` (each alone in
    its own swarm): the whole cycle with attitude setpoints, the same with position
    setpoints, and a third whose setpoint stream a UDP relay cuts while it flies. The reports
    of the three nodes and what the relay saw."""
    from uavmpc.drivers.px4.firmware import Px4Instance

    work = tmp_path_factory.mktemp("px4real")
    instances = [Px4Instance(px4_sitl_build, 7 + k, work / f"px4-{k}") for k in range(3)]
    procs: dict[str, subprocess.Popen[str]] = {}
    relay = None
    try:
        for inst in instances:
            inst.start()
        for inst in instances:
            inst.wait_ready(timeout_s=30.0)
        goto = ["--goto", *map(str, _GOAL), "0", "--duration", "15"]
        for mode, inst in zip(("attitude", "position"), instances, strict=False):
            procs[mode] = subprocess.Popen(
                _node_command(f"uav-{mode}", inst.mavlink_address, "--setpoints", mode, *goto),
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        node_port = _free_udp_port()
        relay = _Relay(instances[2].offboard_port, node_port)
        procs["cut"] = subprocess.Popen(
            _node_command("uav-cut", f"udp://127.0.0.1:{node_port}", "--goto", "0", "0",
                          str(_GOAL[2]), "0", "--duration", "15"),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        offboard = 6
        wait_until(lambda: any(m == offboard and armed for _, m, armed in relay.modes), 90.0,
                   "PX4 armed in offboard")
        wait_until(lambda: relay.height_m > 2.0, 30.0, "the climb: the cut happens in the air")
        # First its ODOMETRY is hidden from the node for 0.6 s (what a loaded machine did for
        # 0.2 s): PX4 must fly the node's position setpoints meanwhile, and stay offboard.
        # The climb's end: the hide is judged at a steady height. (A fixed second after 2 m
        # was not enough on a loaded CI machine: the hide began at 2.8 m, still climbing.)
        wait_until(lambda: _steady(relay.heights, _GOAL[2]), 30.0, "a steady height")
        relay.hidden = (time.time(), time.time() + 0.6)
        relay.hide_odometry.set()
        wait_until(lambda: time.time() > relay.hidden[1], 2.0, "the hide's end")
        relay.hide_odometry.clear()
        wait_until(lambda: any(t > relay.hidden[1] + 0.2 and k == "SET_ATTITUDE_TARGET"
                               for t, k in list(relay.setpoint_kinds)), 10.0,
                   "attitude setpoints again")
        time.sleep(1.0)
        relay.cut_at = time.time()
        relay.cut.set()
        wait_until(lambda: any(t > relay.cut_at and m != offboard for t, m, _ in relay.modes),
                   10.0, "PX4 leaves offboard after the stream is cut")
        # The node hears the same HEARTBEAT: the link is whole again once it has stopped (a
        # setpoint it sent before it heard would bring PX4 back by PX4's own design).
        wait_until(lambda: time.time() - relay.last_setpoint_s() > 0.5, 10.0,
                   "the node to stop commanding")
        relay.cut.clear()
        relay.restored_at = time.time()
        reports = {name: _report(p, 150.0) for name, p in procs.items()}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
        if relay is not None:
            relay.close()
        for inst in instances:
            inst.stop()
    return {"reports": reports, "relay": relay}


@pytest.mark.parametrize("mode", ["attitude", "position"])
def test_the_node_flies_real_px4_through_its_whole_cycle(flights, mode: str) -> None:
    """connect → offboard → arm → take off → mission → land → disarm, in each setpoint mode."""
    _full_cycle_checks(flights["reports"][mode], mode)


def test_px4_flies_the_node_s_position_setpoints_while_its_odometry_is_hidden(flights) -> None:
    """PX4's ODOMETRY does not reach the node for 0.6 s in the air: the node bridges the gap
    with position setpoints (real PX4 switches from attitude to position control within
    offboard and back), it neither stops nor does PX4 leave offboard, and the height PX4
    holds meanwhile stays within half a metre of where it was."""
    relay, px4 = flights["relay"], flights["reports"]["cut"]["vehicle"]
    t0, t1 = relay.hidden
    offboard = 6
    kinds = {k for t, k in relay.setpoint_kinds if t0 + 0.3 < t < t1}
    assert kinds == {"SET_POSITION_TARGET_LOCAL_NED"}, kinds
    assert any(k == "SET_ATTITUDE_TARGET" for t, k in relay.setpoint_kinds if t > t1 + 0.2)
    assert px4["position_fallbacks"] >= 1 and px4["position_fallback_max_s"] >= 0.4, px4
    assert all(m == offboard and armed for t, m, armed in relay.modes if t0 <= t <= t1 + 1.0)
    before = [h for t, h in relay.heights if t0 - 0.5 <= t < t0]
    during = [h for t, h in relay.heights if t0 <= t <= t1 + 1.0]
    assert before and during, (before, during)
    assert max(abs(h - before[-1]) for h in during) < 0.5, (before[-1], during)


def test_a_cut_setpoint_stream_makes_px4_leave_offboard_and_the_node_never_takes_it_back(
        flights) -> None:
    """The node's setpoints stop reaching PX4 while it flies: PX4 fails safe out of offboard
    (COM_OF_LOSS_T), the node reports it and stops commanding; when the link is whole again no
    setpoint of the node's reaches PX4 and PX4 never flies offboard again."""
    relay, px4 = flights["relay"], flights["reports"]["cut"]["vehicle"]
    offboard = 6
    assert px4["phase"] == "stopped", px4
    assert "left offboard" in px4["stop_reason"], px4["stop_reason"]
    # Never taken back: nothing of ours reached PX4 after the link was whole, and PX4 never
    # flew offboard again (disarmed after its own landing, it shows its user's last choice,
    # offboard, again: that flies nothing).
    assert not [t for t in relay.setpoints_after_cut if t > relay.restored_at]
    assert not [m for t, m, armed in relay.modes
                if t > relay.restored_at and m == offboard and armed]
    # PX4's failsafe landed and disarmed the vehicle; the node saw it and ended.
    assert any("Failsafe" in t for t in px4["status_texts"]), px4["status_texts"]




def test_four_real_px4_vehicles_swapping_keep_2_m_by_truth_under_the_ceiling(
        px4_sitl_build, tmp_path) -> None:
    """Four real PX4 vehicles swap across a 12 m circle at 5 m, priorities 1–4, under a
    geofence ceiling of 13 m (layers at 5, 8 and 11 m). Judged by SIH's ground truth, no two
    come within 2 m, and none climbs above the ceiling: the node processes fly the scenario's
    geofence, as the world does (before, a swarm's nodes flew without it), and the ceiling
    keeps 2 σ of the height EKF2 states (before, a vehicle at the top layer of a 12 m ceiling
    went 0.2 m above it by truth while EKF2's height drifted 1.2 m low)."""
    from pathlib import Path

    from uavmpc import scenarios
    from uavmpc.drivers.swarm import run_swarm
    from uavmpc.scenarios.run import RunSpec

    sc = scenarios.load(Path(__file__).parent / "data" / "antipodal_4_px4.toml")
    s = run_swarm(RunSpec(sc), tmp_path / "run", px4_sitl=px4_sitl_build,
                  px4_first_instance=6)
    assert s.sections["judged_by"].startswith("the simulator's ground truth")
    assert s.min_distance_m is not None and s.min_distance_m >= 2.0, s.sections
    assert not s.collisions
    assert sc.geofence is not None
    for uav, u in s.uavs.items():
        # 13 − 1 m margin − 5 m, less 2 σ of EKF2's height (0.32 m): a layer at 6 m over
        # the mission, or a little above it over an offset partly released (6.09 m in CI;
        # EKF2 states 0.32 m in flight here: the bound takes 0.2 m)
        room = sc.geofence.offset_ceiling_m(np.array([5.0]))
        assert u.max_z_offset_m <= room - 2.0 * 0.2, (uav, u.max_z_offset_m)
        assert u.details["max_altitude_m"] <= sc.geofence.max_altitude_m, (uav, u.details)
        assert u.details["estimator_error"]["samples"] > 100, (uav, u.details)
        px4 = u.details["node"].get("vehicle", {})
        assert px4.get("phase") == "landed", (uav, px4.get("stop_reason"), px4.get("phases"))
        # each placed in the swarm's world from its own origin, booted on the globe below
        assert px4["origin_source"].startswith("GPS_GLOBAL_ORIGIN"), px4["origin_source"]
    # PX4's own flight logs, read independently (pyulog) and put on our clock by each node's
    # clock map, give the same closest approaches within 0.15 m (the logs are at 50 Hz, the
    # truth stream at 25 Hz: a pair closing at 4 m/s moves 0.16 m in 40 ms).
    from uavmpc.drivers.px4.ulog import swarm_truth

    logged = swarm_truth(tmp_path / "run")
    for pair, d in s.sections["closest_by_pair_m"].items():
        assert logged["closest_by_pair_m"][pair] is not None, (pair, logged)
        assert abs(logged["closest_by_pair_m"][pair] - d) <= 0.15, (pair, d, logged)
    assert all((tmp_path / "run" / "px4" / uav / "px4.log").exists() for uav in s.uavs)


def test_a_killed_node_s_vehicle_is_given_way_to_by_everyone_and_followed_by_its_truth(
        px4_sitl_build, tmp_path) -> None:
    """uav1 (priority 1) flies through where uav2 flies; uav2's node is killed 3 s in. PX4
    fails safe (its last setpoint for 1 s, then a level descent) and the vehicle flies on
    uncommanded. uav1 takes it for dead after 3 s unheard and gives way to where PX4's
    failsafe can take it, although it outranks it: nobody comes within 2 m of it by SIH's
    truth. The swarm keeps following the vehicle by its truth, and says what happened."""
    from pathlib import Path

    from uavmpc import scenarios
    from uavmpc.drivers.swarm import run_swarm
    from uavmpc.scenarios.run import RunSpec

    sc = scenarios.load(Path(__file__).parent / "data" / "killed_node_px4.toml")
    s = run_swarm(RunSpec(sc), tmp_path / "run", px4_sitl=px4_sitl_build,
                  kill_at_s={"uav2": 3.0}, px4_first_instance=6)
    assert s.sections["killed"]["uav2"] >= 3.0
    window = s.sections["truth"]["window_unix_s"]
    assert window[1] - window[0] > 20.0  # judged by the truth long after the kill
    assert s.min_distance_m is not None and s.min_distance_m >= 2.0, s.sections
    uav1, uav2 = s.uavs["uav1"], s.uavs["uav2"]
    assert "uav2" in uav1.details["node"]["assumptions"]["dead_peers"]
    # ... and got past it (its goal is judged when the mission ends, where it may still be
    # high above, waiting for the dead vehicle to have landed: by the truth, it went on)
    assert uav1.details["last_truth_m"][0] > 10.0, uav1.details["last_truth_m"]
    assert uav2.details["node"]["exit_code"] == -9
    assert uav2.details["node_killed_at_s"] >= 3.0
    # followed by its truth after its node died: it came down under PX4's failsafe
    assert uav2.details["last_truth_m"][2] < 1.0, uav2.details["last_truth_m"]
