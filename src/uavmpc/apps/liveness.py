"""Liveness: what the avoidance cost each UAV in time, against the same flight without it.

A collision-free layer that never lets a UAV arrive is not safe, it is parked. So a run
reports, per UAV, when it arrived for good (:func:`~uavmpc.drivers.world_report.arrival_s`)
with avoidance and in the same run spec flown without avoidance (same seed, link, faults and
wind: without avoidance the UAVs do not interact, so that is each one's own flight). A UAV
that arrives later than :func:`late_after_s` allows, or not at all, says why: whom its
avoidance yielded to and when, and at which offset above its mission it ended. A UAV that
starts at its goal (hovering) is never late, only missing if it has not come back.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from uavmpc.drivers.world import World, WorldResult
from uavmpc.scenarios.run import RunSpec

__all__ = ["LATE_ABSOLUTE_S", "LATE_RELATIVE", "late_after_s", "liveness", "liveness_section"]

#: A delay is late beyond LATE_ABSOLUTE_S + LATE_RELATIVE × the free flight's time to the
#: goal: a wait of one or two yields (a crossing at 5 m/s costs a few seconds each) is the
#: avoidance working; doubling the trip is not.
LATE_ABSOLUTE_S = 10.0
LATE_RELATIVE = 0.5


def late_after_s(free_s: float) -> float:
    """The delay [s] beyond which a UAV whose free flight took ``free_s`` [s] is late."""
    return LATE_ABSOLUTE_S + LATE_RELATIVE * free_s


def liveness_section(flown: WorldResult, free: WorldResult) -> dict[str, Any]:
    """Per UAV with a goal: ``goal_s`` (arrival with avoidance), ``free_s`` (without),
    ``delay_s``, ``late`` and, when late or not arrived, ``why``; and a ``late`` list of ids.
    Both results must be the same scenario's."""
    if flown.uav_ids != free.uav_ids:
        raise ValueError("liveness: the two flights are of different UAVs")
    per_uav: dict[str, Any] = {}
    late: list[str] = []
    for i, uav in enumerate(flown.uav_ids):
        out, alone = flown.per_uav[uav], free.per_uav[uav]
        if out.reached_goal is None:
            continue  # its mission sets its way: no goal to time
        got, own = out.goal_reached_s, alone.goal_reached_s
        entry: dict[str, Any] = {"goal_s": None if got is None else round(got, 2),
                                 "free_s": None if own is None else round(own, 2)}
        # A UAV that starts at its goal (hovering, free_s the first sample) has no trip to be
        # late on: that it made way and came back is the avoidance working.
        station = own is not None and own <= float(free.t_s[0]) + 1e-9
        if got is not None and own is not None:
            entry["delay_s"] = round(got - own, 2)
            is_late = not station and got - own > late_after_s(own)
        else:
            entry["delay_s"] = None
            is_late = got is None and own is not None  # missed what it reaches alone
        entry["late"] = is_late
        if is_late or got is None:
            entry["why"] = _why(out.yielded_to, float(flown.z_offset_m[-1, i]),
                                out.max_z_offset_m)
            if is_late:
                late.append(uav)
        per_uav[uav] = entry
    return {"late": late, "per_uav": per_uav,
            "bound": f"late: delay > {LATE_ABSOLUTE_S:g} s + {LATE_RELATIVE:g} × free time"}


def _why(yielded_to: dict[str, list[float]], final_offset_m: float, max_offset_m: float) -> str:
    spans = sorted(yielded_to.items(), key=lambda kv: -kv[1][1])
    said = ", ".join(f"{other} ({a:.1f}–{b:.1f} s)" for other, (a, b) in spans[:4])
    words = f"yielded to {said}" if said else "yielded to no one"
    return (f"{words}; ended {final_offset_m:+.1f} m above its mission "
            f"(highest offset {max_offset_m:.1f} m)")


def liveness(spec: RunSpec, flown: WorldResult) -> dict[str, Any]:
    """:func:`liveness_section` of ``flown`` (``spec`` flown) against ``spec`` flown again
    without avoidance (no log)."""
    free = World(dataclasses.replace(spec, avoidance=False)).run(
        flown.duration_s)
    section = liveness_section(flown, free)
    delays = [e["delay_s"] for e in section["per_uav"].values() if e["delay_s"] is not None]
    section["delay_median_s"] = float(np.median(delays)) if delays else None
    section["delay_max_s"] = max(delays) if delays else None
    return section
