"""Whether a change left the flights bit for bit as they were (docs/scale.md).

``python benchmarks/final_states.py save FILE`` flies random walks of 5, 20 and 60 UAVs with
avoidance (60, 30 and 15 s, one thread) and saves every plant's and tracker's final state;
``python benchmarks/final_states.py compare FILE``, run on the changed code, flies them again
and prints, per world, whether the states are equal value for value and byte for byte (a
trajectory's end is where any difference along the way shows: the flights are chaotic).
"""

from __future__ import annotations

import sys

import numpy as np

from uavmpc.drivers.world import World
from uavmpc.jit import set_threads
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec

#: (UAVs, area side [m], seconds flown)
WORLDS = ((5, 100.0, 60.0), (20, 200.0, 30.0), (60, 346.0, 15.0))


def final_states() -> dict[str, np.ndarray]:
    set_threads(1)
    out = {}
    for n, area, seconds in WORLDS:
        w = World(RunSpec(random_walk(n, area_m=area, duration_s=seconds, seed=3), avoidance=True,
                          seed=3))
        w.run(seconds)
        out[f"plants_{n}"] = w.plants.x.copy()
        out[f"trackers_{n}"] = w.onboard.tracker.rows.state.copy()
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("save", "compare"):
        print("usage: python benchmarks/final_states.py save|compare FILE", file=sys.stderr)
        return 2
    mode, path = argv
    states = final_states()
    if mode == "save":
        np.savez(path, **states)
        print(f"saved {len(states)} arrays to {path}")
        return 0
    ref = np.load(path)
    same = True
    for k, v in states.items():
        equal, exact = np.array_equal(ref[k], v), ref[k].tobytes() == v.tobytes()
        same = same and exact
        print(f"{k:12s} equal {equal}  byte for byte {exact}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
