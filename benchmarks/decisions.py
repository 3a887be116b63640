"""Whether a change left every avoidance decision as it was (docs/scale.md).

``python benchmarks/decisions.py save FILE`` flies five worlds with avoidance and saves, for
each, every change of a UAV's avoidance decision (the UAV, its tracker's time, every field of
the decision) and the UAVs' final positions; ``python benchmarks/decisions.py compare FILE``,
run on the changed code, flies them again and prints, per world, whether both are the same,
or the first decision that differs. The worlds: a 60-UAV random walk (30 s), a 40-UAV one on
a link with 30 % burst loss (30 s), ``antipodal_12`` (more UAVs than height layers: holds),
``swap_through_static`` and ``noncooperative_crossing`` (the stuck rule, flags down). About a
minute; the strategy's law changes rarely, and each of its rules shows up in one of them.
"""

from __future__ import annotations

import dataclasses
import pickle
import sys
from collections.abc import Callable
from typing import Any

from uavmpc import scenarios
from uavmpc.avoidance.round import Steering
from uavmpc.drivers.world import World
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec

#: (name, the scenario, World's keywords, seconds flown (None: the scenario's)).
WORLDS: list[tuple[str, Callable[[], Any], dict[str, Any], float | None]] = [
    ("rw60", lambda: random_walk(60, area_m=350.0, duration_s=30.0, seed=4),
     {"avoidance": True, "seed": 4}, 30.0),
    ("rw40lossy", lambda: random_walk(40, area_m=250.0, duration_s=30.0, seed=5),
     {"avoidance": True, "seed": 5, "link": LinkSettings(loss=0.3, burst_len=3.0)}, 30.0),
    ("antipodal_12", lambda: scenarios.load("antipodal_12"), {"avoidance": True}, None),
    ("swap", lambda: scenarios.load("swap_through_static"), {"avoidance": True}, None),
    ("noncoop", lambda: scenarios.load("noncooperative_crossing"), {"avoidance": True}, None),
]


def decisions() -> dict[str, tuple[list[tuple[str, float, dict[str, Any]]], bytes]]:
    """Per world: every change of decision as (UAV, tracker time [s], fields), in order, and
    the final positions' bytes."""
    changes: list[tuple[str, float, dict[str, Any]]] = []
    apply = Steering.apply

    def recorded(self: Steering, decision: Any) -> None:
        if decision != self.decision:
            changes.append((self.uav_id, float(self.tracker.time_s),
                            dataclasses.asdict(decision)))
        apply(self, decision)

    Steering.apply = recorded  # type: ignore[method-assign]
    try:
        out = {}
        for name, make, kwargs, seconds in WORLDS:
            changes.clear()
            result = World(RunSpec(make(), **kwargs)).run(seconds)
            out[name] = (list(changes), result.positions_m[-1].tobytes())
        return out
    finally:
        Steering.apply = apply  # type: ignore[method-assign]


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("save", "compare"):
        print("usage: python benchmarks/decisions.py save|compare FILE", file=sys.stderr)
        return 2
    mode, path = argv
    now = decisions()
    if mode == "save":
        with open(path, "wb") as f:
            pickle.dump(now, f)
        print({name: len(changes) for name, (changes, _) in now.items()})
        return 0
    with open(path, "rb") as f:
        saved = pickle.load(f)
    same_all = True
    for name, (changes, positions) in saved.items():
        new_changes, new_positions = now[name]
        same = changes == new_changes and positions == new_positions
        same_all &= same
        if same:
            print(f"{name:13s} same: {len(changes)} changes of decision, the same end")
            continue
        k = next((i for i, (a, b) in enumerate(zip(changes, new_changes, strict=False))
                  if a != b), min(len(changes), len(new_changes)))
        print(f"{name:13s} DIFFERENT: {len(changes)} → {len(new_changes)} changes, first at "
              f"{k}: {changes[k] if k < len(changes) else None} → "
              f"{new_changes[k] if k < len(new_changes) else None}")
    return 0 if same_all else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
