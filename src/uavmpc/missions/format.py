"""The one mission format: what a UAV is told to fly, whatever the source.

A scenario's ``[[uavs]]`` table, a mission sent to a node over the network (JSON), the mission
file a swarm hands each node, ``--goto`` on the command line and a goal or trajectory from
ROS 2 all become the same table, checked here by one validator, which names the field of any
problem. Exactly one of:

    goto = [x, y, z, heading]                   fly to a point and hold it, from now on
    trajectory = { points = [[x, y, z, heading], ...],
                   sample_period_s = 0.2,       (or times_s = [t0, t1, ...]: absolute stamps)
                   start_s = t,                 (absolute; default: now; not with times_s)
                   loop = false }
    path = { waypoints = [[x, y, z], ...],      a smooth path flown at a constant speed,
             speed_mps = v, sample_period_s = 0.2, start_s = t }     facing along it

Positions in metres in the ENU world frame, headings in radians, times in seconds on the UAV's
clock ("now" is 0 in a scenario, the node's clock for a mission it receives). A go-to that must
wait for a start time is a trajectory of one point.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.config import ConfigError, read_toml
from uavmpc.reference import (
    MAX_ABS_HEADING_RAD,
    MAX_ABS_POSITION_M,
    MAX_ABS_TIME_S,
    MAX_POINTS,
    MIN_SAMPLE_PERIOD_S,
    InvalidReferenceError,
    Reference,
)

__all__ = ["FORMS", "mission_from_json", "mission_from_table", "mission_table", "read_mission"]

#: The forms of a mission: exactly one of them is given.
FORMS = ("goto", "trajectory", "path")
#: At most one point an hour [s].
MAX_SAMPLE_PERIOD_S = 3600.0
#: The fastest a path may be flown [m/s].
MAX_PATH_SPEED_MPS = 100.0
_FIELDS = {
    "trajectory": ("points", "sample_period_s", "times_s", "start_s", "loop"),
    "path": ("waypoints", "speed_mps", "sample_period_s", "start_s"),
}
_FLOAT_MAX = float(np.finfo(float).max)


def _describe(value: object) -> str:
    # Never repr() a container: a deeply nested one would recurse, a large one flood logs.
    if isinstance(value, list | tuple | dict):
        return f"{'an object' if isinstance(value, dict) else 'a list'} of {len(value)}"
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:37]}..."


def _number(value: object, name: str, bound: float = _FLOAT_MAX) -> float:
    # bool is an int to Python; NaN fails every comparison; a huge integer is compared exactly
    # here (float() of it would raise OverflowError).
    if isinstance(value, np.floating | np.integer):
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InvalidReferenceError(f"{name}: must be a number, got {_describe(value)}")
    if not -bound <= value <= bound:
        within = "" if bound == _FLOAT_MAX else f" within ±{bound:g}"
        raise InvalidReferenceError(f"{name}: must be a finite number{within}, got "
                                    f"{_describe(value)}")
    return float(value)


def _list(value: object, name: str, what: str, least: int = 1) -> list[object]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, list | tuple) or len(value) < least:
        raise InvalidReferenceError(f"{name}: must be a list of {'≥ ' if least > 1 else ''}"
                                    f"{least if least > 1 else 'one or more'} {what}, got "
                                    f"{_describe(value)}")
    if len(value) > MAX_POINTS:
        raise InvalidReferenceError(f"{name}: {len(value)} entries, more than the limit "
                                    f"{MAX_POINTS}")
    return list(value)


def _row(value: object, name: str, heading: bool = True) -> list[float]:
    size = 4 if heading else 3
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, list | tuple) or len(value) != size:
        raise InvalidReferenceError(f"{name}: must be [x, y, z{', heading' if heading else ''}]"
                                    f", got {_describe(value)}")
    row = [_number(v, f"{name}[{j}]", MAX_ABS_POSITION_M) for j, v in enumerate(value[:3])]
    if heading:
        row.append(_number(value[3], f"{name}[3]", MAX_ABS_HEADING_RAD))
    return row


def _table(value: object, name: str, form: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise InvalidReferenceError(f"{name}: must be a table, got {_describe(value)}")
    _reject_unknown(value, _FIELDS[form], name)
    return value


def _reject_unknown(table: Mapping[str, Any], known: tuple[str, ...], name: str) -> None:
    # A typo ("sample_periods") must not silently fall back to a default. Named as the
    # scenario loader names its fields (uavmpc.config.reject_unknown), a long key cut short.
    unknown = sorted(str(k) for k in table if k not in known)
    if unknown:
        key = unknown[0] if len(unknown[0]) <= 40 else f"{unknown[0][:37]}..."
        raise InvalidReferenceError(f"{name}.{key}: unknown field (known: "
                                    f"{', '.join(sorted(known))})")


def _period(t: Mapping[str, Any], name: str) -> float:
    period = _number(t.get("sample_period_s", 0.2), f"{name}.sample_period_s",
                     MAX_SAMPLE_PERIOD_S)
    if period < MIN_SAMPLE_PERIOD_S:
        raise InvalidReferenceError(f"{name}.sample_period_s: must be ≥ {MIN_SAMPLE_PERIOD_S} s,"
                                    f" got {period:g}")
    return period


def _trajectory(t: Mapping[str, Any], name: str, now_s: float) -> Reference:
    rows = [_row(p, f"{name}.points[{k}]")
            for k, p in enumerate(_list(t.get("points"), f"{name}.points", "[x, y, z, heading]"))]
    loop = t.get("loop", False)
    if not isinstance(loop, bool):
        raise InvalidReferenceError(f"{name}.loop: must be true or false, got {_describe(loop)}")
    if "times_s" in t:
        clash = [k for k in ("sample_period_s", "start_s") if k in t]
        if clash:
            raise InvalidReferenceError(f"{name}.{clash[0]}: not with times_s (the stamps are "
                                        "absolute)")
        times = [_number(v, f"{name}.times_s[{k}]", MAX_ABS_TIME_S)
                 for k, v in enumerate(_list(t["times_s"], f"{name}.times_s", "stamps"))]
        if len(times) != len(rows):
            raise InvalidReferenceError(f"{name}.times_s: {len(times)} stamps for "
                                        f"{len(rows)} points")
        return Reference(np.array(times), np.array(rows), loop)
    start = _number(t.get("start_s", now_s), f"{name}.start_s", MAX_ABS_TIME_S)
    return Reference.sampled(np.array(rows), _period(t, name), start, loop=loop)


def _path(t: Mapping[str, Any], name: str, now_s: float) -> Reference:
    rows = [_row(p, f"{name}.waypoints[{k}]", heading=False)
            for k, p in enumerate(_list(t.get("waypoints"), f"{name}.waypoints", "[x, y, z]",
                                        least=2))]
    if "speed_mps" not in t:
        raise InvalidReferenceError(f"{name}.speed_mps: missing")
    speed = _number(t["speed_mps"], f"{name}.speed_mps", MAX_PATH_SPEED_MPS)
    if speed <= 0.0:
        raise InvalidReferenceError(f"{name}.speed_mps: must be > 0, got {speed:g}")
    start = _number(t.get("start_s", now_s), f"{name}.start_s", MAX_ABS_TIME_S)
    return Reference.along_path(np.array(rows), speed, start, _period(t, name))


def mission_from_table(table: Mapping[str, Any], where: str = "mission",
                       now_s: float = 0.0) -> Reference:
    """The desired trajectory a mission table describes (see the module's text).

    Args:
        table: exactly one of ``goto``, ``trajectory`` or ``path`` (and nothing else).
        where: the table's name in the caller's terms, e.g. ``uavs[2]`` or ``mission``: every
            error names the field under it.
        now_s: "now" on the UAV's clock [s]: when a go-to starts, and the default ``start_s``.

    Raises:
        InvalidReferenceError: the first problem, naming its field. Every value is known to be
            a finite number in range before it reaches numpy, so nothing else is raised from
            inside, whatever the table holds.
    """
    if not isinstance(table, Mapping):
        raise InvalidReferenceError(f"{where}: must be a table, got {_describe(table)}")
    _reject_unknown(table, FORMS, where)
    given = [k for k in FORMS if k in table]
    if len(given) != 1:
        raise InvalidReferenceError(f"{where}: needs exactly one of goto, trajectory or path,"
                                    f" got {' and '.join(given) or 'none'}")
    form = given[0]
    name = f"{where}.{form}"
    try:
        if form == "goto":
            r = _row(table["goto"], name)
            return Reference.goto(r[0], r[1], r[2], r[3],
                                  start_s=_number(now_s, "now_s", MAX_ABS_TIME_S))
        t = _table(table[form], name, form)
        return (_trajectory if form == "trajectory" else _path)(t, name, now_s)
    except InvalidReferenceError as exc:  # the Reference's own checks, named by our field
        text = str(exc)
        raise InvalidReferenceError(text if text.startswith(where) else f"{name}: {text}") \
            from None


def mission_from_json(payload: bytes, now_s: float, where: str = "mission") -> Reference:
    """A mission table sent as JSON bytes (over the network or in a file): as
    :func:`mission_from_table`, and a payload that is not a JSON object is refused by name."""
    try:
        data = json.loads(payload)
    except RecursionError:
        raise InvalidReferenceError(f"{where} is not JSON: nested too deeply") from None
    except (TypeError, ValueError) as exc:  # also bad UTF-8, and integers of > 4300 digits
        raise InvalidReferenceError(f"{where} is not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise InvalidReferenceError(f"{where} must be a JSON object, got {_describe(data)}")
    return mission_from_table(data, where, now_s)


def mission_table(reference: Reference) -> dict[str, Any]:
    """A trajectory as a mission table (absolute stamps), the inverse of
    :func:`mission_from_table`: JSON- and TOML-serialisable."""
    return {"trajectory": {"times_s": np.asarray(reference.times_s, dtype=float).tolist(),
                           "points": np.asarray(reference.points, dtype=float).tolist(),
                           "loop": bool(reference.loop)}}


def read_mission(path: str | Path, now_s: float) -> tuple[dict[str, Any], Reference]:
    """A mission file: JSON when its name ends in ``.json``, else TOML; its table and its
    trajectory.

    Raises:
        InvalidReferenceError: the file cannot be read or parsed, or its mission is invalid;
            the message names the file (and the field).
    """
    p = Path(path)
    if p.suffix.lower() == ".json":
        try:
            raw = p.read_bytes()
        except (OSError, ValueError) as exc:
            raise InvalidReferenceError(f"{p}: cannot read: {exc}") from None
        reference = mission_from_json(raw, now_s, str(p))
        return json.loads(raw), reference
    try:
        table = read_toml(p)
    except ConfigError as exc:
        raise InvalidReferenceError(str(exc)) from None
    return table, mission_from_table(table, str(p), now_s)
