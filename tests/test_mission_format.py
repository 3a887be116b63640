"""The one mission format: every source of a mission (a scenario, a network message, a file, a
swarm's hand-over, ROS 2, the command line) goes through the same validator, to the same
trajectory."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from uavmpc import scenarios
from uavmpc.drivers.ros2 import ros2_mission
from uavmpc.missions.format import (
    mission_from_json,
    mission_from_table,
    mission_table,
    read_mission,
)
from uavmpc.reference import InvalidReferenceError, Reference

NOW_S = 1.7e9

MISSIONS = {
    "goto": {"goto": [10.0, -2.0, 5.0, 0.5]},
    "trajectory": {"trajectory": {"points": [[0, 0, 5, 0], [1, 0, 5, 0], [2, 1, 5, 0.2]],
                                  "sample_period_s": 0.5, "start_s": 3.0, "loop": True}},
    "stamped": {"trajectory": {"points": [[0, 0, 5, 0], [4, 0, 5, 0]], "times_s": [1.0, 3.5]}},
    "path": {"path": {"waypoints": [[0, 0, 5], [20, 0, 5], [20, 20, 8]], "speed_mps": 3.0,
                      "start_s": 2.0, "sample_period_s": 0.1}},
}


def _toml(table: dict) -> str:
    # These tables hold only numbers, booleans, lists of them and one sub-table, which JSON
    # and TOML spell alike.
    (form, value), = table.items()
    if not isinstance(value, dict):
        return f"{form} = {json.dumps(value)}\n"
    return f"[{form}]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in value.items())


def _same(a: Reference, b: Reference) -> None:
    assert a.loop == b.loop
    np.testing.assert_array_equal(a.times_s, b.times_s)
    np.testing.assert_array_equal(a.points, b.points)


@pytest.mark.parametrize("name", sorted(MISSIONS))
def test_a_scenario_and_a_network_message_give_the_same_trajectory(name: str) -> None:
    table = MISSIONS[name]
    scenario = scenarios.from_dict({"duration_s": 10.0, "uavs": [
        {"id": "a", "priority": 1, "start": [0.0, 0.0, 5.0], **table}]})
    sent = mission_from_json(json.dumps(table).encode(), 0.0)
    _same(scenario.uavs[0].mission, sent)
    # The goal a scenario judges arrival by is the mission's last point.
    assert scenario.uavs[0].goal_m == tuple(sent.points[-1, :3])


@pytest.mark.parametrize("name", sorted(MISSIONS))
def test_toml_and_json_files_give_the_same_trajectory(name: str, tmp_path: Path) -> None:
    toml_file, json_file = tmp_path / "m.toml", tmp_path / "m.json"
    toml_file.write_text(_toml(MISSIONS[name]))
    json_file.write_text(json.dumps(MISSIONS[name]))
    (t_table, t_ref), (j_table, j_ref) = (read_mission(toml_file, NOW_S),
                                          read_mission(json_file, NOW_S))
    _same(t_ref, j_ref)
    _same(t_ref, mission_from_table(t_table, "x", NOW_S))
    assert j_table == MISSIONS[name]


def test_a_trajectory_survives_its_table_exactly() -> None:
    # What a swarm writes for each node: the absolute stamps, not a start and a period.
    for table in MISSIONS.values():
        ref = mission_from_table(table, "mission", NOW_S)
        back = mission_from_json(json.dumps(mission_table(ref)).encode(), 0.0)
        _same(ref, back)


def test_ros2_goals_and_paths_go_through_the_same_validator() -> None:
    goal = ros2_mission(None, np.array([[1.0, 2.0, 3.0, 0.1]]), NOW_S)
    _same(goal, mission_from_table({"goto": [1.0, 2.0, 3.0, 0.1]}, "x", NOW_S))
    pts = np.array([[0.0, 0.0, 5.0, 0.0], [1.0, 0.0, 5.0, 0.0]])
    _same(ros2_mission(None, pts, NOW_S), Reference.sampled(pts, 0.2, NOW_S))
    with pytest.raises(InvalidReferenceError,
                       match=r"^ros2 mission\.trajectory: times_s must increase"):
        ros2_mission(np.array([NOW_S, NOW_S]), pts, NOW_S)  # stamps that do not increase
    with pytest.raises(InvalidReferenceError, match=r"^ros2 mission\.goto\[2\]"):
        ros2_mission(None, np.array([[0.0, 0.0, np.nan, 0.0]]), NOW_S)


def test_a_goto_starts_now_and_a_start_time_is_a_one_point_trajectory() -> None:
    now = mission_from_table({"goto": [1.0, 0.0, 5.0, 0.0]}, "m", NOW_S)
    later = mission_from_table({"trajectory": {"points": [[1.0, 0.0, 5.0, 0.0]],
                                               "start_s": NOW_S + 5.0}}, "m", NOW_S)
    assert now.start_s == NOW_S and later.start_s == NOW_S + 5.0
    np.testing.assert_array_equal(now.points, later.points)


@pytest.mark.parametrize(("table", "needle"), [
    ({}, r"^uavs\[3\]: needs exactly one of goto, trajectory or path, got none"),
    ({"goto": [0, 0, 5, 0], "speed": 1}, r"^uavs\[3\]\.speed: unknown field"),
    ({"path": {"waypoints": [[0, 0, 5], [1, 0, 5]], "speed_mps": 500}},
     r"^uavs\[3\]\.path\.speed_mps: must be a finite number within ±100"),
    ({"trajectory": {"points": [[0, 0, 5, 0]], "times_s": [0.0], "start_s": 1.0}},
     r"^uavs\[3\]\.trajectory\.start_s: not with times_s"),
    ({"trajectory": {"points": [[0, 0, 2e5, 0]]}}, r"^uavs\[3\]\.trajectory\.points\[0\]\[2\]"),
    ({"trajectory": "fast"}, r"^uavs\[3\]\.trajectory: must be a table"),
])
def test_every_error_names_its_field_under_the_callers_name(table: dict, needle: str) -> None:
    with pytest.raises(InvalidReferenceError, match=needle):
        mission_from_table(table, "uavs[3]", 0.0)


def test_the_cli_checks_a_mission_file_before_sending_it(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[path]\nwaypoints = [[0, 0, 5]]\nspeed_mps = 2.0\n')
    run = subprocess.run([sys.executable, "-m", "uavmpc.apps.cli", "mission", "--to", "uav1",
                          "--file", str(bad)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [
        f"uavmpc mission: {bad}.path.waypoints: must be a list of ≥ 2 [x, y, z], got a list of 1"]
