"""Flying in formation along a leader's plan (SPEC §6, *formation*).

The leader flies any mission. Each follower derives its desired trajectory from the leader's
broadcast prediction (the 8 s plan every UAV sends at 2 Hz for the avoidance, received over the
same lossy link) plus its slot: at every predicted time ``t_k`` the slot is the leader's
predicted position plus the follower's offset turned into the formation frame, whose forward
axis is the leader's predicted direction of travel (:func:`formation_frame`). So the formation
moves as the leader *plans* to move, not as it moved: a follower's tracker sees the leader's
turns 8 s ahead. The plan is continued past its end at its last velocity (:func:`extend_plan`)
so that a plan received late still covers the follower's whole horizon.

Offsets are given in the formation frame (forward, left, up) relative to the leader, by shape
(:func:`slot_offsets`); a shape change is blended over ``transition_s`` (a smooth step), so
the slots move continuously and never jump.

How the avoidance treats members: members keep each other at the formation's spacing by
construction, and a shape change brings them to 0.7 spacing — inside the avoidance cylinder's
radius ``R_p`` (4.2 m with the default 6 m spacing and 5 m cylinder) — so between members the
avoidance applies a member cylinder of radius
``member_radius_m`` (default 2.5 m, and the full height) instead: it still acts if two members
come that close (a follower's slot tracking fails, a shape change goes wrong), but it does not
make members climb away from slots that are exactly where they should be. Everyone outside the
formation is met with the full cylinder: an outside UAV crossing the formation is avoided as
any other.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.config import ConfigError, describe, finite, positive, read_toml, reject_unknown, take
from uavmpc.missions.mission import MissionInput, MissionOutput
from uavmpc.reference import (
    MAX_ABS_HEADING_RAD,
    MAX_ABS_TIME_S,
    InvalidReferenceError,
    Reference,
)

__all__ = ["SHAPES", "FormationFollower", "FormationSpec", "extend_plan", "formation_error",
           "formation_frame", "formation_table", "load_formation", "slot_offsets",
           "slot_positions"]

SHAPES = ("line", "square")
#: Below this speed the direction of travel is not used (the last one is kept).
MIN_TRACK_SPEED_MPS = 1.0
#: A follower extends the leader's plan past its end at its last velocity for this long
#: (every :data:`EXTEND_STEP_S`): a received plan is up to a broadcast period plus the
#: latency old, and without the extension the follower's own plan would stop where the
#: leader's ends — found with 30 % loss: a follower climbed over another whose stale plan
#: seemed to stop 7 s ahead.
EXTEND_S = 2.0
EXTEND_STEP_S = 0.2


def slot_offsets(shape: str, n: int, spacing_m: float) -> np.ndarray:
    """(n, 3) slots of n members in the formation frame (forward, left, up) [m], relative to
    member 0 (the leader).

    * ``line``: abreast, members to the leader's right, ``spacing_m`` apart;
    * ``square``: two deep, columns ``spacing_m`` apart (4 members: a square with the leader at
      its front left). Member j's slot moves between the two shapes without crossing another's
      path closer than 0.7 spacing (4 members)."""
    if shape not in SHAPES:
        raise ValueError(f"shape: must be one of {', '.join(SHAPES)}, got {shape!r}")
    j = np.arange(n)
    out = np.zeros((n, 3))
    if shape == "line":
        out[:, 1] = -spacing_m * j
    else:
        out[:, 0] = -spacing_m * (j % 2)
        out[:, 1] = -spacing_m * (j // 2)
    return out


def formation_frame(times_s: np.ndarray, positions_m: np.ndarray, fallback_rad: float
                    ) -> np.ndarray:
    """The formation's heading [rad] at each of (m,) times along a path (m, 3): the direction
    of horizontal travel where the path moves faster than :data:`MIN_TRACK_SPEED_MPS`, else the
    last such direction (``fallback_rad`` before the first); continuous (unwrapped)."""
    t = np.asarray(times_s, dtype=float)
    p = np.asarray(positions_m, dtype=float)
    if t.shape[0] < 2:
        return np.full(t.shape, fallback_rad)
    vx = np.gradient(p[:, 0], t)
    vy = np.gradient(p[:, 1], t)
    moving = np.hypot(vx, vy) >= MIN_TRACK_SPEED_MPS
    angle = np.arctan2(vy, vx)
    out = np.empty(t.shape)
    last = fallback_rad
    for k in range(t.shape[0]):
        if moving[k]:
            last = last + math.remainder(angle[k] - last, 2.0 * math.pi)
        out[k] = last
    return out


@dataclass(frozen=True)
class FormationSpec:
    """A formation (validated from a scenario's ``[formation]`` table).

    Attributes:
        leader: the leader's id; followers: the others' ids, in slot order.
        spacing_m: distance between neighbouring slots.
        shape: the shape at the start; changes: ``((t_s, shape), ...)`` later ones.
        transition_s: how long a shape change takes.
        member_radius_m: the avoidance cylinder's radius between members (see the module doc).
        heading_rad: the formation's heading until the leader first moves.
        period_s: the followers' step.
    """

    leader: str
    followers: tuple[str, ...]
    spacing_m: float = 6.0
    shape: str = "line"
    changes: tuple[tuple[float, str], ...] = ()
    transition_s: float = 8.0
    member_radius_m: float = 2.5
    heading_rad: float = 0.0
    period_s: float = 0.1

    @property
    def members(self) -> tuple[str, ...]:
        return (self.leader, *self.followers)

    def pair_radii(self, uav_id: str) -> dict[str, float]:
        """The avoidance cylinder radius member ``uav_id`` applies to each other member."""
        return {m: self.member_radius_m for m in self.members if m != uav_id}

    def offsets_at(self, t_s: np.ndarray) -> np.ndarray:
        """(m, n, 3) every member's slot offset at each of the (m,) times, shape changes
        blended."""
        n = len(self.members)
        t = np.asarray(t_s, dtype=float)
        out = np.broadcast_to(slot_offsets(self.shape, n, self.spacing_m), (t.shape[0], n, 3))
        out = out.copy()
        for t_change, shape in self.changes:
            u = np.clip((t - t_change) / self.transition_s, 0.0, 1.0)
            w = (u * u * (3.0 - 2.0 * u))[:, None, None]  # smooth step
            out = (1.0 - w) * out + w * slot_offsets(shape, n, self.spacing_m)[None]
        return out

    @classmethod
    def from_dict(cls, t: dict[str, Any], ids: set[str], prefix: str = "formation"
                  ) -> FormationSpec:
        """From a TOML table; ``ids`` are the scenario's UAVs."""
        if not isinstance(t, dict):
            raise ConfigError(f"{prefix}: must be a table")
        reject_unknown(t, {"leader", "followers", "spacing_m", "shape", "changes",
                           "transition_s", "member_radius_m", "heading_rad", "period_s"}, prefix)
        leader = take(t, "leader", prefix)
        followers = take(t, "followers", prefix)
        if not isinstance(followers, list) or not followers:
            raise ConfigError(f"{prefix}.followers: must be a non-empty list of UAV ids")
        members = [leader, *followers]
        for k, m in enumerate(members):
            where = f"{prefix}.leader" if k == 0 else f"{prefix}.followers[{k - 1}]"
            # Checked first: `m not in ids` of a list or a table raises TypeError (unhashable).
            if not isinstance(m, str):
                raise ConfigError(f"{where}: must be a UAV id string, got {describe(m)}")
            if m not in ids:
                raise ConfigError(f"{where}: {m!r} is not a UAV of the scenario")
            if m in members[:k]:
                raise ConfigError(f"{where}: {m!r} is in the formation twice")
        shape = t.get("shape", "line")
        if shape not in SHAPES:
            raise ConfigError(f"{prefix}.shape: must be one of {', '.join(SHAPES)}, got "
                              f"{describe(shape)}")
        changes: list[tuple[float, str]] = []
        raw = t.get("changes", [])
        if not isinstance(raw, list):
            raise ConfigError(f"{prefix}.changes: must be a list of {{ t_s, shape }} tables")
        for k, c in enumerate(raw):
            p = f"{prefix}.changes[{k}]"
            if not isinstance(c, dict):
                raise ConfigError(f"{p}: must be a table {{ t_s, shape }}")
            reject_unknown(c, {"t_s", "shape"}, p)
            # Scenario times, or absolute ones on a swarm's wall clock (Unix time).
            at = positive(take(c, "t_s", p), f"{p}.t_s", upper=1e10, allow_zero=True)
            if changes and at <= changes[-1][0]:
                raise ConfigError(f"{p}.t_s: changes must be in time order")
            s = take(c, "shape", p)
            if s not in SHAPES:
                raise ConfigError(f"{p}.shape: must be one of {', '.join(SHAPES)}, got "
                                  f"{describe(s)}")
            changes.append((at, s))
        # Bounded as every reference heading is (the followers' slots are references); an
        # integer beyond the float range is refused, not an OverflowError of math.isfinite().
        heading = finite(t.get("heading_rad", 0.0), f"{prefix}.heading_rad",
                         MAX_ABS_HEADING_RAD)
        d = cls("", ())
        spacing = positive(t.get("spacing_m", d.spacing_m), f"{prefix}.spacing_m", upper=1000.0)
        radius = positive(t.get("member_radius_m", d.member_radius_m),
                          f"{prefix}.member_radius_m", upper=1000.0)
        if radius >= 0.75 * spacing:
            raise ConfigError(f"{prefix}.member_radius_m: must be < 0.75 spacing_m = "
                              f"{0.75 * spacing} (slots meet at 0.7 spacing in a shape change), "
                              f"got {radius}")
        return cls(leader=str(leader), followers=tuple(str(f) for f in followers),
                   spacing_m=spacing, shape=str(shape), changes=tuple(changes),
                   transition_s=positive(t.get("transition_s", d.transition_s),
                                         f"{prefix}.transition_s", upper=3600.0),
                   member_radius_m=radius, heading_rad=heading,
                   period_s=positive(t.get("period_s", d.period_s), f"{prefix}.period_s",
                                     upper=10.0))


def load_formation(path: str | Path) -> FormationSpec:
    """A formation from a file: JSON (as ``uavmpc swarm`` writes for its nodes) or TOML, the
    ``[formation]`` table's fields at the top level or under ``[formation]``."""
    p = Path(path)
    if p.suffix == ".json":
        try:
            data = json.loads(p.read_text())
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{p}: {exc}") from None
    else:
        data = read_toml(p)
    if isinstance(data, dict) and "formation" in data:
        data = data["formation"]
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: must hold a formation table")
    # The file names its own members; only strings can be ids (from_dict names anything else,
    # and a list among them would make the set comprehension raise TypeError: unhashable).
    followers = data.get("followers")
    members = [data.get("leader"), *(followers if isinstance(followers, list) else [])]
    return FormationSpec.from_dict(data, {m for m in members if isinstance(m, str)},
                                   prefix=f"{p.name}: formation")


def formation_table(spec: FormationSpec, shift_s: float = 0.0) -> dict[str, Any]:
    """``spec`` as a ``[formation]`` table (JSON-serialisable), its shape changes' times moved
    by ``shift_s`` (e.g. onto the wall clock of a swarm's epoch)."""
    return {"leader": spec.leader, "followers": list(spec.followers),
            "spacing_m": spec.spacing_m, "shape": spec.shape,
            "changes": [{"t_s": t + shift_s, "shape": shape} for t, shape in spec.changes],
            "transition_s": spec.transition_s, "member_radius_m": spec.member_radius_m,
            "heading_rad": spec.heading_rad, "period_s": spec.period_s}


class FormationFollower:
    """One follower's mission (:class:`~uavmpc.missions.mission.Mission`): its slot along the
    leader's newest received plan.

    Attributes:
        plans_used: leader predictions it built a desired trajectory from.
    """

    def __init__(self, spec: FormationSpec, uav_id: str) -> None:
        if uav_id not in spec.followers:
            raise ValueError(f"{uav_id!r} is not a follower of the formation")
        self.spec = spec
        self.uav_id = uav_id
        self.index = spec.members.index(uav_id)
        self.period_s = spec.period_s
        self.plans_used = 0
        self._used_stamp: float | None = None
        self._heading = spec.heading_rad

    def command(self, payload: bytes, now_s: float) -> bool:
        """A shape change sent while flying: JSON ``{"shape": "square", "at_s": T}`` (``at_s``
        absolute, default ``now_s``), blended from then on like a scheduled one. A repeat of a
        change already taken is ignored (False); a bad or out-of-order one raises ValueError
        naming the problem."""
        try:
            cmd = json.loads(payload)
        except RecursionError:
            raise ValueError("formation command is not JSON: nested too deeply") from None
        except (TypeError, ValueError) as exc:  # also bad UTF-8
            raise ValueError(f"formation command is not JSON: {exc}") from None
        if not isinstance(cmd, dict) or set(cmd) - {"shape", "at_s"} or "shape" not in cmd:
            raise ValueError('formation command must be {"shape": ..., "at_s": optional}')
        shape = cmd["shape"]
        if shape not in SHAPES:
            raise ValueError(f"formation command: shape must be one of {', '.join(SHAPES)}, "
                             f"got {describe(shape)}")
        at = cmd.get("at_s", now_s)
        # A comparison, not math.isfinite(): that raises OverflowError for a JSON integer
        # beyond the float range; NaN fails it too.
        if isinstance(at, bool) or not isinstance(at, int | float) \
                or not -MAX_ABS_TIME_S <= at <= MAX_ABS_TIME_S:
            raise ValueError(f"formation command: at_s must be a finite time within "
                             f"±{MAX_ABS_TIME_S:g} s, got {describe(at)}")
        change = (float(at), str(shape))
        if change in self.spec.changes:
            return False
        if self.spec.changes and change[0] <= self.spec.changes[-1][0]:
            raise ValueError(f"formation command: at_s {change[0]} is not after the last change "
                             f"({self.spec.changes[-1][0]})")
        self.spec = dataclasses.replace(self.spec, changes=(*self.spec.changes, change))
        self._used_stamp = None  # fly the new slots with the plan in hand
        return True

    def step(self, inp: MissionInput) -> MissionOutput:
        msg = inp.neighbours.get(self.spec.leader)
        if msg is None or msg.stamp_s == self._used_stamp:
            return MissionOutput()  # nothing new: the last plan still runs (8 s of it)
        self._used_stamp = msg.stamp_s
        times, positions = extend_plan(msg.times_s, msg.positions_m, EXTEND_S)
        ref = self.slot_reference(times, positions)
        self.plans_used += 1
        return MissionOutput(reference=ref)

    def slot_reference(self, times_s: np.ndarray, leader_m: np.ndarray) -> Reference:
        """This follower's slot along a leader plan (times (m,), positions (m, 3))."""
        slots, psi = slot_positions(self.spec, times_s, leader_m, self._heading)
        self._heading = float(psi[0])
        points = np.column_stack([slots[:, self.index], psi])
        try:
            return Reference(np.asarray(times_s, dtype=float), points)
        except InvalidReferenceError as exc:  # a valid message always gives a valid one
            raise ValueError(f"formation slot of {self.uav_id}: {exc}") from None

    def summary(self) -> dict[str, Any]:
        return {"leader": self.spec.leader, "plans_used": self.plans_used}


def extend_plan(times_s: np.ndarray, positions_m: np.ndarray, extend_s: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """A plan (times (m,), positions (m, 3)) continued past its end at the velocity of its
    last segment for ``extend_s`` seconds."""
    t = np.asarray(times_s, dtype=float)
    p = np.asarray(positions_m, dtype=float)
    if extend_s <= 0.0 or t.shape[0] < 2:
        return t, p
    v = (p[-1] - p[-2]) / (t[-1] - t[-2])
    dt = EXTEND_STEP_S * np.arange(1, round(extend_s / EXTEND_STEP_S) + 1)
    return np.concatenate([t, t[-1] + dt]), np.vstack([p, p[-1] + dt[:, None] * v])


def slot_positions(spec: FormationSpec, times_s: np.ndarray, leader_m: np.ndarray,
                   fallback_rad: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every member's slot along a leader path (times (m,), positions (m, 3)): positions
    (m, n, 3) and the formation's heading (m,) (:func:`formation_frame`, from ``fallback_rad``,
    default the spec's). The law the followers fly, also applied to the leader's *true* path to
    measure how well the formation is kept."""
    leader_m = np.asarray(leader_m, dtype=float)
    psi = formation_frame(times_s, leader_m,
                          spec.heading_rad if fallback_rad is None else fallback_rad)
    off = spec.offsets_at(times_s)
    c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
    out = np.empty(off.shape)
    out[..., 0] = leader_m[:, None, 0] + c * off[..., 0] - s * off[..., 1]
    out[..., 1] = leader_m[:, None, 1] + s * off[..., 0] + c * off[..., 1]
    out[..., 2] = leader_m[:, None, 2] + off[..., 2]
    return out, psi


def formation_error(spec: FormationSpec, times_s: np.ndarray, positions_m: dict[str, np.ndarray]
                    ) -> dict[str, Any]:
    """How well the followers kept their slots: each follower's distance from its slot along
    the leader's *true* path (:func:`slot_positions`), over the times (m,) given (positions
    (m, 3) per member id). Returns ``{"rms", "max", "per_follower": {id: {"rms", "max"}}}``
    [m] and the series ``"series_m"`` (m, followers) for figures."""
    slots, _ = slot_positions(spec, times_s, positions_m[spec.leader])
    err = np.stack([np.linalg.norm(positions_m[f] - slots[:, j + 1], axis=1)
                    for j, f in enumerate(spec.followers)], axis=1)
    per = {f: {"rms": float(np.sqrt(np.mean(err[:, j] ** 2))), "max": float(err[:, j].max())}
           for j, f in enumerate(spec.followers)}
    return {"rms": float(np.sqrt(np.mean(err**2))), "max": float(err.max()),
            "per_follower": per, "series_m": err}
