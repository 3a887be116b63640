"""The node against the real PX4 firmware (SITL with SIH): each phase's time, the hold error by
PX4's estimate, the setpoint period and the estimate age, in both setpoint modes.

    python benchmarks/px4_real.py DIR [--runs 3] [--instance 5]

DIR is a PX4 SITL build (``bin/px4`` and ``etc/``) or its ``.tar.gz``. Each run boots a fresh
PX4 instance, flies ``uavmpc node --mavlink`` through its whole cycle (take off to 3 m, 3 m
east, hold, land), and reads the node's report. The last line is JSON.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.drivers.px4.firmware import Px4Instance, Px4SitlBuild

GOAL = (3.0, 0.0, 3.0)
DURATION_S = 15.0


def _at(entries: list[str], what: str) -> float | None:
    """The time [s] of the first ``"<t> s: <what>"`` entry of a report list."""
    for e in entries:
        t, _, name = e.partition(" s: ")
        if name.strip().startswith(what):
            return float(t)
    return None


def fly(build: Px4SitlBuild, instance: int, mode: str, work: Path) -> dict[str, Any]:
    """One whole cycle against a fresh PX4 instance; the figures of the node's report."""
    with Px4Instance(build, instance, work / f"px4-{mode}") as px4:
        px4.wait_ready(60.0)
        cmd = [sys.executable, "-m", "uavmpc.apps.cli", "node", "--id", "bench", "--priority",
               "1", "--airframe", "x500", "--mavlink", px4.mavlink_address, "--setpoints",
               mode, "--swarm", f"bench{instance}", "--start", "0", "0", str(GOAL[2]),
               "--goto", *map(str, GOAL), "0", "--duration", str(DURATION_S)]
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=300).stdout
    rep = json.loads([line for line in out.splitlines() if line.startswith("{")][-1])
    v = rep["vehicle"]
    phases = v["phases"]
    armed, flying = _at(phases, "arming"), _at(phases, "flying")
    landing, landed = _at(phases, "landing"), _at(phases, "landed")
    lift_off = _at(v["landed_states"][1:], "IN_AIR")
    end = np.array(rep["mission_end_position_m"])
    return {
        "mode": mode, "phase": v["phase"], "stop_reason": v["stop_reason"],
        "connect_to_streaming_s": _at(phases, "streaming"),
        "streaming_to_offboard_s": _at(phases, "offboard") - _at(phases, "streaming"),
        "offboard_to_armed_s": flying - armed if flying and armed else None,
        "armed_to_lift_off_s": lift_off - flying if lift_off and flying else None,
        "landing_to_landed_s": landed - landing if landed and landing else None,
        "hold_error_m": float(np.linalg.norm(end - np.array(GOAL))),
        "tracking_rmse_m": rep["tracking_rmse_m"],
        "setpoint_period_p50_ms": v["setpoint_period_p50_ms"],
        "setpoint_period_p99_ms": v["setpoint_period_p99_ms"],
        "estimate_age_p50_ms": v["estimate_age_p50_ms"],
        "estimate_age_p99_ms": v["estimate_age_p99_ms"],
        "clock_rate": v["clock_rate"],
        "clock_round_trip_ms": v["clock_round_trip_ms"],
        "heartbeats_behind_ack": v["heartbeats_behind_ack"],
        "unknown_ids": v["unknown_ids"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("build", help="PX4 SITL build folder (bin/px4, etc/) or its .tar.gz")
    ap.add_argument("--runs", type=int, default=3, help="cycles per setpoint mode")
    ap.add_argument("--instance", type=int, default=5, help="PX4 instance number (0..9)")
    args = ap.parse_args()
    build = Px4SitlBuild.locate(args.build)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.runs):
            for mode in ("attitude", "position"):
                row = fly(build, args.instance, mode, Path(tmp) / str(k))
                rows.append(row)
                print(f"{mode:9s} run {k}: {row['phase']}, hold {row['hold_error_m']:.2f} m, "
                      f"lift-off {row['armed_to_lift_off_s']} s after arming, landed "
                      f"{row['landing_to_landed_s']} s after the landing began, setpoints p99 "
                      f"{row['setpoint_period_p99_ms']:.1f} ms, estimate age p50/p99 "
                      f"{row['estimate_age_p50_ms']:.1f}/{row['estimate_age_p99_ms']:.1f} ms, "
                      f"clock rate {row['clock_rate']:.4f}", flush=True)
    print(json.dumps({"runs": rows}))


if __name__ == "__main__":
    main()
