"""The tick's closest distance: the sweep along x against every pair, in the same run
(docs/scale.md).

``python benchmarks/closest.py [UAVS ...]`` (default 300 1000) places the UAVs as ``bench world``
spreads them (5 per 100 m × 100 m, 10–30 m up, seed 1) and prints, per size, the µs per call of
``world_tick.closest_distance`` and of every pair's distance (``pair_distances``) and its
minimum, and whether the two agree bit for bit.
"""

from __future__ import annotations

import json
import math
import sys
import timeit

import numpy as np

from uavmpc.drivers.world_tick import closest_distance, pair_distances


def main(sizes: list[int]) -> dict[str, object]:
    rng = np.random.default_rng(1)
    out = []
    for n in sizes:
        half = 50.0 * math.sqrt(n / 5.0)
        pos = np.column_stack([rng.uniform(-half, half, (n, 2)), rng.uniform(10.0, 30.0, n)])
        pairs = np.empty(n * (n - 1) // 2)

        def every_pair(pos: np.ndarray = pos, pairs: np.ndarray = pairs) -> float:
            pair_distances(pos, pairs)
            return float(pairs.min())

        same = closest_distance(pos) == every_pair()
        calls = max(20, 200_000 // n)
        sweep = timeit.timeit(lambda pos=pos: closest_distance(pos), number=calls) / calls
        ref = timeit.timeit(every_pair, number=max(5, calls // 20)) / max(5, calls // 20)
        row = {"uavs": n, "sweep_us": round(sweep * 1e6, 1), "every_pair_us": round(ref * 1e6, 1),
               "same": bool(same)}
        print(row, file=sys.stderr)
        out.append(row)
    return {"sizes": out}


if __name__ == "__main__":
    print(json.dumps(main([int(a) for a in sys.argv[1:]] or [300, 1000])))
