"""Where a UAV may fly: an operational volume, the missions it admits, and the way back in.

A :class:`Geofence` is a prism: a simple polygon in the horizontal plane (ENU x, y; a box is a
rectangle) between a minimum and a maximum altitude (z, metres, the world's frame). Three rules
use it, each written once here:

- **Missions outside are refused** (:meth:`Geofence.check_reference`): every point of a desired
  trajectory, and every straight piece between two of them (the tracker flies the pieces; a
  piece can leave a non-convex polygon between two points inside it), must lie at least
  ``margin_m`` inside. The error names the first point or piece outside and by how much.
- **Avoidance stays below the ceiling** (:meth:`Geofence.offset_ceiling_m`): the highest height
  offset a UAV may take over its mission's points, so that it stays ``margin_m`` under the
  maximum altitude.
- **A UAV found outside flies back in and holds** (:meth:`Geofence.recovery_point`): the
  nearest point ``inset_m`` inside the volume (wind, a bad estimate or a take-off can put a UAV
  outside even though its mission is inside). It holds there until it is given a new mission,
  which must be inside like any other: the mission it had led it (or let it be pushed) out.

The numbers come from one compiled law, :func:`fence_margin` (signed distance to the volume's
boundary: positive inside), over arrays of points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from uavmpc.config import ConfigError, reject_unknown
from uavmpc.jit import kernel
from uavmpc.reference import MAX_ABS_POSITION_M, Reference

#: Default distance a mission must keep from the volume's boundary [m]: the tracker's
#: overshoot is centimetres, a gust's push decimetres.
DEFAULT_MARGIN_M = 1.0
#: Default distance inside the boundary a UAV found outside flies back to [m].
DEFAULT_INSET_M = 2.0
#: Steps of :meth:`Geofence.recovery_point` at most (each moves to the inset from the nearest
#: edge; in a corner the steps alternate between its two edges and shrink geometrically).
RECOVERY_STEPS = 200
#: Largest number of polygon vertices accepted (a field boundary, not a map).
MAX_VERTICES = 1000


class GeofenceError(ValueError):
    """A mission or position outside the operational volume (the message says where)."""


@kernel
def _edge_distance(poly: np.ndarray, x: float, y: float) -> tuple[float, int, float, float]:
    """(distance to the polygon's boundary, index of the nearest edge, nearest point x, y)."""
    n = poly.shape[0]
    best = math.inf
    best_k = 0
    bx = by = 0.0
    for k in range(n):
        ax, ay = poly[k, 0], poly[k, 1]
        ex, ey = poly[(k + 1) % n, 0] - ax, poly[(k + 1) % n, 1] - ay
        ll = ex * ex + ey * ey
        t = 0.0 if ll == 0.0 else ((x - ax) * ex + (y - ay) * ey) / ll
        t = min(max(t, 0.0), 1.0)
        qx, qy = ax + t * ex, ay + t * ey
        d = math.hypot(x - qx, y - qy)
        if d < best:
            best, best_k, bx, by = d, k, qx, qy
    return best, best_k, bx, by


@kernel
def _inside_xy(poly: np.ndarray, x: float, y: float) -> bool:
    """Even–odd rule (a ray towards +x): for a simple polygon, inside."""
    n = poly.shape[0]
    inside = False
    for k in range(n):
        ax, ay = poly[k, 0], poly[k, 1]
        bx, by = poly[(k + 1) % n, 0], poly[(k + 1) % n, 1]
        if (ay > y) != (by > y):
            xc = ax + (y - ay) * (bx - ax) / (by - ay)
            if x < xc:
                inside = not inside
    return inside


@kernel
def fence_margin(poly: np.ndarray, z_min: float, z_max: float, points: np.ndarray,
                 out: np.ndarray) -> None:
    """Signed distance of each of ``points`` (P, 3) to the boundary of the prism
    ``poly`` (K, 2) × [z_min, z_max] into ``out`` (P,) [m]: > 0 inside (the distance to the
    nearest wall, floor or ceiling), < 0 outside (minus the largest distance outside any of
    them; a bound, exact outside one face), NaN for a non-finite point."""
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            out[i] = math.nan
            continue
        d_xy, _, _, _ = _edge_distance(poly, x, y)
        if not _inside_xy(poly, x, y):
            d_xy = -d_xy
        out[i] = min(d_xy, z - z_min, z_max - z)


@kernel
def _cross(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@kernel
def first_crossing(poly: np.ndarray, a: np.ndarray, b: np.ndarray) -> int:
    """The first piece ``a[s] → b[s]`` (S, 2 each) that crosses an edge of ``poly`` (K, 2)
    properly (touching is not crossing: the margin test of the points catches those), or −1."""
    n = poly.shape[0]
    for s in range(a.shape[0]):
        for k in range(n):
            px, py = poly[k, 0], poly[k, 1]
            qx, qy = poly[(k + 1) % n, 0], poly[(k + 1) % n, 1]
            d1 = _cross(px, py, qx, qy, a[s, 0], a[s, 1])
            d2 = _cross(px, py, qx, qy, b[s, 0], b[s, 1])
            d3 = _cross(a[s, 0], a[s, 1], b[s, 0], b[s, 1], px, py)
            d4 = _cross(a[s, 0], a[s, 1], b[s, 0], b[s, 1], qx, qy)
            if d1 * d2 < 0.0 and d3 * d4 < 0.0:
                return s
    return -1


@kernel
def _point_segment(x: float, y: float, ax: float, ay: float, bx: float, by: float) -> float:
    ex, ey = bx - ax, by - ay
    ll = ex * ex + ey * ey
    t = 0.0 if ll == 0.0 else min(max(((x - ax) * ex + (y - ay) * ey) / ll, 0.0), 1.0)
    return math.hypot(x - ax - t * ex, y - ay - t * ey)


@kernel
def first_too_close(poly: np.ndarray, a: np.ndarray, b: np.ndarray, clearance: float) -> int:
    """The first piece ``a[s] → b[s]`` (S, 2 each) that comes nearer than ``clearance`` [m] to
    an edge of ``poly`` (K, 2), or −1. With both ends inside, a piece stays inside with that
    clearance iff none does (two segments that do not cross are nearest at an end of one)."""
    n = poly.shape[0]
    for s in range(a.shape[0]):
        ax, ay, bx, by = a[s, 0], a[s, 1], b[s, 0], b[s, 1]
        for k in range(n):
            px, py = poly[k, 0], poly[k, 1]
            qx, qy = poly[(k + 1) % n, 0], poly[(k + 1) % n, 1]
            d1 = _cross(px, py, qx, qy, ax, ay)
            d2 = _cross(px, py, qx, qy, bx, by)
            d3 = _cross(ax, ay, bx, by, px, py)
            d4 = _cross(ax, ay, bx, by, qx, qy)
            if d1 * d2 <= 0.0 and d3 * d4 <= 0.0:
                return s  # they cross or touch
            d = min(_point_segment(ax, ay, px, py, qx, qy), _point_segment(bx, by, px, py, qx, qy),
                    _point_segment(px, py, ax, ay, bx, by), _point_segment(qx, qy, ax, ay, bx, by))
            if d < clearance:
                return s
    return -1


def _simple(poly: np.ndarray) -> bool:
    """No two non-adjacent edges of ``poly`` cross (O(K²), K ≤ MAX_VERTICES, once per load)."""
    n = poly.shape[0]
    a, b = poly, np.roll(poly, -1, axis=0)
    for k in range(n):
        others = [j for j in range(n) if j not in (k, (k + 1) % n, (k - 1) % n)]
        if others and first_crossing(poly[[k, (k + 1) % n]],
                                     a[others], b[others]) >= 0:
            return False
    return True


@dataclass(frozen=True, eq=False)
class Geofence:
    """An operational volume: ``polygon_xy_m`` (K, 2) ENU [m], a simple polygon (either
    orientation, closed implicitly), between ``min_altitude_m`` and ``max_altitude_m`` (z).

    ``margin_m``: how far inside missions must stay; ``inset_m``: how far inside a UAV found
    outside flies back to (≥ margin_m, so that the way back ends inside the mission volume).
    """

    polygon_xy_m: np.ndarray
    min_altitude_m: float
    max_altitude_m: float
    margin_m: float = DEFAULT_MARGIN_M
    inset_m: float = DEFAULT_INSET_M

    def __post_init__(self) -> None:
        poly = np.array(self.polygon_xy_m, dtype=float)
        if poly.ndim != 2 or poly.shape[1] != 2 or not 3 <= poly.shape[0] <= MAX_VERTICES:
            raise GeofenceError(f"polygon: needs 3 to {MAX_VERTICES} [x, y] vertices, got "
                                f"shape {poly.shape}")
        if not np.isfinite(poly).all() or np.abs(poly).max() > MAX_ABS_POSITION_M:
            raise GeofenceError(f"polygon: vertices must be finite and within "
                                f"±{MAX_ABS_POSITION_M:g} m")
        if not abs(_signed_area(poly)) > 0.0:
            raise GeofenceError("polygon: has no area")
        if not _simple(poly):
            raise GeofenceError("polygon: its edges cross (it must be a simple polygon)")
        for name in ("min_altitude_m", "max_altitude_m", "margin_m", "inset_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise GeofenceError(f"{name}: must be a finite number, got {v!r}")
        if not self.max_altitude_m > self.min_altitude_m:
            raise GeofenceError(f"max_altitude_m ({self.max_altitude_m}) must be above "
                                f"min_altitude_m ({self.min_altitude_m})")
        if not (self.margin_m >= 0.0 and self.inset_m >= self.margin_m):
            raise GeofenceError(f"need 0 ≤ margin_m ≤ inset_m, got margin_m={self.margin_m}, "
                                f"inset_m={self.inset_m}")
        if 2.0 * self.inset_m >= self.max_altitude_m - self.min_altitude_m:
            raise GeofenceError(f"the volume is too thin for inset_m={self.inset_m} "
                                f"between {self.min_altitude_m} and {self.max_altitude_m} m")
        object.__setattr__(self, "polygon_xy_m", np.ascontiguousarray(poly))
        self.polygon_xy_m.setflags(write=False)

    @classmethod
    def box(cls, x_m: tuple[float, float], y_m: tuple[float, float],
            altitude_m: tuple[float, float], **kw: float) -> Geofence:
        """The box [x0, x1] × [y0, y1] × [z0, z1]."""
        (x0, x1), (y0, y1) = x_m, y_m
        if not (x1 > x0 and y1 > y0):
            raise GeofenceError(f"box: needs x0 < x1 and y0 < y1, got {x_m}, {y_m}")
        return cls(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float), altitude_m[0],
                   altitude_m[1], **kw)

    def to_table(self) -> dict[str, Any]:
        """The volume as a ``[geofence]`` table (the inverse of :meth:`from_dict`): what a
        node process is handed so that it flies the scenario's volume."""
        return {"polygon": self.polygon_xy_m.tolist(),
                "min_altitude_m": float(self.min_altitude_m),
                "max_altitude_m": float(self.max_altitude_m),
                "margin_m": float(self.margin_m), "inset_m": float(self.inset_m)}

    @classmethod
    def from_dict(cls, t: object, prefix: str = "geofence") -> Geofence:
        """From a TOML table: ``polygon = [[x, y], ...]`` or ``box = [x0, y0, x1, y1]``, and
        ``min_altitude_m``, ``max_altitude_m``, optional ``margin_m``, ``inset_m``.

        Raises:
            ConfigError: naming ``prefix.<field>``.
        """
        if not isinstance(t, dict):
            raise ConfigError(f"{prefix}: must be a table")
        reject_unknown(t, {"polygon", "box", "min_altitude_m", "max_altitude_m", "margin_m",
                           "inset_m"}, prefix)
        if ("polygon" in t) == ("box" in t):
            raise ConfigError(f"{prefix}: needs exactly one of polygon = [[x, y], ...] or "
                              "box = [x0, y0, x1, y1]")
        for name in ("min_altitude_m", "max_altitude_m"):
            if name not in t:
                raise ConfigError(f"{prefix}.{name}: missing")
        kw = {k: t[k] for k in ("margin_m", "inset_m") if k in t}
        for k, v in {**kw, "min_altitude_m": t["min_altitude_m"],
                     "max_altitude_m": t["max_altitude_m"]}.items():
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ConfigError(f"{prefix}.{k}: must be a finite number, got {v!r}")
        try:
            if "box" in t:
                b = t["box"]
                if not (isinstance(b, list) and len(b) == 4 and all(
                        isinstance(v, int | float) and not isinstance(v, bool) for v in b)):
                    raise ConfigError(f"{prefix}.box: must be [x0, y0, x1, y1] (numbers)")
                return cls.box((b[0], b[2]), (b[1], b[3]),
                               (t["min_altitude_m"], t["max_altitude_m"]), **kw)
            poly = t["polygon"]
            if not (isinstance(poly, list) and all(
                    isinstance(p, list) and len(p) == 2
                    and all(isinstance(v, int | float) and not isinstance(v, bool) for v in p)
                    for p in poly)):
                raise ConfigError(f"{prefix}.polygon: must be a list of [x, y] (numbers)")
            return cls(np.array(poly, float), t["min_altitude_m"], t["max_altitude_m"], **kw)
        except GeofenceError as exc:
            raise ConfigError(f"{prefix}: {exc}") from None

    # -- the three rules ---------------------------------------------------------------------

    def margin(self, points_m: np.ndarray) -> np.ndarray:
        """Signed distance to the boundary of each point (P, 3) or (3,) [m], > 0 inside."""
        p = np.atleast_2d(np.asarray(points_m, dtype=float))
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points: expected shape (P, 3), got {p.shape}")
        out = np.empty(p.shape[0])
        fence_margin(self.polygon_xy_m, float(self.min_altitude_m), float(self.max_altitude_m),
                     np.ascontiguousarray(p), out)
        return out

    def contains(self, point_m: np.ndarray, margin_m: float = 0.0) -> bool:
        """``point_m`` (3,) is at least ``margin_m`` inside."""
        return bool(self.margin(point_m)[0] >= margin_m)

    def check_reference(self, reference: Reference) -> None:
        """Raise :class:`GeofenceError` unless every point and piece of ``reference`` keeps
        :attr:`margin_m` inside (a looping reference: its closing piece too)."""
        pts = reference.points[:, :3]
        d = self.margin(pts)
        bad = np.flatnonzero(~(d >= self.margin_m))
        if bad.size:
            i = int(bad[0])
            raise GeofenceError(
                f"mission point {i} at t={reference.times_s[i]:.2f} s, {_fmt(pts[i])}, is "
                f"{_where(d[i], self.margin_m)}")
        ends = np.vstack([pts[1:], pts[:1]]) if reference.loop else pts[1:]
        if len(ends):
            s = first_too_close(self.polygon_xy_m, np.ascontiguousarray(pts[:len(ends), :2]),
                                np.ascontiguousarray(ends[:, :2]), float(self.margin_m))
            if s >= 0:
                raise GeofenceError(
                    f"mission piece {s} from {_fmt(pts[s])} to {_fmt(ends[s])} leaves the "
                    f"operational volume (or its {self.margin_m:.2f} m margin) between its "
                    "points")

    def offset_ceiling_m(self, reference_z_m: np.ndarray) -> float:
        """The highest avoidance offset over mission altitudes ``reference_z_m`` that keeps
        :attr:`margin_m` below the maximum altitude (≥ 0: an offset never goes negative)."""
        top = float(np.max(reference_z_m)) if np.size(reference_z_m) else -math.inf
        return max(0.0, self.max_altitude_m - self.margin_m - top)

    def recovery_point(self, point_m: np.ndarray) -> np.ndarray:
        """The nearest point :attr:`inset_m` inside, for a UAV at ``point_m`` (3,) outside
        (or too near the boundary); a point that far inside already is its own.

        Altitude: clamped into the inset band. Horizontally: stepped to ``inset_m`` from the
        nearest boundary point, away from it, until no edge is nearer (near a corner each step
        corrects for the other edge; a few steps suffice, at most :data:`RECOVERY_STEPS`).
        """
        p = np.asarray(point_m, dtype=float)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"point_m: expected a finite (3,) position, got {p!r}")
        poly = self.polygon_xy_m
        z = min(max(float(p[2]), self.min_altitude_m + self.inset_m),
                self.max_altitude_m - self.inset_m)
        x, y = float(p[0]), float(p[1])
        inward = 1.0 if _signed_area(poly) > 0.0 else -1.0
        for _ in range(RECOVERY_STEPS):
            d, k, cx, cy = _edge_distance(poly, x, y)
            inside = _inside_xy(poly, x, y)
            if inside and d >= self.inset_m - 1e-9:
                break
            ux, uy = x - cx, y - cy
            n = math.hypot(ux, uy)
            if n > 1e-12:
                sign = 1.0 if inside else -1.0
                ux, uy = sign * ux / n, sign * uy / n
            else:  # on the boundary: the edge's inward normal
                e = poly[(k + 1) % len(poly)] - poly[k]
                ux, uy = -inward * e[1] / math.hypot(*e), inward * e[0] / math.hypot(*e)
            # A step slightly past the inset: exactly at it, a corner's other edge would take
            # one more step per step forever.
            x, y = cx + ux * self.inset_m * (1.0 + 1e-9), cy + uy * self.inset_m * (1.0 + 1e-9)
        return np.array([x, y, z])


def _signed_area(poly: np.ndarray) -> float:
    return 0.5 * float(np.sum(poly[:, 0] * np.roll(poly[:, 1], -1)
                              - np.roll(poly[:, 0], -1) * poly[:, 1]))


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.2f}" for v in p[:3]) + ") m"


def _where(d: float, margin: float) -> str:
    if not np.isfinite(d):
        return "not a finite position"
    if d < 0.0:
        return f"outside the operational volume by {-d:.2f} m"
    return f"only {d:.2f} m inside the operational volume (the margin is {margin:.2f} m)"


class FenceWatch:
    """One UAV's failsafe: when it is found outside the volume, where to fly back to.

    A UAV taking off from below the floor is not outside until it has been inside once (the
    floor is an operational limit, not the ground); horizontally and above the ceiling it is
    outside from the start. Each exit counts as one breach and yields one recovery point; the
    UAV then holds there (:attr:`holding`) until :meth:`mission_accepted` (a new mission,
    checked against the same volume)."""

    def __init__(self, fence: Geofence) -> None:
        self.fence = fence
        self.entered = False
        self.outside = False
        self.holding = False
        self.breaches = 0
        #: The farthest outside it has been [m] (0: never).
        self.worst_outside_m = 0.0

    def check(self, position_m: np.ndarray, margin_m: float | None = None) -> np.ndarray | None:
        """The recovery point (3,) when ``position_m`` is a new exit, else None. ``margin_m``:
        the position's :meth:`Geofence.margin`, if the caller computed it in a batch."""
        f = self.fence
        d = float(f.margin(position_m)[0]) if margin_m is None else float(margin_m)
        if not math.isfinite(d):
            return None  # no position to judge (the estimate is the controller's problem)
        if d >= 0.0:
            self.entered = True
            self.outside = False
            return None
        p = np.asarray(position_m, dtype=float)
        if not self.entered and p[2] < f.min_altitude_m and f.margin(
                np.array([p[0], p[1], f.min_altitude_m + 1e-6]))[0] >= 0.0:
            return None  # climbing into the volume from below its floor
        self.worst_outside_m = max(self.worst_outside_m, -d)
        if self.outside:
            return None
        self.outside = True
        self.breaches += 1
        if self.holding:
            return None  # already flying back to a point inside
        self.holding = True
        return f.recovery_point(p)

    def mission_accepted(self) -> None:
        """A new mission (inside the volume) replaces the hold."""
        self.holding = False

    def report(self) -> dict[str, float | int | bool]:
        """What a run's summary says of it."""
        return {"breaches": self.breaches, "worst_outside_m": round(self.worst_outside_m, 3),
                "holding": self.holding}
