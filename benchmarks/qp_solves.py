"""How often the tracker's QP is solved, and how many iterations a solve takes (docs/scale.md).

``python benchmarks/qp_solves.py [UAVS ...]`` (default 5 100) flies a random walk with
avoidance per size (one thread) for 20 s and reads every row's counters of its last tick once
a second: QP solves per UAV-tick (axes whose unconstrained optimum broke a bound) and the
dual active-set iterations per solve (0: the warm start was already optimal).
"""

from __future__ import annotations

import math
import sys

from uavmpc.drivers.world import World
from uavmpc.jit import set_threads
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec


def main(sizes: list[int]) -> None:
    set_threads(1)
    for n in sizes:
        area = 100.0 * math.sqrt(n / 5.0)  # the protocol's density
        w = World(RunSpec(random_walk(n, area_m=area, duration_s=30.0, seed=1), avoidance=True,
                          seed=1))
        solves = iterations = samples = 0
        for _ in range(20):
            w.run(1.0)
            rows = w.onboard.tracker.rows
            solves += int(rows.qp_solves.sum())
            iterations += int(rows.iterations.sum())
            samples += n
        print(f"{n} UAVs: {solves / samples:.2f} QP solves per UAV-tick, "
              f"{iterations / max(solves, 1):.2f} iterations per solve")


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [5, 100])
