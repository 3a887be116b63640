"""One world's phases, in this process, for side-by-side comparisons of two commits
(docs/scale.md).

``python benchmarks/world_phases.py [THREADS] [UAVS] [SECONDS]`` (default 2 300 10) flies the
random walk of ``uavmpc bench world`` (the protocol's density, avoidance on, seed 1) after a
throw-away flight that loads the kernels, and prints the real-time factor and the wall time
of each phase per tick. To compare two commits, check the other one out as a ``git worktree`` and
run this script with its ``src`` first on ``PYTHONPATH``, taking turns: a shared machine's
slow spells then fall on both.
"""

from __future__ import annotations

import json
import math
import sys

import uavmpc
from uavmpc.drivers.world import World
from uavmpc.jit import set_threads
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec


def main(threads: int = 2, uavs: int = 300, seconds: float = 10.0) -> dict[str, object]:
    set_threads(threads)
    World(RunSpec(random_walk(2, duration_s=1.0), avoidance=True)).run(0.5)
    area = 100.0 * math.sqrt(uavs / 5.0)
    world = World(RunSpec(random_walk(uavs, area_m=area, duration_s=seconds, seed=1),
                          avoidance=True, seed=1))
    result = world.run(seconds)
    ticks = round(seconds / world.period_s)
    phases = result.sections["timing"]["wall_s_by_phase"]
    return {"code": str(uavmpc.__file__), "threads": threads, "uavs": uavs,
            "realtime_factor": round(seconds / result.wall_s, 3),
            "us_per_tick_by_phase": {k: round(v / ticks * 1e6) for k, v in phases.items()}}


if __name__ == "__main__":
    args = sys.argv[1:]
    print(json.dumps(main(int(args[0]) if args else 2, int(args[1]) if len(args) > 1 else 300,
                          float(args[2]) if len(args) > 2 else 10.0)))
