"""Desired trajectories (SPEC §2.4): what the mission asks the tracker to fly.

A reference is a sequence of points ``[x, y, z, heading]`` (ENU metres, heading in rad) stamped
with absolute times. It may be infeasible on purpose (steps, jumps, too fast): the tracker makes
it flyable. A "go to" is a reference with one point. Validation happens here, on arrival, so a
bad reference is rejected with a message naming the problem before it can reach the tracker.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uavmpc.config import describe
from uavmpc.jit import kernel

#: Largest accepted |x|, |y|, |z| in metres: far beyond any mission, small enough that
#: squared errors in the QP stay well inside float64 precision.
MAX_ABS_POSITION_M = 1.0e5
#: Largest number of points in one reference (≈ 55 h at 0.2 s): guards memory, not physics.
MAX_POINTS = 1_000_000
#: Smallest accepted spacing between two reference stamps.
MIN_SAMPLE_PERIOD_S = 1.0e-3
#: Largest accepted |stamp| in seconds (Unix time until about the year 5000): a looping
#: reference's closing knot, one gap after the last stamp, then stays finite (≤ 3e11 s), and a
#: stamp keeps a resolution far finer than :data:`MIN_SAMPLE_PERIOD_S`.
MAX_ABS_TIME_S = 1.0e11
#: Largest accepted |heading| in rad (≈ 160 000 turns): headings are unwrapped on arrival, and
#: the differences np.unwrap takes of headings near ±1e308 overflow to a NaN heading.
MAX_ABS_HEADING_RAD = 1.0e6


class InvalidReferenceError(ValueError):
    """A desired trajectory that cannot be flown as given (the message names the problem)."""


@dataclass(frozen=True, eq=False)
class Reference:
    """A desired trajectory, validated.

    Attributes:
        times_s: (N,) absolute stamps in seconds, strictly increasing.
        points: (N, 4) rows ``[x_m, y_m, z_m, heading_rad]`` in the ENU world frame. Headings are
            stored unwrapped so that linear interpolation between points turns the short way.
        loop: when true the trajectory repeats after its last point, closing back to the first
            point over one last sample period; otherwise the last point is held.
    """

    times_s: np.ndarray
    points: np.ndarray
    loop: bool = False
    # Derived in __post_init__ (not arguments): the knots, their points and the uniform period.
    _knots: np.ndarray = field(init=False, repr=False)
    _values: np.ndarray = field(init=False, repr=False)
    _uniform_period: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        times = _as_float_array(self.times_s, "times_s")
        points = _as_float_array(self.points, "points")
        if times.ndim != 1:
            raise InvalidReferenceError(f"times_s must be 1-D, got shape {times.shape}")
        if points.ndim != 2 or points.shape[1] != 4:
            raise InvalidReferenceError(
                f"points must have shape (N, 4) [x, y, z, heading], got {points.shape}"
            )
        n = points.shape[0]
        if n == 0:
            raise InvalidReferenceError("points is empty: a reference needs at least one point")
        if n > MAX_POINTS:
            raise InvalidReferenceError(f"points has {n} rows, more than the limit {MAX_POINTS}")
        if times.shape[0] != n:
            raise InvalidReferenceError(
                f"times_s has {times.shape[0]} stamps but points has {n} rows"
            )
        if not np.all(np.isfinite(times)):
            raise InvalidReferenceError("times_s contains NaN or inf")
        if np.any(np.abs(times) > MAX_ABS_TIME_S):
            i = int(np.argmax(np.abs(times)))
            raise InvalidReferenceError(
                f"times_s[{i}]={times[i]} is beyond the sane bound of ±{MAX_ABS_TIME_S:g} s"
            )
        bad = ~np.isfinite(points)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            name = ("x", "y", "z", "heading")[col]
            raise InvalidReferenceError(
                f"points[{row}] {name} is {points[row, col]}: NaN or inf is not allowed"
            )
        if np.any(np.abs(points[:, 3]) > MAX_ABS_HEADING_RAD):
            row = int(np.argmax(np.abs(points[:, 3])))
            raise InvalidReferenceError(
                f"points[{row}] heading is {points[row, 3]:g} rad, beyond the sane bound of "
                f"±{MAX_ABS_HEADING_RAD:g} rad"
            )
        if np.any(np.abs(points[:, :3]) > MAX_ABS_POSITION_M):
            row = int(np.argmax(np.abs(points[:, :3]).max(axis=1)))
            raise InvalidReferenceError(
                f"points[{row}] lies {np.abs(points[row, :3]).max():.3g} m from the origin, "
                f"beyond the sane bound of {MAX_ABS_POSITION_M:.0e} m"
            )
        if n > 1:
            gaps = np.diff(times)
            if np.any(gaps < MIN_SAMPLE_PERIOD_S):
                i = int(np.argmax(gaps < MIN_SAMPLE_PERIOD_S))
                raise InvalidReferenceError(
                    f"times_s must increase by at least {MIN_SAMPLE_PERIOD_S} s between points; "
                    f"times_s[{i}]={times[i]} then times_s[{i + 1}]={times[i + 1]}"
                )
        if self.loop and n < 2:
            raise InvalidReferenceError("a looping reference needs at least two points")
        points = points.copy()
        points[:, 3] = np.unwrap(points[:, 3])
        times = times.copy()
        times.flags.writeable = False
        points.flags.writeable = False
        object.__setattr__(self, "times_s", times)
        object.__setattr__(self, "points", points)
        # Sampling tables: a looping reference gets its closing segment appended once here.
        knots, values = times, points
        if self.loop:
            closing = times[-1] - times[-2]
            last = points[0].copy()
            # Close the loop the short way round in heading.
            last[3] = points[-1, 3] + _wrap(points[0, 3] - points[-1, 3])
            knots = np.append(times, times[-1] + closing)
            values = np.vstack([points, last])
        gaps = np.diff(knots)
        uniform = gaps.size > 0 and bool(np.all(np.abs(gaps - gaps[0]) <= 1e-9 * gaps[0]))
        object.__setattr__(self, "_knots", knots)
        object.__setattr__(self, "_values", values)
        object.__setattr__(self, "_uniform_period", float(gaps[0]) if uniform else 0.0)

    @classmethod
    def sampled(
        cls, points: np.ndarray, sample_period_s: float = 0.2, start_s: float = 0.0, *,
        loop: bool = False,
    ) -> Reference:
        """A trajectory sampled every ``sample_period_s`` seconds from ``start_s`` on."""
        period = _finite_scalar(sample_period_s, "sample_period_s")
        if period < MIN_SAMPLE_PERIOD_S:
            raise InvalidReferenceError(
                f"sample_period_s must be ≥ {MIN_SAMPLE_PERIOD_S} s, got {period}"
            )
        start = _time(start_s, "start_s")
        pts = _as_float_array(points, "points")
        n = pts.shape[0] if pts.ndim >= 1 else 0
        if n > MAX_POINTS:
            raise InvalidReferenceError(f"points has {n} rows, more than the limit {MAX_POINTS}")
        # The last knot (a looping reference's closing one, a period after the last point)
        # named by the inputs that put it out of range, not as an anonymous times_s entry.
        last = start + period * (n if loop else max(n - 1, 0))
        if not abs(last) <= MAX_ABS_TIME_S:
            raise InvalidReferenceError(
                f"sample_period_s={period} from start_s={start} puts the last "
                f"{'(closing) ' if loop else ''}knot at {last} s, beyond the sane bound of "
                f"±{MAX_ABS_TIME_S:g} s"
            )
        return cls(start + period * np.arange(n), pts, loop)

    @classmethod
    def goto(cls, x: float, y: float, z: float, heading: float = 0.0,
             start_s: float = 0.0) -> Reference:
        """A single point to fly to and hold (a step reference, infeasible on purpose)."""
        return cls(np.array([_time(start_s, "start_s")]),
                   _as_float_array([[x, y, z, heading]], "goto"))

    @classmethod
    def along_path(cls, waypoints_m: np.ndarray, speed_mps: float, start_s: float = 0.0,
                   sample_period_s: float = 0.2) -> Reference:
        """A smooth path through ``waypoints_m`` (k ≥ 2, 3) flown at a constant ``speed_mps``
        from ``start_s``, facing along the path: a Catmull–Rom curve through the points,
        resampled by arc length (the last point is then held)."""
        w = _as_float_array(waypoints_m, "waypoints")
        if w.ndim != 2 or w.shape[1] != 3 or w.shape[0] < 2:
            raise InvalidReferenceError(f"waypoints must have shape (k ≥ 2, 3), got {w.shape}")
        if not np.all(np.isfinite(w)):
            raise InvalidReferenceError("waypoints contain NaN or inf")
        if np.any(np.abs(w) > MAX_ABS_POSITION_M):  # the curve's arithmetic would overflow
            row = int(np.argmax(np.abs(w).max(axis=1)))
            raise InvalidReferenceError(
                f"waypoints[{row}] lies {np.abs(w[row]).max():.3g} m from the origin, beyond "
                f"the sane bound of {MAX_ABS_POSITION_M:.0e} m"
            )
        speed = _finite_scalar(speed_mps, "speed_mps")
        if speed <= 0.0:
            raise InvalidReferenceError(f"speed_mps must be > 0, got {speed}")
        period = _finite_scalar(sample_period_s, "sample_period_s")
        if period < MIN_SAMPLE_PERIOD_S:
            raise InvalidReferenceError(f"sample_period_s must be ≥ {MIN_SAMPLE_PERIOD_S} s")
        if np.any(np.linalg.norm(np.diff(w, axis=0), axis=1) < 1e-6):
            raise InvalidReferenceError("waypoints: two consecutive points are the same")
        ext = np.vstack([2 * w[0] - w[1], w, 2 * w[-1] - w[-2]])
        u = np.linspace(0.0, 1.0, 64, endpoint=False)[:, None]
        pieces = []
        for i in range(1, ext.shape[0] - 2):  # uniform Catmull–Rom between ext[i], ext[i+1]
            p0, p1, p2, p3 = ext[i - 1], ext[i], ext[i + 1], ext[i + 2]
            pieces.append(0.5 * (2 * p1 + (p2 - p0) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u**2
                                 + (3 * p1 - p0 - 3 * p2 + p3) * u**3))
        dense = np.vstack([*pieces, w[-1:]])
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        length_m, step_m = float(arc[-1]), speed * period
        # Compared as a product: a subnormal speed makes step_m ~0 (or exactly 0) and the
        # quotient inf, which int() refuses with an OverflowError.
        if not length_m < MAX_POINTS * step_m:
            raise InvalidReferenceError(
                f"speed_mps={speed:g} is too small: {length_m:.3g} m sampled every "
                f"{period:g} s would need more than the limit of {MAX_POINTS} points"
            )
        n = int(length_m / step_m) + 1
        if n > MAX_POINTS:  # (the product's rounding)
            raise InvalidReferenceError(f"the path needs {n} points, more than {MAX_POINTS}")
        at = np.minimum(np.arange(n + 1) * speed * period, arc[-1])
        xyz = np.column_stack([np.interp(at, arc, dense[:, j]) for j in range(3)])
        # Facing along the curve (its tangent at each sample, so the held end keeps the last
        # direction).
        tangent = np.gradient(dense, axis=0)
        heading = np.interp(at, arc, np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0])))
        return cls.sampled(np.column_stack([xyz, heading]), period, start_s)

    @property
    def start_s(self) -> float:
        return float(self.times_s[0])

    @property
    def knots_s(self) -> np.ndarray:
        """(K,) the sampling knots: ``times_s``, plus the closing knot of a looping reference."""
        return self._knots

    @property
    def values(self) -> np.ndarray:
        """(K, 4) the points at :attr:`knots_s`."""
        return self._values

    @property
    def uniform_period_s(self) -> float:
        """The knot spacing when it is uniform (sampling is then O(1)), else 0."""
        return self._uniform_period

    def sample(self, t_s: np.ndarray) -> np.ndarray:
        """Linear interpolation at the times ``t_s`` (K,) → (K, 4); holds the end points."""
        times = np.ascontiguousarray(t_s, dtype=float).reshape(-1)
        out = np.empty((times.shape[0], 4))
        sample_reference(self.knots_s, self.values, self.uniform_period_s, self.loop, times,
                         out)
        return out


@kernel
def sample_reference(knots: np.ndarray, values: np.ndarray, period: float, loop: bool,
                     times: np.ndarray, out: np.ndarray) -> None:
    """Linear interpolation of one reference's table (knots (n,), values (n, 4)) at ``times``
    (k,) into ``out`` (k, 4); the end points are held, a looping reference wraps.

    ``period`` > 0 says the knots are uniform (O(1) indexing); otherwise the segment is found
    by bisection, or by walking on from the previous one while the times increase.
    """
    n = knots.shape[0]
    m = times.shape[0]
    if n == 1:
        for k in range(m):
            for j in range(4):
                out[k, j] = values[0, j]
        return
    t0 = knots[0]
    cycle = knots[n - 1] - t0
    idx = 0
    for k in range(m):
        t = times[k]
        if loop:
            t = t0 + (0.0 if t < t0 else np.mod(t - t0, cycle))
        if period > 0.0:
            pos = min(max((t - t0) / period, 0.0), n - 1.0)
            i = min(int(pos), n - 2)
            frac = pos - i
        else:
            # searchsorted(knots, t, "right") − 1, clipped to [0, n − 2].
            if loop or k == 0 or knots[idx] > t:
                lo, hi = 0, n
                while lo < hi:
                    mid = (lo + hi) // 2
                    if knots[mid] <= t:
                        lo = mid + 1
                    else:
                        hi = mid
                idx = lo - 1
            else:
                while idx + 1 < n and knots[idx + 1] <= t:
                    idx += 1
            i = min(max(idx, 0), n - 2)
            k0 = knots[i]
            frac = min(max((t - k0) / (knots[i + 1] - k0), 0.0), 1.0)
        for j in range(4):
            lo_v = values[i, j]
            out[k, j] = lo_v + (values[i + 1, j] - lo_v) * frac



def _wrap(angle: np.ndarray | float) -> np.ndarray | float:
    """Wrap to [-π, π)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _as_float_array(value: object, name: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=float)
    except OverflowError:  # a Python integer beyond the float range
        raise InvalidReferenceError(f"{name} holds a number beyond the float range") from None
    except (TypeError, ValueError) as exc:
        raise InvalidReferenceError(f"{name} is not numeric: {exc}") from None


def _finite_scalar(value: Any, name: str) -> float:
    try:
        out = float(value)
    except OverflowError:  # float() of an integer beyond the float range
        raise InvalidReferenceError(f"{name} must be finite, got {describe(value)} (beyond "
                                    "the float range)") from None
    except (TypeError, ValueError):
        raise InvalidReferenceError(f"{name} must be a number, got {describe(value)}") from None
    if not np.isfinite(out):
        raise InvalidReferenceError(f"{name} must be finite, got {out}")
    return out


def _time(value: object, name: str) -> float:
    """A finite stamp within ±:data:`MAX_ABS_TIME_S`."""
    out = _finite_scalar(value, name)
    if abs(out) > MAX_ABS_TIME_S:
        raise InvalidReferenceError(
            f"{name}={out} is beyond the sane bound of ±{MAX_ABS_TIME_S:g} s"
        )
    return out
