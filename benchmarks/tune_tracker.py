"""The weight scan of docs/tracker.md: ``python benchmarks/tune_tracker.py``.

A 50 m step at the default limits for each (q_v, q_a); prints overshoot and the time after which
the virtual UAV stays within 1 cm, then one JSON object last.
"""

import dataclasses
import json

import numpy as np

from uavmpc import MpcTracker, Reference, TrackerConfig

SCAN = [(0.0, 150.0), (3000.0, 150.0), (5000.0, 150.0), (5000.0, 0.0), (10000.0, 0.0),
        (6000.0, 20.0)]


def main() -> None:
    rows = []
    for q_v, q_a in SCAN:
        config = dataclasses.replace(TrackerConfig.from_toml(), q_velocity=q_v, q_acceleration=q_a)
        tracker = MpcTracker(config, position_m=(0.0, 0.0, 10.0))
        tracker.set_reference(Reference.goto(50.0, 0.0, 10.0))
        x = np.array([tracker.step().command.position_m[0] for _ in range(2500)])
        outside = np.flatnonzero(np.abs(x - 50.0) >= 0.01)
        row = {"q_velocity": q_v, "q_acceleration": q_a,
               "overshoot_m": round(max(float(x.max()) - 50.0, 0.0), 4),
               "settle_1cm_s": round((outside[-1] + 1) * 0.01, 2)}
        rows.append(row)
        print(f"q_v {q_v:7.0f}  q_a {q_a:5.0f}  overshoot {100 * row['overshoot_m']:6.1f} cm  "
              f"within 1 cm after {row['settle_1cm_s']:5.2f} s")
    print(json.dumps({"step_m": 50.0, "rows": rows}))


if __name__ == "__main__":
    main()
