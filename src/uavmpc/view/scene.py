"""The 3-D scene of a flight as Foxglove ``SceneUpdate`` messages (JSON encoding, checked
against Foxglove's published schemas in ``uavmpc/data/foxglove``).

One pure function, :func:`scene_update`, turns a snapshot (:class:`UavView` per UAV, the
geofence, other objects) into a message: the same message goes into a log file
(:class:`uavmpc.log.FlightRecorder`) and to a live viewer (:mod:`uavmpc.view.live`). Entities,
all in the frame ``"world"`` (ENU, metres):

- ``<id>/body``: a sphere at the UAV's position and an arrow along its heading, with its id
  and z offset as a label;
- ``<id>/plan``: its 8 s prediction as broadcast (line strip);
- ``<id>/desired``: its desired trajectory over the same horizon, before the avoidance raised
  it (thin line strip);
- ``<id>/cylinder``: its avoidance cylinder (radius R_p, height H_p) around its position,
  coloured by :data:`STATES`;
- ``ground``, ``geofence`` (the operational volume's edges), and any :class:`ObjectView`
  (the car and deck of the landing scenario).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

#: Cylinder states, in the order one wins over the next: a UAV whose radio is silent, one
#: holding its climb until the way is clear, one yielding (climbing, or holding a raised
#: offset), one in a conflict the others resolve (it only slows down), one with nothing near.
STATES = ("silent", "waiting", "yielding", "avoiding", "free")

#: RGBA by state (translucent: the cylinders overlap the bodies and plans).
STATE_COLORS: dict[str, tuple[float, float, float, float]] = {
    "free": (0.20, 0.70, 0.30, 0.15),
    "avoiding": (1.00, 0.65, 0.00, 0.30),
    "yielding": (0.15, 0.45, 1.00, 0.30),
    "waiting": (0.65, 0.25, 0.90, 0.35),
    "silent": (0.50, 0.50, 0.50, 0.35),
}

#: Distinct body/plan colours, cycled over the UAVs.
_PALETTE = ((0.12, 0.47, 0.71), (1.00, 0.50, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16),
            (0.58, 0.40, 0.74), (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.50, 0.50, 0.50),
            (0.74, 0.74, 0.13), (0.09, 0.75, 0.81))

FRAME = "world"
SCENE_SCHEMA = "foxglove.SceneUpdate"
#: The plot-ready numbers beside the scene (``/metrics``): the closest pair's distance [m], and
#: per UAV its cylinder state (:data:`STATES`) and whom it yields to or waits for, its z
#: offset [m], how far its virtual UAV is outside its limits, its tracker fallbacks (ticks)
#: and whether it is avoiding.
METRICS_SCHEMA: dict[str, Any] = {
    "title": "uavmpc.Metrics",
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "min_distance_m": {"type": ["number", "null"]},
        "uavs": {"type": "object", "additionalProperties": {
            "type": "object", "properties": {
                "state": {"type": "string", "enum": list(STATES)}, "detail": {"type": "string"},
                "z_offset_m": {"type": "number"}, "limit_excess": {"type": "number"},
                "tracker_fallbacks": {"type": "integer"}, "avoiding": {"type": "boolean"}}}},
    },
}


@cache
def published_schema(name: str) -> str:
    """Foxglove's published JSON schema text of ``name`` (e.g. ``"foxglove.SceneUpdate"``)."""
    short = name.removeprefix("foxglove.")
    return resources.files("uavmpc").joinpath(f"data/foxglove/{short}.json").read_text()


@dataclass(frozen=True, eq=False)
class UavView:
    """One UAV as the scene shows it (ENU world frame, SI units).

    Attributes:
        uav_id: its id.
        position_m: (3,) where it is.
        heading_rad: its heading (yaw from +x, counter-clockwise).
        plan_m: (m, 3) its prediction as broadcast (with the avoidance offset), or (0, 3).
        desired_m: (k, 3) its desired trajectory over the same horizon, without the offset,
            or (0, 3).
        z_offset_m: the avoidance offset in force.
        state: one of :data:`STATES`.
        radius_m, height_m: its avoidance cylinder (R_p, H_p).
        detail: a short line for the label (e.g. ``"yielding to uav1"``).
    """

    uav_id: str
    position_m: np.ndarray
    heading_rad: float
    plan_m: np.ndarray
    desired_m: np.ndarray
    z_offset_m: float
    state: str
    radius_m: float
    height_m: float
    detail: str = ""

    def __post_init__(self) -> None:
        if self.state not in STATES:
            raise ValueError(f"state: must be one of {', '.join(STATES)}, got {self.state!r}")
        for name in ("plan_m", "desired_m"):
            a = np.asarray(getattr(self, name), dtype=float).reshape(-1, 3)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "position_m", np.asarray(self.position_m, dtype=float))


@dataclass(frozen=True, eq=False)
class ObjectView:
    """Something else in the scene: a box (``size_m`` (3,)) centred at ``position_m`` (3,),
    turned by ``heading_rad``, in colour ``rgba``."""

    object_id: str
    position_m: np.ndarray
    heading_rad: float
    size_m: tuple[float, float, float]
    rgba: tuple[float, float, float, float] = (0.3, 0.3, 0.3, 1.0)


def state_of(*, silent: bool, waiting_for: Sequence[str], yielding_to: Sequence[str],
             z_offset_m: float, avoiding: bool) -> str:
    """The cylinder state (:data:`STATES`) of a UAV from its avoidance decision and the
    offset in force."""
    if silent:
        return "silent"
    if waiting_for:
        return "waiting"
    if yielding_to or z_offset_m > 0.0:
        return "yielding"
    return "avoiding" if avoiding else "free"


def detail_of(*, yielding_to: Sequence[str], waiting_for: Sequence[str]) -> str:
    """A label's second line: whom a UAV yields to, or waits for."""
    if yielding_to:
        return "yielding to " + ", ".join(yielding_to)
    if waiting_for:
        return "waiting for " + ", ".join(waiting_for)
    return ""


def stamp(t_s: float) -> dict[str, int]:
    """A Foxglove time (``sec``, ``nsec``) from seconds (≥ 0)."""
    ns = max(0, round(t_s * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def pose(p: Sequence[float] | np.ndarray, heading_rad: float = 0.0) -> dict[str, Any]:
    """A Foxglove pose at ``p`` turned by ``heading_rad`` about z."""
    x, y, z = (float(v) for v in p)
    half = 0.5 * float(heading_rad)
    return {"position": {"x": x, "y": y, "z": z},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(half), "w": math.cos(half)}}


def _color(rgba: Sequence[float]) -> dict[str, float]:
    r, g, b, a = (float(v) for v in rgba)
    return {"r": r, "g": g, "b": b, "a": a}


def _vec(x: float, y: float, z: float) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "z": float(z)}


def _entity(t_s: float, entity_id: str, **primitives: list[dict[str, Any]]) -> dict[str, Any]:
    e: dict[str, Any] = {
        "timestamp": stamp(t_s), "frame_id": FRAME, "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
        "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "lines": [],
        "triangles": [], "texts": [], "models": []}
    e.update(primitives)
    return e


def _line(points: np.ndarray, rgba: Sequence[float], thickness: float, *,
          line_type: int = 0) -> dict[str, Any]:
    """``line_type``: 0 a strip through the points, 2 a list of segments (pairs)."""
    return {"type": line_type, "pose": pose((0.0, 0.0, 0.0)), "thickness": thickness,
            "scale_invariant": True,
            "points": [_vec(*p) for p in np.asarray(points, dtype=float).tolist()],
            "color": _color(rgba), "colors": [], "indices": []}


def _uav_entities(t_s: float, u: UavView, rgb: Sequence[float]) -> list[dict[str, Any]]:
    p = u.position_m
    label = f"{u.uav_id}  +{u.z_offset_m:.1f} m" + (f"\n{u.detail}" if u.detail else "")
    body = _entity(
        t_s, f"{u.uav_id}/body",
        spheres=[{"pose": pose(p), "size": _vec(0.6, 0.6, 0.25), "color": _color((*rgb, 1.0))}],
        arrows=[{"pose": pose(p, u.heading_rad), "shaft_length": 0.8, "shaft_diameter": 0.08,
                 "head_length": 0.3, "head_diameter": 0.2, "color": _color((*rgb, 1.0))}],
        texts=[{"pose": pose(p + np.array([0.0, 0.0, 0.5 * u.height_m + 0.5])),
                "billboard": True, "font_size": 14.0, "scale_invariant": True,
                "color": _color((1.0, 1.0, 1.0, 1.0)), "text": label}])
    out = [body]
    out.append(_entity(t_s, f"{u.uav_id}/plan",
                       lines=[_line(u.plan_m, (*rgb, 1.0), 3.0)] if len(u.plan_m) > 1 else []))
    out.append(_entity(t_s, f"{u.uav_id}/desired",
                       lines=[_line(u.desired_m, (*rgb, 0.45), 1.5)]
                       if len(u.desired_m) > 1 else []))
    out.append(_entity(
        t_s, f"{u.uav_id}/cylinder",
        cylinders=[{"pose": pose(p), "size": _vec(2 * u.radius_m, 2 * u.radius_m, u.height_m),
                    "bottom_scale": 1.0, "top_scale": 1.0,
                    "color": _color(STATE_COLORS[u.state])}],
        metadata=[{"key": "state", "value": u.state}]))
    return out


def _fence_entity(t_s: float, polygon_xy_m: np.ndarray, z_min_m: float,
                  z_max_m: float) -> dict[str, Any]:
    poly = np.asarray(polygon_xy_m, dtype=float)
    segments = []
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        for z in (z_min_m, z_max_m):
            segments += [(a[0], a[1], z), (b[0], b[1], z)]
        segments += [(a[0], a[1], z_min_m), (a[0], a[1], z_max_m)]
    return _entity(t_s, "geofence", lines=[_line(np.array(segments), (0.95, 0.3, 0.3, 0.9), 2.0,
                                                  line_type=2)])


def ground_entity(t_s: float, centre_xy_m: Sequence[float], half_m: float,
                  spacing_m: float = 10.0) -> dict[str, Any]:
    """A flat ground with grid lines every ``spacing_m``, ``half_m`` around the centre."""
    cx, cy = (float(v) for v in centre_xy_m)
    n = max(1, math.ceil(half_m / spacing_m))
    ticks = np.arange(-n, n + 1) * spacing_m
    segs = []
    for s in ticks:
        segs += [(cx + s, cy - n * spacing_m, 0.0), (cx + s, cy + n * spacing_m, 0.0),
                 (cx - n * spacing_m, cy + s, 0.0), (cx + n * spacing_m, cy + s, 0.0)]
    side = 2 * n * spacing_m
    return _entity(t_s, "ground",
                   cubes=[{"pose": pose((cx, cy, -0.05)), "size": _vec(side, side, 0.1),
                           "color": _color((0.25, 0.27, 0.25, 1.0))}],
                   lines=[_line(np.array(segs), (0.6, 0.6, 0.6, 0.5), 1.0, line_type=2)])


def ground_around(points_m: np.ndarray, margin_m: float = 20.0) -> dict[str, Any]:
    """A ground under ``points_m`` ((n, 3), e.g. a scenario's starts and waypoints), with
    ``margin_m`` to spare on every side."""
    pts = np.asarray(points_m, dtype=float).reshape(-1, 3)
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    return ground_entity(0.0, 0.5 * (lo + hi), 0.5 * float((hi - lo).max()) + margin_m)


def scene_update(t_s: float, uavs: Sequence[UavView], *,
                 fence: tuple[np.ndarray, float, float] | None = None,
                 objects: Sequence[ObjectView] = (),
                 ground: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``foxglove.SceneUpdate`` (as a JSON-ready dict) of one snapshot at ``t_s``.

    ``fence``: (polygon (n, 2), minimum altitude, maximum altitude) [m]; ``ground``: an entity
    from :func:`ground_around` (made once, stamped here with every update). Entities keep
    their ids from one update to the next, so that each replaces the last."""
    entities: list[dict[str, Any]] = [] if ground is None else [
        dict(ground, timestamp=stamp(t_s))]
    for i, u in enumerate(uavs):
        entities += _uav_entities(t_s, u, _PALETTE[i % len(_PALETTE)])
    if fence is not None:
        entities.append(_fence_entity(t_s, *fence))
    for o in objects:
        entities.append(_entity(t_s, o.object_id, cubes=[{
            "pose": pose(o.position_m, o.heading_rad), "size": _vec(*o.size_m),
            "color": _color(o.rgba)}]))
    return {"deletions": [], "entities": entities}


def metrics_update(t_s: float, min_distance_m: float | None, views: Sequence[UavView],
                   rows: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The plot-ready numbers shown beside a :func:`scene_update` (the live view's plots, a
    flight log's metrics): the closest pair's distance [m] and, per UAV, what its driver
    knows (``rows``: its z offset, whether it avoids, …) with its view's cylinder state and
    whom it yields to or waits for."""
    out = {uav: dict(row) for uav, row in rows.items()}
    for v in views:
        out.setdefault(v.uav_id, {}).update(state=v.state, detail=v.detail)
    return {"t_s": t_s, "min_distance_m": min_distance_m, "uavs": out}


def encode(msg: dict[str, Any]) -> bytes:
    """The JSON bytes of a message (compact)."""
    return json.dumps(msg, separators=(",", ":")).encode()
