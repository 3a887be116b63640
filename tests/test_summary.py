"""The run summary: one typed schema for world and swarm, versioned, read back only at its
version, its status the worst of what happened."""

from __future__ import annotations

import dataclasses
import json

import pytest

from uavmpc import scenarios
from uavmpc.drivers.summary import (
    SUMMARY_VERSION,
    RunStatus,
    RunSummary,
    SummaryError,
    run_status,
)
from uavmpc.drivers.world import World
from uavmpc.scenarios.run import RunSpec


@pytest.fixture(scope="module")
def landing() -> RunSummary:
    return World(RunSpec(scenarios.load("moving_target_landing"), seed=1)).run(12.0).summary()


@pytest.fixture(scope="module")
def formation() -> RunSummary:
    return World(RunSpec(scenarios.load("formation"), seed=0)).run(12.0).summary()


def test_a_summary_round_trips_through_its_file(tmp_path, landing, formation) -> None:
    assert landing.landing is not None and formation.formation is not None
    assert formation.formation.error is not None and landing.driver == "world"
    for k, s in enumerate((landing, formation.with_sections(link={"loss": 0.3}))):
        s.write(tmp_path / f"{k}.json")
        back = RunSummary.read(tmp_path / f"{k}.json")
        assert back == s
        assert json.loads((tmp_path / f"{k}.json").read_text())["version"] == SUMMARY_VERSION


def test_another_version_or_a_bad_field_is_refused_by_name(tmp_path, landing) -> None:
    data = landing.to_json()
    for version in (0, SUMMARY_VERSION + 1, None):
        with pytest.raises(SummaryError, match=f"summary version {version!r}, this uavmpc "
                                               f"reads version {SUMMARY_VERSION}"):
            RunSummary.from_json({**data, "version": version})
    old = {k: v for k, v in data.items() if k != "version"}  # before versions: none at all
    (tmp_path / "old.json").write_text(json.dumps(old))
    with pytest.raises(SummaryError, match=r"old\.json: summary version None"):
        RunSummary.read(tmp_path / "old.json")
    with pytest.raises(SummaryError, match="missing field 'status'"):
        RunSummary.from_json({k: v for k, v in data.items() if k != "status"})
    with pytest.raises(SummaryError, match="unknown field 'landing_uav'"):
        RunSummary.from_json({**data, "landing_uav": "lander"})
    with pytest.raises(SummaryError,
                       match=r"summary\.status: must be one of .*'complete', not 'fine'"):
        RunSummary.from_json({**data, "status": "fine"})
    bad = json.loads(json.dumps(data))
    bad["landing"]["touchdowns"] = "two"
    with pytest.raises(SummaryError,
                       match=r"landing\.touchdowns: must be an integer, not 'two'"):
        RunSummary.from_json(bad)
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(SummaryError, match=r"broken\.json: cannot read"):
        RunSummary.read(tmp_path / "broken.json")


@pytest.mark.parametrize(("facts", "status"), [
    ({"collisions": 1, "reached_goal": [False], "stopped": ["a"], "interrupted": True,
      "landed": False}, RunStatus.COLLISION),
    ({"collisions": 0, "reached_goal": [False], "stopped": ["a"], "interrupted": True,
      "landed": False}, RunStatus.VEHICLE_STOPPED),
    ({"collisions": 0, "reached_goal": [False], "interrupted": True, "landed": False},
     RunStatus.INTERRUPTED),
    ({"collisions": 0, "reached_goal": [True, False]}, RunStatus.GOAL_MISSED),
    ({"collisions": 0, "reached_goal": [True, None], "landed": False}, RunStatus.GOAL_MISSED),
    ({"collisions": 0, "reached_goal": [True, None], "landed": True}, RunStatus.COMPLETE),
    ({"collisions": 0, "reached_goal": [None]}, RunStatus.COMPLETE),
])
def test_the_status_is_the_worst_that_happened(facts, status) -> None:
    assert run_status(**facts) is status


def test_a_world_run_gets_its_status_from_the_same_rule(landing, formation) -> None:
    # 12 s of a landing: the lander has not landed yet; the formation has no goal missed.
    assert landing.landing is not None and not landing.landing.landed
    assert landing.status is RunStatus.GOAL_MISSED
    assert formation.status is run_status(
        collisions=len(formation.collisions),
        reached_goal=[u.reached_goal for u in formation.uavs.values()])
    crash = World(RunSpec(scenarios.load("swap_through_static"), avoidance=False, seed=0)).run()
    assert crash.summary().status is RunStatus.COLLISION


def test_world_and_swarm_write_the_same_top_level_fields(landing) -> None:
    fields = {f.name for f in dataclasses.fields(RunSummary)}
    assert set(landing.to_json()) == fields | {"version"}
    # the swarm builds the same dataclass (tests/test_node.py reads one back from its file)
    with pytest.raises(ValueError, match="driver: one of world, swarm"):
        dataclasses.replace(landing, driver="campaign")
