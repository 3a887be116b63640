"""uavmpc's swarm on ROS 2's DDS middleware, as a real rclpy node (Fast DDS) receives it.

``python benchmarks/bench_ros2_dds.py [SECONDS]``: ``swap_through_static`` as three node
processes with ``--ros2-dds`` (run_swarm, a domain of its own), and a real ROS 2 Jazzy rclpy
node (tests/rclpy_probe.py in the cached venv of tests/rclpy_env.py, built on first use,
about 260 MB) that subscribes to every UAV's pose, odom and prediction, publishes a goal for
uav1, and records SECONDS (default 10) once all topics have data. Prints, per topic kind, the
receive rate of each UAV against the rate the node publishes at (the reference: 50 Hz pose and
odom, 2 Hz prediction); the latency from write to receive, by DDS's own time stamps (the source
time stamp the writer sets, the reception time stamp of rclpy's middleware; one clock, one
host); the age of the state when rclpy's callback runs (its header stamp is the node's clock,
which lags the wall clock when the node runs late); and how far from the goal uav1 ended. The
last line is one JSON object.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from rclpy_env import rclpy_python, run_probe

from uavmpc import scenarios
from uavmpc.drivers.swarm import run_swarm
from uavmpc.scenarios.run import RunSpec

UAVS = ("uav1", "uav2", "uav3")
PUBLISHED_HZ = {"pose": 50.0, "odom": 50.0, "prediction": 2.0}
GOAL = [-25.0, 4.0, 6.0]


def main(seconds: float = 10.0) -> dict:
    python, why = rclpy_python()
    if python is None:
        raise SystemExit(f"no rclpy here: {why}")
    domain = 100 + os.getpid() % 100
    result: dict = {}
    with tempfile.TemporaryDirectory(prefix="uavmpc-bench-dds-") as tmp:
        def fly() -> None:
            result["summary"] = (run_swarm(
                RunSpec(scenarios.load("swap_through_static"), duration_s=seconds + 18.0),
                Path(tmp), ros2=f"dds/{domain}"))

        thread = threading.Thread(target=fly, daemon=True)
        thread.start()
        seen = run_probe(python, {"op": "watch", "uavs": list(UAVS), "seconds": seconds,
                                  "timeout": 90.0, "goal": {"uav": "uav1", "position": GOAL,
                                                             "within_m": 0.5}},
                         domain_id=domain, timeout_s=seconds + 200.0)
        thread.join()
    out: dict = {"seconds": seconds, "rate_hz": {}, "latency_ms": {}, "age_ms": {}}
    print("topics (what `ros2 topic list -t` lists):")
    for name, types in seen["topics"]:
        print(f"  {name} [{', '.join(types)}]")
    print("nodes (`ros2 node list`): " + " ".join(ns.rstrip("/") + "/" + n
                                                  for ns, n in seen["nodes"]))
    print("last /uav1/pose (`ros2 topic echo /uav1/pose`):", json.dumps(seen["last"]["/uav1/pose"]))
    print("/uav1/pose's publisher (`ros2 topic info -v`):",
          json.dumps(seen["publishers"]["/uav1/pose"]), flush=True)
    for kind, reference in PUBLISHED_HZ.items():
        rates, lat, age = [], [], []
        for uav in UAVS:
            t = np.array(seen["times"][f"/{uav}/{kind}"])
            stamp = np.array(seen["stamps"][f"/{uav}/{kind}"])
            wire = np.array(seen["wire_s"][f"/{uav}/{kind}"])
            window = t >= t[-1] - seconds  # the recorded seconds, after every topic had data
            rates.append(float(window.sum() / seconds))
            lat.extend(wire[window] * 1e3)
            age.extend((t[window] - stamp[window]) * 1e3)
        out["rate_hz"][kind] = {"min": min(rates), "max": max(rates), "published": reference}
        out["latency_ms"][kind] = {"median": float(np.median(lat)),
                                   "p95": float(np.percentile(lat, 95)), "max": float(max(lat))}
        out["age_ms"][kind] = {"median": float(np.median(age)),
                               "p95": float(np.percentile(age, 95))}
        print(f"{kind:>10}: {min(rates):5.1f}–{max(rates):5.1f} Hz received (published "
              f"{reference:g} Hz); write → receive median {np.median(lat):.2f} ms, p95 "
              f"{np.percentile(lat, 95):.2f} ms; header stamp → callback median "
              f"{np.median(age):.0f} ms", flush=True)
    s = result["summary"]
    final = np.array(s.uavs["uav1"].final_position_m)
    out["goal_error_m"] = float(np.linalg.norm(final - GOAL))
    out["goal_error_at_mission_end_m"] = float(np.linalg.norm(
        np.array(s.uavs["uav1"].details["mission_end_position_m"]) - GOAL))
    out["missions_rejected_uav1"] = s.uavs["uav1"].details["node"].get("missions_rejected")
    out["collisions"] = len(s.collisions)
    print(f"uav1 ended {out['goal_error_m']:.2f} m from the goal rclpy published", flush=True)
    return out


if __name__ == "__main__":
    print(json.dumps(main(float(sys.argv[1]) if len(sys.argv) > 1 else 10.0)))
