"""Liveness: each UAV's time to its goal with avoidance against the same flight without it,
and a UAV that does not arrive says why."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from uavmpc import scenarios
from uavmpc.apps.liveness import late_after_s, liveness
from uavmpc.drivers.world import World
from uavmpc.drivers.world_report import arrival_s
from uavmpc.scenarios.run import RunSpec


def test_arrival_is_the_last_entry_into_the_goal_from_which_it_stays() -> None:
    t = np.arange(6.0)
    goal = np.zeros(3)
    x = np.array([5.0, 0.5, 2.0, 0.2, 0.1, 0.0])  # in at 1 s, out at 2 s, in for good at 3 s
    track = np.stack([x, np.zeros(6), np.zeros(6)], axis=1)
    assert arrival_s(t, track, goal) == 3.0
    assert arrival_s(t, track[:3], goal) is None  # ends outside
    assert arrival_s(t, np.zeros((6, 3)), goal) == 0.0  # there all along


def _scenario(tmp_path: Path, text: str) -> scenarios.Scenario:
    path = tmp_path / "s.toml"
    path.write_text(text)
    return scenarios.load(path)


def test_a_uav_whose_goal_a_higher_priority_occupies_is_late_and_says_whom_it_yields_to(
        tmp_path: Path) -> None:
    """uav1 (priority 1) hovers at uav2's goal: uav2 cannot arrive, which its flight without
    avoidance does in a few seconds. The liveness section says uav2 is late, and why: it
    yielded to uav1."""
    sc = _scenario(tmp_path, """
name = "occupied_goal"
duration_s = 25.0
[[uavs]]
id = "uav1"
priority = 1
start = [0.0, 0.0, 10.0]
goto = [0.0, 0.0, 10.0, 0.0]
[[uavs]]
id = "uav2"
priority = 2
start = [20.0, 0.0, 10.0]
[uavs.path]
waypoints = [[20.0, 0.0, 10.0], [0.0, 0.0, 10.0]]
speed_mps = 3.0
start_s = 1.0
""")
    spec = RunSpec(sc)
    flown = World(spec).run()
    live = liveness(spec, flown)
    uav2 = live["per_uav"]["uav2"]
    assert uav2["free_s"] is not None and uav2["free_s"] < 15.0  # alone it flies there
    assert uav2["goal_s"] is None and uav2["late"]
    assert live["late"] == ["uav2"]
    assert "uav1" in uav2["why"], uav2
    assert not live["per_uav"]["uav1"]["late"]  # at its goal from the start


def test_the_delay_is_the_arrival_with_avoidance_less_the_arrival_without(tmp_path: Path) -> None:
    """A head-on pair: each arrives, the one that yields later than alone; the delays are
    the differences of the two flights' arrivals, and within the bound."""
    sc = _scenario(tmp_path, """
name = "head_on"
duration_s = 30.0
[[uavs]]
id = "a"
priority = 1
start = [-15.0, 0.0, 10.0]
[uavs.path]
waypoints = [[-15.0, 0.0, 10.0], [15.0, 0.0, 10.0]]
speed_mps = 3.0
start_s = 1.0
[[uavs]]
id = "b"
priority = 2
start = [15.0, 0.0, 10.0]
[uavs.path]
waypoints = [[15.0, 0.0, 10.0], [-15.0, 0.0, 10.0]]
speed_mps = 3.0
start_s = 1.0
""")
    spec = RunSpec(sc)
    flown = World(spec).run()
    free = World(RunSpec(sc, avoidance=False)).run()
    live = liveness(spec, flown)
    for uav in ("a", "b"):
        e = live["per_uav"][uav]
        assert e["goal_s"] == round(flown.per_uav[uav].goal_reached_s, 2)
        assert e["free_s"] == round(free.per_uav[uav].goal_reached_s, 2)
        assert abs(e["delay_s"] - (e["goal_s"] - e["free_s"])) < 0.011
        assert not e["late"] and e["delay_s"] < late_after_s(e["free_s"])
    assert live["per_uav"]["b"]["delay_s"] > 0.2  # b climbed over a and came down again


def test_uavmpc_run_prints_and_writes_the_liveness(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "uavmpc.apps.cli", "run", "swap_through_static",
                        "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "liveness: 3 of 3 at their goals" in r.stdout, r.stdout
    live = json.loads((out / "summary.json").read_text())["sections"]["liveness"]
    assert set(live["per_uav"]) == {"uav1", "uav2", "uav3"}
