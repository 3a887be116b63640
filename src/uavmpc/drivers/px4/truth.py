"""Where a simulated vehicle really is: its simulator's ground truth over MAVLink (issue 51).

An autopilot's estimate is not where the vehicle is. Against PX4 v1.16's SIH, EKF2's height
read 0.65–0.69 m low in a hover, and closest approaches computed from estimates differed from
the truth by up to 0.4 m either way. So wherever a simulator knows the truth, separation and
collisions are judged on it.

PX4's SIH SITL sends the truth itself: its start-up script (``etc/init.d-posix/px4-rc.mavlink``)
starts, for ``PX4_SIMULATOR=sihsim``, a MAVLink instance of its own that streams
``HIL_STATE_QUATERNION`` at 25 Hz to UDP 127.0.0.1:19410 + i (instance i, from port
19450 + i). That stream (``src/modules/mavlink/streams/HIL_STATE_QUATERNION.hpp``) reads
``vehicle_global_position_groundtruth`` and friends: latitude and longitude in 1e-7 degrees,
altitude in millimetres, velocity in cm/s, and leaves ``time_usec`` at 0, so a sample is
stamped when it arrives (loopback: well under a millisecond). It flows whether or not a node
flies the vehicle, so a vehicle whose node died is still followed.

The stand-in PX4 (:mod:`uavmpc.drivers.px4.sitl`) sends the same message from its plant, the
same way (:func:`truth_message`), and the simulated-plant nodes need none: their state is
their plant's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np

from uavmpc.drivers.px4.dialect import mavlink
from uavmpc.drivers.px4.endpoint import MavlinkEndpoint
from uavmpc.drivers.px4.frames import enu_to_geodetic, enu_to_ned, geodetic_to_enu

__all__ = ["TRUTH_PORT_BASE", "Track", "TruthListener", "TruthSample", "closest_by_pair",
           "truth_message"]

#: PX4 SIH SITL sends instance i's ground truth to UDP 127.0.0.1:TRUTH_PORT_BASE + i.
TRUTH_PORT_BASE = 19410
#: The rate of that stream (``mavlink stream -r 25 -s HIL_STATE_QUATERNION``) [Hz].
TRUTH_RATE_HZ = 25.0


@dataclass(frozen=True)
class TruthSample:
    """One ground-truth sample: ``t_s`` when it arrived [s, Unix], from MAVLink system
    ``system_id``, ``position_m`` (3,) in the world's ENU frame [m]."""

    t_s: float
    system_id: int
    position_m: np.ndarray


class TruthListener:
    """Receives ``HIL_STATE_QUATERNION`` on UDP 127.0.0.1:``port`` and places each sample in
    the world whose ENU origin is ``geo_origin`` = (lat [deg], lon [deg], alt [m AMSL]).

    Raises:
        OSError: the port cannot be listened on (the message names it).
    """

    def __init__(self, port: int, geo_origin: tuple[float, float, float]) -> None:
        self.geo_origin = cast("tuple[float, float, float]",
                               tuple(float(v) for v in geo_origin))
        self.link = MavlinkEndpoint(f"udp://127.0.0.1:{int(port)}", system_id=255,
                                    component_id=191)
        #: Samples that could not be placed (non-finite or off the globe).
        self.refused = 0

    def poll(self) -> list[TruthSample]:
        """Every sample that arrived since the last call (never blocks)."""
        out: list[TruthSample] = []
        for msg, _sender, arrived in self.link.receive():
            if msg.get_type() != "HIL_STATE_QUATERNION":
                continue
            try:
                p = geodetic_to_enu(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3,
                                    self.geo_origin)
            except ValueError:
                self.refused += 1
                continue
            out.append(TruthSample(arrived, int(msg.get_srcSystem()), p))
        return out

    def close(self) -> None:
        self.link.close()


def truth_message(position_m: np.ndarray, velocity_mps: np.ndarray,
                  attitude_wxyz_ned: np.ndarray,
                  geo_origin: tuple[float, float, float]) -> mavlink.MAVLink_message:
    """``HIL_STATE_QUATERNION`` as PX4's SIH sends it: the true ENU ``position_m`` (3,) and
    ``velocity_mps`` (3,) in the world about ``geo_origin``, the attitude already in NED/FRD
    (w, x, y, z); ``time_usec`` 0 and no rates or accelerations, as PX4 leaves or fills them."""
    lat, lon, alt = enu_to_geodetic(np.asarray(position_m, float), geo_origin)
    v = enu_to_ned(np.asarray(velocity_mps, float))
    q = [float(x) for x in attitude_wxyz_ned]

    def cm(x: float) -> int:
        return max(-32768, min(32767, round(x * 100.0)))

    return mavlink.MAVLink_hil_state_quaternion_message(
        0, q, 0.0, 0.0, 0.0, round(float(lat) * 1e7), round(float(lon) * 1e7),
        round(float(alt) * 1e3), cm(v[0]), cm(v[1]), cm(v[2]), 0, 0, 0, 0, 0)


# --- tracks: where each vehicle was over time, and the pairs' closest approaches ---------

@dataclass(frozen=True)
class Track:
    """One vehicle's positions over time.

    Attributes:
        t_s: (K,) sample times [s], strictly increasing: PX4's boot clock as read from a log,
            Unix time after :func:`on_wall_clock`.
        position_m: (K, 3) positions [m], world ENU about the world's geodetic origin.
    """

    t_s: np.ndarray
    position_m: np.ndarray

    def __post_init__(self) -> None:
        t = np.array(self.t_s, dtype=float)  # copies: the caller's arrays stay writable
        p = np.array(self.position_m, dtype=float)
        if t.ndim != 1 or p.shape != (t.size, 3):
            raise ValueError(f"Track: t_s must be (K,) and position_m (K, 3), got {t.shape} "
                             f"and {p.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
            raise ValueError("Track: times and positions must be finite")
        if np.any(np.diff(t) <= 0.0):
            raise ValueError("Track: t_s must be strictly increasing")
        t.setflags(write=False)
        p.setflags(write=False)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "position_m", p)

    @property
    def span_s(self) -> tuple[float, float]:
        """First and last sample time [s]; (nan, nan) for an empty track."""
        if self.t_s.size == 0:
            return math.nan, math.nan
        return float(self.t_s[0]), float(self.t_s[-1])


# --- reading ---------------------------------------------------------------------------------

def time_grid(t0: float, t1: float, step_s: float) -> np.ndarray:
    """Times from ``t0`` to ``t1`` [s], ``step_s`` apart, both ends included."""
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 >= t0):
        raise ValueError(f"time window must be finite with t1 >= t0, got [{t0!r}, {t1!r}]")
    if not (math.isfinite(step_s) and step_s > 0.0):
        raise ValueError(f"step_s must be positive, got {step_s!r}")
    n = math.floor((t1 - t0) / step_s) + 1
    grid = t0 + step_s * np.arange(n)
    return grid if grid[-1] >= t1 else np.append(grid, t1)


def resample(track: Track, grid: np.ndarray) -> np.ndarray:
    """(G, 3) positions on ``grid``, linear between samples, NaN outside the track's span."""
    out = np.full((grid.size, 3), np.nan)
    if track.t_s.size == 0:
        return out
    inside = (grid >= track.t_s[0]) & (grid <= track.t_s[-1])
    for k in range(3):
        out[inside, k] = np.interp(grid[inside], track.t_s, track.position_m[:, k])
    return out


def closest_by_pair(tracks: dict[str, Track], t0: float, t1: float,
                    step_s: float = 0.02) -> dict[tuple[str, str], float]:
    """Each pair's closest approach [m, 3-D] over ``[t0, t1]`` (the tracks' clock, s).

    Every track is resampled linearly on one grid (``step_s`` apart, both ends included); a
    pair is judged where both tracks have samples. Pairs ``(a, b)`` with ``a`` before ``b`` in
    ``tracks``' order, sorted like a swarm summary's ``closest_by_pair_m``; a pair whose spans
    do not meet inside the window is left out."""
    grid = time_grid(float(t0), float(t1), float(step_s))
    ids = list(tracks)
    on_grid = {u: resample(tracks[u], grid) for u in ids}
    out: dict[tuple[str, str], float] = {}
    for i, a in enumerate(ids):
        for b in ids[i + 1:]:
            d = np.linalg.norm(on_grid[a] - on_grid[b], axis=1)
            d = d[np.isfinite(d)]
            if d.size:
                out[(a, b)] = float(d.min())
    return dict(sorted(out.items()))
