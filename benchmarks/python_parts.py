"""Where a world's Python time goes, function by function (docs/scale.md).

``python benchmarks/python_parts.py [UAVS] [THREADS] [SECONDS]`` (default 300 2 6) flies a
random walk at the protocol's density with avoidance, every call of the functions below timed
by a wrapper (``time.perf_counter`` around the call, so each figure includes what it calls),
and prints per tick: the world's three phases, then each function's wall time, calls and time
per call. The wrappers add a little to every call; the flight itself is unchanged.
"""

from __future__ import annotations

import collections
import json
import math
import sys
import time
from collections.abc import Callable
from typing import Any

import uavmpc.avoidance.encounters as encounters
import uavmpc.avoidance.round as avoidance_round
import uavmpc.comms.inbox as inbox
import uavmpc.comms.link as link
import uavmpc.drivers.delivery as delivery
import uavmpc.drivers.world as world
import uavmpc.onboard as onboard
from uavmpc.jit import bound, set_threads
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec

#: (owner, attribute, label): the functions timed; module functions where they are called.
TIMED: list[tuple[Any, str, str]] = [
    (world.World, "_receive_and_plan_batched", "receive and plan"),
    (world.World, "_plan_round", "  avoidance round"),
    (avoidance_round, "avoidance_plans", "    plans"),
    (avoidance_round, "avoidance_plans_threads", "    plans"),
    (encounters.EncounterFinder, "find_rows", "    encounter search"),
    (avoidance_round, "decide_rows", "    decisions (compiled)"),
    (avoidance_round.Steering, "steer_by_kind", "    steering by them"),
    (delivery.WorldLink, "deliver", "  delivery"),
    (link.SimulatedLink, "take_due", "    copies due"),
    (inbox.InboxTable, "slot_for", "    decode (once per broadcast)"),
    (delivery, "accept_copies", "    into the inbox rows"),
    (delivery, "accept_copies_threads", "    into the inbox rows"),
    (world.World, "_emit", "broadcast"),
    (world, "broadcast", "  messages"),
    (onboard, "broadcast_rows", "    written (compiled)"),
    (onboard, "broadcast_rows_threads", "    written (compiled)"),
    (onboard.OnboardStack, "sent", "    each stack's bookkeeping"),
    (delivery.WorldLink, "publish", "  onto the link"),
]


def _timed(f: Callable[..., Any], label: str, spent: dict[str, float],
           calls: collections.Counter[str]) -> Callable[..., Any]:
    call = bound(f)  # a kernel as the package calls it (uavmpc.jit.bound); else f itself

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return call(*args, **kwargs)
        finally:
            spent[label] += time.perf_counter() - t0
            calls[label] += 1
    return wrapper


def main(uavs: int = 300, threads: int = 2, seconds: float = 6.0) -> None:
    set_threads(threads)
    spent: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter[str] = collections.Counter()
    # Load (or compile) the kernels before wrapping them: a kernel calling a wrapped one
    # would not compile. 120 UAVs: several broadcast in one tick, as below.
    world.World(RunSpec(random_walk(120, area_m=490.0, duration_s=1.0), avoidance=True)).run(0.6)
    for owner, name, label in TIMED:
        setattr(owner, name, _timed(getattr(owner, name), label, spent, calls))
    area = 100.0 * math.sqrt(uavs / 5.0)  # 5 UAVs per 100 m × 100 m
    w = world.World(RunSpec(random_walk(uavs, area_m=area, duration_s=seconds, seed=1),
                            avoidance=True, seed=1))
    t0 = time.perf_counter()
    w.run(seconds)
    wall = time.perf_counter() - t0
    ticks = seconds / w.period_s
    print(f"{uavs} UAVs, {threads} thread(s), {seconds:g} s: {seconds / wall:.2f}× real time, "
          f"{wall / ticks * 1e6:.0f} µs per tick")
    names = ("receive and plan", "compiled tick", "broadcast")
    print("phases, µs per tick: " + ", ".join(
        f"{n} {x / ticks * 1e6:.0f}" for n, x in zip(names, w.phase_wall_s, strict=True)))
    labels = list(dict.fromkeys(label for _, _, label in TIMED))  # a kernel and its threads'
    for label in labels:
        if calls[label]:
            print(f"{label:34s} {spent[label] / ticks * 1e6:8.0f} µs per tick "
                  f"{calls[label]:7d} calls {spent[label] / calls[label] * 1e6:8.1f} µs each")
    print(json.dumps({
        "uavs": uavs, "threads": threads, "duration_s": seconds, "realtime_factor": seconds / wall,
        "us_per_tick_by_phase": {n: x / ticks * 1e6 for n, x in zip(names, w.phase_wall_s,
                                                                      strict=True)},
        "us_per_tick": {label.strip(): spent[label] / ticks * 1e6 for label in labels},
        "calls": {label.strip(): calls[label] for label in labels}}))


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]) if args else 300, int(args[1]) if len(args) > 1 else 2,
         float(args[2]) if len(args) > 2 else 6.0)
