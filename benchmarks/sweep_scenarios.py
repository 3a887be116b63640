"""Both built-in scenarios over many seeds, ideal and faulty link, with and without avoidance.

``python benchmarks/sweep_scenarios.py [--seeds N]`` prints a table and, last, one JSON object.
"""

import argparse
import json

from uavmpc import scenarios
from uavmpc.drivers.world import World
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.run import RunSpec

LINKS = {
    "ideal (50 ms)": None,
    "30 % loss, 200 ms": LinkSettings(latency_s=0.2, jitter_s=0.02, loss=0.3),
}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    rows = []
    for name in scenarios.CONFLICTS:
        for link_name, link in LINKS.items():
            for avoidance in (False, True):
                runs = [World(RunSpec(scenarios.load(name), avoidance=avoidance, seed=seed,
                                      link=link)).run().summary() for seed in range(args.seeds)]
                row = {
                    "scenario": name, "link": link_name, "avoidance": avoidance,
                    "runs": len(runs),
                    "runs_with_collision": sum(bool(r.collisions) for r in runs),
                    "min_distance_m": min(r.min_distance_m or float("inf") for r in runs),
                    "all_goals_reached": all(u.reached_goal for r in runs
                                             for u in r.uavs.values()),
                    "max_z_offset_m": max(u.max_z_offset_m for r in runs
                                          for u in r.uavs.values()),
                    "limit_violations": sum(u.details["limit_violations"] for r in runs
                                            for u in r.uavs.values()),
                }
                rows.append(row)
                print(f"{name:20s} {link_name:18s} avoidance={avoidance!s:5s} "
                      f"collisions in {row['runs_with_collision']}/{row['runs']} runs, "
                      f"closest {row['min_distance_m']:.2f} m, "
                      f"goals {'all' if row['all_goals_reached'] else 'NOT all'} reached",
                      flush=True)
    print(json.dumps({"seeds": args.seeds, "rows": rows}))


if __name__ == "__main__":
    main()
