"""Non-cooperative UAVs (``avoidance = false``, ``Faults.given(non_cooperative=...)``) and
the dense, adversarial built-in scenarios (antipodal circles, a non-cooperative crossing)."""

import dataclasses
import json

import numpy as np
import pytest

from uavmpc import ConfigError, scenarios
from uavmpc.drivers import world as world_module
from uavmpc.drivers.world import World
from uavmpc.scenarios import dense
from uavmpc.scenarios.dense import antipodal, time_to_goals
from uavmpc.scenarios.faults import Faults
from uavmpc.scenarios.run import RunSpec

DZ = 3.0

#: A head-on swap at one height. "b" has the lower priority: when it flies without avoidance,
#: only its flag makes "a" yield.
SWAP = """
name = "swap2"
duration_s = 30.0
[[uavs]]
id = "a"
priority = 1
start = [-20.0, 0.0, 5.0]
goto = [20.0, 0.0, 5.0, 0.0]
[[uavs]]
id = "b"
priority = 2
start = [20.0, 0.0, 5.0]
heading_rad = 3.141592653589793
goto = [-20.0, 0.0, 5.0, 3.141592653589793]
"""


def _swap(tmp_path, b_line: str = ""):
    text = SWAP if not b_line else SWAP.replace('id = "b"\n', f'id = "b"\n{b_line}\n')
    path = tmp_path / "swap2.toml"
    path.write_text(text)
    return scenarios.load(path)


def _flags_heard(world: World) -> dict[str, bool]:
    """Each UAV's broadcast flag, as the other UAV last received it."""
    a, b = world.uavs
    return {"a": b.stack.inbox.latest["a"].avoiding, "b": a.stack.inbox.latest["b"].avoiding}


# ------------------------------------------------------------------ the flag reaches the world
def test_the_toml_flag_makes_a_uav_fly_without_avoidance(tmp_path) -> None:
    sc = _swap(tmp_path, "avoidance = false")
    assert [u.avoidance for u in sc.uavs] == [True, False]
    world = World(RunSpec(sc))
    assert world.non_cooperative == ("b",)
    assert world.uavs[0].stack.avoidance is not None
    assert world.uavs[1].stack.avoidance is None
    world.run(2.0)
    assert _flags_heard(world) == {"a": True, "b": False}


def test_the_keyword_is_the_same_as_the_toml_flag(tmp_path) -> None:
    by_keyword = World(RunSpec(_swap(tmp_path), drawn=Faults.given(non_cooperative=["b"])))
    assert by_keyword.non_cooperative == ("b",)
    r1 = by_keyword.run(12.0)
    assert _flags_heard(by_keyword) == {"a": True, "b": False}
    r2 = World(RunSpec(_swap(tmp_path, "avoidance = false"))).run(12.0)
    np.testing.assert_array_equal(r1.positions_m, r2.positions_m)
    for r in (r1, r2):
        s = r.summary()
        assert s.sections["non_cooperative"] == ["b"]
        json.dumps(s.to_json(), allow_nan=False)  # JSON-serialisable


def test_cooperative_is_world_avoidance_and_spec_and_not_listed(tmp_path) -> None:
    sc = _swap(tmp_path, "avoidance = true")
    assert World(RunSpec(sc)).non_cooperative == ()
    assert World(RunSpec(sc, drawn=Faults.given(non_cooperative=("a",
                                                                 "b")))).non_cooperative == ("a",
                                                                                             "b")
    off = World(RunSpec(sc, avoidance=False))
    assert off.non_cooperative == ("a", "b")
    assert all(u.stack.avoidance is None for u in off.uavs)
    # Nobody singled out: the summary says nothing (with avoidance off, "avoidance": false).
    assert "non_cooperative" not in World(RunSpec(sc)).run(1.0).summary().sections
    assert "non_cooperative" not in off.run(1.0).summary().sections


def test_a_non_cooperative_uav_flies_the_same_on_every_path(tmp_path) -> None:
    """Batched or UAV by UAV, encounters by the index or all pairs: bit for bit one flight."""
    sc = _swap(tmp_path, "avoidance = false")
    ref = World(RunSpec(sc, seed=4)).run(12.0).positions_m
    for kwargs in ({"batched": False}, {"index": True}, {"index": False}):
        np.testing.assert_array_equal(
            World(RunSpec(sc, seed=4), **kwargs).run(12.0).positions_m, ref)


def test_an_all_cooperative_world_flies_as_before(tmp_path) -> None:
    sc = _swap(tmp_path)
    a = World(RunSpec(sc, seed=2)).run(12.0)
    b = World(RunSpec(sc, seed=2, drawn=Faults.given(non_cooperative=()))).run(12.0)
    np.testing.assert_array_equal(a.positions_m, b.positions_m)


# ------------------------------------------------------------------ who yields to whom
def test_a_cooperative_uav_climbs_over_a_non_cooperative_one(tmp_path) -> None:
    result = World(RunSpec(_swap(tmp_path, "avoidance = false"))).run()
    s = result.summary()
    assert s.collisions == () and s.min_distance_m is not None and s.min_distance_m > 2.0
    a, b = s.uavs["a"], s.uavs["b"]
    # "a" has the higher priority, yet yields: "b" will not.
    assert "b" in a.details["yielded_to"] and a.max_z_offset_m >= DZ
    assert b.max_z_offset_m == 0.0 and b.details["yielded_to"] == {}
    assert np.all(result.z_offset_m[:, 1] == 0.0)
    assert a.reached_goal and b.reached_goal
    assert result.z_offset_m[-1, 0] == 0.0  # back down once "b" has passed


def test_two_non_cooperative_uavs_collide(tmp_path) -> None:
    s = World(RunSpec(_swap(tmp_path), drawn=Faults.given(non_cooperative=["a",
                                                                           "b"]))).run(15.0).summary()
    assert s.collisions and s.collisions[0].a == "a"
    assert s.min_distance_m is not None and s.min_distance_m < 1.0
    assert s.sections["non_cooperative"] == ["a", "b"]


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize("value", ['"no"', "0", "1", "[true]"])
def test_the_flag_must_be_a_bool(tmp_path, value: str) -> None:
    with pytest.raises(ConfigError, match=r"uavs\[1\]\.avoidance: must be true or false"):
        _swap(tmp_path, f"avoidance = {value}")


def test_unknown_non_cooperative_ids_are_named(tmp_path) -> None:
    sc = _swap(tmp_path)
    with pytest.raises(ValueError, match=r"non_cooperative: 'c', 'zz' not UAVs"):
        World(RunSpec(sc, drawn=Faults.given(non_cooperative=["a", "zz", "c"])))
    with pytest.raises(ValueError, match="not the string 'a'"):
        World(RunSpec(sc, drawn=Faults.given(non_cooperative="a")))


def test_uav_spec_keeps_its_positional_constructor() -> None:
    u = antipodal(2).uavs[0]
    assert u.avoidance is True
    assert dataclasses.replace(u, avoidance=False).avoidance is False


# ------------------------------------------------------------------ dense scenarios
def test_the_built_in_antipodal_circles_are_the_generator_s() -> None:
    for n, duration in ((8, 90.0), (12, 150.0)):
        built_in, made = scenarios.load(f"antipodal_{n}"), antipodal(n, duration_s=duration)
        assert built_in.duration_s == made.duration_s
        for u, v in zip(built_in.uavs, made.uavs, strict=True):
            assert (u.uav_id, u.priority, u.airframe) == (v.uav_id, v.priority, v.airframe)
            assert (u.start_m, u.heading_rad, u.goal_m) == (v.start_m, v.heading_rad, v.goal_m)
            np.testing.assert_array_equal(u.mission.times_s, v.mission.times_s)
            np.testing.assert_array_equal(u.mission.points, v.mission.points)
            assert u.avoidance and v.avoidance
        starts = np.array([u.start_m for u in made.uavs])
        goals = np.array([u.goal_m for u in made.uavs])
        np.testing.assert_allclose(np.hypot(starts[:, 0], starts[:, 1]), 30.0)
        np.testing.assert_allclose(starts[:, :2] + goals[:, :2], 0.0, atol=1e-6)  # opposite
        np.testing.assert_allclose(goals[:, 2], 10.0)
        # Everyone above the centre at once: 30 m at 6 m/s from t = 2 s.
        centre = np.array([u.mission.sample(np.array([7.0]))[0, :3] for u in made.uavs])
        np.testing.assert_allclose(centre, [[0.0, 0.0, 10.0]] * n, atol=0.05)


def test_antipodal_rejects_crowded_or_bad_circles() -> None:
    with pytest.raises(ConfigError, match="ceiling_m: 11 m leaves no room"):
        antipodal(4, ceiling_m=11.0)
    with pytest.raises(ConfigError, match="radius_m: 100 UAVs"):
        antipodal(100, radius_m=20.0)
    with pytest.raises(ConfigError, match="uavs: must be an integer"):
        antipodal(1)
    with pytest.raises(ConfigError, match="height_m"):
        antipodal(4, height_m=-1.0)


def test_the_goal_tolerance_is_the_world_s() -> None:
    assert dense.GOAL_TOLERANCE_M == world_module.GOAL_TOLERANCE_M


#: Per dense scenario: the time budget for every goal [s] (the scenario's duration is ≥ twice
#: it; benchmarks/sweep_dense.py over 10 seeds with 30 % loss: every UAV at its goal by 28.2 s
#: and 22.4 s).
BUDGET_S = {"antipodal_8": 45.0, "noncooperative_crossing": 45.0}
#: After the budget, the least share of the time each UAV spends at its goal under loss (10
#: seeds: at least 0.87; a hovering neighbour silent for 2.6 s is made way for, one layer up).
AT_GOAL_SHARE = 0.8


@pytest.mark.parametrize("name", sorted(BUDGET_S))
def test_dense_scenario_under_loss_no_collision_every_goal_in_time(name: str) -> None:
    """One seed, 30 % loss (the sweep, benchmarks/sweep_dense.py, flies ten of each)."""
    sc = scenarios.load(name)
    assert name in scenarios.CONFLICTS + scenarios.DENSE
    assert sc.duration_s >= 2.0 * BUDGET_S[name]
    link = dataclasses.replace(sc.link, loss=0.3)
    result = World(RunSpec(sc, seed=1, link=link)).run()
    s = result.summary()
    assert s.collisions == (), s.collisions
    assert s.min_distance_m is not None and s.min_distance_m > 2.0
    assert s.messages.dropped > 0.2 * s.messages.sent
    first = time_to_goals(result, sc, settled=False)
    after = result.t_s >= BUDGET_S[name]
    for k, (uid, u) in enumerate(s.uavs.items()):
        assert u.reached_goal, uid
        assert first[uid] is not None and first[uid] < BUDGET_S[name], (uid, first[uid])
        # No endless climbing: below the ceiling, and at its goal most of the time after.
        goal = np.asarray(sc.uavs[k].goal_m)
        at_goal = np.linalg.norm(result.positions_m[after, k] - goal, axis=1) < 1.0
        assert u.max_z_offset_m < 30.0 and at_goal.mean() >= AT_GOAL_SHARE, (uid,
                                                                               at_goal.mean())
    if name == "noncooperative_crossing":
        # The intruder flies straight through; the group gets out of its way, and back.
        assert s.sections["non_cooperative"] == ["intruder"]
        assert s.uavs["intruder"].max_z_offset_m == 0.0
        ids = list(s.uavs)
        for uid in ("west", "north", "east", "south"):
            assert "intruder" in s.uavs[uid].details["yielded_to"]
            assert s.uavs[uid].max_z_offset_m >= DZ
            assert first[uid] == pytest.approx(result.t_s[0])  # where it started
            k = ids.index(uid)
            off = np.linalg.norm(result.positions_m[~after, k] - np.asarray(sc.uavs[k].goal_m),
                                 axis=1)
            assert off.max() > DZ - 0.5  # pushed off by the intruder (then back, above)


def test_antipodal_12_more_uavs_than_layers_hold_short_and_every_goal_is_reached() -> None:
    """docs/safety.md, A6: 12 UAVs above one point need 12 layers, 30 m of offset in 3 m steps
    gives 11. The lowest priorities hold short (stop within their plans) until the way is
    clear. (Without holding, two once ended up in one layer and collided; since a climb under
    way is checked again on its way, that run no longer collides either, so the test watches
    the holds happen instead.)"""
    assert "antipodal_12" in scenarios.DENSE
    sc = scenarios.load("antipodal_12")
    held: set[str] = set()

    def watch(world: World) -> None:
        held.update(u.uav_id for u in world.uavs
                    if u.stack.steering.decision is not None
                    and u.stack.steering.decision.holding)

    result = World(RunSpec(sc)).run(45.0, on_log=watch)
    s = result.summary()
    assert s.collisions == (), s.collisions
    assert s.min_distance_m is not None and s.min_distance_m > 2.0
    goals = time_to_goals(result, sc)
    assert all(t is not None for t in goals.values()), goals
    assert held, "no UAV held short"
    assert "uav1" not in held  # the highest priority never holds


@pytest.mark.slow
def test_16_uavs_swap_under_a_30_m_ceiling_one_at_a_time_where_layers_run_out() -> None:
    """A geofence's 30 m ceiling over a circle at 10 m leaves 7 layers (0 … 18 m of offset,
    1 m of margin) for 16 UAVs meeting above one point. Every goal was reached until a hold
    stopped in 3-D (docs/safety.md: a held UAV takes no new layer): two UAVs, held at 10 and
    18 m of offset over the centre, now wait there to the end, each for the other's layer.
    The rest arrive; no collision, 2 m kept."""
    sc = antipodal(16, duration_s=60.0, ceiling_m=30.0)
    result = World(RunSpec(sc)).run()
    s = result.summary()
    assert s.collisions == (), s.collisions
    assert s.min_distance_m is not None and s.min_distance_m > 2.0
    goals = time_to_goals(result, sc)
    assert sum(t is not None for t in goals.values()) >= 14, goals
    assert max(u.max_z_offset_m for u in s.uavs.values()) <= 19.0  # under the ceiling
    assert max(result.positions_m[:, :, 2].max(axis=0)) <= 30.0


def test_time_to_goals_needs_the_scenario_of_the_result(tmp_path) -> None:
    result = World(RunSpec(_swap(tmp_path))).run(0.5)
    assert time_to_goals(result, _swap(tmp_path)) == {"a": None, "b": None}
    with pytest.raises(ValueError, match="not the scenario's"):
        time_to_goals(result, antipodal(2))
