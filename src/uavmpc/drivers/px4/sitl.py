"""A stand-in for a PX4 autopilot: our plant and attitude loop behind a MAVLink endpoint.

``uavmpc sitl`` is a test double for users without a vehicle (and for our tests). It speaks
PX4's dialect on UDP — its HEARTBEAT (``MAV_AUTOPILOT_PX4``, PX4's custom-mode encoding, the
armed flag), ``COMMAND_ACK`` for every command, ``ODOMETRY`` (local NED, body FRD) at 100 Hz,
``LOCAL_POSITION_NED``, ``ATTITUDE_QUATERNION``, ``EXTENDED_SYS_STATE`` and ``PARAM_VALUE`` — and
keeps the rules an offboard controller must live with:

- the offboard signal is present while the last valid setpoint is younger than
  ``COM_OF_LOSS_T`` (1 s), as in PX4's commander (its documentation asks for more: > 2 Hz for
  about 1 s before the switch); without it, arming in offboard and switching to offboard while
  armed are refused with ``MAV_RESULT_TEMPORARILY_REJECTED`` (a switch while disarmed is always
  taken, as PX4 does);
- in offboard, a signal lost for ``COM_OF_LOSS_T`` makes it fall back to position mode
  (``COM_OBL_RC_ACT`` = 0: with centred sticks, hold the position); it returns to offboard when
  the stream resumes unless another mode was requested meanwhile, as PX4 does;
- ``SET_ATTITUDE_TARGET`` with the roll- and pitch-rate bits ignored is attitude control (the
  yaw rate a feed-forward); with all rates given PX4 flies rates, which the stand-in does not
  model (it drops such setpoints);
- every refused transition is ``MAV_RESULT_TEMPORARILY_REJECTED``, as PX4 answers; a disarm in
  the air is refused unless forced; after landing it disarms itself (``COM_DISARM_LAND``), and
  an armed vehicle that never takes off disarms after ``COM_DISARM_PRFLT``.

What it does not model (docs/px4.md): PX4's estimator (it reports the true state), its
position controller's jerk-limited braking (its hold is our SE(3) controller on the point where
hold began), rate and thrust-vector setpoints, RC input and RC-loss failsafes, preflight
checks, geofence, battery, mission and takeoff modes, the parameter protocol beyond reading a
few values, MAVLink signing.
"""

from __future__ import annotations

import math
import signal
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from uavmpc.control.se3 import Se3Controller
from uavmpc.drivers.px4.dialect import (
    COM_OF_LOSS_T_S,
    FORCE_DISARM,
    HOLD,
    LAND,
    OFFBOARD,
    POSCTL,
    MainMode,
    Px4Mode,
    mavlink,
)
from uavmpc.drivers.px4.endpoint import MavlinkEndpoint
from uavmpc.drivers.px4.frames import (
    enu_flu_quat_to_ned_frd,
    enu_to_ned,
    flu_to_frd,
    frd_to_flu,
    heading_ned_to_enu,
    ned_frd_quat_to_enu_flu,
    ned_to_enu,
)
from uavmpc.plant import Airframe, AttitudeTarget, VehicleState
from uavmpc.plant.interface import heading_of, yaw_quat
from uavmpc.plant.multirotor import Multirotor

__all__ = ["StandInPx4", "run_sitl"]

_M = mavlink
PERIOD_S = 0.01
G = 9.80665
#: PX4 defaults the stand-in keeps.
COM_DISARM_LAND_S = 2.0
COM_DISARM_PRFLT_S = 10.0
MPC_LAND_SPEED_MPS = 0.7
#: The modes it flies; others are answered MAV_RESULT_UNSUPPORTED.
MODES = (OFFBOARD, HOLD, LAND, POSCTL)
#: Upper-triangle covariance as PX4 fills it: the diagonal known (the true state: tiny), the
#: rest NaN.
_COVARIANCE = [1e-6 if i in (0, 6, 11, 15, 18, 20) else math.nan for i in range(21)]


@dataclass
class _Setpoint:
    kind: str  # "attitude" or "position"
    received_s: float
    values: Any


@dataclass
class _Hold:
    """A position-controller setpoint (ENU): hold, land and position-mode offboard use it."""

    t_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    heading_rad: float
    heading_rate_radps: float = 0.0


class StandInPx4:
    """The stand-in autopilot (see the module docstring).

    Args:
        airframe: the simulated vehicle.
        address: where its MAVLink goes (``udpout://127.0.0.1:14540`` sends to an offboard
            API listening there, as PX4 SITL does; ``udp://:PORT`` listens).
        position_m: where it boots in the world (ENU; the ground is z = 0). Its local NED
            frame has its origin here, as PX4's does where its estimator started.
        heading_rad: initial heading (ENU).
        system_id: its MAVLink system id (PX4's default 1).
        odometry_rate_hz: ODOMETRY rate (≥ 50 Hz; LOCAL_POSITION_NED and ATTITUDE_QUATERNION
            go at half of it).
        offboard_loss_s: ``COM_OF_LOSS_T``.
    """

    def __init__(self, airframe: Airframe, address: str, *,
                 position_m: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
                 heading_rad: float = 0.0, system_id: int = 1,
                 odometry_rate_hz: float = 100.0,
                 offboard_loss_s: float = COM_OF_LOSS_T_S) -> None:
        if not 1 <= int(system_id) <= 255:
            raise ValueError(f"system_id: must be in 1..255, got {system_id!r}")
        if not 1.0 <= float(odometry_rate_hz) <= 1.0 / PERIOD_S:
            raise ValueError(f"odometry_rate_hz: must be in [1, {1.0 / PERIOD_S:g}], "
                             f"got {odometry_rate_hz!r}")
        if not float(offboard_loss_s) > 0.0:
            raise ValueError(f"offboard_loss_s: must be > 0, got {offboard_loss_s!r}")
        self.airframe = airframe
        self.origin_m = np.asarray(position_m, dtype=float).copy()
        self.system_id = int(system_id)
        self.link = MavlinkEndpoint(address, system_id=self.system_id, component_id=1)
        self.plant = Multirotor(airframe, position_m=self.origin_m, yaw_rad=heading_rad)
        self.controller = Se3Controller(airframe, period_s=PERIOD_S)
        self.hover_thrust = airframe.mass_kg * G / airframe.max_thrust_n
        self.offboard_loss_s = float(offboard_loss_s)
        self.odometry_period_s = 1.0 / float(odometry_rate_hz)
        self.mode: Px4Mode = HOLD
        #: The mode last asked for (PX4's "user intention"): a failsafe fallback keeps it and
        #: returns to it when the cause is gone.
        self.intention: Px4Mode = HOLD
        self.armed = False
        self.setpoint: _Setpoint | None = None
        self.hold: _Hold | None = None
        self.t0_s = time.time()
        self.armed_s = 0.0
        self.airborne_since_arming = False
        self.landed_since_s: float | None = None
        self.events: list[str] = []
        self.params = {"MPC_THR_HOVER": self.hover_thrust, "COM_OF_LOSS_T": self.offboard_loss_s,
                       "COM_DISARM_LAND": COM_DISARM_LAND_S, "MPC_LAND_SPEED": MPC_LAND_SPEED_MPS}
        self._next = {"heartbeat": 0.0, "odometry": 0.0, "local": 0.0, "extended": 0.0}
        self._stop = False

    # ------------------------------------------------------------------ the loop
    def stop(self) -> None:
        self._stop = True

    def run(self, duration_s: float | None = None) -> None:
        """Fly on the wall clock until :meth:`stop` (or ``duration_s``)."""
        t_end = math.inf if duration_s is None else time.time() + duration_s
        deadline = time.perf_counter()
        while not self._stop and time.time() < t_end:
            self.tick(time.time())
            deadline += PERIOD_S
            slack = deadline - time.perf_counter()
            if slack > 0.0:
                self.link.wait(slack)
                # Messages that arrive while waiting are taken at the next tick; sleep the
                # rest so the physics keeps its period.
                rest = deadline - time.perf_counter()
                if rest > 0.0:
                    time.sleep(rest)
            elif -slack > 5 * PERIOD_S:
                deadline = time.perf_counter()

    def tick(self, now_s: float) -> None:
        """One period: take messages, apply the mode's control, step the plant, send."""
        for msg, sender, _arrived in self.link.receive():
            self._handle(msg, sender, now_s)
        self._failsafes(now_s)
        self.plant.step(self._control(now_s), PERIOD_S)
        self._disarm_checks(now_s)
        self._send_streams(now_s)

    # ------------------------------------------------------------------ control
    def _control(self, now_s: float) -> AttitudeTarget:
        state = self.plant.state()
        level = AttitudeTarget(yaw_quat(float(heading_of(state.attitude_wxyz))), 0.0)
        if not self.armed:
            return level  # motors stopped (the plant's idle floor)
        if self.mode == OFFBOARD and self.setpoint is not None:
            sp = self.setpoint
            if sp.kind == "attitude":
                q_ned, rates_frd, thrust = sp.values
                return AttitudeTarget(ned_frd_quat_to_enu_flu(q_ned),
                                      thrust / self.hover_thrust * self.airframe.mass_kg * G,
                                      frd_to_flu(rates_frd))
            return self.controller.update(sp.values, state)
        if self.plant.landed and self.mode != OFFBOARD:
            return level  # armed on the ground: idle
        if self.mode == LAND and self.hold is not None:
            h = self.hold
            h.position_m = h.position_m + np.array([0.0, 0.0, -MPC_LAND_SPEED_MPS * PERIOD_S])
            h.velocity_mps = np.array([0.0, 0.0, -MPC_LAND_SPEED_MPS])
        if self.hold is None:
            self.hold = self._hold_here(state)
        return self.controller.update(self.hold, state)

    def _hold_here(self, state: VehicleState) -> _Hold:
        return _Hold(state.t_s, state.position_m.copy(), np.zeros(3), np.zeros(3),
                     float(heading_of(state.attitude_wxyz)))

    def _set_mode(self, mode: Px4Mode, now_s: float, why: str = "") -> None:
        if mode == self.mode:
            return
        if mode != self.mode:
            self.events.append(f"{now_s - self.t0_s:.2f} s: {self.mode} → {mode}{why}")
        self.mode = mode
        self.hold = None
        self.controller.reset()
        self._next["heartbeat"] = 0.0  # tell at once

    def _failsafes(self, now_s: float) -> None:
        if not self.armed or self.intention != OFFBOARD:
            return
        signal = self._offboard_available(now_s)
        if self.mode == OFFBOARD and not signal:
            self._set_mode(POSCTL, now_s, " (failsafe: offboard signal lost)")
            self._status(_M.MAV_SEVERITY_WARNING,
                         "Failsafe activated: offboard signal lost, position mode")
        elif self.mode == POSCTL and signal:
            self._set_mode(OFFBOARD, now_s, " (offboard signal back)")

    def _offboard_available(self, now_s: float) -> bool:
        """PX4's commander rule: the last valid setpoint is younger than COM_OF_LOSS_T."""
        return (self.setpoint is not None
                and now_s - self.setpoint.received_s < self.offboard_loss_s)

    def _disarm_checks(self, now_s: float) -> None:
        if not self.armed:
            return
        if not self.plant.landed:
            self.airborne_since_arming = True
            self.landed_since_s = None
            return
        if self.landed_since_s is None:
            self.landed_since_s = now_s
        if self.airborne_since_arming and now_s - self.landed_since_s >= COM_DISARM_LAND_S:
            self._disarm(now_s, "landed")
        elif not self.airborne_since_arming and now_s - self.armed_s >= COM_DISARM_PRFLT_S:
            self._disarm(now_s, f"no take-off within {COM_DISARM_PRFLT_S:g} s")

    def _disarm(self, now_s: float, why: str) -> None:
        self.armed = False
        self.events.append(f"{now_s - self.t0_s:.2f} s: disarmed ({why})")
        self._status(_M.MAV_SEVERITY_INFO, f"Disarmed: {why}")
        self._next["heartbeat"] = 0.0

    # ------------------------------------------------------------------ receiving
    def _handle(self, msg: Any, sender: tuple[str, int], now_s: float) -> None:
        kind = msg.get_type()
        if kind in ("SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED", "COMMAND_LONG",
                    "COMMAND_INT", "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST"):
            if msg.target_system not in (0, self.system_id) \
                    or msg.target_component not in (0, 1):
                return
        elif kind != "HEARTBEAT":
            return
        self.link.trust(sender)
        if kind == "SET_ATTITUDE_TARGET":
            self._on_attitude_target(msg, now_s)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._on_position_target(msg, now_s)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._on_command(msg, now_s)
        elif kind == "PARAM_REQUEST_READ":
            name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else ""
            names = list(self.params)
            if name in self.params:
                self._send_param(name, names.index(name))
            elif 0 <= msg.param_index < len(names):
                self._send_param(names[msg.param_index], msg.param_index)
        elif kind == "PARAM_REQUEST_LIST":
            for i, name in enumerate(self.params):
                self._send_param(name, i)

    def _take_setpoint(self, sp: _Setpoint, now_s: float) -> None:
        self.setpoint = sp

    def _on_attitude_target(self, msg: Any, now_s: float) -> None:
        q = np.array(msg.q, dtype=float)
        mask = int(msg.type_mask)
        rate_mode = not mask & (_M.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                                | _M.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE)
        if rate_mode or mask & (_M.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
                                | _M.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE):
            return  # rate or thrust-vector setpoints: not modelled (PX4 would fly rates)
        yaw_rate = (0.0 if mask & _M.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE
                    else float(msg.body_yaw_rate))  # PX4: the yaw feed-forward
        rates = np.array([0.0, 0.0, yaw_rate])
        if not (np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1.0) < 1e-2
                and np.all(np.isfinite(rates)) and 0.0 <= msg.thrust <= 1.0):
            return  # PX4 drops invalid setpoints
        self._take_setpoint(_Setpoint("attitude", now_s,
                                      (q / np.linalg.norm(q), rates, float(msg.thrust))), now_s)

    def _on_position_target(self, msg: Any, now_s: float) -> None:
        if msg.coordinate_frame != _M.MAV_FRAME_LOCAL_NED:
            return
        vals = np.array([msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.afx, msg.afy,
                         msg.afz, msg.yaw, msg.yaw_rate], dtype=float)
        mask = int(msg.type_mask)
        for bits, sl in ((0b111, slice(0, 3)), (0b111000, slice(3, 6)),
                         (0b111000000, slice(6, 9))):
            if mask & bits:
                vals[sl] = 0.0 if sl.start else np.nan
        if not np.all(np.isfinite(vals[3:])) or (not mask & 0b111
                                                 and not np.all(np.isfinite(vals[:3]))):
            return
        state = self.plant.state()
        p = self.origin_m + ned_to_enu(vals[0:3]) if not mask & 0b111 else state.position_m
        heading = (heading_ned_to_enu(vals[9])
                   if not mask & _M.POSITION_TARGET_TYPEMASK_YAW_IGNORE
                   else float(heading_of(state.attitude_wxyz)))
        rate = 0.0 if mask & _M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE else -vals[10]
        self._take_setpoint(_Setpoint("position", now_s, _Hold(
            now_s, p, ned_to_enu(vals[3:6]), ned_to_enu(vals[6:9]), heading, rate)), now_s)

    def _on_command(self, msg: Any, now_s: float) -> None:
        cmd = int(msg.command)
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        if cmd == _M.MAV_CMD_DO_SET_MODE:
            result = self._request_mode(p, now_s)
        elif cmd == _M.MAV_CMD_COMPONENT_ARM_DISARM:
            result = self._request_arming(p, now_s)
        elif cmd == _M.MAV_CMD_NAV_LAND:
            result = self._request_mode([1.0, LAND.main, LAND.sub], now_s)
        elif cmd == _M.MAV_CMD_REQUEST_MESSAGE and int(p[0]) == _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            result = _M.MAV_RESULT_ACCEPTED
            self._send_autopilot_version()
        else:
            result = _M.MAV_RESULT_UNSUPPORTED
        self.link.send(_M.MAVLink_command_ack_message(cmd, result, 0, 0, msg.get_srcSystem(),
                                                      msg.get_srcComponent()))

    def _request_mode(self, p: list[float], now_s: float) -> int:
        if not int(p[0]) & _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return _M.MAV_RESULT_UNSUPPORTED  # PX4 takes modes as its custom modes
        mode = Px4Mode(int(p[1]), int(p[2]) if int(p[1]) == MainMode.AUTO else 0)
        if mode not in MODES:
            return _M.MAV_RESULT_UNSUPPORTED
        if mode == OFFBOARD and self.armed and not self._offboard_available(now_s):
            self._status(_M.MAV_SEVERITY_CRITICAL, "Switching to Offboard is currently not "
                         "available: No offboard signal")
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        self.intention = mode
        self._set_mode(mode, now_s)
        return _M.MAV_RESULT_ACCEPTED

    def _request_arming(self, p: list[float], now_s: float) -> int:
        arm = p[0] > 0.5
        if arm == self.armed:
            return _M.MAV_RESULT_ACCEPTED
        if arm:
            if not self.plant.landed:
                return _M.MAV_RESULT_TEMPORARILY_REJECTED
            if self.mode == OFFBOARD and not self._offboard_available(now_s):
                self._status(_M.MAV_SEVERITY_CRITICAL, "Arming denied: No offboard signal")
                return _M.MAV_RESULT_TEMPORARILY_REJECTED
            self.armed = True
            self.armed_s = now_s
            self.airborne_since_arming = False
            self.landed_since_s = None
            self.controller.reset()
            self.events.append(f"{now_s - self.t0_s:.2f} s: armed in {self.mode}")
        else:
            if not self.plant.landed and p[1] != FORCE_DISARM:
                self._status(_M.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed")
                return _M.MAV_RESULT_TEMPORARILY_REJECTED
            self._disarm(now_s, "commanded")
        self._next["heartbeat"] = 0.0
        return _M.MAV_RESULT_ACCEPTED

    # ------------------------------------------------------------------ sending
    def _send_streams(self, now_s: float) -> None:
        nxt = self._next
        if now_s >= nxt["heartbeat"]:
            nxt["heartbeat"] = now_s + 1.0
            self.link.send(self._heartbeat())
        if now_s >= nxt["odometry"]:
            nxt["odometry"] = max(nxt["odometry"] + self.odometry_period_s, now_s - PERIOD_S)
            self.link.send(self._odometry(now_s))
        if now_s >= nxt["local"]:
            nxt["local"] = max(nxt["local"] + 2.0 * self.odometry_period_s, now_s - PERIOD_S)
            for m in self._local_and_attitude(now_s):
                self.link.send(m)
        if now_s >= nxt["extended"]:
            nxt["extended"] = now_s + 0.2
            landed = (_M.MAV_LANDED_STATE_ON_GROUND if self.plant.landed
                      else _M.MAV_LANDED_STATE_IN_AIR)
            self.link.send(_M.MAVLink_extended_sys_state_message(
                _M.MAV_VTOL_STATE_UNDEFINED, landed))

    def _heartbeat(self) -> Any:
        # PX4's flags: auto modes AUTO|GUIDED|STABILIZE, position mode MANUAL_INPUT|STABILIZE,
        # offboard (attitude or position setpoints) STABILIZE only.
        base = _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | _M.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.armed:
            base |= _M.MAV_MODE_FLAG_SAFETY_ARMED
        if self.mode.main == MainMode.AUTO:
            base |= _M.MAV_MODE_FLAG_AUTO_ENABLED | _M.MAV_MODE_FLAG_GUIDED_ENABLED
        elif self.mode.main != MainMode.OFFBOARD:
            base |= _M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        failsafe = self.mode != self.intention
        status = (_M.MAV_STATE_STANDBY if not self.armed
                  else _M.MAV_STATE_CRITICAL if failsafe else _M.MAV_STATE_ACTIVE)
        return _M.MAVLink_heartbeat_message(_M.MAV_TYPE_QUADROTOR, _M.MAV_AUTOPILOT_PX4, base,
                                            self.mode.custom_mode, status, 3)

    def _boot_us(self, now_s: float) -> int:
        return int((now_s - self.t0_s) * 1e6)

    def _odometry(self, now_s: float) -> Any:
        s = self.plant.state()
        p = enu_to_ned(s.position_m - self.origin_m)
        q = enu_flu_quat_to_ned_frd(s.attitude_wxyz)
        v = enu_to_ned(s.velocity_mps)  # PX4's EKF2: velocity in local NED too
        w = flu_to_frd(s.body_rates_radps)
        return _M.MAVLink_odometry_message(
            self._boot_us(now_s), _M.MAV_FRAME_LOCAL_NED, _M.MAV_FRAME_LOCAL_NED,
            *map(float, p), q.tolist(), *map(float, v), *map(float, w), _COVARIANCE,
            _COVARIANCE, 0, _M.MAV_ESTIMATOR_TYPE_AUTOPILOT, 0)

    def _local_and_attitude(self, now_s: float) -> list[Any]:
        s = self.plant.state()
        ms = int((now_s - self.t0_s) * 1e3)
        p = enu_to_ned(s.position_m - self.origin_m)
        v = enu_to_ned(s.velocity_mps)
        q = enu_flu_quat_to_ned_frd(s.attitude_wxyz)
        w = flu_to_frd(s.body_rates_radps)
        return [_M.MAVLink_local_position_ned_message(ms, *map(float, p), *map(float, v)),
                _M.MAVLink_attitude_quaternion_message(ms, *map(float, q), *map(float, w),
                                                       [0.0, 0.0, 0.0, 0.0])]

    def _send_param(self, name: str, index: int) -> None:
        self.link.send(_M.MAVLink_param_value_message(
            name.encode(), float(self.params[name]), _M.MAV_PARAM_TYPE_REAL32,
            len(self.params), index))

    def _send_autopilot_version(self) -> None:
        caps = (_M.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | _M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | _M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
                | _M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | _M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT)
        self.link.send(_M.MAVLink_autopilot_version_message(
            caps, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.system_id, [0] * 18))

    def _status(self, severity: int, text: str) -> None:
        self.link.send(_M.MAVLink_statustext_message(severity, text[:50].encode()))


def run_sitl(sitl: StandInPx4, duration_s: float | None = None) -> None:
    """Run until SIGINT/SIGTERM or ``duration_s``; print its events at the end."""
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in previous:
        signal.signal(sig, lambda *_: sitl.stop())
    try:
        sitl.run(duration_s)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        sitl.link.close()
