"""The world's tick on 1 and on every thread, on idle cores and with one core kept busy by
another process: a parallel tick waits for its slowest thread (docs/scale.md).

    python benchmarks/bench_busy_core.py [--seconds 60] [--uavs 5]

Each flight in a fresh process (its thread count fixed before numba starts); the same flight
every time (bit-identical: its closest approach is printed). Last line: JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

_CHILD = """
import sys, time
from uavmpc.drivers.world import World
from uavmpc.jit import set_threads
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec
n, seconds, threads = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
set_threads(threads)
sc = random_walk(n, area_m=100.0 * (n / 5) ** 0.5, duration_s=seconds, seed=3)
World(RunSpec(sc, seed=3)).run(1.0)  # kernels loaded before the clock starts
t = time.perf_counter()
r = World(RunSpec(sc, seed=3)).run(seconds)
print(time.perf_counter() - t, float(r.min_distance_m.min()))
"""


def _fly(uavs: int, seconds: float, threads: int) -> tuple[float, float]:
    env = {**os.environ, "NUMBA_NUM_THREADS": str(threads), "UAVMPC_THREADS": str(threads)}
    out = subprocess.run([sys.executable, "-c", _CHILD, str(uavs), str(seconds), str(threads)],
                         capture_output=True, text=True, env=env, check=True).stdout.split()
    return float(out[0]), float(out[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--uavs", type=int, default=5)
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    rows = []
    for busy in (False, True):
        hog = (subprocess.Popen([sys.executable, "-c", "while True: pass"])
               if busy else None)
        try:
            for threads in sorted({1, cores}):
                wall, closest = _fly(args.uavs, args.seconds, threads)
                rows.append({"busy_core": busy, "threads": threads, "wall_s": round(wall, 3),
                             "closest_m": closest})
                print(f"{'one core busy' if busy else 'idle cores':14s} {threads} thread(s): "
                      f"{args.seconds:g} s of {args.uavs} UAVs in {wall:.2f} s "
                      f"(closest {closest:.4f} m)", flush=True)
        finally:
            if hog is not None:
                hog.kill()
                hog.wait()
    print(json.dumps({"uavs": args.uavs, "seconds": args.seconds, "cores": cores,
                      "rows": rows}))


if __name__ == "__main__":
    main()
