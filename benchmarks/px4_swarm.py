"""Swarms of real PX4 vehicles (SITL with SIH) swapping across a 12 m circle, judged by the
truth: each run's closest approach by SIH's ground truth, by the autopilots' estimates, and by
PX4's own flight logs read independently, with every vehicle's estimator error.

    python benchmarks/px4_swarm.py DIR [--sizes 4,6] [--runs 3] [--duration 45]

DIR is a PX4 SITL build (``bin/px4`` and ``etc/``) or its ``.tar.gz``. Each run flies
``uavmpc swarm`` of an antipodal swap (N UAVs evenly on a circle of radius 6 m at 5 m, each to
the opposite point at 2 m/s, priorities 1..N; instances 0..N−1, so N ≤ 10), and reads its
``summary.json`` and its ULogs (:func:`uavmpc.drivers.px4.ulog.swarm_truth`). A run takes
about 1.5–2 min on a 2-core machine. The last line is JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from uavmpc import scenarios
from uavmpc.drivers.px4.firmware import Px4SitlBuild
from uavmpc.drivers.px4.ulog import swarm_truth
from uavmpc.drivers.swarm import run_swarm
from uavmpc.scenarios.dense import antipodal_toml
from uavmpc.scenarios.run import RunSpec


def fly(build: Px4SitlBuild, n: int, duration_s: float, work: Path) -> dict[str, Any]:
    """One swap of ``n`` real PX4 vehicles; its figures."""
    path = work / f"antipodal_{n}_px4.toml"
    path.write_text(antipodal_toml(n, radius_m=6.0, height_m=5.0, speed_mps=2.0, start_s=2.0,
                                   duration_s=duration_s))
    s = run_swarm(RunSpec(scenarios.load(path)), work / "run", px4_sitl=build)
    logged = swarm_truth(work / "run")
    est = s.sections.get("estimate", {})
    errors = [u.details.get("estimator_error") or {} for u in s.uavs.values()]
    diffs = [abs(logged["closest_by_pair_m"][p] - d)
             for p, d in s.sections["closest_by_pair_m"].items()
             if logged["closest_by_pair_m"].get(p) is not None]
    return {
        "uavs": n, "status": s.status.value, "collisions": len(s.collisions),
        "closest_truth_m": s.min_distance_m, "closest_estimate_m": est.get("min_distance_m"),
        "closest_ulog_m": logged["min_distance_m"],
        "ulog_vs_live_max_m": round(max(diffs), 3) if diffs else None,
        "goals": sum(bool(u.reached_goal) for u in s.uavs.values()),
        "highest_truth_m": max((u.details.get("max_altitude_m") or 0.0)
                               for u in s.uavs.values()),
        "estimator_h_rms_m": [e.get("horizontal_rms_m") for e in errors],
        "estimator_v_max_m": [e.get("vertical_max_m") for e in errors],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("build", help="PX4 SITL build folder or archive")
    ap.add_argument("--sizes", default="4,6", help="swarm sizes, comma-separated (≤ 10)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--duration", type=float, default=45.0, help="mission length [s]")
    args = ap.parse_args(argv)
    sizes = [int(v) for v in args.sizes.split(",")]
    if not all(2 <= n <= 10 for n in sizes) or args.runs < 1 or not args.duration > 0:
        print("px4_swarm: sizes in 2..10 (PX4 SITL's onboard ports), runs ≥ 1, duration > 0",
              file=sys.stderr)
        return 2
    build = Px4SitlBuild.locate(args.build)
    rows = []
    for n in sizes:
        for run in range(args.runs):
            with tempfile.TemporaryDirectory(prefix="uavmpc-px4-swarm-") as tmp:
                row = fly(build, n, args.duration, Path(tmp))
            row["run"] = run + 1
            rows.append(row)
            print(f"{n} UAVs, run {run + 1}: {row['status']}, closest by truth "
                  f"{row['closest_truth_m']:.2f} m, by the estimates "
                  f"{row['closest_estimate_m']} m, by the ULogs {row['closest_ulog_m']:.2f} m "
                  f"(pairs within {row['ulog_vs_live_max_m']} m); {row['goals']}/{n} goals; "
                  f"highest {row['highest_truth_m']:.2f} m; EKF2 horizontal RMS "
                  f"{row['estimator_h_rms_m']}, vertical max {row['estimator_v_max_m']}",
                  flush=True)
    print(json.dumps({"runs": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
