"""A stand-in for a PX4 v1.16 autopilot: our plant behind a MAVLink endpoint, with PX4's rules.

``uavmpc sitl`` is a test double for users without a vehicle (and for our tests). Its plant is
our multirotor (attitude loop, motors, rigid body, ground contact); around it sit the parts of
PX4 an offboard companion meets. Each rule below was measured against PX4 v1.16 SITL on this
project's machine and read in PX4's source (paths relative to PX4/PX4-Autopilot; the stored
copies read were close to, not exactly, v1.16):

- HEARTBEAT is a constant 1 Hz stream, never sent on a change: after an arm or mode
  ``COMMAND_ACK`` it shows the old state for up to 1 s
  → ``src/modules/mavlink/mavlink_main.cpp`` ("HEARTBEAT is constant rate stream").
- Onboard-link streams: ATTITUDE 100 Hz; HIGHRES_IMU, ATTITUDE_QUATERNION, GLOBAL_POSITION_INT
  50 Hz; ODOMETRY and LOCAL_POSITION_NED 30 Hz; TIMESYNC, ALTITUDE, ATTITUDE_TARGET,
  POSITION_TARGET_LOCAL_NED 10 Hz; GPS_RAW_INT 8 Hz; EXTENDED_SYS_STATE, SYS_STATUS 5 Hz;
  HEARTBEAT 1 Hz; and frames of ids 8, 380, 411, 436 (not in pymavlink's ``common``) at 1 Hz
  → ``src/modules/mavlink/mavlink_main.cpp`` (``configure_streams_to_default``, onboard mode).
- ODOMETRY: ``frame_id`` and ``child_frame_id`` LOCAL_NED (velocity in NED), ``time_usec`` the
  estimate's sample time on PX4's clock → ``src/modules/mavlink/streams/ODOMETRY.hpp``.
- The clock: every stamp it sends (``time_usec``, ``time_boot_ms``, TIMESYNC) is its boot
  clock, starting at 0 at its start and running at ``clock_rate`` × the wall clock (lockstep
  SITL's simulated time ran 1.2–1.5 % slow here, so the default is 0.986); its physics and
  every timer (COM_OF_LOSS_T, hysteresis, auto-disarm) run on that clock too.
- TIMESYNC: a request (``tc1`` = 0) is answered at once with ``tc1`` = its time [ns], ``ts1``
  echoed; it sends its own requests at 10 Hz (``tc1`` = 0, ``ts1`` = its time [ns])
  → ``src/modules/mavlink/mavlink_timesync.cpp``, ``src/lib/timesync/Timesync.cpp``,
  ``src/modules/mavlink/streams/TIMESYNC.hpp``.
- The estimate is not the truth: seeded, slowly varying position errors (first-order
  Gauss–Markov, smoothed once so the velocity error is their derivative: horizontal σ 0.15 m,
  vertical σ 0.3 m, correlation 30 s / 20 s) are added to ODOMETRY, LOCAL_POSITION_NED,
  GLOBAL_POSITION_INT, and PX4's position control flies the estimate, so the true vehicle sits
  off by the error (EKF2: ``src/modules/ekf2/EKF2.cpp``; measured, not derived from source).
- Offboard: ``DO_SET_MODE`` is accepted while disarmed and answered with two identical
  ACCEPTED ACKs (measured; not found in the source read); arming in offboard, or switching to
  it armed, needs a setpoint younger than ``COM_OF_LOSS_T`` (1 s); a stream lost for that long
  falls back to Position mode (HEARTBEAT CRITICAL), and without RC the vehicle then descends
  at ``MPC_LAND_SPEED`` and disarms itself after landing; the stream back returns it to
  offboard → ``src/modules/commander/Commander.cpp``,
  ``src/modules/commander/failsafe/failsafe.cpp``.
- Setpoints: ``SET_ATTITUDE_TARGET`` with roll and pitch rates ignored is attitude control,
  the yaw rate a feed-forward, ``thrust_body[2] = -thrust``; ``SET_POSITION_TARGET_LOCAL_NED``
  ignores per axis (an ignored field is NaN in PX4's trajectory setpoint: an ignored position
  axis is not held, an ignored velocity or acceleration is no feed-forward); a message with
  nothing in it is dropped → ``src/modules/mavlink/mavlink_receiver.cpp``.
- Take-off in position control (position offboard, Hold): motors idle for ``COM_SPOOLUP_TIME``
  (1 s) after arming, then, once a setpoint above the estimate asks for it, the upward
  velocity limit ramps from −g / ``MPC_Z_VEL_P_ACC`` to ``MPC_TKO_SPEED`` over
  ``MPC_TKO_RAMP_T`` (3 s): lift-off ≈ 3 s after arming
  → ``src/modules/mc_pos_control/Takeoff/Takeoff.cpp``,
  ``src/modules/mc_pos_control/MulticopterPositionControl.cpp``. Attitude offboard has no
  spool-up or ramp (its setpoints go straight to the attitude controller).
- Ground contact in flight (and before take-off) makes the position controller idle
  (``MPC_THR_MIN``, integrators reset)
  → ``src/modules/mc_pos_control/MulticopterPositionControl.cpp``.
- The land detector, on the applied throttle and the estimate's velocities: ground contact =
  throttle ≤ ``MPC_THR_MIN`` + 0.3 (hover − ``MPC_THR_MIN``), |vz| ≤ ``LNDMC_Z_VEL_MAX`` (× 2.5
  once maybe-landed), horizontal speed ≤ ``LNDMC_XY_VEL_MAX``, and under climb-rate control a
  commanded descent (trajectory vz down > 1.1 × ``LNDMC_Z_VEL_MAX``, measured) until
  maybe-landed; maybe-landed = ground contact held + throttle ≤ ``MPC_THR_MIN`` + 0.1 (hover −
  min) (attitude control: ``MPC_MANTHR_MIN`` + 0.01) + no roll/pitch rotation (``LNDMC_ROT_MAX``);
  landed = maybe-landed held; each state rises after ``LNDMC_TRIG_TIME`` / 3 and falls at once
  → ``src/modules/land_detector/MulticopterLandDetector.cpp``,
  ``src/modules/land_detector/LandDetector.cpp``.
- Disarming needs the detector's landed or maybe-landed, else ``TEMPORARILY_REJECTED`` and
  "Disarming denied: not landed" (force code 21196 overrides); it disarms itself
  ``COM_DISARM_LAND`` (2 s) after landed once it took off (the detector left landed), or
  ``COM_DISARM_PRFLT`` (10 s) after arming if it never did
  → ``src/modules/commander/Commander.cpp``.
- ``EXTENDED_SYS_STATE.landed_state``: ON_GROUND when the detector says landed, else IN_AIR
  (LANDING in AUTO.LAND) → ``src/modules/mavlink/streams/EXTENDED_SYS_STATE.hpp``.
- STATUSTEXT goes out only once a ground station's HEARTBEAT (``MAV_TYPE_GCS``, any system) or
  an onboard controller's of its own system was heard (texts younger than 5 s wait for it)
  → ``src/modules/mavlink/streams/STATUSTEXT.hpp``, ``src/modules/mavlink/mavlink_receiver.cpp``.
- ``MAV_CMD_REQUEST_MESSAGE`` for GPS_GLOBAL_ORIGIN (49), HOME_POSITION (242) and
  AUTOPILOT_VERSION: the message, then an ACCEPTED ACK (DENIED without a global position);
  GPS_GLOBAL_ORIGIN is also sent once at boot → ``src/modules/mavlink/mavlink_receiver.cpp``
  (``handle_request_message_command``), ``src/modules/mavlink/streams/GPS_GLOBAL_ORIGIN.hpp``,
  ``src/modules/mavlink/streams/HOME_POSITION.hpp``.

Geodesy: ``geo_origin_deg`` = (lat, lon, alt AMSL) of the *world's* ENU origin (default PX4
SITL's home, 47.397742°, 8.545594°, 488 m). The stand-in boots at ``position_m`` in that world,
so its estimator origin (GPS_GLOBAL_ORIGIN, HOME_POSITION) is the geodetic point of
``position_m`` by PX4's azimuthal-equidistant projection (``frames.enu_to_geodetic``).

What it does not model (docs/px4.md): rate and thrust-vector setpoints (dropped), PX4's
jerk-limited position smoothing, RC input, preflight checks, geofence, battery, missions and
the take-off mode, the parameter protocol beyond reading a few values, MAVLink signing.
"""

from __future__ import annotations

import math
import signal
import struct
import time
from collections import deque
from dataclasses import dataclass
from typing import cast

import numpy as np

from uavmpc.control.se3 import Se3Controller
from uavmpc.drivers.px4.dialect import (
    COM_OF_LOSS_T_S,
    FORCE_DISARM,
    HOLD,
    LAND,
    OFFBOARD,
    POSCTL,
    CommandMsg,
    HeartbeatMsg,
    MainMode,
    OdometryMsg,
    Px4Mode,
    SetAttitudeTargetMsg,
    SetPositionTargetLocalNedMsg,
    TimesyncMsg,
    mavlink,
)
from uavmpc.drivers.px4.endpoint import MavlinkEndpoint
from uavmpc.drivers.px4.frames import (
    enu_flu_quat_to_ned_frd,
    enu_to_geodetic,
    enu_to_ned,
    flu_to_frd,
    frd_to_flu,
    heading_enu_to_ned,
    heading_ned_to_enu,
    ned_frd_quat_to_enu_flu,
    ned_to_enu,
)
from uavmpc.drivers.px4.truth import TRUTH_RATE_HZ, truth_message
from uavmpc.plant import Airframe, AttitudeTarget, VehicleState
from uavmpc.plant.interface import heading_of, yaw_quat
from uavmpc.plant.multirotor import Multirotor

__all__ = ["PX4_SITL_HOME", "StandInPx4", "run_sitl"]

_M = mavlink
# The MAV_RESULTs a command is answered with (pymavlink's constants have no types).
_ACCEPTED: int = _M.MAV_RESULT_ACCEPTED
_TEMPORARILY_REJECTED: int = _M.MAV_RESULT_TEMPORARILY_REJECTED
_DENIED: int = _M.MAV_RESULT_DENIED
_UNSUPPORTED: int = _M.MAV_RESULT_UNSUPPORTED
#: Physics and control period on PX4's clock [s].
PERIOD_S = 0.01
G = 9.80665
#: Lockstep SITL's clock against the wall clock, as measured here.
CLOCK_RATE = 0.986
#: PX4 SITL's default home (PX4_HOME_LAT/LON/ALT): the world origin unless told otherwise.
PX4_SITL_HOME = (47.397742, 8.545594, 488.0)
#: PX4 defaults the stand-in keeps.
COM_DISARM_LAND_S = 2.0
COM_DISARM_PRFLT_S = 10.0
COM_SPOOLUP_TIME_S = 1.0
MPC_LAND_SPEED_MPS = 0.7
MPC_TKO_RAMP_T_S = 3.0
MPC_TKO_SPEED_MPS = 1.5
MPC_Z_VEL_P_ACC = 4.0
MPC_THR_MIN = 0.12
MPC_MANTHR_MIN = 0.08
LNDMC_Z_VEL_MAX_MPS = 0.25
LNDMC_XY_VEL_MAX_MPS = 1.5
LNDMC_ROT_MAX_DEGPS = 20.0
LNDMC_TRIG_TIME_S = 1.0
#: A commanded descent for the land detector (measured on PX4 v1.16: ≥ 1.1 × LNDMC_Z_VEL_MAX).
DESCENT_VZ_MPS = 1.1 * LNDMC_Z_VEL_MAX_MPS
#: How long a heard ground station counts as connected, and how old a STATUSTEXT may be.
GCS_TIMEOUT_S = 3.0
STATUSTEXT_MAX_AGE_S = 5.0
#: The modes it flies; others are answered MAV_RESULT_UNSUPPORTED.
MODES = (OFFBOARD, HOLD, LAND, POSCTL)
#: Estimator error model: (σ [m], correlation time [s]) horizontal and vertical, and the
#: smoothing time that makes the velocity error the position error's derivative.
EKF_XY = (0.15, 30.0)
EKF_Z = (0.3, 20.0)
EKF_SMOOTH_S = 3.0
#: Stream periods on PX4's clock [s] (ODOMETRY's is the constructor's).
STREAMS_S = {"attitude": 0.01, "imu": 0.02, "attitude_q": 0.02, "global": 0.02,
             "local": 1 / 30, "timesync": 0.1, "altitude": 0.1, "att_target": 0.1,
             "pos_target": 0.1, "gps": 0.125, "extended": 0.2, "sys_status": 0.2,
             "heartbeat": 1.0, "unknown": 1.0}
#: Message ids PX4 v1.16 sends that pymavlink's common dialect lacks, with a payload length
#: and a CRC extra of ours (a receiver without the definition cannot check it anyway).
UNKNOWN_IDS = {8: (36, 117), 380: (20, 232), 411: (3, 106), 436: (9, 193)}


def _covariance(pos_var: float, vel_var: float) -> tuple[list[float], list[float]]:
    """Upper-triangle 6×6 covariances as PX4 fills them: the diagonal, the rest NaN."""
    pose = [math.nan] * 21
    twist = [math.nan] * 21
    for i, k in enumerate((0, 6, 11, 15, 18, 20)):
        pose[k] = pos_var if i < 3 else 1e-4
        twist[k] = vel_var if i < 3 else 1e-4
    return pose, twist


_POSE_COV, _TWIST_COV = _covariance(EKF_XY[0] ** 2, 0.01)


@dataclass
class _Setpoint:
    kind: str  # "attitude" or "position"
    received_s: float  # PX4's clock
    #: Attitude: (q NED/FRD, body rates FRD [rad/s], normalised thrust); position: the hold.
    values: tuple[np.ndarray, np.ndarray, float] | _Hold
    #: Position: the trajectory setpoint's vz (NED, down > 0), NaN when not given.
    vz_down_mps: float = math.nan
    #: Position: whether it asks to go up (a position above, or an upward velocity or
    #: acceleration): PX4's want_takeoff.
    wants_up: bool = False


@dataclass
class _Hold:
    """A position-controller setpoint (ENU): hold, land and position-mode offboard use it."""

    t_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    heading_rad: float
    heading_rate_radps: float = 0.0


class _Hysteresis:
    """PX4's systemlib Hysteresis as the land detector sets it: rising after ``rise_s`` held,
    falling at once."""

    def __init__(self, rise_s: float, state: bool = True) -> None:
        self.rise_s = rise_s
        self.state = state
        self._since: float | None = None

    def update(self, value: bool | np.bool_, t_s: float) -> bool:
        if value == self.state:
            self._since = None
        elif not value:
            self.state = False
        else:
            if self._since is None:
                self._since = t_s
            if t_s - self._since >= self.rise_s:
                self.state, self._since = True, None
        return self.state


class _LandDetector:
    """PX4's multicopter land detector (MulticopterLandDetector.cpp, LandDetector.cpp)."""

    def __init__(self, hover_thrust: float) -> None:
        rise = LNDMC_TRIG_TIME_S / 3.0
        self.hover = hover_thrust
        self.ground_contact = _Hysteresis(rise)
        self.maybe_landed = _Hysteresis(rise)
        self.landed = _Hysteresis(rise)
        self.in_descend = False

    def update(self, t_s: float, *, armed: bool, throttle: float, climb_rate_control: bool,
               vz_sp_down_mps: float, velocity_ned_mps: np.ndarray,
               body_rates_frd_radps: np.ndarray) -> None:
        """One update on PX4's clock: ``throttle`` the normalised collective thrust applied,
        velocities the estimate's (NED), ``vz_sp_down_mps`` the trajectory setpoint's."""
        maybe = self.maybe_landed.state
        vz_max = LNDMC_Z_VEL_MAX_MPS * (2.5 if maybe else 1.0)
        vertical = abs(float(velocity_ned_mps[2])) > vz_max
        horizontal = math.hypot(float(velocity_ned_mps[0]),
                                float(velocity_ned_mps[1])) > LNDMC_XY_VEL_MAX_MPS
        # PX4 compares in float32 (a MAVLink thrust of 0.09 is 0.09f, not 0.0900000036).
        throttle32 = np.float32(throttle)
        low = throttle32 <= np.float32(MPC_THR_MIN + 0.3 * (self.hover - MPC_THR_MIN))
        contact: bool | np.bool_ = low
        if climb_rate_control:
            self.in_descend = math.isfinite(vz_sp_down_mps) and vz_sp_down_mps > DESCENT_VZ_MPS
            if not maybe and not self.landed.state:
                contact = contact and self.in_descend
        else:
            self.in_descend = False
        contact = True if not armed else contact and not horizontal and not vertical
        self.ground_contact.update(contact, t_s)

        sys_min = (MPC_THR_MIN + 0.1 * (self.hover - MPC_THR_MIN) if climb_rate_control
                   else MPC_MANTHR_MIN + 0.01)
        rot_max = math.radians(LNDMC_ROT_MAX_DEGPS) * (2.5 if maybe else 1.0)
        rotating = math.hypot(float(body_rates_frd_radps[0]),
                              float(body_rates_frd_radps[1])) > rot_max
        maybe_now = (not armed) or (throttle32 <= np.float32(sys_min) and not rotating
                                    and self.ground_contact.state)
        self.maybe_landed.update(maybe_now, t_s)
        self.landed.update((not armed) or self.maybe_landed.state, t_s)


class _Estimator:
    """EKF2's error, as measured: slowly varying position errors (ENU) and their derivative."""

    def __init__(self, seed: int | None, enabled: bool) -> None:
        self.enabled = enabled
        self.rng = np.random.default_rng(seed)
        sigma = np.array([EKF_XY[0], EKF_XY[0], EKF_Z[0]])
        self.tau = np.array([EKF_XY[1], EKF_XY[1], EKF_Z[1]])
        # The smoothing lag shrinks the variance by τ/(τ + τs): the driving process makes up.
        self.sigma_gm = sigma * np.sqrt((self.tau + EKF_SMOOTH_S) / self.tau)
        self.gm = np.zeros(3)
        self.position_m = np.zeros(3)
        self.velocity_mps = np.zeros(3)
        self._noise = np.empty((0, 3))

    def step(self, dt_s: float) -> None:
        if not self.enabled:
            return
        if not len(self._noise):
            self._noise = self.rng.standard_normal((256, 3))  # batches: cheap per tick
        w, self._noise = self._noise[0], self._noise[1:]
        a = np.exp(-dt_s / self.tau)
        self.gm = a * self.gm + self.sigma_gm * np.sqrt(1.0 - a * a) * w
        self.velocity_mps = (self.gm - self.position_m) / EKF_SMOOTH_S
        self.position_m = self.position_m + self.velocity_mps * dt_s


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
        odometry_rate_hz: ODOMETRY rate [Hz] on its clock (PX4's onboard default 30).
        offboard_loss_s: ``COM_OF_LOSS_T`` [s].
        clock_rate: its clock's rate against the wall clock (time stamps, TIMESYNC, physics
            and timers when run on the wall clock); 0.986 as lockstep SITL measured here.
        seed: the estimator error's seed.
        estimator_error: False reports (and controls on) the true state.
        geo_origin_deg: (lat [deg], lon [deg], alt AMSL [m]) of the world's ENU origin, or
            None for no global position (no GPS_GLOBAL_ORIGIN, GLOBAL_POSITION_INT, ...).
        truth_port: send the plant's ground truth as PX4's SIH SITL does
            (``HIL_STATE_QUATERNION`` at 25 Hz, ``time_usec`` 0, from a port of its own) to
            UDP 127.0.0.1:``truth_port`` (:mod:`uavmpc.drivers.px4.truth`); None: not at all.
            Needs ``geo_origin_deg``.
    """

    def __init__(self, airframe: Airframe, address: str, *,
                 position_m: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
                 heading_rad: float = 0.0, system_id: int = 1,
                 odometry_rate_hz: float = 30.0,
                 offboard_loss_s: float = COM_OF_LOSS_T_S,
                 clock_rate: float = CLOCK_RATE, seed: int | None = 0,
                 estimator_error: bool = True,
                 geo_origin_deg: tuple[float, float, float] | None = PX4_SITL_HOME,
                 truth_port: int | None = None) -> None:
        if not 1 <= int(system_id) <= 255:
            raise ValueError(f"system_id: must be in 1..255, got {system_id!r}")
        if not 1.0 <= float(odometry_rate_hz) <= 1.0 / PERIOD_S:
            raise ValueError(f"odometry_rate_hz: must be in [1, {1.0 / PERIOD_S:g}], "
                             f"got {odometry_rate_hz!r}")
        if not float(offboard_loss_s) > 0.0:
            raise ValueError(f"offboard_loss_s: must be > 0, got {offboard_loss_s!r}")
        if not 0.1 <= float(clock_rate) <= 10.0:
            raise ValueError(f"clock_rate: must be in [0.1, 10], got {clock_rate!r}")
        self.airframe = airframe
        self.origin_m = np.asarray(position_m, dtype=float).copy()
        self.system_id = int(system_id)
        self.clock_rate = float(clock_rate)
        self.geo_origin_deg = (None if geo_origin_deg is None
                               else cast("tuple[float, float, float]",
                                         tuple(float(v) for v in geo_origin_deg)))
        #: The estimator's origin (this boot position) on the globe: (lat, lon, alt AMSL).
        #: Floats: ``origin_m`` is one point.
        self.boot_geodetic = (None if self.geo_origin_deg is None
                              else cast("tuple[float, float, float]",
                                        enu_to_geodetic(self.origin_m, self.geo_origin_deg)))
        if truth_port is not None and self.geo_origin_deg is None:
            raise ValueError("truth_port: the truth is sent on the globe; it needs a geo origin")
        self.link = MavlinkEndpoint(address, system_id=self.system_id, component_id=1)
        self.truth_link = (None if truth_port is None else MavlinkEndpoint(
            f"udpout://127.0.0.1:{int(truth_port)}", system_id=self.system_id,
            component_id=1))
        self.plant = Multirotor(airframe, position_m=self.origin_m, yaw_rad=heading_rad)
        self.controller = Se3Controller(airframe, period_s=PERIOD_S)
        self.hover_thrust = airframe.mass_kg * G / airframe.max_thrust_n
        self.offboard_loss_s = float(offboard_loss_s)
        self.odometry_period_s = 1.0 / float(odometry_rate_hz)
        self.estimator = _Estimator(seed, bool(estimator_error))
        self.detector = _LandDetector(self.hover_thrust)
        self.mode: Px4Mode = HOLD
        #: The mode last asked for (PX4's "user intention"): a failsafe fallback keeps it and
        #: returns to it when the cause is gone.
        self.intention: Px4Mode = HOLD
        self.armed = False
        self.setpoint: _Setpoint | None = None
        self.hold: _Hold | None = None
        #: Wall (or caller's) time of its boot: its clock reads 0 there. Set by the first tick.
        self.t0_s: float | None = None
        #: Its clock at the last tick [s].
        self.clock_s = 0.0
        self.armed_s = 0.0
        self.taken_off = False
        self._landed_since_s: float | None = None
        self.takeoff_state = "disarmed"
        self._ramp = 0.0
        self.throttle = 0.0
        self._attitude_throttle: float | None = None
        self._last_target: AttitudeTarget | None = None
        self._gcs_heard_s = -math.inf
        self._texts: deque[tuple[float, int, str]] = deque(maxlen=32)
        self._origin_sent = False
        self.events: list[str] = []
        self.params = {"MPC_THR_HOVER": self.hover_thrust, "COM_OF_LOSS_T": self.offboard_loss_s,
                       "COM_DISARM_LAND": COM_DISARM_LAND_S, "COM_DISARM_PRFLT": COM_DISARM_PRFLT_S,
                       "COM_SPOOLUP_TIME": COM_SPOOLUP_TIME_S, "MPC_LAND_SPEED": MPC_LAND_SPEED_MPS,
                       "MPC_THR_MIN": MPC_THR_MIN, "MPC_MANTHR_MIN": MPC_MANTHR_MIN,
                       "MPC_TKO_RAMP_T": MPC_TKO_RAMP_T_S, "MPC_TKO_SPEED": MPC_TKO_SPEED_MPS,
                       "LNDMC_Z_VEL_MAX": LNDMC_Z_VEL_MAX_MPS,
                       "LNDMC_XY_VEL_MAX": LNDMC_XY_VEL_MAX_MPS,
                       "LNDMC_ROT_MAX": LNDMC_ROT_MAX_DEGPS, "LNDMC_TRIG_TIME": LNDMC_TRIG_TIME_S}
        self._periods = dict(STREAMS_S, odometry=self.odometry_period_s,
                             truth=1.0 / TRUTH_RATE_HZ)
        self._next = dict.fromkeys(self._periods, 0.0)
        self._stop = False

    # ------------------------------------------------------------------ the clock
    @property
    def tick_period_s(self) -> float:
        """Wall (caller's) time per tick: one physics period on its clock."""
        return PERIOD_S / self.clock_rate

    def px4_time_s(self, now_s: float) -> float:
        """Its boot clock [s] at the caller's time ``now_s`` (the wall clock in :meth:`run`)."""
        if self.t0_s is None:
            self.t0_s = now_s
        return (now_s - self.t0_s) * self.clock_rate

    # ------------------------------------------------------------------ the loop
    def stop(self) -> None:
        self._stop = True

    def run(self, duration_s: float | None = None) -> None:
        """Fly on the wall clock until :meth:`stop` (or ``duration_s``): a physics tick every
        ``PERIOD_S`` of its clock, and messages taken as they arrive in between (so TIMESYNC
        is answered at once)."""
        start = time.time()
        t_end = math.inf if duration_s is None else start + duration_s
        step = self.tick_period_s
        next_tick = start
        while not self._stop:
            now = time.time()
            if now >= t_end:
                break
            if now >= next_tick:
                self.tick(now)
                next_tick += step
                if now - next_tick > 5 * step:  # far behind (a stalled host): do not race
                    next_tick = now + step
                continue
            if self.link.wait(next_tick - now):
                self._receive(time.time())

    def tick(self, now_s: float) -> None:
        """One period: take messages, run the commander and land detector, send what is due
        (the state now, stamped now), apply the mode's control and step the plant."""
        t = self.px4_time_s(now_s)
        self.clock_s = t
        self._receive(now_s)
        self._failsafes(t)
        truth = self.plant.state()
        est = self._estimate_of(truth)
        self._update_detector(t, est)
        self._disarm_checks(t)
        self._send_streams(t, truth, est)
        target = self._control(t, truth, est)
        self._last_target = target
        if self._attitude_throttle is not None:  # exactly what was sent (no round trip)
            self.throttle = self._attitude_throttle
        else:
            self.throttle = (float(target.thrust_n) / self.airframe.max_thrust_n
                             if self.armed else 0.0)
        self.plant.step(target, PERIOD_S)
        self.estimator.step(PERIOD_S)

    def _receive(self, now_s: float) -> None:
        for msg, sender, _arrived in self.link.receive():
            self._handle(msg, sender, now_s)

    # ------------------------------------------------------------------ the estimate
    def estimate(self) -> VehicleState:
        """The estimator's state (world ENU): the truth plus the estimator's error."""
        return self._estimate_of(self.plant.state())

    def odometry_message(self, t_s: float, truth: VehicleState,
                         est: VehicleState) -> OdometryMsg:
        """``ODOMETRY`` as PX4 sends it at its time ``t_s`` [s since boot]: EKF2's position
        and velocity in local NED (``child_frame_id`` LOCAL_NED), the attitude body FRD →
        NED and the body rates of ``truth`` (the estimate's error is in position and
        velocity only)."""
        p = enu_to_ned(est.position_m - self.origin_m)
        msg: OdometryMsg = _M.MAVLink_odometry_message(
            int(t_s * 1e6), _M.MAV_FRAME_LOCAL_NED, _M.MAV_FRAME_LOCAL_NED, *map(float, p),
            enu_flu_quat_to_ned_frd(truth.attitude_wxyz).tolist(),
            *map(float, enu_to_ned(est.velocity_mps)),
            *map(float, flu_to_frd(truth.body_rates_radps)), _POSE_COV, _TWIST_COV, 0,
            _M.MAV_ESTIMATOR_TYPE_AUTOPILOT, 0)
        return msg

    def _estimate_of(self, s: VehicleState) -> VehicleState:
        if not self.estimator.enabled:
            return s
        return VehicleState(s.t_s, s.position_m + self.estimator.position_m,
                            s.velocity_mps + self.estimator.velocity_mps, s.attitude_wxyz,
                            s.body_rates_radps)

    # ------------------------------------------------------------------ control
    def _climb_rate_control(self) -> bool:
        """PX4's flag_control_climb_rate_enabled: every mode here but attitude offboard."""
        return not (self.mode == OFFBOARD and self.setpoint is not None
                    and self.setpoint.kind == "attitude")

    def _control(self, t: float, truth: VehicleState, est: VehicleState) -> AttitudeTarget:
        self._attitude_throttle = None
        level = AttitudeTarget(yaw_quat(float(heading_of(truth.attitude_wxyz))), 0.0)
        if not self.armed:
            self.takeoff_state = "disarmed"
            return level  # motors stopped (the plant's idle floor)
        if self.mode == OFFBOARD and self.setpoint is not None \
                and self.setpoint.kind == "attitude":
            self._takeoff_update(t, False)
            assert isinstance(self.setpoint.values, tuple)  # what an attitude setpoint holds
            q_ned, rates_frd, thrust = self.setpoint.values
            self._attitude_throttle = thrust
            return AttitudeTarget(ned_frd_quat_to_enu_flu(q_ned),
                                  thrust * self.airframe.max_thrust_n, frd_to_flu(rates_frd))
        # Position control (Takeoff.cpp, MulticopterPositionControl.cpp) on the estimate.
        if self.mode == OFFBOARD and self.setpoint is not None:
            command = self.setpoint.values
            assert isinstance(command, _Hold)  # what a position setpoint holds
            wants_up = self.setpoint.wants_up
        else:
            if self.hold is None:
                self.hold = self._hold_here(est)
            descend = self.mode == LAND or (self.mode == POSCTL and self.mode != self.intention)
            if descend and self.takeoff_state == "flight":
                h = self.hold
                h.position_m = h.position_m + np.array([0.0, 0.0, -MPC_LAND_SPEED_MPS * PERIOD_S])
                h.velocity_mps = np.array([0.0, 0.0, -MPC_LAND_SPEED_MPS])
            command, wants_up = self.hold, False
        self._takeoff_update(t, wants_up)
        if self.takeoff_state in ("spoolup", "ready") or (
                self.takeoff_state == "flight" and self.detector.ground_contact.state):
            self.controller.reset()  # PX4: no corrections, integrators reset, idle thrust
            idle = 0.0 if self.takeoff_state != "flight" else MPC_THR_MIN
            return AttitudeTarget(level.attitude_wxyz, idle * self.airframe.max_thrust_n)
        target = self.controller.update(command, est)
        if self.takeoff_state == "rampup":
            # The upward velocity limit ramps: PX4's velocity loop then asks at most
            # g + P (v_limit − v_up) of the vehicle.
            v0 = -G / MPC_Z_VEL_P_ACC
            v_limit = v0 + self._ramp * (MPC_TKO_SPEED_MPS - v0)
            cap = self.airframe.mass_kg * max(0.0, G + MPC_Z_VEL_P_ACC
                                              * (v_limit - float(est.velocity_mps[2])))
            if target.thrust_n > cap:
                target = AttitudeTarget(target.attitude_wxyz, cap, target.body_rates_ff_radps)
        return target

    def _takeoff_update(self, t: float, wants_up: bool) -> None:
        """PX4's TakeoffHandling state machine (Takeoff.cpp) on its clock."""
        state = self.takeoff_state
        if state == "disarmed":
            state = "spoolup"
        if state == "spoolup" and t - self.armed_s >= COM_SPOOLUP_TIME_S:
            state = "ready"
        if state in ("spoolup", "ready") and not self.detector.landed.state:
            state = "flight"  # airborne already (e.g. after attitude offboard): no take-off
        if state == "ready" and wants_up:
            state, self._ramp = "rampup", 0.0
        if state == "rampup":
            self._ramp += PERIOD_S / MPC_TKO_RAMP_T_S
            if self._ramp >= 1.0:
                state = "flight"
        if state == "flight" and self.detector.landed.state:
            state = "ready"
        self.takeoff_state = state

    def _hold_here(self, state: VehicleState) -> _Hold:
        return _Hold(state.t_s, state.position_m.copy(), np.zeros(3), np.zeros(3),
                     float(heading_of(state.attitude_wxyz)))

    def _set_mode(self, mode: Px4Mode, t: float, why: str = "") -> None:
        if mode == self.mode:
            return
        self.events.append(f"{t:.2f} s: {self.mode} → {mode}{why}")
        self.mode = mode
        self.hold = None
        self.controller.reset()

    def _failsafes(self, t: float) -> None:
        if not self.armed or self.intention != OFFBOARD:
            return
        signal_ok = self._offboard_available(t)
        if self.mode == OFFBOARD and not signal_ok:
            self._set_mode(POSCTL, t, " (failsafe: offboard signal lost; no RC: descend)")
            self._status(_M.MAV_SEVERITY_WARNING,
                         "Failsafe activated: offboard signal lost, position mode", t)
        elif self.mode == POSCTL and signal_ok:
            self._set_mode(OFFBOARD, t, " (offboard signal back)")

    def _offboard_available(self, t: float) -> bool:
        """PX4's commander rule: the last valid setpoint is younger than COM_OF_LOSS_T."""
        return self.setpoint is not None and t - self.setpoint.received_s < self.offboard_loss_s

    def _update_detector(self, t: float, est: VehicleState) -> None:
        vz_down = math.nan
        if self.mode == OFFBOARD and self.setpoint is not None \
                and self.setpoint.kind == "position":
            vz_down = self.setpoint.vz_down_mps
        elif self.mode == LAND or (self.mode == POSCTL and self.mode != self.intention):
            vz_down = MPC_LAND_SPEED_MPS
        elif self.hold is not None:
            vz_down = 0.0
        was_landed = self.detector.landed.state
        self.detector.update(t, armed=self.armed, throttle=self.throttle,
                             climb_rate_control=self._climb_rate_control(),
                             vz_sp_down_mps=vz_down, velocity_ned_mps=enu_to_ned(est.velocity_mps),
                             body_rates_frd_radps=flu_to_frd(est.body_rates_radps))
        if self.armed and was_landed and not self.detector.landed.state:
            self.taken_off = True
            self.events.append(f"{t:.2f} s: land detector: in air")
        elif self.armed and not was_landed and self.detector.landed.state:
            self.events.append(f"{t:.2f} s: land detector: landed")

    def _disarm_checks(self, t: float) -> None:
        if not self.armed:
            return
        landed = self.detector.landed.state
        if self.taken_off:
            if not landed:
                self._landed_since_s = None
            elif self._landed_since_s is None:
                self._landed_since_s = t
            if landed:
                assert self._landed_since_s is not None  # set above when landed
                if t - self._landed_since_s >= COM_DISARM_LAND_S:
                    self._disarm(t, "landing")
        elif t - self.armed_s >= COM_DISARM_PRFLT_S:
            self._disarm(t, "auto preflight disarming")

    def _disarm(self, t: float, why: str) -> None:
        self.armed = False
        self.takeoff_state = "disarmed"
        self.events.append(f"{t:.2f} s: disarmed ({why})")
        self._status(_M.MAV_SEVERITY_INFO, f"Disarmed by {why}", t)

    # ------------------------------------------------------------------ receiving
    def _handle(self, msg: mavlink.MAVLink_message, sender: tuple[str, int],
                now_s: float) -> None:
        kind = msg.get_type()
        if kind in ("SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED", "COMMAND_LONG",
                    "COMMAND_INT", "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST"):
            if msg.target_system not in (0, self.system_id) \
                    or msg.target_component not in (0, 1):
                return
        elif kind == "TIMESYNC":
            self._on_timesync(msg, now_s)
            return
        elif kind != "HEARTBEAT":
            return
        self.link.trust(sender)
        t = self.px4_time_s(now_s)
        if kind == "HEARTBEAT":
            # A GCS from any system, an onboard controller of ours (mavlink_receiver.cpp).
            if msg.type == _M.MAV_TYPE_GCS or (msg.type == _M.MAV_TYPE_ONBOARD_CONTROLLER
                                               and msg.get_srcSystem() == self.system_id):
                self._gcs_heard_s = t
                self._flush_texts(t)
        elif kind == "SET_ATTITUDE_TARGET":
            self._on_attitude_target(msg, t)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._on_position_target(msg, t)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._on_command(msg, t)
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

    def _on_timesync(self, msg: TimesyncMsg, now_s: float) -> None:
        """mavlink_timesync.cpp: a request (tc1 = 0) is answered with our time [ns] and its
        ts1; an answer to our own requests only feeds PX4's offset filter (not modelled)."""
        if int(msg.tc1) == 0:
            # tc1 = 0 would read as a request: at boot (its clock at 0) answer 1 ns.
            self.link.send(_M.MAVLink_timesync_message(
                max(1, round(float(self.px4_time_s(now_s) * 1e9))), int(msg.ts1)))

    def _on_attitude_target(self, msg: SetAttitudeTargetMsg, t: float) -> None:
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
        self.setpoint = _Setpoint("attitude", t, (q / np.linalg.norm(q), rates, float(msg.thrust)))

    def _on_position_target(self, msg: SetPositionTargetLocalNedMsg, t: float) -> None:
        if msg.coordinate_frame != _M.MAV_FRAME_LOCAL_NED:
            return
        mask = int(msg.type_mask)
        vals = np.array([msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.afx, msg.afy,
                         msg.afz], dtype=float)
        for i in range(9):  # PX4: each ignored field is NaN in its trajectory setpoint
            if mask & (1 << i):
                vals[i] = math.nan
        if np.all(np.isnan(vals)) or mask & _M.POSITION_TARGET_TYPEMASK_FORCE_SET:
            return  # "SET_POSITION_TARGET_LOCAL_NED invalid" / force not supported
        est = self.estimate()
        here_ned = enu_to_ned(est.position_m - self.origin_m)
        pos_ned = np.where(np.isnan(vals[0:3]), here_ned, vals[0:3])
        if not np.all(np.isfinite(pos_ned)):
            return
        wants_up = ((not math.isnan(vals[2]) and vals[2] < here_ned[2])
                    or (not math.isnan(vals[5]) and vals[5] < 0.0)
                    or (not math.isnan(vals[8]) and vals[8] < 0.0))
        vel, acc = np.nan_to_num(vals[3:6]), np.nan_to_num(vals[6:9])
        heading = (heading_ned_to_enu(float(msg.yaw))
                   if not mask & _M.POSITION_TARGET_TYPEMASK_YAW_IGNORE
                   and math.isfinite(msg.yaw) else float(heading_of(est.attitude_wxyz)))
        rate = (0.0 if mask & _M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
                or not math.isfinite(msg.yaw_rate) else -float(msg.yaw_rate))
        self.setpoint = _Setpoint("position", t, _Hold(
            t, self.origin_m + ned_to_enu(pos_ned), ned_to_enu(vel), ned_to_enu(acc), heading,
            rate), vz_down_mps=float(vals[5]), wants_up=bool(wants_up))

    def _on_command(self, msg: CommandMsg, t: float) -> None:
        cmd = int(msg.command)
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        acks = 1
        if cmd == _M.MAV_CMD_DO_SET_MODE:
            result = self._request_mode(p, t)
            if result == _ACCEPTED:
                acks = 2  # PX4 v1.16 answers an accepted mode change twice (measured)
        elif cmd == _M.MAV_CMD_COMPONENT_ARM_DISARM:
            result = self._request_arming(p, t)
        elif cmd == _M.MAV_CMD_NAV_LAND:
            result = self._request_mode([1.0, LAND.main, LAND.sub], t)
        elif cmd == _M.MAV_CMD_REQUEST_MESSAGE:
            result = self._request_message(int(p[0]), t)
        else:
            result = _UNSUPPORTED
        for _ in range(acks):
            self.link.send(_M.MAVLink_command_ack_message(
                cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _request_message(self, msg_id: int, t: float) -> int:
        """handle_request_message_command: the message goes out before the ACK."""
        if msg_id == _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self._send_autopilot_version()
        elif msg_id == _M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN and self.boot_geodetic is not None:
            self._send_origin(t)
        elif msg_id == _M.MAVLINK_MSG_ID_HOME_POSITION and self.boot_geodetic is not None:
            self._send_home(t)
        else:
            return _DENIED
        return _ACCEPTED

    def _request_mode(self, p: list[float], t: float) -> int:
        if not int(p[0]) & _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return _UNSUPPORTED  # PX4 takes modes as its custom modes
        mode = Px4Mode(int(p[1]), int(p[2]) if int(p[1]) == MainMode.AUTO else 0)
        if mode not in MODES:
            return _UNSUPPORTED
        if mode == OFFBOARD and self.armed and not self._offboard_available(t):
            self._status(_M.MAV_SEVERITY_CRITICAL, "Switching to Offboard is currently not "
                         "available: No offboard signal", t)
            return _TEMPORARILY_REJECTED
        self.intention = mode
        self._set_mode(mode, t)
        return _ACCEPTED

    def _request_arming(self, p: list[float], t: float) -> int:
        arm = p[0] > 0.5
        if arm == self.armed:
            return _ACCEPTED
        if arm:
            if not self.plant.landed:
                return _TEMPORARILY_REJECTED
            if self.mode == OFFBOARD and not self._offboard_available(t):
                self._status(_M.MAV_SEVERITY_CRITICAL, "Arming denied: No offboard signal", t)
                return _TEMPORARILY_REJECTED
            self.armed = True
            self.armed_s = t
            self.taken_off = False
            self._landed_since_s = None
            self.takeoff_state = "disarmed"
            self.hold = None
            self.controller.reset()
            self.events.append(f"{t:.2f} s: armed in {self.mode}")
        else:
            landed = self.detector.landed.state or self.detector.maybe_landed.state
            if not landed and p[1] != FORCE_DISARM:
                self._status(_M.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed", t)
                return _TEMPORARILY_REJECTED
            self._disarm(t, "external command")
        return _ACCEPTED

    # ------------------------------------------------------------------ sending
    def _due(self, name: str, t: float) -> bool:
        if t < self._next[name] - 1e-6:
            return False
        period = self._periods[name]
        # Keep the average rate without bursts after a stall.
        self._next[name] = max(self._next[name] + period, t - period + 1e-9)
        return True

    def _send_streams(self, t: float, truth: VehicleState, est: VehicleState) -> None:
        send = self.link.send
        if not self._origin_sent and self.boot_geodetic is not None:
            self._origin_sent = self._send_origin(t)  # the stream's first, forced send
        if self._due("heartbeat", t):
            send(self._heartbeat())
        us, ms = int(t * 1e6), int(t * 1e3)
        p = enu_to_ned(est.position_m - self.origin_m)
        v = enu_to_ned(est.velocity_mps)
        q = enu_flu_quat_to_ned_frd(truth.attitude_wxyz)
        w = flu_to_frd(truth.body_rates_radps)
        if self._due("attitude", t):
            roll, pitch, yaw = _euler(q)
            send(_M.MAVLink_attitude_message(ms, roll, pitch, yaw, *map(float, w)))
        if self._due("odometry", t):
            send(self.odometry_message(t, truth, est))
        if self.truth_link is not None and self._due("truth", t):
            assert self.geo_origin_deg is not None
            self.truth_link.send(truth_message(truth.position_m, truth.velocity_mps, q,
                                               self.geo_origin_deg))
        if self._due("local", t):
            send(_M.MAVLink_local_position_ned_message(ms, *map(float, p), *map(float, v)))
        if self._due("attitude_q", t):
            send(_M.MAVLink_attitude_quaternion_message(ms, *map(float, q), *map(float, w),
                                                        [0.0, 0.0, 0.0, 0.0]))
        if self._due("imu", t):
            send(_M.MAVLink_highres_imu_message(us, 0.0, 0.0, -G, *map(float, w), 0.2, 0.0, 0.4,
                                                1013.0, 0.0, float(-p[2]), 25.0, 0x1FFF))
        if self._due("timesync", t):  # PX4's own requests (streams/TIMESYNC.hpp)
            send(_M.MAVLink_timesync_message(0, round(float(t * 1e9))))
        if self._due("altitude", t):
            amsl = (self.boot_geodetic[2] if self.boot_geodetic else 0.0) - float(p[2])
            send(_M.MAVLink_altitude_message(us, amsl, amsl, float(-p[2]), float(-p[2]),
                                             math.nan, math.nan))
        if self._due("att_target", t):
            send(self._attitude_target_message(ms))
        if self._due("pos_target", t):
            send(self._position_target_message(ms))
        if self.boot_geodetic is not None:
            due_global, due_gps = self._due("global", t), self._due("gps", t)
            if due_global or due_gps:
                assert self.geo_origin_deg is not None  # boot_geodetic is made from it
                lat, lon, alt = enu_to_geodetic(est.position_m, self.geo_origin_deg)
                if due_global:
                    hdg = round(float(math.degrees(math.atan2(
                        2.0 * (q[0] * q[3] + q[1] * q[2]),
                        1.0 - 2.0 * (q[2] ** 2 + q[3] ** 2))) * 100.0)) % 36000
                    send(_M.MAVLink_global_position_int_message(
                        ms, round(float(lat * 1e7)), round(float(lon * 1e7)),
                        round(float(alt * 1e3)), round(float(-p[2] * 1e3)),
                        *(round(float(c * 100.0)) for c in v), hdg))
                if due_gps:
                    speed = round(float(math.hypot(v[0], v[1]) * 100.0))
                    send(_M.MAVLink_gps_raw_int_message(
                        us, 3, round(float(lat * 1e7)), round(float(lon * 1e7)),
                        round(float(alt * 1e3)), 70, 110, speed, 65535, 12))
        if self._due("extended", t):
            landed = self.detector.landed.state
            state = (_M.MAV_LANDED_STATE_ON_GROUND if landed
                     else _M.MAV_LANDED_STATE_LANDING if self.mode == LAND
                     else _M.MAV_LANDED_STATE_IN_AIR)
            send(_M.MAVLink_extended_sys_state_message(_M.MAV_VTOL_STATE_UNDEFINED, state))
        if self._due("sys_status", t):
            sensors = 0x3FFF
            send(_M.MAVLink_sys_status_message(sensors, sensors, sensors, 250, 16000, -1, 100,
                                               0, 0, 0, 0, 0, 0))
        if self._due("unknown", t):
            for msg_id, (length, crc_extra) in UNKNOWN_IDS.items():
                self._send_raw(msg_id, bytes(length), crc_extra)

    def _send_raw(self, msg_id: int, payload: bytes, crc_extra: int) -> None:
        """A MAVLink 2 frame of an id outside pymavlink's dialect, framed by hand."""
        if self.link.peer is None:
            return
        mav = self.link.mav
        # MAVLink 2 trims trailing zero bytes of the payload (at least one byte stays).
        body = payload.rstrip(b"\x00") or b"\x00"
        header = struct.pack("<BBBBBBBHB", 0xFD, len(body), 0, 0, mav.seq, self.system_id, 1,
                             msg_id & 0xFFFF, msg_id >> 16)
        crc = _M.x25crc(header[1:] + body)
        crc.accumulate(bytes([crc_extra]))
        mav.seq = (mav.seq + 1) % 256
        try:
            self.link.sock.sendto(header + body + struct.pack("<H", crc.crc), self.link.peer)
        except OSError:
            pass

    def _heartbeat(self) -> HeartbeatMsg:
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
        msg: HeartbeatMsg = _M.MAVLink_heartbeat_message(
            _M.MAV_TYPE_QUADROTOR, _M.MAV_AUTOPILOT_PX4, base, self.mode.custom_mode, status, 3)
        return msg

    def _attitude_target_message(self, ms: int) -> mavlink.MAVLink_message:
        tgt = self._last_target
        if tgt is None:
            q, ff, thrust = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), 0.0
        else:
            q = enu_flu_quat_to_ned_frd(tgt.attitude_wxyz)
            ff = flu_to_frd(tgt.body_rates_ff_radps)
            thrust = float(tgt.thrust_n) / self.airframe.max_thrust_n
        return _M.MAVLink_attitude_target_message(ms, 0, q.tolist(), *map(float, ff),
                                                  min(max(thrust, 0.0), 1.0))

    def _position_target_message(self, ms: int) -> mavlink.MAVLink_message:
        h = (self.setpoint.values if self.mode == OFFBOARD and self.setpoint is not None
             and self.setpoint.kind == "position" else self.hold)
        assert not isinstance(h, tuple)  # what a position setpoint holds
        if h is None:
            vals = [math.nan] * 11
        else:
            vals = [*enu_to_ned(h.position_m - self.origin_m), *enu_to_ned(h.velocity_mps),
                    *enu_to_ned(h.acceleration_mps2), heading_enu_to_ned(h.heading_rad),
                    -h.heading_rate_radps]
        return _M.MAVLink_position_target_local_ned_message(ms, _M.MAV_FRAME_LOCAL_NED, 0,
                                                            *map(float, vals))

    def _send_origin(self, t: float) -> bool:
        assert self.boot_geodetic is not None  # only sent with a geo origin
        lat, lon, alt = self.boot_geodetic
        return self.link.send(_M.MAVLink_gps_global_origin_message(
            round(float(lat * 1e7)), round(float(lon * 1e7)), round(float(alt * 1e3)), 0))

    def _send_home(self, t: float) -> None:
        assert self.boot_geodetic is not None  # only sent with a geo origin
        lat, lon, alt = self.boot_geodetic
        self.link.send(_M.MAVLink_home_position_message(
            round(float(lat * 1e7)), round(float(lon * 1e7)), round(float(alt * 1e3)),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0))

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

    def _status(self, severity: int, text: str, t: float) -> None:
        """Queue a STATUSTEXT: it goes out once a ground station is connected."""
        self._texts.append((t, severity, text))
        self._flush_texts(t)

    def _flush_texts(self, t: float) -> None:
        if t - self._gcs_heard_s > GCS_TIMEOUT_S:
            return
        while self._texts:
            t_text, severity, text = self._texts.popleft()
            if t - t_text < STATUSTEXT_MAX_AGE_S:
                self.link.send(_M.MAVLink_statustext_message(severity, text[:50].encode()))


def _euler(q: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw [rad] (ZYX) of a (w, x, y, z) quaternion."""
    w, x, y, z = (float(c) for c in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


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
        if sitl.truth_link is not None:
            sitl.truth_link.close()
