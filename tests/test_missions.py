"""Missions beside the stack: the landing state machine on a tracked car, formation slots from
a received leader plan, the per-pair avoidance radius, and both built-in scenarios flown in the
world (landing on the deck; a formation crossed by an outside UAV)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uavmpc import scenarios
from uavmpc.avoidance import AvoidanceParams, HeightOffsetStrategy
from uavmpc.comms.message import SCHEMA_VERSION, PredictionMessage
from uavmpc.config import ConfigError
from uavmpc.drivers.summary import RunStatus, RunSummary
from uavmpc.missions.formation import FormationFollower, FormationSpec, slot_offsets
from uavmpc.missions.landing import LandingMission, LandingParams, Phase
from uavmpc.missions.mission import MissionInput
from uavmpc.plant.ground_vehicle import GroundVehicle
from uavmpc.plant.interface import VehicleState
from uavmpc.plant.sensors import TargetFix
from uavmpc.reference import Reference
from uavmpc.scenarios.run import RunSpec


def _state(p: np.ndarray, v: np.ndarray, t: float = 0.0) -> VehicleState:
    return VehicleState(t_s=t, position_m=np.asarray(p, float), velocity_mps=np.asarray(v, float),
                        attitude_wxyz=np.array([1.0, 0, 0, 0]), body_rates_radps=np.zeros(3))


class _Lander:
    """A LandingMission fed exact fixes of a car; the UAV's estimate is placed by the test."""

    def __init__(self, car: GroundVehicle, params: LandingParams | None = None) -> None:
        self.car = car
        self.mission = LandingMission(params)
        self.t = 0.0

    def step(self, offset_m=(0.0, 0.0), height_m: float = 2.0, landed: bool = False,
             rel_v=(0.0, 0.0)):
        s = self.car.state(self.t)
        p = s.position_m + np.array([*offset_m, height_m])
        v = s.velocity_mps + np.array([*rel_v, 0.0])
        fixes = [TargetFix(self.t, s.position_m[:2])]
        out = self.mission.step(MissionInput(self.t, _state(p, v, self.t), landed, {}, fixes))
        self.t += self.mission.params.period_s
        return out


def _straight_car() -> GroundVehicle:
    return GroundVehicle(start_arc_m=0.0)  # the crossing of the figure eight: nearly straight


def test_landing_waits_for_a_track_then_approaches_above_the_predicted_path() -> None:
    lander = _Lander(_straight_car())
    first = lander.step(offset_m=(-30.0, 0.0))
    assert first.reference is None and lander.mission.phase is Phase.WAIT  # one fix: no track
    out = lander.step(offset_m=(-30.0, 0.0))
    out = lander.step(offset_m=(-30.0, 0.0))
    out = lander.step(offset_m=(-30.0, 0.0))
    assert lander.mission.phase is Phase.APPROACH and out.reference is not None
    ref = out.reference
    now = lander.t - lander.mission.params.period_s
    # The far end of the desired trajectory is the deck's predicted place (8 s ahead, from
    # four fixes: within a few metres of the true one), 2 m above it ...
    far = ref.sample(np.array([now + 8.0]))[0]
    car_far = lander.car.state(now + 8.0).position_m
    assert np.hypot(*(far[:2] - car_far[:2])) < 3.0
    assert far[2] == pytest.approx(1.5 + 2.0)
    # ... and its start is where the UAV is: the approach closes the gap at a bounded
    # relative speed instead of jumping to the deck.
    near = ref.sample(np.array([now]))[0]
    car_now = lander.car.state(now).position_m
    assert np.hypot(*(near[:2] - car_now[:2])) > 25.0


def test_synchronised_above_the_deck_it_descends_and_cuts_the_motors_on_touchdown() -> None:
    lander = _Lander(_straight_car())
    for _ in range(20):  # on station above the deck, at its velocity
        out = lander.step()
    assert lander.mission.phase is Phase.DESCEND
    now = lander.t - lander.mission.params.period_s
    heights = out.reference.sample(now + np.array([0.0, 1.0, 2.0, 6.0]))[:, 2] - 1.5
    assert np.all(np.diff(heights) < 0) and heights[-1] == pytest.approx(-0.5)  # sinks in
    out = lander.step(height_m=0.0, landed=True)
    assert lander.mission.phase is Phase.LANDED and out.cut_motors
    assert lander.step(height_m=0.0, landed=True).cut_motors  # and stays so


def test_a_descent_off_the_deck_aborts_climbs_back_and_tries_again() -> None:
    lander = _Lander(_straight_car())
    while lander.mission.phase is not Phase.DESCEND:
        lander.step()
    lander.step(offset_m=(0.0, 0.8), height_m=1.5)  # drifted 0.8 m across, above the commit
    assert lander.mission.aborts == {"off the deck": 1}
    assert lander.mission.transitions[-2][1] == "abort"  # then straight back to the approach
    # height (it had only begun to descend)
    for _ in range(30):
        lander.step(height_m=1.5)
        if lander.mission.phase is not Phase.ABORT:
            break
    assert lander.mission.phase in (Phase.APPROACH, Phase.DESCEND)
    names = [p for _, p in lander.mission.transitions]
    assert names[:4] == ["approach", "descend", "abort", "approach"]


def test_the_commit_height_and_the_relative_speed_bound() -> None:
    lander = _Lander(_straight_car())
    while lander.mission.phase is not Phase.DESCEND:
        lander.step()
    lander.step(offset_m=(0.0, 0.8), height_m=0.1)  # mission's own wanted height still high
    assert lander.mission.aborts == {"off the deck": 1}  # the commit is on the wanted height
    lander = _Lander(_straight_car(), LandingParams(commit_height_m=5.0))
    while lander.mission.phase is not Phase.DESCEND:
        lander.step()
    lander.step(rel_v=(2.0, 0.0))
    assert lander.mission.phase is Phase.DESCEND  # committed: the speed does not abort ...
    lander.step(offset_m=(0.0, 0.8))
    assert lander.mission.aborts == {"off the deck": 1}  # ... being off the deck does
    lander = _Lander(_straight_car())
    while lander.mission.phase is not Phase.DESCEND:
        lander.step()
    lander.step(rel_v=(1.0, 0.0))
    assert lander.mission.phase is Phase.DESCEND
    lander.step(rel_v=(2.0, 0.0))
    assert lander.mission.aborts == {"relative speed": 1}


def test_no_descent_while_the_car_turns_sharply() -> None:
    car = GroundVehicle()
    # 9.9–12.7 s: the car turns faster than 0.3 rad/s (an end of the figure eight).
    assert all(abs(car.state(t).yaw_rate_radps) > 0.3 for t in np.arange(9.9, 12.7, 0.1))
    lander = _Lander(car, LandingParams(max_turn_rate_radps=0.25))
    lander.t = 9.9
    for _ in range(26):  # 2.6 s on station above the deck, but the car is turning
        lander.step()
    assert lander.mission.phase is Phase.APPROACH


def test_landing_params_are_validated() -> None:
    with pytest.raises(ConfigError, match="abort_radius_m: must be ≥ sync_radius_m"):
        LandingParams(sync_radius_m=0.6, abort_radius_m=0.5)
    with pytest.raises(ConfigError, match=r"landing.nope"):
        LandingParams.from_dict({"nope": 1})
    with pytest.raises(ConfigError, match="descend_speed_mps"):
        LandingParams(descend_speed_mps=-1.0)


# ------------------------------------------------------------------ formation
def _leader_plan(heading_rad: float, speed: float = 3.0, stamp: float = 10.0,
                 turn_radps: float = 0.0) -> PredictionMessage:
    times = stamp + np.concatenate([[0.01], 0.01 + 0.2 * np.arange(1, 40)])
    psi = heading_rad + turn_radps * (times - stamp)
    if turn_radps:
        r = speed / turn_radps
        xy = np.column_stack([r * (np.sin(psi) - math.sin(heading_rad)),
                              -r * (np.cos(psi) - math.cos(heading_rad))])
    else:
        xy = speed * (times - stamp)[:, None] * np.array([math.cos(psi[0]), math.sin(psi[0])])
    pos = np.column_stack([xy, np.full(times.shape, 10.0)])
    return PredictionMessage(SCHEMA_VERSION, "leader", 1, stamp, times, pos, True)


def _spec(**kw) -> FormationSpec:
    return FormationSpec(leader="leader", followers=("f1", "f2", "f3"), **kw)


def test_a_follower_flies_its_slot_along_the_leaders_received_plan() -> None:
    spec = _spec(spacing_m=6.0)
    f2 = FormationFollower(spec, "f2")  # second to the leader's right in the line
    msg = _leader_plan(heading_rad=0.0)
    out = f2.step(MissionInput(10.2, _state([0, -12, 10], [3, 0, 0]), False, {"leader": msg}))
    ref = out.reference
    assert ref is not None and np.array_equal(ref.times_s[:40], msg.times_s)
    assert np.allclose(ref.points[:40, 0], msg.positions_m[:, 0])  # abreast
    assert np.allclose(ref.points[:40, 1], msg.positions_m[:, 1] - 12.0)  # 12 m to the right
    assert np.allclose(ref.points[:, 3], 0.0)  # facing the leader's way
    # Past the plan's end, on at the leader's last velocity (a late plan still covers the
    # whole horizon).
    assert ref.times_s[-1] == pytest.approx(msg.times_s[-1] + 2.0)
    assert ref.points[-1, 0] == pytest.approx(msg.positions_m[-1, 0] + 3.0 * 2.0)
    # The same message again: nothing new to fly.
    assert f2.step(MissionInput(10.3, _state([0, -12, 10], [3, 0, 0]), False,
                                {"leader": msg})).reference is None
    # Heading north, the right is east.
    north = _leader_plan(heading_rad=math.pi / 2, stamp=10.5)
    ref = f2.step(MissionInput(10.6, _state([12, 0, 10], [0, 3, 0]), False,
                               {"leader": north})).reference
    assert np.allclose(ref.points[:40, 0], north.positions_m[:, 0] + 12.0, atol=1e-6)


def test_in_a_turn_the_slots_turn_with_the_leaders_planned_direction() -> None:
    spec = _spec(spacing_m=6.0)
    f1 = FormationFollower(spec, "f1")
    msg = _leader_plan(heading_rad=0.0, turn_radps=0.1)
    ref = f1.step(MissionInput(10.0, _state([0, -6, 10], [3, 0, 0]), False,
                               {"leader": msg})).reference
    psi = 0.1 * (msg.times_s - msg.stamp_s)
    right = np.column_stack([np.sin(psi), -np.cos(psi)]) * 6.0
    inner = msg.positions_m[:, :2] + right
    assert np.allclose(ref.points[1:39, :2], inner[1:39], atol=0.05)  # the plan's own turn


def test_shape_changes_blend_the_slots_without_a_jump() -> None:
    spec = _spec(spacing_m=6.0, changes=((20.0, "square"),), transition_s=8.0)
    t = np.array([19.0, 20.0, 24.0, 28.0, 40.0])
    off = spec.offsets_at(t)
    assert np.allclose(off[0], slot_offsets("line", 4, 6.0))
    assert np.allclose(off[-1], slot_offsets("square", 4, 6.0))
    assert np.allclose(off[2], 0.5 * (off[0] + off[-1]))  # half way at half the transition
    fine = spec.offsets_at(np.arange(19.0, 30.0, 0.01))
    assert np.abs(np.diff(fine, axis=0)).max() < 0.03  # continuous: < 3 m/s
    # Along the way, members stay ≥ 0.7 spacing apart (> the member cylinder).
    d = [np.linalg.norm(o[a] - o[b]) for o in fine for a in range(4) for b in range(a + 1, 4)]
    assert min(d) >= 0.7 * 6.0


def test_formation_tables_are_validated() -> None:
    ids = {"leader", "f1", "f2", "f3", "x"}
    base = {"leader": "leader", "followers": ["f1", "f2", "f3"]}
    assert FormationSpec.from_dict(base, ids).members == ("leader", "f1", "f2", "f3")
    with pytest.raises(ConfigError, match=r"followers\[1\]: 'zz' is not a UAV"):
        FormationSpec.from_dict({**base, "followers": ["f1", "zz"]}, ids)
    with pytest.raises(ConfigError, match="in the formation twice"):
        FormationSpec.from_dict({**base, "followers": ["f1", "f1"]}, ids)
    with pytest.raises(ConfigError, match=r"member_radius_m: must be < 0.75 spacing_m"):
        FormationSpec.from_dict({**base, "member_radius_m": 5.0}, ids)
    with pytest.raises(ConfigError, match="changes must be in time order"):
        FormationSpec.from_dict({**base, "changes": [{"t_s": 9.0, "shape": "square"},
                                                     {"t_s": 5.0, "shape": "line"}]}, ids)
    with pytest.raises(ConfigError, match="shape: must be one of line, square"):
        FormationSpec.from_dict({**base, "shape": "vee"}, ids)


def test_members_meet_a_member_cylinder_and_outsiders_the_full_one() -> None:
    times = np.linspace(0.0, 7.8, 40)
    own = np.column_stack([np.zeros(40), np.zeros(40), np.full(40, 10.0)])
    beside = own + np.array([0.0, 4.0, 0.0])
    near = PredictionMessage(SCHEMA_VERSION, "f1", 1, 0.0, times, beside, True)
    full = HeightOffsetStrategy(AvoidanceParams())
    d = full.update(0.0, "f2", 2, times, own, {"f1": near})
    assert d.conflicts == ("f1",) and d.z_offset_m > 0  # 4 m apart: inside R_p = 5 m
    member = HeightOffsetStrategy(AvoidanceParams(), pair_radius_m={"f1": 2.5})
    d = member.update(0.0, "f2", 2, times, own, {"f1": near})
    assert d.conflicts == () and d.z_offset_m == 0.0  # a member: only 2.5 m counts
    closer = dataclasses.replace(near, positions_m=own + np.array([0.0, 2.0, 0.0]))
    assert member.update(0.1, "f2", 2, times, own, {"f1": closer}).conflicts == ("f1",)


# ------------------------------------------------------------------ paths and scenarios
def test_along_path_flies_the_waypoints_at_constant_speed_facing_ahead() -> None:
    ref = Reference.along_path(np.array([[0, 0, 5], [50, 0, 5], [50, 50, 5]]), 2.0, 3.0)
    assert ref.start_s == 3.0
    p = ref.points
    speed = np.linalg.norm(np.diff(p[:, :3], axis=0), axis=1) / 0.2
    assert np.allclose(speed[:-1], 2.0, rtol=0.02)
    assert np.allclose(p[-1, :3], [50, 50, 5]) and np.allclose(p[0, :3], [0, 0, 5])
    assert p[0, 3] == pytest.approx(0.0, abs=0.05)
    assert p[-1, 3] == pytest.approx(math.pi / 2, abs=0.05)
    with pytest.raises(ValueError, match="same"):
        Reference.along_path(np.array([[0, 0, 5], [0, 0, 5]]), 2.0)


def test_the_field_scenarios_load_and_bad_ones_are_refused() -> None:
    land = scenarios.load("moving_target_landing")
    assert land.landing[0] == "lander" and land.ground_vehicle.speed_mps == pytest.approx(15 / 3.6)
    assert land.landing[1].deck_height_m == land.ground_vehicle.deck_height_m
    form = scenarios.load("formation")
    assert form.formation.followers == ("f1", "f2", "f3")
    fast = scenarios.load("moving_target_landing_30kmh")
    assert fast.limits.as_dict() == {"horizontal_accel_mps2": 5.0, "horizontal_speed_mps": 12.0}
    base = {"name": "x", "duration_s": 10.0,
            "uavs": [{"id": "a", "priority": 1, "start": [0.0, 0.0, 5.0]}]}
    with pytest.raises(ConfigError, match=r"landing: needs a \[ground_vehicle\]"):
        scenarios.from_dict({**base, "landing": {"uav": "a"}})
    with pytest.raises(ConfigError, match=r"landing.uav: 'b' is not a UAV"):
        scenarios.from_dict({**base, "ground_vehicle": {}, "landing": {"uav": "b"}})
    with pytest.raises(ConfigError, match=r"limits.horizontal_speed_mps"):
        scenarios.from_dict({**base, "limits": {"horizontal_speed_mps": -1.0}})
    with pytest.raises(ConfigError, match=r"ground_vehicle.speed_kmh"):
        scenarios.from_dict({**base, "ground_vehicle": {"speed_kmh": -3}})
    with pytest.raises(ConfigError,
                       match="exactly one of goto, trajectory or path, got goto and path"):
        scenarios.from_dict({**base, "uavs": [{**base["uavs"][0], "goto": [0, 0, 5, 0],
                                                "path": {"waypoints": [[0, 0, 5], [1, 0, 5]],
                                                         "speed_mps": 1.0}}]})


# ------------------------------------------------------------------ flown in the world
def test_moving_target_landing_lands_on_the_deck_and_rides_it(tmp_path) -> None:
    from uavmpc.apps.cli import main
    from uavmpc.log import read_topics

    assert main(["run", "moving_target_landing", "--duration", "40", "--out",
                 str(tmp_path)]) == 0

    s = RunSummary.read(tmp_path / "summary.json").landing
    assert s is not None and s.uav == "lander"
    assert s.landed is True and s.edge_strikes == 0 and s.on_deck_at_end
    assert s.time_to_land_s is not None and 5.0 < s.time_to_land_s < 40.0
    td = s.touchdown
    assert td is not None and 0.0 < td.vertical_speed_mps <= s.max_touchdown_speed_mps
    assert td.offset_from_centre_m < 0.75  # on the 1.5 m deck
    assert sum(s.phases_s.values()) == pytest.approx(s.time_to_land_s, abs=0.15)
    assert (tmp_path / "landing.png").stat().st_size > 10_000
    topics = read_topics(tmp_path / "flight.mcap")
    car = topics["/ground_vehicle/state"]
    assert len(car) > 700 and car[0]["pose"]["position"]["z"] == 1.5


def test_a_second_uav_can_share_the_landing_arena() -> None:
    from uavmpc.drivers.world import World

    sc = scenarios.load("moving_target_landing")
    crossing = dataclasses.replace(
        sc.uavs[0], uav_id="patrol", priority=0, start_m=(-40.0, 20.0, 3.5),
        mission=Reference.along_path(np.array([[-40.0, 20.0, 3.5], [45.0, -20.0, 3.5]]), 4.0),
        goal_m=(45.0, -20.0, 3.5))
    sc = dataclasses.replace(sc, uavs=(*sc.uavs, crossing), duration_s=45.0)
    r = World(RunSpec(sc, seed=1)).run()
    s = r.summary()
    assert s.collisions == () and s.min_distance_m is not None and s.min_distance_m > 1.0
    assert s.landing is not None and s.landing.landed is True
    assert s.uavs["patrol"].reached_goal and s.status is RunStatus.COMPLETE


def test_the_formation_keeps_its_slots_and_gives_way_to_an_outsider_as_a_whole() -> None:
    from uavmpc.drivers.world import World

    sc = dataclasses.replace(scenarios.load("formation"), duration_s=70.0)
    r = World(RunSpec(sc, seed=0)).run()
    s = r.summary()
    assert s.collisions == ()
    fe = s.formation
    assert fe is not None and fe.error is not None and fe.outsiders == ("intruder",)
    assert set(fe.per_follower) == {"f1", "f2", "f3"}
    calm = fe.while_no_member_avoids
    assert calm is not None and calm.rms_m < 0.3 and calm.share_of_time > 0.6
    assert fe.error.max_m < 4.0
    # Members never gave way to each other (the member cylinder); they did to the intruder.
    for uav in ("leader", "f1", "f2", "f3"):
        assert set(s.uavs[uav].details["yielded_to"]) <= {"intruder"}
    assert "intruder" in s.uavs["leader"].details["yielded_to"]
    assert s.uavs["intruder"].max_z_offset_m == 0.0  # the highest priority held on


def test_the_landing_world_flies_the_same_batched_and_object_by_object() -> None:
    from uavmpc.drivers.world import World

    sc = scenarios.load("moving_target_landing")
    a = World(RunSpec(sc, seed=3)).run(12.0)
    b = World(RunSpec(sc, seed=3), batched=False).run(12.0)
    assert np.array_equal(a.positions_m, b.positions_m)
    assert a.landing is not None and b.landing is not None
    assert a.landing.transitions == b.landing.transitions


def test_target_fixes_come_at_their_rate_with_their_noise_and_dropouts() -> None:
    from uavmpc.plant.sensors import TargetSensor

    car = GroundVehicle()
    sensor = TargetSensor(lambda t: car.state(t).position_m, rate_hz=20.0, sigma_m=0.3,
                          dropout=0.2, seed=4)
    fixes = sensor.fixes_until(100.0)
    assert sensor.delivered + sensor.dropped == 2001
    assert sensor.dropped / 2001 == pytest.approx(0.2, abs=0.03)
    err = np.array([f.position_m - car.state(f.t_s).position_m[:2] for f in fixes])
    assert err.std(axis=0) == pytest.approx([0.3, 0.3], rel=0.1)
    assert sensor.fixes_until(100.0) == []  # nothing twice
    again = TargetSensor(lambda t: car.state(t).position_m, rate_hz=20.0, sigma_m=0.3,
                         dropout=0.2, seed=4).fixes_until(100.0)
    assert all(np.array_equal(f.position_m, g.position_m) for f, g in zip(fixes, again,
                                                                          strict=True))
    with pytest.raises(ValueError, match="dropout"):
        TargetSensor(lambda t: np.zeros(3), dropout=1.0)


@pytest.mark.realtime
def test_node_processes_refuse_scenarios_whose_missions_only_the_world_runs(tmp_path) -> None:
    from uavmpc.drivers.swarm import run_swarm
    from uavmpc.scenarios.run import RunSpec

    for name in ("moving_target_landing", "moving_target_landing_30kmh"):
        with pytest.raises(ConfigError, match=f"need the simulated world.*uavmpc run {name}"):
            run_swarm(RunSpec(scenarios.load(name)), tmp_path)


@pytest.mark.realtime
def test_a_formation_of_node_processes_over_zenoh(tmp_path) -> None:
    """The same follower mission in real node processes: slots from the leader's plans as they
    arrive over Zenoh, a shape change on the swarm's wall clock."""
    from uavmpc.drivers.swarm import run_swarm
    from uavmpc.scenarios.run import RunSpec

    sc = scenarios.from_dict({
        "name": "formation_nodes", "duration_s": 22.0,
        "formation": {"leader": "lead", "followers": ["w1", "w2"], "spacing_m": 6.0,
                      "changes": [{"t_s": 10.0, "shape": "square"}], "transition_s": 5.0},
        "uavs": [
            {"id": "lead", "priority": 1, "start": [0.0, 0.0, 5.0],
             "path": {"waypoints": [[0.0, 0.0, 5.0], [60.0, 0.0, 5.0]], "speed_mps": 3.0,
                      "start_s": 2.0}},
            {"id": "w1", "priority": 2, "start": [0.0, -6.0, 5.0]},
            {"id": "w2", "priority": 3, "start": [0.0, -12.0, 5.0]},
        ]})
    s = run_swarm(RunSpec(sc), tmp_path)
    assert s.collisions == ()
    fe = s.formation
    assert fe is not None and fe.error is not None and set(fe.per_follower) == {"w1", "w2"}
    assert fe.error.rms_m < 0.5, fe
    ends = {u: np.array(s.uavs[u].final_position_m) for u in ("lead", "w1", "w2")}
    # After the change (square, three members): w1 behind the leader, w2 to its right.
    assert ends["lead"][0] > 45.0
    assert np.allclose(ends["w1"][:2], ends["lead"][:2] + np.array([-6.0, 0.0]), atol=1.0)
    assert np.allclose(ends["w2"][:2], ends["lead"][:2] + np.array([0.0, -6.0]), atol=1.0)
    assert s.uavs["w1"].reached_goal is None


def test_formation_members_must_be_id_strings() -> None:
    ids = {"a", "b"}
    # `m not in ids` of a list raised TypeError: unhashable type.
    for table, field in [({"leader": [1], "followers": ["a"]}, "leader"),
                         ({"leader": "a", "followers": [{"x": 1}]}, r"followers\[0\]"),
                         ({"leader": "a", "followers": ["b", 7]}, r"followers\[1\]")]:
        with pytest.raises(ConfigError, match=rf"^formation\.{field}: must be a UAV id string, "
                                              r"got "):
            FormationSpec.from_dict(table, ids)
    # The scenario loader's reproducer.
    with pytest.raises(ConfigError, match=r"^formation\.leader: must be a UAV id string, got "
                                          r"an array of 1$"):
        scenarios.from_dict({"duration_s": 10.0,
                             "uavs": [{"id": "a", "priority": 1, "start": [0, 0, 1]}],
                             "formation": {"leader": [1], "followers": ["a"]}})
    # Its heading: bounded like every reference heading, a huge integer named.
    base = {"leader": "a", "followers": ["b"]}
    for heading in (10**400, 2e6, float("nan"), "north"):
        with pytest.raises(ConfigError, match=r"^formation\.heading_rad: must be a finite "
                                              r"number within ±1e\+06"):
            FormationSpec.from_dict({**base, "heading_rad": heading}, ids)
    assert FormationSpec.from_dict({**base, "heading_rad": 3}, ids).heading_rad == 3.0


def test_a_formation_file_with_odd_members_is_refused_by_name(tmp_path) -> None:
    from uavmpc.missions.formation import load_formation

    path = tmp_path / "f.json"
    for text, field in [('{"leader": [1], "followers": ["a"]}', "leader"),
                        ('{"leader": "a", "followers": [[1]]}', r"followers\[0\]"),
                        ('{"leader": "a", "followers": 5}', "followers")]:
        path.write_text(text)
        with pytest.raises(ConfigError, match=rf"^f\.json: formation\.{field}: must be "):
            load_formation(path)


def test_a_bad_formation_command_is_refused_by_name() -> None:
    f1 = FormationFollower(_spec(), "f1")
    for payload, needle in [(b'{"shape": "square", "at_s": 1' + b"0" * 400 + b"}", "at_s"),
                            (b'{"shape": "square", "at_s": NaN}', "at_s"),
                            (b'{"shape": ' + b"[" * 100_000 + b"]" * 100_000 + b"}",
                             "nested too deeply"),
                            (b'{"shape": [[1]]}', "shape must be one of")]:
        with pytest.raises(ValueError, match=rf"^formation command.*{needle}"):
            f1.command(payload, 0.0)
    assert f1.command(b'{"shape": "square", "at_s": 5}', 0.0)
