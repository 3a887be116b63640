"""One UAV, end to end, in simulation: reference → tracker → SE(3) → attitude → motors → body.

:func:`fly` runs the closed loop on a simulated clock and returns a :class:`FlightLog` whose
``status`` says how the flight ended (as RotorPy's exit status does), and :func:`summarize`
condenses it into the numbers of ``summary.json``.
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from uavmpc.estimation.receiver import GnssNoise
from uavmpc.onboard import OnboardStack
from uavmpc.plant import Airframe, Wind
from uavmpc.plant.interface import heading_of
from uavmpc.plant.multirotor import Multirotor
from uavmpc.reference import Reference
from uavmpc.tracker import TrackerConfig

#: Beyond this distance from the tracker's command the UAV is declared flown away.
FLY_AWAY_M = 50.0


class FlightStatus(enum.Enum):
    """How a flight ended."""

    COMPLETE = "complete"  #: flew the whole duration
    NAN = "nan"  #: a state became non-finite (a bug, never expected)
    FLY_AWAY = "fly_away"  #: the UAV got further than FLY_AWAY_M from its command


@dataclass(frozen=True, eq=False)
class FlightLog:
    """Everything recorded at 100 Hz, K samples.

    Attributes:
        t_s: (K,) time.
        reference: (K, 4) the user's reference [x, y, z, heading] at t.
        command: (K, 4) the tracker's command (virtual UAV) [x, y, z, heading].
        actual: (K, 4) the UAV's true position and heading.
        tilt_deg: (K,) angle between body z and world z.
        motor_saturated: (K,) any rotor at its idle or maximum speed while airborne.
        wall_s: wall-clock time of the loop.
        status: how the flight ended.
        fallbacks: tracker ticks that fell back to braking.
    """

    t_s: np.ndarray
    reference: np.ndarray
    command: np.ndarray
    actual: np.ndarray
    tilt_deg: np.ndarray
    motor_saturated: np.ndarray
    wall_s: float
    status: FlightStatus
    fallbacks: int


def demanding_reference(z0_m: float = 5.0) -> Reference:
    """Steps, a fast (infeasible) zig-zag and a climb with a turn; 0.2 s sampling, 60 s."""
    dt = 0.2
    t = np.arange(0.0, 60.0 + dt / 2, dt)
    pts = np.zeros((t.shape[0], 4))
    pts[:, 2] = z0_m
    step = (t >= 3.0) & (t < 15.0)  # 10 m step in x, then 8 m in y
    pts[step, 0] = 10.0
    pts[(t >= 9.0) & (t < 15.0), 1] = 8.0
    zig = (t >= 15.0) & (t < 30.0)  # 3 m/s forward with a ±4 m zig-zag of period 2 s (16 m/s)
    tz = t[zig] - 15.0
    pts[zig, 0] = 10.0 + 3.0 * tz
    pts[zig, 1] = 8.0 + 4.0 * (2.0 * np.abs(2.0 * (tz / 2.0 - np.floor(tz / 2.0 + 0.5))) - 1.0)
    climb = t >= 30.0  # climb by 15 m and turn by 180° at once, then fly back home
    pts[climb, 0] = 55.0
    pts[climb, 1] = 8.0
    pts[climb, 2] = z0_m + 15.0
    pts[climb, 3] = np.pi * np.minimum((t[climb] - 30.0) / 3.0, 1.0)
    home = t >= 45.0
    pts[home, :3] = [0.0, 0.0, z0_m]
    return Reference(t, pts)


def fly(
    airframe: Airframe,
    reference: Reference,
    duration_s: float,
    *,
    start_m: tuple[float, float, float] | None = None,
    wind: Wind | None = None,
    gnss: GnssNoise | None = None,
    tracker_config: TrackerConfig | None = None,
) -> FlightLog:
    """Fly one UAV in closed loop for ``duration_s`` from hover at ``start_m``.

    ``start_m`` defaults to the reference's first point; the UAV starts hovering there.
    """
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be > 0, got {duration_s}")
    first = reference.points[0]
    start = tuple(first[:3]) if start_m is None else start_m
    plant = Multirotor(airframe, position_m=start, yaw_rad=float(first[3]), wind=wind,
                       rotors_at_hover=True)
    stack = OnboardStack(airframe, tracker_config, position_m=start,
                         heading_rad=float(first[3]))
    stack.set_mission(reference)
    period = stack.period_s
    n = round(duration_s / period)
    t_log = np.empty(n)
    cmd_log = np.empty((n, 4))
    pos_log = np.empty((n, 3))
    quat_log = np.empty((n, 4))
    sat = np.zeros(n, dtype=bool)
    w_lo = airframe.omega_idle_radps * 1.001
    w_hi = airframe.omega_max_radps * 0.999
    status = FlightStatus.COMPLETE
    state = plant.state()
    wall0 = time.perf_counter()
    k = 0
    for k in range(n):
        estimate = gnss.apply(state) if gnss is not None else state
        out = stack.tick(stack.tracker.time_s, estimate)
        state = plant.step(out.target, period)
        c = stack.command()
        t_log[k] = c.t_s
        cmd_log[k, :3] = c.position_m
        cmd_log[k, 3] = c.heading_rad
        pos_log[k] = state.position_m
        quat_log[k] = state.attitude_wxyz
        rotors = plant.rotor_speeds_radps
        sat[k] = (rotors.min() <= w_lo or rotors.max() >= w_hi) and not plant.landed
        dist = math.dist(pos_log[k], cmd_log[k, :3])
        if not dist <= FLY_AWAY_M:  # NaN included
            status = FlightStatus.FLY_AWAY if math.isfinite(dist) else FlightStatus.NAN
            break
    wall = time.perf_counter() - wall0
    m = k + 1
    q = quat_log[:m]
    heading = heading_of(q)
    # body z in world z is 1 − 2(x² + y²)
    tilt = np.degrees(np.arccos(np.clip(1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2), -1.0, 1.0)))
    return FlightLog(
        t_s=t_log[:m], reference=reference.sample(t_log[:m]), command=cmd_log[:m],
        actual=np.column_stack([pos_log[:m], heading]), tilt_deg=tilt, motor_saturated=sat[:m],
        wall_s=wall, status=status, fallbacks=stack.tracker.fallback_count,
    )


def summarize(log: FlightLog, airframe: Airframe) -> dict[str, Any]:
    """The numbers of ``summary.json`` (tracking error = actual position vs the command)."""
    err = np.linalg.norm(log.actual[:, :3] - log.command[:, :3], axis=1)
    period = float(np.median(np.diff(log.t_s))) if log.t_s.shape[0] > 1 else 0.01
    sim_s = float(log.t_s[-1] - log.t_s[0] + period)
    return {
        "status": log.status.value,
        "airframe": airframe.name,
        "duration_s": sim_s,
        "tracking_rmse_m": float(np.sqrt(np.mean(err**2))),
        "max_tracking_error_m": float(err.max()),
        "max_tilt_deg": float(log.tilt_deg.max()),
        "tilt_limit_deg": float(math.degrees(airframe.se3.max_tilt_rad)),
        "motor_saturation_s": float(log.motor_saturated.sum() * period),
        "realtime_factor": float(sim_s / log.wall_s) if log.wall_s > 0 else float("inf"),
        "tracker_fallbacks": int(log.fallbacks),
    }
