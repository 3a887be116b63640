"""One UAV's watch over the assumptions its safety rests on, measured while it flies (issue 51).

The safety argument (docs/safety.md) assumes, among others, that each UAV knows the 1σ of its
position estimate (A3) and that the vehicle tracks its virtual UAV (A4). On a simulator both
hold by construction; on a vehicle they are measured: the autopilot states its estimate's
covariance (PX4's ``ODOMETRY``), and the node sees where the vehicle is against where its
virtual UAV is. Each measure feeds the mechanism it belongs to, and nothing new:

- **The pair's widening.** What a UAV broadcasts as its position uncertainty (the σ every
  receiver widens the pair's cylinder by, ``uncertainty_k`` σ) is
  √(σ_estimate² + (e / k)²) per axis, with e the largest tracking error of the last
  :data:`TRACKING_WINDOW_S`: k σ then covers both the estimate's error and the vehicle's lag
  behind the plan it broadcasts. A climbing vehicle that lags its virtual UAV keeps its
  conflict open (its half height widened by the lag) until the vehicle, not the plan, is
  clear: a layer counts as reached when the vehicle is there.
- **The bounds.** A measure beyond its assumption's bound (:class:`Bounds`) means the widening
  no longer describes the vehicle: the UAV holds where its plan is and says which assumption
  broke (:meth:`AssumptionWatch.broken`), until the measure is back within it.

The link's age of each peer's predictions (their receive time minus their stamp: the latency
plus the clocks' offset, A1 and A5) and its loss (from the stamps, at the broadcast period)
are measured per peer and reported.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from uavmpc.comms.message import MAX_SIGMA_M, SCHEMA_VERSION, PredictionMessage

#: How long a tracking error counts towards the stated uncertainty [s]: the avoidance decides
#: every 0.1 s and a broadcast lives 0.5 s; a lag seen within the last second still matters.
TRACKING_WINDOW_S = 1.0
#: The broadcast period the loss is counted against [s] (:data:`uavmpc.onboard.
#: BROADCAST_PERIOD_S`).
BROADCAST_PERIOD_S = 0.5


@dataclass(frozen=True)
class Bounds:
    """Where each measured assumption breaks (SI units).

    Attributes:
        sigma_h_m, sigma_v_m: A3, the estimate's stated 1σ: beyond it the autopilot does not
            know where the vehicle is well enough for a 5 m cylinder (2σ = 3 m of margin).
        tracking_m: A4, the vehicle's distance from its virtual UAV: beyond it the plan
            broadcast is not what the vehicle flies (3-D).
        age_s: A1/A5, a peer's predictions arriving older than this (latency plus clock
            offset; the inbox ignores them past ``timeout_s``)."""

    sigma_h_m: float = 1.5
    sigma_v_m: float = 1.5
    tracking_m: float = 3.0
    age_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ("sigma_h_m", "sigma_v_m", "tracking_m", "age_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not (
                    math.isfinite(v) and v > 0.0):
                raise ValueError(f"bounds.{name}: must be a number > 0, got {v!r}")


class _Peer:
    """What one peer's predictions told about the link: ages and stamps."""

    def __init__(self) -> None:
        self.ages_s: deque[float] = deque(maxlen=20)
        self.first_stamp_s = math.nan
        self.last_stamp_s = math.nan
        self.heard = 0

    def add(self, stamp_s: float, received_s: float) -> None:
        if self.heard and not stamp_s > self.last_stamp_s:
            return  # the same prediction seen again
        self.ages_s.append(received_s - stamp_s)
        if not self.heard:
            self.first_stamp_s = stamp_s
        self.last_stamp_s = stamp_s
        self.heard += 1

    def report(self) -> dict[str, Any]:
        ages = sorted(self.ages_s)
        span = self.last_stamp_s - self.first_stamp_s
        expected = round(span / BROADCAST_PERIOD_S) + 1 if self.heard else 0
        return {"heard": self.heard,
                "age_p50_s": round(ages[len(ages) // 2], 4) if ages else None,
                "age_max_s": round(ages[-1], 4) if ages else None,
                "loss": (round(max(0.0, 1.0 - self.heard / expected), 4) if expected > 1
                         else None)}


class AssumptionWatch:
    """The measures of one UAV (see the module): fed by its driver, read by its broadcasts
    (:meth:`stated_sigma_m`) and its supervision (:meth:`broken`).

    Args:
        uncertainty_k: the pair's widening in σ (``AvoidanceParams.uncertainty_k``).
        bounds: where each assumption breaks.
    """

    def __init__(self, uncertainty_k: float, bounds: Bounds | None = None) -> None:
        self.k = float(uncertainty_k)
        self.bounds = bounds if bounds is not None else Bounds()
        self.sigma_m = (0.0, 0.0)  # the estimate's own 1σ (horizontal, vertical) [m]
        self._errors: deque[tuple[float, float, float]] = deque()  # (t, e_h, e_v)
        self.peers: dict[str, _Peer] = {}
        #: Each assumption's longest measure so far, and how often it broke.
        self.worst = {"sigma_h_m": 0.0, "sigma_v_m": 0.0, "tracking_m": 0.0, "age_s": 0.0}
        self.breaks: dict[str, int] = {}
        self._was: tuple[str, ...] = ()
        #: The vehicle has come near its virtual UAV since it set off: A4's bound is judged
        #: from then on (an autopilot's take-off, spooling up and ramping, lags the plan by
        #: design; the stated σ covers that lag meanwhile).
        self._caught_up = False
        #: Peers taken for dead (A7), and when [s, the node's clock].
        self.dead_peers: dict[str, float] = {}

    # ---------------------------------------------------------------- measures in
    def estimate(self, sigma_h_m: float, sigma_v_m: float) -> None:
        """The autopilot's (or observer's) stated 1σ of its position; NaN: unknown (kept)."""
        h = sigma_h_m if math.isfinite(sigma_h_m) and sigma_h_m >= 0.0 else self.sigma_m[0]
        v = sigma_v_m if math.isfinite(sigma_v_m) and sigma_v_m >= 0.0 else self.sigma_m[1]
        self.sigma_m = (float(h), float(v))
        self.worst["sigma_h_m"] = max(self.worst["sigma_h_m"], self.sigma_m[0])
        self.worst["sigma_v_m"] = max(self.worst["sigma_v_m"], self.sigma_m[1])

    def tracking(self, now_s: float, vehicle_m: npt.NDArray[np.float64] | Sequence[float],
                 virtual_m: npt.NDArray[np.float64] | Sequence[float],
                 airborne: bool = True) -> None:
        """The vehicle's estimate ``vehicle_m`` (3,) against its virtual UAV ``virtual_m``
        (3,) at ``now_s`` [s]; ``airborne``: clear of the ground (a vehicle still on it has
        not begun to track)."""
        dx, dy, dz = (float(vehicle_m[a]) - float(virtual_m[a]) for a in range(3))
        e_h, e_v = math.hypot(dx, dy), abs(dz)
        self._errors.append((now_s, e_h, e_v))
        while self._errors and self._errors[0][0] < now_s - TRACKING_WINDOW_S:
            self._errors.popleft()
        self.worst["tracking_m"] = max(self.worst["tracking_m"], math.hypot(e_h, e_v))
        if airborne and math.hypot(e_h, e_v) < 0.25 * self.bounds.tracking_m:
            self._caught_up = True

    def heard(self, peer: str, stamp_s: float, received_s: float) -> None:
        """A prediction of ``peer`` stamped ``stamp_s`` arrived at ``received_s`` [s]."""
        self.peers.setdefault(peer, _Peer()).add(stamp_s, received_s)

    # ---------------------------------------------------------------- what they mean
    def tracking_error_m(self) -> tuple[float, float]:
        """The largest (horizontal, vertical) tracking error of the window [m]."""
        if not self._errors:
            return 0.0, 0.0
        return (max(e[1] for e in self._errors), max(e[2] for e in self._errors))

    def stated_sigma_m(self) -> tuple[float, float]:
        """The position uncertainty to broadcast: (horizontal, vertical) 1σ [m] (the module's
        √(σ² + (e / k)²))."""
        e_h, e_v = self.tracking_error_m()
        k = self.k if self.k > 0.0 else 1.0
        return (math.hypot(self.sigma_m[0], e_h / k), math.hypot(self.sigma_m[1], e_v / k))

    def broken(self, now_s: float) -> tuple[str, ...]:
        """The assumptions whose measure is beyond its bound now, each as one line naming it
        and the numbers (empty: all hold). A new break is counted."""
        b = self.bounds
        out = []
        if self.sigma_m[0] > b.sigma_h_m:
            out.append(f"A3 estimate: horizontal σ {self.sigma_m[0]:.2f} m > {b.sigma_h_m:g} m")
        if self.sigma_m[1] > b.sigma_v_m:
            out.append(f"A3 estimate: vertical σ {self.sigma_m[1]:.2f} m > {b.sigma_v_m:g} m")
        e_h, e_v = self.tracking_error_m()
        if self._caught_up and math.hypot(e_h, e_v) > b.tracking_m:
            out.append(f"A4 vehicle: {math.hypot(e_h, e_v):.2f} m from its virtual UAV > "
                       f"{b.tracking_m:g} m")
        for peer, p in sorted(self.peers.items()):
            if p.ages_s:
                age = p.ages_s[-1]
                self.worst["age_s"] = max(self.worst["age_s"], age)
                if age > b.age_s:
                    out.append(f"A1/A5 link: {peer}'s predictions arrive {age:.2f} s old > "
                               f"{b.age_s:g} s")
        names = tuple(out)
        for line in names:
            key = line.split(":")[0]
            if not any(w.split(":")[0] == key for w in self._was):
                self.breaks[key] = self.breaks.get(key, 0) + 1
        self._was = names
        return names

    def report(self) -> dict[str, Any]:
        """The measures so far: the worst of each, the breaks counted by assumption, the
        link per peer."""
        return {"worst": {k: round(v, 3) for k, v in self.worst.items()},
                "bounds": {"sigma_h_m": self.bounds.sigma_h_m,
                           "sigma_v_m": self.bounds.sigma_v_m,
                           "tracking_m": self.bounds.tracking_m, "age_s": self.bounds.age_s},
                "breaks": dict(self.breaks), "broken_now": list(self._was),
                "dead_peers": {p: round(t, 3) for p, t in sorted(self.dead_peers.items())},
                "peers": {p: v.report() for p, v in sorted(self.peers.items())}}


# ---------------------------------------------------------------------------- a dead peer
#: A peer unheard this long past its last prediction's stamp [s] is taken for a node that
#: died (A7): its vehicle flies on uncommanded, under its autopilot's failsafe. Past the
#: message timeout (1 s) and the acknowledgement's grace (2 s), so that a lossy link's
#: silences of a second or two do not count (30 % i.i.d. loss at 2 Hz: six losses in a row).
DEAD_AFTER_S = 3.0
#: What PX4 v1.16 (no RC) does when its offboard setpoints stop, as measured against its
#: SITL (a node killed mid-flight): it flies its last setpoint for ``COM_OF_LOSS_T`` (1 s), then
#: fails safe to a descent that stays level (``FlightTaskDescend``: no horizontal position
#: hold) at ``MPC_LAND_SPEED`` — 0.6–0.8 m/s by the truth — and disarms on the ground.
FAILSAFE_DELAY_S = 1.0
FAILSAFE_DESCENT_MPS = (0.6, 0.8)
#: How far the vehicle's velocity can be from its last plan's when the failsafe levels it
#: [m/s]: its last plan's acceleration over the delay, plus this (the controller's tracking
#: error; measured: a vehicle killed in a hover drifted 0.3 m in 19 s by the truth).
FAILSAFE_SPEED_MARGIN_MPS = 0.5
#: How long past the latest it can have touched down it is still assumed flying [s].
FAILSAFE_LANDED_MARGIN_S = 2.0


def failsafe_prediction(last: PredictionMessage, now_s: float, uncertainty_k: float,
                        ground_z_m: float = 0.0) -> PredictionMessage | None:
    """Where a peer whose node died can be, as a prediction of our own making: from its last
    state (the first point of its ``last`` plan, its velocity from the plan's first step), it
    drifts level at that velocity and, after :data:`FAILSAFE_DELAY_S`, descends at the slower
    failsafe rate (the higher path); its flag is down (it avoids no one), so every UAV, of
    any priority, gives way to it. Its stated 1σ covers the rest of its reach one second
    ahead, divided by ``uncertainty_k`` (receivers widen by k σ): horizontally, a velocity
    off its plan's by its plan's acceleration over the delay plus
    :data:`FAILSAFE_SPEED_MARGIN_MPS`; vertically, the spread of the descent rates. None once
    it can only be on the ground (``ground_z_m``)."""
    t0 = float(last.times_s[0])  # when it was at its plan's first point
    p0 = np.asarray(last.positions_m[0], dtype=float)
    dt_plan = float(last.times_s[1] - last.times_s[0]) if last.points > 1 else 0.0
    v0 = ((np.asarray(last.positions_m[1], dtype=float) - p0) / dt_plan if dt_plan > 0.0
          else np.zeros(3))
    a0 = np.zeros(3)
    if last.points > 2 and dt_plan > 0.0:  # its plan's acceleration at the first point
        a0 = (np.asarray(last.positions_m[2], dtype=float)
              - 2.0 * np.asarray(last.positions_m[1], dtype=float) + p0) / dt_plan ** 2
    slow, fast = FAILSAFE_DESCENT_MPS
    climb = max(float(v0[2]), 0.0) * FAILSAFE_DELAY_S
    t_down = FAILSAFE_DELAY_S + max(p0[2] + climb - ground_z_m, 0.0) / slow
    age = now_s - float(last.stamp_s)
    if age > t_down + FAILSAFE_LANDED_MARGIN_S:
        return None
    horizon = np.asarray(last.times_s, dtype=float) - float(last.times_s[0])
    times = now_s + horizon
    dt = times - t0
    pos = np.empty((times.size, 3))
    pos[:, 0] = p0[0] + v0[0] * dt
    pos[:, 1] = p0[1] + v0[1] * dt
    pos[:, 2] = np.maximum(p0[2] + np.minimum(dt, FAILSAFE_DELAY_S) * max(float(v0[2]), 0.0)
                           - slow * np.maximum(dt - FAILSAFE_DELAY_S, 0.0), ground_z_m)
    reach_s = age + 1.0
    # the speed it may have beside its plan's once levelled, times the time since
    gained = float(np.hypot(a0[0], a0[1])) * FAILSAFE_DELAY_S + FAILSAFE_SPEED_MARGIN_MPS
    reach_h = gained * max(reach_s, 0.0)
    # the spread of the descent rates, until even the slower one is on the ground
    reach_v = 0.0 if reach_s >= t_down else (fast - slow) * max(reach_s - FAILSAFE_DELAY_S,
                                                                0.0)
    k = uncertainty_k if uncertainty_k > 0.0 else 1.0
    return PredictionMessage(
        SCHEMA_VERSION, last.uav_id, last.priority, now_s, times, pos, False, now_s, (),
        (min(float(math.hypot(last.position_sigma_m[0], reach_h / k)), MAX_SIGMA_M),
         min(float(math.hypot(last.position_sigma_m[1], reach_v / k)), MAX_SIGMA_M)))
