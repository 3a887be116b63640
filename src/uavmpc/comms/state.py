"""A node's state as it tells its swarm's monitor (``uavmpc/<swarm>/<id>/state``, ~20 Hz).

Not what other UAVs fly on (that is the signed prediction, :mod:`uavmpc.comms.message`): this
is what an observer draws and judges collisions by. A compact JSON object, written and read only
here; :meth:`NodeState.decode` checks every field, so a malformed or hostile message is refused
by name and never reaches the monitor's arithmetic.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass

__all__ = ["InvalidStateError", "NodeState"]

#: Bounds of a sane state: a position within 100 km, a time within ±1e11 s (Unix time), an
#: offset within 1 km, at most this many ids per list.
_MAX_ABS_M = 1.0e5
_MAX_ABS_T_S = 1.0e11
_MAX_OFFSET_M = 1.0e3
_MAX_IDS = 1000
_ID = re.compile(r"[A-Za-z0-9_-]{1,32}")


class InvalidStateError(ValueError):
    """A state message that is not one (the text names the field)."""


@dataclass(frozen=True)
class NodeState:
    """One UAV's state, as its node publishes it.

    Attributes:
        t_s: the node's clock (Unix time) [s].
        position_m: (x, y, z) ENU [m]; velocity_mps: ENU [m/s]; heading_rad: yaw from east.
        command_m: where the tracker's command puts it now (the virtual UAV) [m].
        z_offset_m: the avoidance's height offset in force [m] (≥ 0).
        avoiding: its avoidance is active.
        conflicts, yielding_to, waiting_for: the ids its last decision names.
    """

    t_s: float
    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    heading_rad: float
    command_m: tuple[float, float, float]
    z_offset_m: float = 0.0
    avoiding: bool = False
    conflicts: tuple[str, ...] = ()
    yielding_to: tuple[str, ...] = ()
    waiting_for: tuple[str, ...] = ()
    #: The assumptions of the safety argument broken now, one line each (it holds meanwhile).
    broken: tuple[str, ...] = ()

    def encode(self) -> bytes:
        """The message's bytes (compact JSON)."""
        return json.dumps(asdict(self), separators=(",", ":"), allow_nan=False).encode()

    @classmethod
    def decode(cls, payload: bytes) -> NodeState:
        """The state in ``payload``.

        Raises:
            InvalidStateError: not JSON, not an object, a field missing, unknown, of the wrong
                type or out of bounds (named).
        """
        try:
            data = json.loads(payload)
        except (RecursionError, TypeError, ValueError) as exc:
            raise InvalidStateError(f"state: not JSON ({type(exc).__name__})") from None
        if not isinstance(data, dict):
            raise InvalidStateError("state: not a JSON object")
        known = cls.__dataclass_fields__
        unknown = sorted(str(k)[:40] for k in data if k not in known)
        if unknown:
            raise InvalidStateError(f"state.{unknown[0]}: unknown field")
        missing = [k for k in ("t_s", "position_m", "velocity_mps", "heading_rad", "command_m")
                   if k not in data]
        if missing:
            raise InvalidStateError(f"state.{missing[0]}: missing")
        return cls(
            t_s=_number(data["t_s"], "t_s", _MAX_ABS_T_S),
            position_m=_vec3(data["position_m"], "position_m"),
            velocity_mps=_vec3(data["velocity_mps"], "velocity_mps"),
            heading_rad=_number(data["heading_rad"], "heading_rad", 1.0e6),
            command_m=_vec3(data["command_m"], "command_m"),
            z_offset_m=_number(data.get("z_offset_m", 0.0), "z_offset_m", _MAX_OFFSET_M),
            avoiding=_flag(data.get("avoiding", False), "avoiding"),
            conflicts=_ids(data.get("conflicts", []), "conflicts"),
            yielding_to=_ids(data.get("yielding_to", []), "yielding_to"),
            waiting_for=_ids(data.get("waiting_for", []), "waiting_for"),
            broken=_texts(data.get("broken", []), "broken"),
        )


def _number(value: object, name: str, bound: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            math.isfinite(value) and abs(value) <= bound):
        raise InvalidStateError(f"state.{name}: must be a finite number within ±{bound:g}")
    return float(value)


def _vec3(value: object, name: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise InvalidStateError(f"state.{name}: must be [x, y, z]")
    x, y, z = (_number(v, f"{name}[{k}]", _MAX_ABS_M) for k, v in enumerate(value))
    return x, y, z


def _flag(value: object, name: str) -> bool:
    if not isinstance(value, bool):
        raise InvalidStateError(f"state.{name}: must be true or false")
    return value


def _ids(value: object, name: str) -> tuple[str, ...]:
    if not isinstance(value, list) or len(value) > _MAX_IDS or not all(
            isinstance(v, str) and _ID.fullmatch(v) for v in value):
        raise InvalidStateError(f"state.{name}: must be a list of UAV ids")
    return tuple(value)


def _texts(value: object, name: str) -> tuple[str, ...]:
    if not isinstance(value, list) or len(value) > _MAX_IDS or not all(
            isinstance(v, str) and len(v) <= 200 for v in value):
        raise InvalidStateError(f"state.{name}: must be a list of short texts")
    return tuple(value)
