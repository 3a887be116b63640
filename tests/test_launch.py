"""A node or a stand-in PX4 as a process of the driver tier (drivers/launch.py): the launch
specification and the report are typed, written as JSON, and checked field by field when read."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from uavmpc import scenarios
from uavmpc.config import ConfigError
from uavmpc.drivers.launch import (
    LaunchError,
    NodeLaunch,
    SitlLaunch,
    SitlReport,
    launch_command,
    load_launch,
    node_settings,
    read_report,
    write_report,
)
from uavmpc.drivers.node import NodeStats
from uavmpc.drivers.swarm import free_ports


def _ceiling_scenario(**changes: dict) -> dict:
    """A scenario table with every safety setting a node must carry, and ``changes``."""
    return {"name": "ceiling", "duration_s": 20.0,
            "avoidance": {"radius_m": 4.0, "time_reference": "receive"},
            "limits": {"horizontal_speed_mps": 5.0},
            "geofence": {"box": [-30, -30, 30, 30], "min_altitude_m": 0.0,
                         "max_altitude_m": 12.0},
            "uavs": [{"id": "uav1", "priority": 1, "start": [0.0, 0.0, 8.0]}], **changes}


def test_a_node_gets_the_scenario_s_settings_or_refuses_them_by_name() -> None:
    sc = scenarios.from_dict(_ceiling_scenario())
    node = NodeLaunch(uav_id="uav1", priority=1, **node_settings(sc))
    params, fence, limits = node.settings()
    assert params == sc.avoidance and limits == sc.limits
    assert fence is not None and fence.max_altitude_m == 12.0
    assert fence.offset_ceiling_m(np.array([8.0])) == sc.geofence.offset_ceiling_m(
        np.array([8.0]))
    for link, named in (({"loss": 0.3}, "[link].loss"), ({"range_m": 50.0}, "[link].range_m"),
                        ({"latency_s": 0.2}, "[link].latency_s")):
        with pytest.raises(ConfigError, match=re.escape(named)):
            node_settings(scenarios.from_dict(_ceiling_scenario(link=link)))


def _write(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


def test_a_spec_reads_back_as_it_was_written(tmp_path: Path) -> None:
    node = NodeLaunch(uav_id="uav1", priority=2, listen=("tcp/127.0.0.1:7447",),
                      start_m=(1.0, -2.5, 5.0), duration_s=12.5, goto=(3.0, 0.0, 5.0, 0.1),
                      mavlink="udp://:14540", geo_origin=(47.0, 8.0, 400.0), system_id=3,
                      report_file=str(tmp_path / "r.json"))
    node = dataclasses.replace(node, **node_settings(scenarios.from_dict(_ceiling_scenario())))
    assert node.geofence is not None and node.limits and node.avoidance_params
    sitl = SitlLaunch(position_m=(1.0, 2.0, 0.0), geo_origin=None, estimator_error=False)
    for spec in (node, sitl):
        path = tmp_path / f"{spec.KIND}.json"
        path.write_text(spec.to_json())
        assert load_launch(path) == spec


@pytest.mark.parametrize(("change", "words"), [
    ({"priority": "1"}, "launch.priority: must be an integer"),
    ({"priority": True}, "launch.priority: must be an integer"),
    ({"start_m": [0.0, 0.0]}, "launch.start_m: must have 3 items"),
    ({"start_m": [0.0, "x", 5.0]}, "launch.start_m[1]: must be a number"),
    ({"listen": "tcp/127.0.0.1:7447"}, "launch.listen: must be a list"),
    ({"avoidance": "no"}, "launch.avoidance: must be true or false"),
    ({"setpoints": "velocity"}, "launch.setpoints: must be one of attitude, position"),
    ({"duration_s": 0}, "launch.duration_s: must be > 0"),
    ({"speed": 3.0}, "unknown field 'speed'"),
    ({"kind": "router"}, "kind: must be one of"),
    ({"avoidance_params": {"radius_m": -1.0}}, "avoidance.radius_m"),
    ({"avoidance_params": {"radius": 5.0}}, "radius"),
    ({"geofence": {"box": [0, 0, 10, 10], "min_altitude_m": 0}}, "geofence.max_altitude_m"),
    ({"limits": {"speed": 3.0}}, "speed"),
])
def test_a_bad_spec_is_refused_in_one_line_naming_its_field(tmp_path: Path, change: dict,
                                                           words: str) -> None:
    data = json.loads(NodeLaunch(uav_id="uav1", priority=1).to_json())
    data.update(change)
    with pytest.raises(LaunchError) as err:
        load_launch(_write(tmp_path / "spec.json", data))
    assert words in str(err.value) and "\n" not in str(err.value)


def test_a_spec_without_a_required_field_names_it(tmp_path: Path) -> None:
    with pytest.raises(LaunchError, match="missing field 'priority'"):
        load_launch(_write(tmp_path / "spec.json", {"kind": "node", "uav_id": "uav1"}))
    (tmp_path / "torn.json").write_text('{"kind": "node", "uav_id"')
    with pytest.raises(LaunchError, match="not JSON"):
        load_launch(tmp_path / "torn.json")


def test_reports_are_typed_and_checked(tmp_path: Path) -> None:
    stats = NodeStats("uav1", ticks=300, rejected={"stale": 2}, final_position_m=[1.0, 2.0, 5.0],
                      vehicle={"phase": "landed"})
    write_report(tmp_path / "node.json", stats)
    assert read_report(tmp_path / "node.json", NodeStats) == stats
    sitl = SitlReport(events=["1.00 s: armed in OFFBOARD"], final_position_m=[0.0, 0.0, 0.0],
                      cpu_s=0.5, wall_s=2.0)
    write_report(tmp_path / "sitl.json", sitl)
    assert read_report(tmp_path / "sitl.json", SitlReport) == sitl
    with pytest.raises(LaunchError, match="node report: must be"):  # the wrong kind
        read_report(tmp_path / "sitl.json", NodeStats)
    bad = {"kind": "node", "report": {**dataclasses.asdict(stats), "ticks": "many"}}
    with pytest.raises(LaunchError, match=r"node report\.ticks: must be an integer"):
        read_report(_write(tmp_path / "bad.json", bad), NodeStats)
    with pytest.raises(FileNotFoundError):  # a killed process writes none
        read_report(tmp_path / "none.json", NodeStats)


def test_the_entry_point_refuses_a_bad_spec_in_one_line(tmp_path: Path) -> None:
    spec = _write(tmp_path / "spec.json", {"kind": "node", "uav_id": "a", "priority": "x"})
    run = subprocess.run(launch_command(spec), capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    (line,) = run.stderr.strip().splitlines()
    assert "launch.priority: must be an integer" in line


@pytest.mark.realtime
def test_the_entry_point_flies_a_node_and_writes_its_report(tmp_path: Path) -> None:
    spec = NodeLaunch(uav_id="solo", priority=1, listen=(f"tcp/127.0.0.1:{free_ports(1)[0]}",),
                      goto=(2.0, 0.0, 5.0, 0.0), duration_s=2.0,
                      report_file=str(tmp_path / "report.json"))
    path = tmp_path / "spec.json"
    path.write_text(spec.to_json())
    run = subprocess.run(launch_command(path), capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout == ""  # the report went to its file
    stats = read_report(spec.report_file, NodeStats)
    assert stats.uav_id == "solo" and stats.ticks > 0 and len(stats.final_position_m) == 3


def test_the_launch_command_is_the_driver_tier_s() -> None:
    assert launch_command("s.json") == [sys.executable, "-m", "uavmpc.drivers.launch", "s.json"]
