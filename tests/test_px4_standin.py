"""The PX4 stand-in keeps PX4 v1.16's rules (src/uavmpc/drivers/px4/sitl.py), one test each.

Driven over real UDP on loopback with raw pymavlink messages (no uavmpc node). The stand-in is
ticked in-process on a synthetic clock (``StandInPx4.tick``), so every run is deterministic and
no test waits on the wall clock.
"""

from __future__ import annotations

import math
import socket
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from pymavlink.dialects.v20 import common as M

from uavmpc.drivers.px4.sitl import StandInPx4
from uavmpc.plant import Airframe

AF = Airframe.named("x500")
OFFBOARD_MAIN = 6


class Bench:
    """A stand-in sending to a pymavlink socket of ours (ephemeral port), on a synthetic clock."""

    def __init__(self, **kwargs: Any) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.mav = M.MAVLink(None, srcSystem=245, srcComponent=190)
        self.mav.robust_parsing = True
        kwargs.setdefault("clock_rate", 1.0)
        self.sitl = StandInPx4(AF, f"udpout://127.0.0.1:{self.sock.getsockname()[1]}", **kwargs)
        self.peer = ("127.0.0.1", self.sitl.link.local_port)
        self.now_s = 1000.0  # the caller's clock: anything; the stand-in's starts at 0
        self.received: list[Any] = []

    def close(self) -> None:
        self.sitl.link.close()
        self.sock.close()

    def send(self, msg: Any) -> None:
        self.sock.sendto(msg.pack(self.mav), self.peer)

    def command(self, cmd: int, *params: float) -> None:
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.send(M.MAVLink_command_long_message(1, 1, cmd, 0, *p))

    def gcs_heartbeat(self) -> None:
        self.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                              M.MAV_STATE_ACTIVE, 3))

    def position_sp(self, z_ned: float, vz_ned: float = 0.0) -> None:
        self.send(M.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0, 0.0, 0.0, z_ned, 0.0, 0.0, vz_ned, 0.0, 0.0, 0.0,
            0.0, 0.0))

    def attitude_sp(self, thrust: float) -> None:
        mask = (M.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                | M.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE)
        self.send(M.MAVLink_set_attitude_target_message(0, 1, 1, mask, [1.0, 0.0, 0.0, 0.0],
                                                        0.0, 0.0, 0.0, thrust))

    def ticks(self, n: int, each: Callable[[], None] | None = None) -> list[Any]:
        """``n`` ticks (``each`` before every one); what arrived meanwhile."""
        out = []
        for _ in range(n):
            if each is not None:
                each()
            self.sitl.tick(self.now_s)
            self.now_s += self.sitl.tick_period_s
            out += self._drain()
        self.received += out
        return out

    def _drain(self) -> list[Any]:
        out = []
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                return out
            out += self.mav.parse_buffer(data) or []

    def until(self, what: Callable[[], bool], each: Callable[[], None] | None = None,
              max_ticks: int = 3000) -> None:
        for _ in range(max_ticks):
            self.ticks(1, each)
            if what():
                return
        raise AssertionError("condition not reached")

    def acks(self, msgs: list[Any], cmd: int) -> list[int]:
        return [m.result for m in msgs if m.get_type() == "COMMAND_ACK" and m.command == cmd]


@pytest.fixture
def bench() -> Any:
    made: list[Bench] = []

    def make(**kwargs: Any) -> Bench:
        made.append(Bench(**kwargs))
        return made[-1]

    yield make
    for b in made:
        b.close()


def of(msgs: list[Any], kind: str) -> list[Any]:
    return [m for m in msgs if m.get_type() == kind]


def offboard_and_arm(b: Bench, stream: Callable[[], None]) -> None:
    b.ticks(30, stream)
    b.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, OFFBOARD_MAIN)
    b.ticks(1, stream)
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    out = b.ticks(1, stream)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_ACCEPTED]


def test_heartbeat_is_a_fixed_1hz_stream_not_sent_on_an_arm(bench: Any) -> None:
    b = bench(estimator_error=False)
    stream = lambda: b.position_sp(0.0)  # noqa: E731
    b.ticks(150, stream)  # past the second HEARTBEAT
    b.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, OFFBOARD_MAIN)
    b.ticks(1, stream)
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    out = b.ticks(1, stream)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_ACCEPTED]
    # The next HEARTBEAT (up to a second later) is the first to tell; none came at once.
    after = []
    while not after:
        after = of(b.ticks(1, stream), "HEARTBEAT")
    assert after[0].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    beats = of(b.received, "HEARTBEAT")
    assert len(beats) == 3  # at 0 s, 1 s and 2 s of its clock: none extra on the changes
    assert not beats[1].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED


def test_do_set_mode_offboard_while_disarmed_is_acked_twice(bench: Any) -> None:
    b = bench(estimator_error=False)
    b.ticks(5)
    b.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, OFFBOARD_MAIN)
    out = b.ticks(2)
    assert b.acks(out, M.MAV_CMD_DO_SET_MODE) == [M.MAV_RESULT_ACCEPTED] * 2
    # Arming there needs the setpoint stream.
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    out = b.ticks(1)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_TEMPORARILY_REJECTED]


def test_timesync_answers_on_its_clock_at_its_rate(bench: Any) -> None:
    """Requests stamped with our (synthetic) clock are answered with its time: a line fitted
    through (our time, its time) has the configured rate."""
    b = bench(clock_rate=0.97, estimator_error=False)
    b.ticks(1)
    ours, its = [], []
    for k in range(150):  # 1.5 s of our clock
        ts1 = int(b.now_s * 1e9)
        b.send(M.MAVLink_timesync_message(0, ts1))
        out = b.ticks(1)
        replies = [m for m in of(out, "TIMESYNC") if m.tc1 != 0 and m.ts1 == ts1]
        assert len(replies) == 1, k
        ours.append(ts1 * 1e-9)
        its.append(replies[0].tc1 * 1e-9)
    rate = np.polyfit(ours, its, 1)[0]
    assert rate == pytest.approx(0.97, abs=1e-3)
    # Its own requests: tc1 = 0, ts1 = its time [ns], 10 per second of its clock.
    requests = [m for m in of(b.received, "TIMESYNC") if m.tc1 == 0]
    assert 13 <= len(requests) <= 16
    assert requests[-1].ts1 * 1e-9 == pytest.approx(its[-1], abs=0.11)


def test_statustext_only_after_a_gcs_heartbeat(bench: Any) -> None:
    b = bench(estimator_error=False)
    b.ticks(5)
    b.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, OFFBOARD_MAIN)
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)  # refused: no offboard signal
    out = b.ticks(3)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_TEMPORARILY_REJECTED]
    assert not of(out, "STATUSTEXT")
    b.gcs_heartbeat()
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    out = b.ticks(3)
    texts = [m.text for m in of(out, "STATUSTEXT")]
    assert texts.count("Arming denied: No offboard signal") == 2  # the queued one, and now


def test_disarm_needs_the_land_detector(bench: Any) -> None:
    b = bench(estimator_error=False)
    b.gcs_heartbeat()
    climb = lambda: b.position_sp(-1.5)  # noqa: E731
    offboard_and_arm(b, climb)
    b.until(lambda: b.sitl.plant.state().position_m[2] > 1.2, climb)
    b.gcs_heartbeat()  # its STATUSTEXT needs a ground station heard in the last seconds
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
    out = b.ticks(1, climb)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_TEMPORARILY_REJECTED]
    assert "Disarming denied: not landed" in [m.text for m in of(out, "STATUSTEXT")]
    # Down to a setpoint on the ground, held there: the controller keeps its thrust up.
    hold = lambda: b.position_sp(0.0)  # noqa: E731
    b.until(lambda: b.sitl.plant.state().position_m[2] < 0.02, hold)
    b.ticks(300, hold)
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
    out = b.ticks(1, hold)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_TEMPORARILY_REJECTED]
    assert b.sitl.armed
    # A commanded descent (0.5 m/s down, below the ground): the detector lands it.
    down = lambda: b.position_sp(0.5, 0.5)  # noqa: E731
    b.until(lambda: b.sitl.detector.landed.state, down, max_ticks=300)
    landed_states = [m.landed_state for m in of(b.ticks(25, down), "EXTENDED_SYS_STATE")]
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
    out = b.ticks(1, down)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_ACCEPTED]
    assert not b.sitl.armed
    assert landed_states[-1] == M.MAV_LANDED_STATE_ON_GROUND
    in_air = [m for m in of(b.received, "EXTENDED_SYS_STATE")
              if m.landed_state == M.MAV_LANDED_STATE_IN_AIR]
    assert in_air


def test_position_take_off_waits_for_spool_up_and_ramp(bench: Any) -> None:
    b = bench(estimator_error=False)
    climb = lambda: b.position_sp(-2.0)  # noqa: E731
    offboard_and_arm(b, climb)
    armed_s = b.sitl.armed_s
    b.until(lambda: b.sitl.plant.state().position_m[2] > 0.02, climb)
    assert 2.5 < b.sitl.clock_s - armed_s < 4.0


def test_attitude_maybe_landed_needs_thrust_at_most_0_09(bench: Any) -> None:
    b = bench(estimator_error=False)
    low = 0.12 + 0.3 * (b.sitl.hover_thrust - 0.12)  # ground contact's throttle
    thrust = {"value": low - 0.01}
    stream = lambda: b.attitude_sp(thrust["value"])  # noqa: E731
    offboard_and_arm(b, stream)  # far below hover: it stays on the ground
    b.ticks(100, stream)
    det = b.sitl.detector
    assert b.sitl.plant.landed and det.ground_contact.state and not det.maybe_landed.state
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
    out = b.ticks(1, stream)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_TEMPORARILY_REJECTED]
    thrust["value"] = 0.095
    b.ticks(100, stream)
    assert not det.maybe_landed.state
    thrust["value"] = 0.09
    b.until(lambda: det.maybe_landed.state, stream, max_ticks=100)
    b.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
    out = b.ticks(1, stream)
    assert b.acks(out, M.MAV_CMD_COMPONENT_ARM_DISARM) == [M.MAV_RESULT_ACCEPTED]


def test_odometry_at_30hz_by_its_stamps_and_unknown_ids(bench: Any) -> None:
    b = bench(clock_rate=0.986)
    b.ticks(305)
    odo = of(b.received, "ODOMETRY")
    stamps = np.array([m.time_usec for m in odo]) * 1e-6
    window = stamps[(stamps >= 0.5) & (stamps < 2.5)]
    assert len(window) / 2.0 == pytest.approx(30.0, abs=1.0)
    assert all(m.frame_id == M.MAV_FRAME_LOCAL_NED and m.child_frame_id == M.MAV_FRAME_LOCAL_NED
               for m in odo)
    assert len(of(b.received, "LOCAL_POSITION_NED")) == pytest.approx(len(odo), abs=2)
    unknown = {m.get_type() for m in b.received if m.get_type().startswith("UNKNOWN_")}
    assert unknown == {"UNKNOWN_8", "UNKNOWN_380", "UNKNOWN_411", "UNKNOWN_436"}


def test_gps_global_origin_on_request(bench: Any) -> None:
    b = bench(position_m=(100.0, -50.0, 0.0), geo_origin_deg=(47.0, 8.0, 400.0))
    b.ticks(2)
    b.command(M.MAV_CMD_REQUEST_MESSAGE, float(M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN))
    out = b.ticks(1)
    kinds = [m.get_type() for m in out if m.get_type() in ("GPS_GLOBAL_ORIGIN", "COMMAND_ACK")]
    assert kinds == ["GPS_GLOBAL_ORIGIN", "COMMAND_ACK"]  # the message, then the ACK
    origin = of(out, "GPS_GLOBAL_ORIGIN")[0]
    # 100 m east, 50 m south of 47° N, 8° E.
    assert origin.latitude * 1e-7 == pytest.approx(47.0 - 50.0 / 6371000.0 * 180 / math.pi,
                                                   abs=1e-7)
    assert origin.longitude * 1e-7 > 8.0 and origin.altitude == 400000
    assert b.acks(out, M.MAV_CMD_REQUEST_MESSAGE) == [M.MAV_RESULT_ACCEPTED]
    none = bench(geo_origin_deg=None)
    none.command(M.MAV_CMD_REQUEST_MESSAGE, float(M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN))
    out = none.ticks(2)
    assert not of(out, "GPS_GLOBAL_ORIGIN")
    assert none.acks(out, M.MAV_CMD_REQUEST_MESSAGE) == [M.MAV_RESULT_DENIED]


def test_estimator_error_is_seeded_and_bounded(bench: Any) -> None:
    def reported(seed: int) -> tuple[np.ndarray, StandInPx4]:
        b = bench(seed=seed)
        b.ticks(300)
        odo = of(b.received, "ODOMETRY")
        return np.array([[m.x, m.y, m.z, m.vx, m.vy, m.vz] for m in odo]), b.sitl

    a, sitl = reported(7)
    a2, _ = reported(7)
    c, _ = reported(8)
    assert np.array_equal(a, a2) and not np.array_equal(a, c)
    # What ODOMETRY reports is the truth (at rest at the origin) plus the error (NED).
    assert np.abs(a[-1, 2]) > 1e-4
    # Its error over two minutes at rest: decimetres, slowly varying, the velocity small.
    est = sitl.estimator
    p, v = [], []
    for _ in range(12000):
        est.step(0.01)
        p.append(est.position_m.copy())
        v.append(est.velocity_mps.copy())
    p, v = np.array(p), np.array(v)
    assert 0.02 < np.abs(p[:, :2]).max() < 0.6
    assert 0.05 < np.abs(p[:, 2]).max() < 1.2
    assert np.abs(v).max() < 0.2
    # The velocity error is the position error's derivative (consistent, not noise).
    assert np.allclose(np.diff(p, axis=0) / 0.01, v[1:], atol=1e-9)
