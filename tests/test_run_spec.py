"""One flight's specification (uavmpc.scenarios.run): validated when made, faults applied once,
and the same flight whichever driver or campaign takes it."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from uavmpc import scenarios
from uavmpc.apps.campaign import RandomWalkSpec, trial_run
from uavmpc.config import ConfigError
from uavmpc.drivers.swarm import run_swarm
from uavmpc.drivers.world import World
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.faults import Faults, FaultSpec
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunChanges, RunSettings, RunSettingsChanges, RunSpec


@pytest.mark.parametrize(("changes", "named"), [
    ({"seed": -1}, "seed"), ({"seed": 1.5}, "seed"), ({"avoidance": 1}, "avoidance"),
    ({"wind_mps": -2.0}, "wind_mps"), ({"wind_mps": float("nan")}, "wind_mps"),
    ({"duration_s": 0.0}, "duration_s"), ({"duration_s": float("inf")}, "duration_s"),
    ({"launch_check_s": 99.0, "duration_s": 10.0}, "launch_check_s"),
    ({"link": LinkSettings(loss=1.5)}, "link.loss"),
    ({"faults": FaultSpec(non_cooperative=3)}, "non_cooperative"),
    ({"faults": FaultSpec(burst_len=4.0)}, "--burst-loss"),
    ({"faults": {"gnss": "rtk"}}, "faults"),
])
def test_a_bad_field_is_refused_by_name(changes: dict, named: str) -> None:
    with pytest.raises(ConfigError, match=named):
        RunSpec(scenarios.load("swap_through_static"), **changes)


def test_the_faults_act_once_and_in_one_place() -> None:
    sc = random_walk(4, duration_s=20.0, seed=2)
    spec = RunSpec(sc, seed=9, link=LinkSettings(loss=0.2),
                   faults=FaultSpec(burst_len=3.0, time_reference="receive",
                                    clock_offset_s=0.4, silent=1))
    flown = spec.flown
    assert spec.flown is flown  # drawn once, not per access
    assert flown.link.burst_len == 3.0 and flown.link.loss == 0.2
    assert flown.scenario.avoidance.time_reference == "receive"
    assert sc.avoidance.time_reference != "receive"  # the spec's scenario is left as it was
    assert flown.faults.clock_offsets_s is not None
    assert all(abs(v) <= 0.4 for v in flown.faults.clock_offsets_s)
    (silent_uav, silent_at), = flown.faults.silent_from_s.items()
    assert silent_uav in {u.uav_id for u in sc.uavs} and 0.0 <= silent_at <= 20.0
    # the same seed draws the same faults; another seed other ones
    assert RunSpec(sc, seed=9, link=LinkSettings(loss=0.2),
                   faults=spec.faults).flown.faults == flown.faults
    assert spec.replace(seed=10).flown.faults != flown.faults
    described = json.loads(json.dumps(spec.describe()))
    assert described["faults"]["silent_from_s"] == {silent_uav: round(silent_at, 3)}
    assert described["link"]["burst_len"] == 3.0 and described["duration_s"] == 20.0


def test_a_spec_flies_what_its_faults_given_by_hand_fly() -> None:
    sc = random_walk(3, duration_s=8.0, seed=4)
    spec = RunSpec(sc, seed=5, link=LinkSettings(loss=0.3, latency_s=0.1), wind_mps=2.0,
                   faults=FaultSpec(clock_offset_s=0.2, non_cooperative=1), duration_s=6.0)
    by_spec = World(spec).run()
    f = spec.flown
    by_hand = World(RunSpec(f.scenario, seed=5, link=f.link, wind_mps=2.0,
                            drawn=Faults.given(clock_offsets_s=f.faults.clock_offsets_s,
                                               non_cooperative=f.faults.non_cooperative))).run(6.0)
    assert by_spec.duration_s == pytest.approx(6.0)
    np.testing.assert_array_equal(by_spec.positions_m, by_hand.positions_m)


def test_a_campaign_trial_is_a_run_spec_rebuilt_alike_from_campaign_json() -> None:
    spec = RandomWalkSpec(run=RunSettings(seed=7, wind_mps=1.0, link=LinkSettings(loss=0.1),
                                          launch_check_s=4.0,
                                          faults=FaultSpec(clock_offset_s=0.3)),
                          uavs=3, length_s=30.0)
    reloaded = RandomWalkSpec.from_json(json.loads(json.dumps(spec.to_json())))
    a, b = trial_run(spec, 2), trial_run(reloaded, 2)
    for name in ("avoidance", "seed", "link", "faults", "wind_mps", "launch_check_s",
                 "duration_s"):
        assert getattr(a, name) == getattr(b, name), name
    assert a.flown.faults == b.flown.faults
    assert [u.start_m for u in a.scenario.uavs] == [u.start_m for u in b.scenario.uavs]
    assert a.launch_check_s == 4.0 and a.wind_mps == 1.0 and a.flight_s == 30.0
    assert trial_run(spec, 3).seed != a.seed
    # the template's fields but the seed and the length, as the campaign gave them
    for f in dataclasses.fields(RunSettings):
        if f.name not in ("seed", "duration_s"):
            assert getattr(a, f.name) == getattr(spec.run, f.name), f.name


def test_run_changes_name_every_field_of_the_spec() -> None:
    """RunSpec.replace is typed by RunChanges: a field added to one and not the other would
    go unchecked by mypy."""
    assert set(RunChanges.__annotations__) == {f.name for f in dataclasses.fields(RunSpec)}
    assert set(RunSettingsChanges.__annotations__) == {
        f.name for f in dataclasses.fields(RunSettings)}
    assert {f.name for f in dataclasses.fields(RunSpec)} == {
        "scenario", *(f.name for f in dataclasses.fields(RunSettings))}


@pytest.mark.parametrize(("changes", "named"), [
    ({"seed": -1}, "seed"), ({"avoidance": "yes"}, "avoidance"), ({"wind_mps": 31.0}, "wind_mps"),
    ({"duration_s": -1.0}, "duration_s"), ({"launch_check_s": -1.0}, "launch_check_s"),
    ({"launch_check_s": 12.0, "duration_s": 10.0}, r"launch_check_s: .*the flight's 10 s"),
    ({"link": LinkSettings(jitter_s=-1.0)}, r"link\.jitter_s"), ({"faults": None}, "faults"),
    ({"drawn": Faults.given(gnss="rtk"), "faults": FaultSpec(gnss="single")}, "faults"),
])
def test_a_template_refuses_what_no_scenario_could_fly(changes: dict, named: str) -> None:
    with pytest.raises(ConfigError, match=named):
        RunSettings(**changes)
    with pytest.raises(ConfigError, match=named):
        RunSettings().replace(**changes)


def test_a_template_meets_its_scenario_in_for_scenario() -> None:
    """What needs the scenario is checked when a template becomes a spec: the faults against
    its UAVs and link, the launch check within its flight, the given faults' UAV ids."""
    sc = scenarios.load("swap_through_static")  # 3 UAVs, 50 s
    template = RunSettings(seed=3, wind_mps=1.5, link=LinkSettings(loss=0.1),
                           faults=FaultSpec(clock_offset_s=0.2), launch_check_s=5.0)
    spec = template.for_scenario(sc)
    assert spec.scenario is sc and isinstance(spec, RunSettings)
    by_hand = RunSpec(sc, seed=3, wind_mps=1.5, link=LinkSettings(loss=0.1),
                      faults=FaultSpec(clock_offset_s=0.2), launch_check_s=5.0)
    assert spec.describe() == by_hand.describe()
    assert spec.flown.faults == by_hand.flown.faults
    assert spec != by_hand and spec == spec  # a flight is equal to itself only
    for bad, named in [(RunSettings(faults=FaultSpec(non_cooperative=3)), "non_cooperative"),
                       (RunSettings(launch_check_s=60.0), r"the flight's 50 s\], got 60"),
                       (RunSettings(faults=FaultSpec(burst_len=2.0)), "--burst-loss"),
                       (RunSettings(drawn=Faults.given(non_cooperative=["uav9"])), "'uav9'")]:
        with pytest.raises(ConfigError, match=named):
            bad.for_scenario(sc)
    # a longer flight than the scenario's holds a longer launch check
    assert RunSettings(launch_check_s=60.0, duration_s=70.0).for_scenario(sc).flight_s == 70.0
    with pytest.raises(ConfigError, match="scenario: must be a Scenario"):
        template.for_scenario("swap_through_static")  # type: ignore[arg-type]


@pytest.mark.parametrize(("changes", "named"), [
    ({"link": LinkSettings(loss=0.2)}, "link"), ({"faults": FaultSpec(silent=1)}, "faults"),
    ({"wind_mps": 3.0}, "wind"), ({"launch_check_s": 2.0}, "launch check"),
])
def test_the_swarm_refuses_what_only_the_simulated_world_can_fly(
        changes: dict, named: str, tmp_path: Path) -> None:
    spec = RunSpec(scenarios.load("swap_through_static"), **changes)
    with pytest.raises(ConfigError, match=named):
        run_swarm(spec, tmp_path)
    assert not any(tmp_path.iterdir())  # refused before a process or a file


def test_a_replaced_field_is_validated_again() -> None:
    spec = RunSpec(scenarios.load("swap_through_static"))
    with pytest.raises(ConfigError, match="seed"):
        spec.replace(seed=-3)
    with pytest.raises(ConfigError, match=r"link\.latency_s"):
        dataclasses.replace(spec, link=LinkSettings(latency_s=-1.0))


CEILING_SCENARIO = Path(__file__).parent / "data" / "crossing_under_ceiling.toml"


@pytest.mark.realtime
def test_a_swarm_flies_the_scenario_s_geofence_and_offsets_as_the_world_does(
        tmp_path: Path) -> None:
    """Three UAVs cross above one point at 8 m under a 12 m ceiling: one 3 m layer fits under
    it (12 − 1 m margin − 8 m). The node processes get the scenario's geofence and avoidance
    settings, so they take the same offsets as the world and none climbs above it (before,
    the nodes flew without the geofence and uav3 climbed to 14 m)."""
    sc = scenarios.load(CEILING_SCENARIO)
    assert sc.geofence is not None
    ceiling = sc.geofence.offset_ceiling_m(np.array([8.0]))
    assert ceiling == 3.0
    world = World(RunSpec(sc)).run()
    swarm = run_swarm(RunSpec(sc), tmp_path)
    offsets = {u: s.max_z_offset_m for u, s in world.per_uav.items()}
    assert offsets == {"uav1": 0.0, "uav2": 3.0, "uav3": 3.0}  # two yield, one layer each
    # Real time on a loaded machine shifts the encounter (a yielding node may also hold
    # short), but never the rules: uav1 yields to no one, no layer above the ceiling's.
    flown = {u: s.max_z_offset_m for u, s in swarm.uavs.items()}
    assert flown["uav1"] == 0.0 and 0.0 < flown["uav2"] <= 3.0 and 0.0 < flown["uav3"] <= 3.0
    tops = {u: s.details["max_altitude_m"] for u, s in swarm.uavs.items()}
    assert max(tops.values()) <= 11.0 + 0.3, tops  # the plant's overshoot of 8 + 3 m
    # when the monitor first heard each node, from the mission's start (on a loaded machine
    # a node may start after it: 1.8–2.3 s in one CI run; the offsets are the nodes' own)
    assert all(s.details["first_heard_s"] is not None for s in swarm.uavs.values())
    assert not world.collisions and not swarm.collisions
    assert all(s.reached_goal for s in swarm.uavs.values())
