"""Scenarios: who flies where, over which link, with which avoidance (SPEC §6).

A scenario is a TOML file (the built-ins live in this package as such files) validated on load
with errors that name the field, e.g. ``uavs[2].priority: duplicate of uavs[0]``.

    name = "swap_through_static"
    duration_s = 60.0
    [link]       latency_s, jitter_s, loss, range_m (0 = unlimited)
    [avoidance]  any AvoidanceParams field (defaults: the reference design)
    [[uavs]]     id, priority, airframe, start = [x, y, z], heading_rad,
                 goto = [x, y, z, heading]                       (one of)
                 trajectory = { points = [[x, y, z, heading], ...], sample_period_s, start_s, loop }
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.config import ConfigError, positive, read_toml, reject_unknown, take
from uavmpc.reference import InvalidReferenceError, Reference

BUILTIN = ("swap_through_static", "converge_center")
_ID = re.compile(r"^[A-Za-z0-9_-]{1,32}$")


@dataclass(frozen=True)
class LinkSettings:
    """The simulated broadcast link: latency = latency_s + U(0, jitter_s), loss probability,
    optional range limit (0 = unlimited)."""

    latency_s: float = 0.05
    jitter_s: float = 0.02
    loss: float = 0.0
    range_m: float = 0.0

    @classmethod
    def from_dict(cls, t: dict[str, Any], prefix: str = "link") -> LinkSettings:
        reject_unknown(t, {"latency_s", "jitter_s", "loss", "range_m"}, prefix)
        d = cls()
        loss = positive(t.get("loss", d.loss), f"{prefix}.loss", upper=1.0, allow_zero=True)
        if loss >= 1.0:
            raise ConfigError(f"{prefix}.loss: must be < 1, got {loss}")
        return cls(
            latency_s=positive(t.get("latency_s", d.latency_s), f"{prefix}.latency_s",
                               upper=10.0, allow_zero=True),
            jitter_s=positive(t.get("jitter_s", d.jitter_s), f"{prefix}.jitter_s", upper=10.0,
                              allow_zero=True),
            loss=loss,
            range_m=positive(t.get("range_m", d.range_m), f"{prefix}.range_m", allow_zero=True),
        )


@dataclass(frozen=True, eq=False)
class UavSpec:
    """One UAV of a scenario. ``mission`` is the desired trajectory (absolute times)."""

    uav_id: str
    priority: int
    airframe: str
    start_m: tuple[float, float, float]
    heading_rad: float
    mission: Reference
    goal_m: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario."""

    name: str
    duration_s: float
    uavs: tuple[UavSpec, ...]
    link: LinkSettings = field(default_factory=LinkSettings)
    avoidance: dict[str, Any] = field(default_factory=dict)


def _vec(value: Any, n: int, name: str) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise ConfigError(f"{name}: must be a list of {n} numbers, got {value!r}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ConfigError(f"{name}[{i}]: must be a finite number, got {v!r}")
        if abs(v) > 1e5:
            raise ConfigError(f"{name}[{i}]: {v} is beyond the sane bound 1e5")
        out.append(float(v))
    return tuple(out)


def _uav(t: dict[str, Any], i: int) -> UavSpec:
    p = f"uavs[{i}]"
    reject_unknown(t, {"id", "priority", "airframe", "start", "heading_rad", "goto",
                       "trajectory"}, p)
    uav_id = take(t, "id", p)
    if not isinstance(uav_id, str) or not _ID.match(uav_id):
        raise ConfigError(f"{p}.id: must be 1–32 characters of [A-Za-z0-9_-], got {uav_id!r}")
    priority = take(t, "priority", p)
    if isinstance(priority, bool) or not isinstance(priority, int) or not 0 <= priority < 2**31:
        raise ConfigError(f"{p}.priority: must be a non-negative integer, got {priority!r}")
    airframe = t.get("airframe", "f550")
    if not isinstance(airframe, str):
        raise ConfigError(f"{p}.airframe: must be a name or a TOML path, got {airframe!r}")
    start = _vec(take(t, "start", p), 3, f"{p}.start")
    if start[2] < 0.0:
        raise ConfigError(f"{p}.start[2]: must be ≥ 0 (ground), got {start[2]}")
    heading = t.get("heading_rad", 0.0)
    _vec([heading], 1, f"{p}.heading_rad")
    if ("goto" in t) == ("trajectory" in t):
        raise ConfigError(f"{p}: needs exactly one of 'goto' or 'trajectory'")
    try:
        if "goto" in t:
            goal = _vec(t["goto"], 4, f"{p}.goto")
            mission = Reference.goto(*goal)
        else:
            tr = t["trajectory"]
            reject_unknown(tr, {"points", "sample_period_s", "start_s", "loop"},
                           f"{p}.trajectory")
            pts = take(tr, "points", f"{p}.trajectory")
            if not isinstance(pts, list) or not pts:
                raise ConfigError(f"{p}.trajectory.points: must be a non-empty list")
            rows = [_vec(r, 4, f"{p}.trajectory.points[{k}]") for k, r in enumerate(pts)]
            mission = Reference.sampled(np.array(rows), tr.get("sample_period_s", 0.2),
                                        tr.get("start_s", 0.0), loop=bool(tr.get("loop", False)))
            goal = rows[-1]
    except InvalidReferenceError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    return UavSpec(uav_id, priority, airframe, start, float(heading), mission,
                   (goal[0], goal[1], goal[2]))


def from_dict(data: dict[str, Any], source: str = "scenario") -> Scenario:
    """Validate a parsed scenario table."""
    reject_unknown(data, {"name", "duration_s", "link", "avoidance", "uavs"}, source)
    name = data.get("name", source)
    duration = positive(take(data, "duration_s", source), "duration_s", upper=7 * 24 * 3600.0)
    uavs_raw = take(data, "uavs", source)
    if not isinstance(uavs_raw, list) or not uavs_raw:
        raise ConfigError("uavs: must be a non-empty list of [[uavs]] tables")
    if len(uavs_raw) > 1000:
        raise ConfigError(f"uavs: {len(uavs_raw)} UAVs, more than the limit 1000")
    uavs = tuple(_uav(t, i) for i, t in enumerate(uavs_raw))
    seen_id: dict[str, int] = {}
    seen_prio: dict[int, int] = {}
    for i, u in enumerate(uavs):
        if u.uav_id in seen_id:
            raise ConfigError(f"uavs[{i}].id: duplicate of uavs[{seen_id[u.uav_id]}]")
        if u.priority in seen_prio:
            raise ConfigError(f"uavs[{i}].priority: duplicate of uavs[{seen_prio[u.priority]}]")
        seen_id[u.uav_id], seen_prio[u.priority] = i, i
    link = LinkSettings.from_dict(data.get("link", {}))
    avoidance = data.get("avoidance", {})
    if not isinstance(avoidance, dict):
        raise ConfigError("avoidance: must be a table")
    return Scenario(str(name), duration, uavs, link, dict(avoidance))


def load(name_or_path: str | Path) -> Scenario:
    """A built-in scenario by name, or a scenario TOML file."""
    if str(name_or_path) in BUILTIN:
        text = resources.files("uavmpc.scenarios").joinpath(f"{name_or_path}.toml").read_bytes()
        import tomllib

        return from_dict(tomllib.loads(text.decode()), str(name_or_path))
    path = Path(name_or_path)
    if not path.exists():
        raise ConfigError(
            f"{name_or_path}: neither a built-in scenario ({', '.join(BUILTIN)}) nor a file")
    return from_dict(read_toml(path), path.stem)
