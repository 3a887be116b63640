"""The companion computer's side of a PX4 vehicle: its state in, setpoints out, and the life
cycle PX4 expects of an offboard controller.

:class:`Px4Vehicle` is what a :class:`~uavmpc.drivers.node.Node` flies instead of its
simulated plant. It reads the vehicle's state from ``ODOMETRY`` (or ``LOCAL_POSITION_NED`` +
``ATTITUDE_QUATERNION``), sends the stack's target at the node's 100 Hz as
``SET_ATTITUDE_TARGET`` (default) or ``SET_POSITION_TARGET_LOCAL_NED``, and walks the phases::

    connecting → streaming (setpoints > 1 s) → offboard (MAV_CMD_DO_SET_MODE, retried while
    refused) → arming → flying (the node takes off and flies its mission) → landing (a
    commanded descent until PX4's land detector says landed) → disarming → landed

What real PX4 does and how this class meets it (docs/px4.md has the table):

- HEARTBEAT is a fixed 1 Hz stream, so its armed flag and mode lag a ``COMMAND_ACK`` by up to a
  second: an accepted ACK sets the state at once, and a HEARTBEAT that contradicts it is believed
  from the second one after the ACK (the first may have left before the change).
- PX4's clock is not ours (in lockstep SITL it runs slow): estimates are placed on our clock
  through a fitted offset and rate (:class:`~.clock.ClockMap`, from MAVLink TIMESYNC).
- PX4 disarms only when its land detector agrees: the landing descends at a commanded rate
  (which is what that detector looks for) until ``EXTENDED_SYS_STATE.landed_state`` says on the
  ground, never judged by the estimator's height (EKF2's drifts by decimetres at rest).
- PX4 sends its STATUSTEXT (the reasons for a refusal) only to a ground station: we send a
  ground station's HEARTBEAT at 1 Hz.

Every command's ``COMMAND_ACK`` is checked, a rejection reported with its result name and PX4's
text. An estimate older than ``estimate_timeout_s`` (0.2 s) is not flown on: until it is fresh
again the node sends the tracker's position, velocity and acceleration
(``SET_POSITION_TARGET_LOCAL_NED``), which PX4 tracks on its own, fresh estimate — the virtual
UAV, and so the plan the node broadcasts, stays what the vehicle flies. (Found on real PX4 on a
loaded two-core machine: ODOMETRY gaps of 0.20–0.21 s, each of which stopped a vehicle that
was flying well.) Our failsafes: no estimate younger than ``estimate_lost_s`` (1 s, PX4's own
``COM_OF_LOSS_T``), an autopilot that leaves offboard or disarms, or a lost link (no HEARTBEAT)
→ **stopped**: no more setpoints, the reason reported; the node then broadcasts what the
vehicle really does (:meth:`OnboardStack.follow <uavmpc.onboard.OnboardStack.follow>`).
A stopped vehicle is never taken back: a pilot who switched modes keeps the vehicle.

Frames: PX4's local frame is NED with its origin where its estimator started; ``origin_m`` is
that origin in the swarm's ENU world, given, or placed from PX4's own ``GPS_GLOBAL_ORIGIN``
against the swarm's geodetic origin (``geo_origin``). The conversions are :mod:`.frames`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

from uavmpc.drivers.px4.clock import ClockMap
from uavmpc.drivers.px4.dialect import (
    FORCE_DISARM,
    OFFBOARD,
    OFFBOARD_STREAM_S,
    AttitudeQuaternionMsg,
    CommandAckMsg,
    ExtendedSysStateMsg,
    GpsGlobalOriginMsg,
    HeartbeatMsg,
    LocalPositionNedMsg,
    OdometryMsg,
    ParamValueMsg,
    Px4Mode,
    SetAttitudeTargetMsg,
    SetPositionTargetLocalNedMsg,
    StatusTextMsg,
    TimesyncMsg,
    command_name,
    mavlink,
    result_name,
)
from uavmpc.drivers.px4.endpoint import MavlinkEndpoint
from uavmpc.drivers.px4.frames import (
    enu_flu_quat_to_ned_frd,
    enu_to_ned,
    flu_to_frd,
    frd_to_flu,
    geodetic_to_enu,
    heading_enu_to_ned,
    ned_frd_quat_to_enu_flu,
    ned_to_enu,
)
from uavmpc.plant import Airframe, AttitudeTarget, VehicleState
from uavmpc.plant.interface import heading_of, quat_to_rot, yaw_quat
from uavmpc.tracker.tracker import TrackerCommand

__all__ = ["SETPOINT_MODES", "Phase", "Px4Vehicle", "VehicleLost"]

#: An estimate older than this is not flown on: the node sends position setpoints (PX4 flies
#: them on its own estimate) until a fresh one arrives.
ESTIMATE_TIMEOUT_S = 0.2
#: No estimate younger than this: the node stops commanding. PX4's offboard-loss timeout
#: (COM_OF_LOSS_T, 1 s by default): no longer than PX4 itself waits for a silent companion.
ESTIMATE_LOST_S = 1.0
#: No HEARTBEAT for this long is a lost link (PX4 sends one per second).
HEARTBEAT_TIMEOUT_S = 2.5
#: A command without COMMAND_ACK is sent again after this, up to COMMAND_ATTEMPTS times.
COMMAND_RETRY_S = 0.5
COMMAND_ATTEMPTS = 3
#: After a refused mode change or arm, ask again after this; give up after GIVE_UP_S.
RETRY_S = 1.0
GIVE_UP_S = 30.0
#: After an accepted mode change, the HEARTBEAT must show it within this.
MODE_CONFIRM_S = 3.0
#: Landed, for an autopilot that never says (no EXTENDED_SYS_STATE): within this height of
#: the take-off point and slower than LANDED_SPEED_MPS for LANDED_HOLD_S. PX4 always says, and
#: its word is taken instead: EKF2's height drifts by ±0.6 m at rest. Its word too must hold
#: for LANDED_HOLD_S before we ask to disarm: PX4 v1.16's land detector flaps at touch-down
#: (SITL, position setpoints: "Landing detected" at 23.57 s, "Takeoff detected" at 23.70 s,
#: and the disarm sent between them was denied "not landed").
LANDED_HEIGHT_M = 0.15
LANDED_SPEED_MPS = 0.25
LANDED_HOLD_S = 0.5
#: Our ground station HEARTBEAT and TIMESYNC requests [s]: PX4 sends its STATUSTEXT only to a
#: link that heard a ground station; five round trips a second keep the clock map fresh.
GCS_HEARTBEAT_S = 1.0
TIMESYNC_S = 0.2
#: A HEARTBEAT that contradicts an accepted ACK is believed from this many HEARTBEATs after it
#: (PX4 sends them at a fixed 1 Hz: the first may have left before the change).
HEARTBEATS_TO_CONTRADICT = 2
#: While landing, a thrust below this fraction of the hover thrust is flown level (a descent
#: pushed into the ground; in the air it is a vertical descent).
TOUCHDOWN_THRUST_FRACTION = 0.5
#: MAV_COMP_ID_ONBOARD_COMPUTER: who we are on the vehicle's MAVLink network.
ONBOARD_COMPONENT = 191
SETPOINT_MODES = ("attitude", "position")

_M = mavlink
_ODOMETRY_CHILD_BODY = (_M.MAV_FRAME_BODY_FRD, _M.MAV_FRAME_BODY_NED, _M.MAV_FRAME_BODY_OFFSET_NED)
# Roll and pitch rates ignored: PX4 then flies the attitude, with the yaw rate as its
# feed-forward (all rates given would make it fly rates instead).
_ATT_TYPE_MASK = (_M.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                  | _M.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE)
_POS_TYPE_MASK = 0  # position, velocity, acceleration, yaw, yaw rate all used


class Phase(StrEnum):
    CONNECTING = "connecting"
    STREAMING = "streaming"
    OFFBOARD = "offboard"
    ARMING = "arming"
    FLYING = "flying"
    LANDING = "landing"
    DISARMING = "disarming"
    LANDED = "landed"
    STOPPED = "stopped"


class VehicleLost(RuntimeError):
    """No autopilot (or no estimate) within the time given to :meth:`Px4Vehicle.start`."""


@dataclass
class _Command:
    command: int
    params: tuple[float, ...]
    sent_s: float
    attempts: int = 1
    result: int | None = None


@dataclass
class Px4Report:
    """What the link did (the node's report has it under ``"px4"``)."""

    phase: str = Phase.CONNECTING.value
    stop_reason: str | None = None
    system_id: int | None = None
    hover_thrust: float | None = None
    hover_thrust_source: str = ""
    setpoint_mode: str = "attitude"
    setpoints_sent: int = 0
    setpoint_period_p50_ms: float = 0.0
    setpoint_period_p99_ms: float = 0.0
    setpoint_period_max_ms: float = 0.0
    estimate_age_p50_ms: float = 0.0
    estimate_age_p99_ms: float = 0.0
    #: Spells with no fresh estimate that the node bridged with position setpoints (PX4
    #: flying on its own estimate), their total and longest duration [s].
    position_fallbacks: int = 0
    position_fallback_s: float = 0.0
    position_fallback_max_s: float = 0.0
    odometry_received: int = 0
    #: Ticks after start() on which no estimate was fresh (none commands on such a tick).
    ticks_without_estimate: int = 0
    heartbeats_received: int = 0
    #: HEARTBEATs that showed the state from before an accepted ACK (and were not believed).
    heartbeats_behind_ack: int = 0
    #: The clock map: our seconds per autopilot second, the shortest TIMESYNC round trip.
    clock_rate: float = 1.0
    #: ... and our time [s, Unix] at the autopilot's time 0 (its boot): an autopilot stamp
    #: t [s] (a ULog's ``timestamp`` / 1e6) is ours at clock_offset_s + clock_rate · t.
    clock_offset_s: float | None = None
    clock_round_trip_ms: float | None = None
    clock_source: str = ""
    #: PX4's local-frame origin in the world (ENU) and where it came from.
    origin_m: list[float] = field(default_factory=list)
    origin_source: str = ""
    landed_states: list[str] = field(default_factory=list)
    garbage: int = 0
    foreign: int = 0
    #: Valid frames of messages outside the common dialect, by id (PX4 sends four such).
    unknown_ids: dict[str, int] = field(default_factory=dict)
    #: Each phase and when it began [s after start()], e.g. "3.41 s: flying".
    phases: list[str] = field(default_factory=list)
    commands: list[dict[str, Any]] = field(default_factory=list)
    modes: list[str] = field(default_factory=list)
    status_texts: list[str] = field(default_factory=list)


def _position_sigma(pose_covariance: Sequence[float]) -> tuple[float, float]:
    """(horizontal, vertical) 1σ [m] from ODOMETRY's ``pose_covariance`` (the upper triangle
    of a 6×6, row-major: x, y, z variances at 0, 6, 11; PX4's ``streams/ODOMETRY.hpp``); NaN
    where it states none (NaN, negative, or absurd)."""
    try:
        var_x, var_y, var_z = (float(pose_covariance[i]) for i in (0, 6, 11))
    except (TypeError, IndexError, ValueError):
        return math.nan, math.nan

    def sigma(var: float) -> float:
        return math.sqrt(var) if math.isfinite(var) and 0.0 <= var < 1e6 else math.nan

    return sigma(max(var_x, var_y)), sigma(var_z)


class Px4Vehicle:
    """One PX4 vehicle over MAVLink, as the node sees it.

    Args:
        address: where the autopilot talks (``udp://:14540`` listens, as PX4 SITL expects of an
            offboard API; ``udpout://HOST:PORT`` sends).
        airframe: the vehicle's mass (thrust normalisation) and, without a hover thrust from
            the autopilot, its thrust range.
        setpoints: ``"attitude"`` (SET_ATTITUDE_TARGET from our SE(3) controller) or
            ``"position"`` (SET_POSITION_TARGET_LOCAL_NED with the tracker's p, v, a, heading;
            PX4's own position controller flies it).
        system_id: the autopilot's MAVLink system id (None: the first autopilot heard).
        hover_thrust: normalised hover thrust in (0, 1) (None: read ``MPC_THR_HOVER`` from
            the autopilot, else the airframe's m·g / T_max).
        origin_m: the ENU world position of the autopilot's local-frame origin.
        offboard_after_s: how long to stream setpoints before asking for offboard (PX4 needs
            more than 1 s).
        estimate_timeout_s: estimate age beyond which the node sends position setpoints
            instead of flying the estimate.
        estimate_lost_s: estimate age that stops the commanding.
        geo_origin: (latitude [deg], longitude [deg], altitude [m AMSL]) of the swarm's ENU
            origin; with it, ``origin_m`` is placed from the autopilot's ``GPS_GLOBAL_ORIGIN``
            (its estimator's origin) instead of being given.
    """

    def __init__(self, address: str, airframe: Airframe, *, setpoints: str = "attitude",
                 system_id: int | None = None, hover_thrust: float | None = None,
                 origin_m: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
                 offboard_after_s: float = OFFBOARD_STREAM_S + 0.2,
                 estimate_timeout_s: float = ESTIMATE_TIMEOUT_S,
                 estimate_lost_s: float = ESTIMATE_LOST_S,
                 own_system_id: int | None = None,
                 geo_origin: tuple[float, float, float] | None = None) -> None:
        if setpoints not in SETPOINT_MODES:
            raise ValueError(f"setpoints: must be one of {SETPOINT_MODES}, got {setpoints!r}")
        if hover_thrust is not None and not 0.0 < float(hover_thrust) < 1.0:
            raise ValueError(f"hover_thrust: must be in (0, 1), got {hover_thrust!r}")
        origin = np.asarray(origin_m, dtype=float)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"origin_m: must be 3 finite numbers, got {origin_m!r}")
        if system_id is not None and not 1 <= int(system_id) <= 255:
            raise ValueError(f"system_id: must be in 1..255, got {system_id!r}")
        if geo_origin is not None:
            geodetic_to_enu(*geo_origin, origin=geo_origin)  # raises naming a bad value
            self.geo_origin: tuple[float, float, float] | None = (
                float(geo_origin[0]), float(geo_origin[1]), float(geo_origin[2]))
        else:
            self.geo_origin = None
        self.airframe = airframe
        self.setpoints = setpoints
        self.origin_m = origin
        self.offboard_after_s = float(offboard_after_s)
        self.estimate_timeout_s = float(estimate_timeout_s)
        self.estimate_lost_s = float(estimate_lost_s)
        if not 0.0 < self.estimate_timeout_s <= self.estimate_lost_s:
            raise ValueError(f"estimate_timeout_s ({estimate_timeout_s!r}) must be positive and "
                             f"at most estimate_lost_s ({estimate_lost_s!r})")
        self.system_id = None if system_id is None else int(system_id)
        self.component_id = 1
        # A companion computer shares its autopilot's system id; before we know it, 245.
        self.link = MavlinkEndpoint(address, system_id=own_system_id or self.system_id or 245,
                                    component_id=ONBOARD_COMPONENT)
        self.report_data = Px4Report(setpoint_mode=setpoints, system_id=self.system_id)
        self.hover_thrust = None if hover_thrust is None else float(hover_thrust)
        if self.hover_thrust is not None:
            self.report_data.hover_thrust_source = "given"
        self.phase = Phase.CONNECTING
        self.armed = False
        self.mode: Px4Mode | None = None
        self.landed_state = 0  # MAV_LANDED_STATE_UNDEFINED until the autopilot says
        self._ground_seen = False  # the land detector said on ground since our landing began
        self.last_heartbeat_s = -math.inf
        self.clock = ClockMap()
        self._odom: tuple[float, VehicleState] | None = None  # (receipt wall time, state)
        #: The estimate's (horizontal, vertical) 1σ from ODOMETRY's covariances [m]; NaN
        #: until an ODOMETRY states them (PX4 fills the diagonal with EKF2's variances).
        self.position_sigma_m = (math.nan, math.nan)
        self._lpn: tuple[float, LocalPositionNedMsg] | None = None  # (receipt, message)
        self._att: tuple[float, AttitudeQuaternionMsg] | None = None
        self._origin_known = geo_origin is None
        self._next_gcs_s = -math.inf
        self._next_timesync_s = -math.inf
        #: The armed flag / mode an accepted ACK set, and HEARTBEATs seen since it.
        self._acked_armed: bool | None = None
        self._acked_mode: Px4Mode | None = None
        self._heartbeats_since_ack = 0
        self._pending: _Command | None = None
        self._texts: list[tuple[float, str]] = []  # (arrival, STATUSTEXT)
        self._command_sent_s = math.inf  # when the current request was sent
        self._refused_s: float | None = None  # when the refused command was sent
        self._phase_s = 0.0
        self._first_request_s = 0.0
        self._stream_start_s: float | None = None
        self._mode_accepted_s: float | None = None
        self._offboard_seen = False
        self._ground_z_m: float | None = None
        self._landed_since_s: float | None = None
        self._last_send_s: float | None = None
        self._periods: list[float] = []
        self._ages: list[float] = []
        self._fallback_since_s: float | None = None
        self._t0_s = time.time()
        self._connected = False

    # ------------------------------------------------------------------ what the node uses
    @property
    def commanding(self) -> bool:
        """True while our setpoints go out (before offboard too: PX4 needs the stream).
        The first goes out at the first :meth:`actuate` with a fresh estimate."""
        return self.phase not in (Phase.CONNECTING, Phase.LANDED, Phase.STOPPED)

    @property
    def flying(self) -> bool:
        """Armed in offboard and ours to fly (the node may take off and fly its mission)."""
        return self.phase == Phase.FLYING

    @property
    def done(self) -> bool:
        """Landed and disarmed, or stopped and disarmed (by PX4's failsafe, or a pilot):
        nothing left to do."""
        return self.phase == Phase.LANDED or (self.phase == Phase.STOPPED and not self.armed)

    @property
    def ground_z_m(self) -> float:
        """World height of the point we took off from (where landing ends)."""
        return 0.0 if self._ground_z_m is None else self._ground_z_m

    def start(self, timeout_s: float = 20.0) -> VehicleState:
        """Wait for the autopilot's HEARTBEAT, a fresh estimate on our clock, its hover thrust
        and (with ``geo_origin``) its estimator's global origin; return the first estimate.

        What queued on the socket before this call is dropped: a first run compiles kernels
        for a minute after the socket opened, and that minute's estimates are history.

        Raises:
            VehicleLost: nothing usable within ``timeout_s`` (the message says what is missing).
        """
        self.link.drain()
        self._t0_s = time.time()
        t_end = self._t0_s + timeout_s
        requested = origin_requested = -math.inf
        est = None
        while time.time() < t_end:
            now = time.time()
            self.poll(now)
            self._send_periodic(now)
            if self.system_id is not None and self.hover_thrust is None \
                    and now - requested > 0.5:
                requested = now
                self.link.send(_M.MAVLink_param_request_read_message(
                    self.system_id, self.component_id, b"MPC_THR_HOVER", -1))
            if self.system_id is not None and not self._origin_known \
                    and now - origin_requested > 0.5:
                origin_requested = now
                self.link.send(_M.MAVLink_command_long_message(
                    self.system_id, self.component_id, _M.MAV_CMD_REQUEST_MESSAGE, 0,
                    float(_M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN), 0, 0, 0, 0, 0, 0))
            est = self.estimate(now)
            if est is not None and self._origin_known and self.hover_thrust is None \
                    and now - self._t0_s > 3.0:  # the autopilot kept its parameter
                self.hover_thrust = self.airframe.mass_kg * 9.80665 / self.airframe.max_thrust_n
                self.report_data.hover_thrust_source = "airframe (MPC_THR_HOVER not answered)"
            if est is not None and self.hover_thrust is not None and self._origin_known \
                    and math.isfinite(self.last_heartbeat_s):
                break
            self.link.wait(0.02)
        else:
            raise VehicleLost(f"{self._missing(est)} on {self.link.address} within "
                              f"{timeout_s:g} s")
        assert est is not None
        self.report_data.hover_thrust = self.hover_thrust
        self.report_data.origin_m = [round(float(v), 3) for v in self.origin_m]
        self.report_data.origin_source = self.report_data.origin_source or "given (--origin)"
        self._ground_z_m = float(est.position_m[2])
        self._connected = True
        return est

    def _missing(self, est: VehicleState | None) -> str:
        """What :meth:`start` still waits for, in words."""
        if self.system_id is None or not math.isfinite(self.last_heartbeat_s):
            return "no HEARTBEAT from an autopilot"
        if not self._origin_known:
            return ("no GPS_GLOBAL_ORIGIN (the autopilot's estimator has no global position "
                    "yet; --geo-origin needs one)")
        if self._odom is None and (self._lpn is None or self._att is None):
            return "no ODOMETRY or LOCAL_POSITION_NED + ATTITUDE_QUATERNION"
        if est is None:
            return (f"estimates arrive but none is younger than {self.estimate_timeout_s:g} s "
                    "on our clock (no TIMESYNC answer, and the stamps do not map)")
        return "no hover thrust"

    def _send_periodic(self, now_s: float) -> None:
        """Our 1 Hz ground-station HEARTBEAT and the TIMESYNC requests (once the autopilot
        is known: a listening endpoint has nobody to send to before)."""
        if self.system_id is None:
            return
        if now_s >= self._next_gcs_s:
            self._next_gcs_s = now_s + GCS_HEARTBEAT_S
            self.link.send(_M.MAVLink_heartbeat_message(
                _M.MAV_TYPE_GCS, _M.MAV_AUTOPILOT_INVALID, 0, 0, _M.MAV_STATE_ACTIVE, 3))
        if now_s >= self._next_timesync_s:
            self._next_timesync_s = now_s + TIMESYNC_S
            self.link.send(_M.MAVLink_timesync_message(0, time.time_ns()))

    def update(self, now_s: float) -> VehicleState | None:
        """Take what arrived, advance the life cycle; the fresh estimate, or None."""
        self.poll(now_s)
        self._send_periodic(now_s)
        est = self.estimate(now_s)
        if est is None and self._connected:
            self.report_data.ticks_without_estimate += 1
        self._advance(now_s, est)
        return est

    def actuate(self, now_s: float, target: AttitudeTarget, command: TrackerCommand) -> None:
        """Send the setpoint of this tick (when commanding): the attitude target, or the
        tracker's ``command`` (p, v, a, heading) in position mode and whenever the estimate is
        not fresh (our attitude would be flown on an old state; PX4's is fresh)."""
        if self.phase == Phase.CONNECTING and self._connected \
                and self.estimate(now_s) is not None:
            self._enter(Phase.STREAMING, now_s)  # the stream (and our failsafes) start here
        if not self.commanding or self.system_id is None:
            return
        msg: SetAttitudeTargetMsg | SetPositionTargetLocalNedMsg
        if self.setpoints == "attitude" and self.estimate(now_s) is not None:
            msg = self.attitude_target_message(now_s, target)
        else:  # position mode, or no fresh estimate to fly our attitude on: PX4 flies it
            msg = self.position_target_message(now_s, command)
        if not self.link.send(msg):
            return
        self.report_data.setpoints_sent += 1
        if self._stream_start_s is None:
            self._stream_start_s = now_s
        if self._last_send_s is not None:
            self._periods.append(now_s - self._last_send_s)
        self._last_send_s = now_s
        if self._odom is not None:  # estimate-to-setpoint latency: from the sample's time
            self._ages.append(now_s - self._odom[1].t_s)

    def _time_boot_ms(self, now_s: float) -> int:
        return int((now_s - self._t0_s) * 1e3) & 0xFFFFFFFF

    def attitude_target_message(self, now_s: float,
                                target: AttitudeTarget) -> SetAttitudeTargetMsg:
        """The SET_ATTITUDE_TARGET that flies our SE(3) controller's attitude and thrust
        (built, not sent)."""
        assert self.hover_thrust is not None, "the hover thrust is known from start()"
        attitude = target.attitude_wxyz
        thrust = float(np.clip(target.thrust_n / (self.airframe.mass_kg * 9.80665)
                               * self.hover_thrust, 0.0, 1.0))
        if self.phase in (Phase.LANDING, Phase.DISARMING) \
                and thrust < TOUCHDOWN_THRUST_FRACTION * self.hover_thrust:
            # Pushed into the ground, the SE(3) law's thrust vector is small and its
            # direction is its horizontal terms: up to the tilt limit, a vehicle rocking on
            # its legs, which PX4's land detector reads as rotation (landings took a minute).
            # Level, as PX4's position controller is on ground contact.
            attitude = yaw_quat(float(heading_of(attitude)))
        q = enu_flu_quat_to_ned_frd(attitude)
        rates = flu_to_frd(target.body_rates_ff_radps)  # only the yaw rate is used
        msg: SetAttitudeTargetMsg = _M.MAVLink_set_attitude_target_message(
            self._time_boot_ms(now_s), self.system_id, self.component_id, _ATT_TYPE_MASK,
            q.tolist(), float(rates[0]), float(rates[1]), float(rates[2]), thrust)
        return msg

    def position_target_message(self, now_s: float,
                                command: TrackerCommand) -> SetPositionTargetLocalNedMsg:
        """The SET_POSITION_TARGET_LOCAL_NED that flies the tracker's p, v, a and heading
        (built, not sent)."""
        p = enu_to_ned(np.asarray(command.position_m) - self.origin_m)
        v = enu_to_ned(command.velocity_mps)
        a = enu_to_ned(command.acceleration_mps2)
        msg: SetPositionTargetLocalNedMsg = _M.MAVLink_set_position_target_local_ned_message(
            self._time_boot_ms(now_s), self.system_id, self.component_id,
            _M.MAV_FRAME_LOCAL_NED, _POS_TYPE_MASK,
            *map(float, p), *map(float, v), *map(float, a),
            heading_enu_to_ned(command.heading_rad), -float(command.heading_rate_radps))
        return msg

    def land(self, now_s: float) -> None:
        """The mission is over: the node now flies down; disarm when on the ground."""
        if self.phase == Phase.FLYING:
            self._enter(Phase.LANDING, now_s)
        elif self.commanding:  # not airborne yet: nothing to land
            self._stop(now_s, "stopped before take-off")

    def abort(self, now_s: float, reason: str) -> None:
        """Stop commanding now (PX4 then fails safe after COM_OF_LOSS_T)."""
        if self.commanding:
            self._stop(now_s, reason)

    def report(self) -> dict[str, Any]:
        r = self.report_data
        r.phase = self.phase.value
        said = self._said_about_refusal()
        if said and r.stop_reason is not None and said not in r.stop_reason:
            r.stop_reason = f"{r.stop_reason} ({said})"
        r.garbage = self.link.garbage
        r.unknown_ids = {str(k): v for k, v in sorted(self.link.unknown_ids.items())}
        r.clock_rate = round(self.clock.rate, 6)
        if self.clock.synced:
            r.clock_offset_s = self.clock.to_local(0.0)
        if math.isfinite(self.clock.round_trip_s):
            r.clock_round_trip_ms = round(self.clock.round_trip_s * 1e3, 3)
        r.clock_source = ("TIMESYNC round trips" if math.isfinite(self.clock.round_trip_s)
                          else "message stamps (no TIMESYNC answer)")
        if self._periods:
            ms = np.array(self._periods) * 1e3
            r.setpoint_period_p50_ms = float(np.median(ms))
            r.setpoint_period_p99_ms = float(np.percentile(ms, 99))
            r.setpoint_period_max_ms = float(ms.max())
        if self._ages:
            ms = np.array(self._ages) * 1e3
            r.estimate_age_p50_ms = float(np.median(ms))
            r.estimate_age_p99_ms = float(np.percentile(ms, 99))
        return {k: getattr(r, k) for k in r.__dataclass_fields__}

    def close(self) -> None:
        self.link.close()

    # ------------------------------------------------------------------ receiving
    def poll(self, now_s: float) -> None:
        """Handle what arrived (bounded); anything not from our autopilot is counted, ignored."""
        for msg, sender, arrived_s in self.link.receive():
            kind = msg.get_type()
            sysid = msg.get_srcSystem()
            if self.system_id is None:
                if kind != "HEARTBEAT" or msg.autopilot == _M.MAV_AUTOPILOT_INVALID \
                        or msg.get_srcComponent() != 1:
                    self.report_data.foreign += 1
                    continue
                self.system_id = sysid
                self.link.mav.srcSystem = sysid
                self.report_data.system_id = sysid
            if sysid != self.system_id or msg.get_srcComponent() != self.component_id:
                self.report_data.foreign += 1
                continue
            self.link.trust(sender)
            handler = _HANDLERS.get(kind)
            if handler is not None:
                handler(self, msg, arrived_s)

    def _on_heartbeat(self, msg: HeartbeatMsg, now_s: float) -> None:
        if msg.type == _M.MAV_TYPE_GCS or msg.autopilot == _M.MAV_AUTOPILOT_INVALID:
            return  # not the autopilot's own (e.g. another component on its id)
        self.report_data.heartbeats_received += 1
        self.last_heartbeat_s = now_s
        armed = bool(msg.base_mode & _M.MAV_MODE_FLAG_SAFETY_ARMED)
        mode = Px4Mode.decode(msg.custom_mode)
        self._heartbeats_since_ack += 1
        behind = ((self._acked_armed is not None and armed != self._acked_armed)
                  or (self._acked_mode is not None and mode != self._acked_mode))
        if behind and self._heartbeats_since_ack < HEARTBEATS_TO_CONTRADICT:
            self.report_data.heartbeats_behind_ack += 1
            return  # sent before the change the ACK confirmed
        self._acked_armed = self._acked_mode = None
        self.armed = armed
        self._set_mode(mode, now_s)

    def _set_mode(self, mode: Px4Mode, now_s: float) -> None:
        if mode != self.mode:
            self.report_data.modes.append(f"{now_s - self._t0_s:.2f} s: {mode}")
        self.mode = mode

    def _on_timesync(self, msg: TimesyncMsg, now_s: float) -> None:
        if msg.tc1 == 0:  # the autopilot's own request: answer with our time, as PX4 expects
            self.link.send(_M.MAVLink_timesync_message(time.time_ns(), msg.ts1))
            return
        # An answer to one of ours: ts1 is our send time [ns], tc1 its time [ns].
        self.clock.add_round_trip(msg.ts1 * 1e-9, msg.tc1 * 1e-9, now_s)

    def _on_global_origin(self, msg: GpsGlobalOriginMsg, now_s: float) -> None:
        if self.geo_origin is None or self._origin_known:
            return
        lat, lon, alt = msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3
        self.origin_m = geodetic_to_enu(lat, lon, alt, origin=self.geo_origin)
        self._origin_known = True
        self.report_data.origin_source = (f"GPS_GLOBAL_ORIGIN {lat:.7f}, {lon:.7f}, {alt:.2f} m "
                                          f"against --geo-origin")

    def _on_odometry(self, msg: OdometryMsg, now_s: float) -> None:
        if msg.frame_id not in (_M.MAV_FRAME_LOCAL_NED, _M.MAV_FRAME_LOCAL_FRD):
            self.report_data.foreign += 1  # not a local-frame odometry we know how to read
            return
        q_ned = np.array(msg.q, dtype=float)
        vals = np.array([msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.rollspeed,
                         msg.pitchspeed, msg.yawspeed], dtype=float)
        if not (np.all(np.isfinite(vals)) and np.all(np.isfinite(q_ned))
                and abs(np.linalg.norm(q_ned) - 1.0) < 1e-2):
            return  # the estimator has no valid solution
        q_ned /= np.linalg.norm(q_ned)
        v_ned = vals[3:6]
        if msg.child_frame_id in _ODOMETRY_CHILD_BODY:  # velocity given in the body frame
            v_ned = quat_to_rot(q_ned) @ v_ned
        self.clock.add_one_way(msg.time_usec * 1e-6, now_s)
        t = self.clock.to_local(msg.time_usec * 1e-6)
        if not math.isfinite(t) or not self._origin_known:
            return  # an estimate placed before its frame's origin is known would be wrong
        self.report_data.odometry_received += 1
        self.position_sigma_m = _position_sigma(msg.pose_covariance)
        self._odom = (now_s, VehicleState(
            t_s=t, position_m=self.origin_m + ned_to_enu(vals[0:3]),
            velocity_mps=ned_to_enu(v_ned), attitude_wxyz=ned_frd_quat_to_enu_flu(q_ned),
            body_rates_radps=frd_to_flu(vals[6:9])))

    def _on_local_position(self, msg: LocalPositionNedMsg, now_s: float) -> None:
        self.clock.add_one_way(msg.time_boot_ms * 1e-3, now_s)
        self._lpn = (now_s, msg)

    def _on_attitude(self, msg: AttitudeQuaternionMsg, now_s: float) -> None:
        self._att = (now_s, msg)

    def _on_ack(self, msg: CommandAckMsg, now_s: float) -> None:
        cmd = self._pending
        if cmd is None or msg.command != cmd.command or cmd.result is not None:
            return  # not ours, or a second ACK (PX4 answers DO_SET_MODE twice)
        if msg.result == _M.MAV_RESULT_IN_PROGRESS:
            return
        cmd.result = int(msg.result)
        if cmd.result == _M.MAV_RESULT_ACCEPTED:
            # The ACK is the news; the 1 Hz HEARTBEAT may tell the old state for a second.
            self._heartbeats_since_ack = 0
            if cmd.command == _M.MAV_CMD_COMPONENT_ARM_DISARM:
                self.armed = self._acked_armed = cmd.params[0] > 0.5
            elif cmd.command == _M.MAV_CMD_DO_SET_MODE:
                mode = Px4Mode(int(cmd.params[1]), int(cmd.params[2]))
                self._acked_mode = mode
                self._set_mode(mode, now_s)
        self.report_data.commands.append({
            "t_s": round(now_s - self._t0_s, 3), "command": command_name(cmd.command),
            "params": list(cmd.params[:3]), "result": result_name(msg.result),
            "attempts": cmd.attempts})

    def _on_param(self, msg: ParamValueMsg, now_s: float) -> None:
        name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else ""
        if name == "MPC_THR_HOVER" and self.hover_thrust is None \
                and 0.0 < msg.param_value < 1.0:
            self.hover_thrust = float(msg.param_value)
            self.report_data.hover_thrust_source = "MPC_THR_HOVER"

    def _on_extended_state(self, msg: ExtendedSysStateMsg, now_s: float) -> None:
        if int(msg.landed_state) != self.landed_state:
            name = mavlink.enums["MAV_LANDED_STATE"].get(int(msg.landed_state))
            self.report_data.landed_states.append(
                f"{now_s - self._t0_s:.2f} s: "
                f"{name.name.removeprefix('MAV_LANDED_STATE_') if name else msg.landed_state}")
        self.landed_state = int(msg.landed_state)
        if self.phase in (Phase.LANDING, Phase.DISARMING) \
                and self.landed_state == _M.MAV_LANDED_STATE_ON_GROUND:
            self._ground_seen = True

    def _on_status_text(self, msg: StatusTextMsg, now_s: float) -> None:
        text = msg.text.rstrip("\x00") if isinstance(msg.text, str) else repr(msg.text)
        self.report_data.status_texts.append(f"{now_s - self._t0_s:.2f} s: {text}")
        del self.report_data.status_texts[:-20]
        self._texts.append((now_s, text))
        del self._texts[:-20]

    def estimate(self, now_s: float) -> VehicleState | None:
        """The latest estimate if younger than ``estimate_timeout_s``, else None."""
        est = self.latest_estimate()
        if est is None or now_s - est.t_s > self.estimate_timeout_s:
            return None
        return est

    def latest_estimate(self) -> VehicleState | None:
        """The autopilot's latest estimate on our clock, however old (None: none yet)."""
        est = None
        if self._odom is not None:
            est = self._odom[1]
        elif self._lpn is not None and self._att is not None and self._origin_known:
            (_, p), (_, a) = self._lpn, self._att
            q_ned = np.array([a.q1, a.q2, a.q3, a.q4])
            t_s = min(self.clock.to_local(p.time_boot_ms * 1e-3),
                      self.clock.to_local(a.time_boot_ms * 1e-3))
            if not math.isfinite(t_s):
                return None
            est = VehicleState(
                t_s=t_s,
                position_m=self.origin_m + ned_to_enu(np.array([p.x, p.y, p.z])),
                velocity_mps=ned_to_enu(np.array([p.vx, p.vy, p.vz])),
                attitude_wxyz=ned_frd_quat_to_enu_flu(q_ned / np.linalg.norm(q_ned)),
                body_rates_radps=frd_to_flu(np.array([a.rollspeed, a.pitchspeed,
                                                      a.yawspeed])))
        return est

    # ------------------------------------------------------------------ the life cycle
    def _enter(self, phase: Phase, now_s: float) -> None:
        if phase != self.phase:
            self.report_data.phases.append(f"{now_s - self._t0_s:.2f} s: {phase.value}")
        self.phase = phase
        self._phase_s = now_s

    def _stop(self, now_s: float, reason: str) -> None:
        self.report_data.stop_reason = reason
        self._pending = None
        self._enter(Phase.STOPPED, now_s)

    def _send_command(self, now_s: float, command: int, *params: float) -> None:
        p = (list(params) + [0.0] * 7)[:7]
        self._command_sent_s = now_s
        self._pending = _Command(command, tuple(p), now_s)
        self._transmit(self._pending)

    def _transmit(self, cmd: _Command) -> None:
        assert self.system_id is not None
        self.link.send(_M.MAVLink_command_long_message(
            self.system_id, self.component_id, cmd.command, cmd.attempts - 1, *cmd.params))

    def _command_state(self, now_s: float) -> str:
        """``"waiting"``, ``"accepted"``, ``"rejected"`` or ``"lost"`` (no ACK at all)."""
        cmd = self._pending
        assert cmd is not None
        if cmd.result is not None:
            return "accepted" if cmd.result == _M.MAV_RESULT_ACCEPTED else "rejected"
        if now_s - cmd.sent_s > COMMAND_RETRY_S:
            if cmd.attempts >= COMMAND_ATTEMPTS:
                self.report_data.commands.append({
                    "t_s": round(now_s - self._t0_s, 3), "command": command_name(cmd.command),
                    "params": list(cmd.params[:3]), "result": "no COMMAND_ACK",
                    "attempts": cmd.attempts})
                return "lost"
            cmd.attempts += 1
            cmd.sent_s = now_s
            self._transmit(cmd)
        return "waiting"

    def _advance(self, now_s: float, est: VehicleState | None) -> None:
        if not self.commanding:
            return
        if now_s - self.last_heartbeat_s > HEARTBEAT_TIMEOUT_S:
            self._stop(now_s, f"link lost: no HEARTBEAT for {HEARTBEAT_TIMEOUT_S:g} s")
            return
        if est is None and self.phase in (Phase.LANDING, Phase.DISARMING) \
                and not self.armed and self._ground_seen:
            # Landed and disarmed by the autopilot: no estimate is needed any more. (Found in
            # CI on a loaded machine: an estimate 0.205 s old after "Disarmed by landing"
            # reported a landed vehicle as stopped.)
            self._pending = None
            self._enter(Phase.LANDED, now_s)
            return
        if est is None:
            latest = self.latest_estimate()
            age = now_s - latest.t_s if latest is not None else math.inf
            if age > self.estimate_lost_s:
                self._end_fallback(now_s)
                self._stop(now_s, f"estimate lost: the last is {age:.3f} s old "
                                  f"(limit {self.estimate_lost_s:g} s)")
                return
        if self._offboard_seen and self.mode is not None and not self.mode.is_offboard:
            self._end_fallback(now_s)
            self._stop(now_s, f"the autopilot left offboard (now {self.mode})")
            return
        if self.phase in (Phase.FLYING, Phase.LANDING, Phase.DISARMING) and not self.armed:
            self._end_fallback(now_s)
            if self.phase != Phase.FLYING and (
                    self._ground_seen or (est is not None and self._autopilot_says_landed(est))):
                self._pending = None  # its own auto-disarm after landing (COM_DISARM_LAND)
                self._enter(Phase.LANDED, now_s)
            else:
                self._stop(now_s, "the autopilot disarmed")
            return
        if est is None:  # bridged by position setpoints (actuate); the life cycle waits
            if self._fallback_since_s is None:
                self._fallback_since_s = now_s
                self.report_data.position_fallbacks += 1
            return
        self._end_fallback(now_s)
        if self.mode is not None and self.mode.is_offboard:
            self._offboard_seen = True
        getattr(self, f"_in_{self.phase.value}")(now_s, est)

    def _end_fallback(self, now_s: float) -> None:
        if self._fallback_since_s is None:
            return
        spell = now_s - self._fallback_since_s
        self._fallback_since_s = None
        r = self.report_data
        r.position_fallback_s = round(r.position_fallback_s + spell, 3)
        r.position_fallback_max_s = round(max(r.position_fallback_max_s, spell), 3)

    def _in_streaming(self, now_s: float, est: VehicleState) -> None:
        if self._stream_start_s is None or now_s - self._stream_start_s < self.offboard_after_s:
            return
        if now_s - self._phase_s < RETRY_S and self.report_data.commands:
            return  # after a refusal: wait before asking again
        if not self._first_request_s:
            self._first_request_s = now_s
        self._send_command(now_s, _M.MAV_CMD_DO_SET_MODE,
                           float(_M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(OFFBOARD.main),
                           float(OFFBOARD.sub))
        self._enter(Phase.OFFBOARD, now_s)

    def _in_offboard(self, now_s: float, est: VehicleState) -> None:
        if self._pending is not None:
            state = self._command_state(now_s)
            if state == "waiting":
                return
            if state != "accepted":
                self._pending = None
                if now_s - self._first_request_s > GIVE_UP_S:
                    self._stop(now_s, "the autopilot refused offboard for "
                                      f"{GIVE_UP_S:g} s: {self._last_result()}")
                else:
                    self._enter(Phase.STREAMING, now_s)  # keep streaming, ask again
                return
            self._pending = None
            self._mode_accepted_s = now_s
        if self._offboard_seen:
            self._send_command(now_s, _M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            self._enter(Phase.ARMING, now_s)
        elif self._mode_accepted_s is not None and now_s - self._mode_accepted_s > MODE_CONFIRM_S:
            self._stop(now_s, "offboard was accepted but the HEARTBEAT never showed it")

    def _in_arming(self, now_s: float, est: VehicleState) -> None:
        self._arm_or_disarm(now_s, True, Phase.FLYING, self._first_request_s)

    def _in_flying(self, now_s: float, est: VehicleState) -> None:
        pass

    def _autopilot_says_landed(self, est: VehicleState) -> bool:
        """Landed by the autopilot's land detector (PX4's EXTENDED_SYS_STATE); only an
        autopilot that never reports it is judged by its estimate (height and speed)."""
        if self.landed_state != _M.MAV_LANDED_STATE_UNDEFINED:
            return bool(self.landed_state == _M.MAV_LANDED_STATE_ON_GROUND)
        return (est.position_m[2] - self.ground_z_m < LANDED_HEIGHT_M
                and float(np.linalg.norm(est.velocity_mps)) < LANDED_SPEED_MPS)

    def _in_landing(self, now_s: float, est: VehicleState) -> None:
        # The node keeps descending at its flare speed through the ground: a commanded descent
        # with no vertical movement is what PX4's land detector calls ground contact.
        if not self._autopilot_says_landed(est):
            self._landed_since_s = None
            return
        if self._landed_since_s is None:
            self._landed_since_s = now_s
        if now_s - self._landed_since_s >= LANDED_HOLD_S:
            self._send_command(now_s, _M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
            self._enter(Phase.DISARMING, now_s)

    def _in_disarming(self, now_s: float, est: VehicleState) -> None:
        assert self._landed_since_s is not None
        self._arm_or_disarm(now_s, False, Phase.LANDED, self._landed_since_s)

    def _arm_or_disarm(self, now_s: float, arm: bool, then: Phase, since_s: float) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM until accepted, then ``then``. "Temporarily rejected"
        (e.g. no offboard signal yet) is asked again every RETRY_S until GIVE_UP_S after
        ``since_s``; a denial, an unsupported command or silence ends the attempt."""
        if self._pending is None:
            if now_s - self._phase_s >= RETRY_S:
                self._send_command(now_s, _M.MAV_CMD_COMPONENT_ARM_DISARM, float(arm))
            return
        state = self._command_state(now_s)
        if state == "waiting":
            return
        result = self._pending.result
        self._pending = None
        if state == "accepted":
            self._enter(then, now_s)
        elif result == _M.MAV_RESULT_TEMPORARILY_REJECTED and now_s - since_s <= GIVE_UP_S:
            self._phase_s = now_s
        elif arm:
            self._stop(now_s, f"arming refused: {self._last_result()}")
        else:
            self._stop(now_s, f"disarm refused: {self._last_result()}; the autopilot's "
                              f"auto-disarm or the pilot (force: param2 = {FORCE_DISARM:g}) "
                              "must end it")

    def _last_result(self) -> str:
        """The last command's result; :meth:`report` adds what the autopilot said about it."""
        if not self.report_data.commands:
            return "?"
        self._refused_s = self._command_sent_s
        return str(self.report_data.commands[-1]["result"])

    def _said_about_refusal(self) -> str:
        """PX4's STATUSTEXT from the refused command's sending to a second after the stop
        (PX4 queues its texts: they may arrive after the ACK)."""
        if self._refused_s is None:
            return ""
        until = self._phase_s + 1.0
        texts = [t for t_s, t in self._texts if self._refused_s - 0.05 <= t_s <= until]
        return "; ".join(f'PX4: "{t}"' for t in texts[-3:])


#: By message name: pymavlink's message of that name has the fields its handler reads.
_HANDLERS: dict[str, Callable[[Px4Vehicle, mavlink.MAVLink_message, float], None]] = {
    "HEARTBEAT": Px4Vehicle._on_heartbeat,
    "ODOMETRY": Px4Vehicle._on_odometry,
    "LOCAL_POSITION_NED": Px4Vehicle._on_local_position,
    "ATTITUDE_QUATERNION": Px4Vehicle._on_attitude,
    "COMMAND_ACK": Px4Vehicle._on_ack,
    "PARAM_VALUE": Px4Vehicle._on_param,
    "EXTENDED_SYS_STATE": Px4Vehicle._on_extended_state,
    "STATUSTEXT": Px4Vehicle._on_status_text,
    "TIMESYNC": Px4Vehicle._on_timesync,
    "GPS_GLOBAL_ORIGIN": Px4Vehicle._on_global_origin,
}
