"""Vertical traffic: two stacks of UAVs swapping places and inverting their heights, every path
climbing or descending through the others' (uavmpc.scenarios.dense.vertical_swap)."""

from __future__ import annotations

import pytest

from uavmpc.config import ConfigError
from uavmpc.drivers.world import World
from uavmpc.scenarios.dense import vertical_swap
from uavmpc.scenarios.run import RunSpec


def test_the_stacks_swap_places_and_invert_their_heights() -> None:
    sc = vertical_swap(3)
    starts = {u.uav_id: u.start_m for u in sc.uavs}
    goals = {u.uav_id: u.goal_m for u in sc.uavs}
    assert starts["uav1"] == (-20.0, 0.0, 6.0) and goals["uav1"] == (20.0, 0.0, 18.0)
    assert starts["uav6"] == (20.0, 0.0, 18.0) and goals["uav6"] == (-20.0, 0.0, 6.0)
    assert [u.priority for u in sc.uavs] == [1, 2, 3, 4, 5, 6]
    assert sc.geofence is not None and sc.geofence.max_altitude_m == 30.0


@pytest.mark.parametrize(("kw", "named"), [
    ({"per_stack": 0}, "per_stack"), ({"per_stack": 2, "spacing_m": 1.0}, "spacing_m"),
    ({"per_stack": 3, "ceiling_m": 19.0}, "ceiling_m"), ({"per_stack": 2, "gap_m": -1.0}, "gap_m"),
])
def test_bad_stacks_name_the_field(kw: dict, named: str) -> None:
    with pytest.raises(ConfigError, match=named):
        vertical_swap(**kw)


@pytest.mark.parametrize("seed", [0, 2])
def test_a_held_uav_stops_its_climb_too(seed: int) -> None:
    """The 2 × 3 swap collided on seeds 0, 1 and 2 (0.70, 0.34, 0.39 m) while a hold stopped
    only the horizontal motion: the mission's own climb carried a held UAV into the one it
    yielded to. A hold now keeps its height (the offset still moves it). Not every goal is
    reached yet: the layer has no sideways move (docs/safety.md)."""
    res = World(RunSpec(vertical_swap(3, duration_s=90.0), seed=seed)).run()
    assert not res.collisions, res.collisions
    assert float(res.min_distance_m.min()) > 1.0
    assert res.positions_m[:, :, 2].max() <= 30.0


def test_the_2x5_swap_checks_every_climb_and_holds_in_3d() -> None:
    """The 2 × 5 swap collided on every seed (0.06 m at 2.4 s): uav9, climbing 15 m for
    those above it, yielded to no one and so was never re-checked, and went on through
    uav10 hovering 6 m over it with no layer left under the ceiling. Then three more ways
    through: a climb told to stop braked at 1 m/s² and went on for 5 m; a hold ended for a
    layer its climb could not reach and the mission's climb went on between holds (0.29 m);
    a UAV held until its mission's point had reached its goal took that goal's height, 22 m
    up, as the height to hold (0.69 m). Not yet 2 m, nor every goal (docs/safety.md)."""
    res = World(RunSpec(vertical_swap(5, duration_s=30.0), seed=0)).run()
    assert not res.collisions, res.collisions
    assert float(res.min_distance_m.min()) > 1.0
    assert res.positions_m[:, :, 2].max() <= 42.0  # the ceiling, 12 m above the top


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_lossy_2x5_swap_holds_in_3d_without_a_collision(seed: int) -> None:
    """30 % loss and 200 ms: the 2 × 5 swap collided in one run of three (seed 1, uav7 and
    uav8, 0.09 m at 8.7 s): a held UAV took a new layer while holding, its climb was
    re-checked a round later against a band that counted it at its end already, cut short
    and chosen again, and each hold ended for a layer it never climbed to, so its mission
    went on between the holds. A hold now stops in 3-D (no new layer while held, only the
    one its hold ends for, whose way up is checked as any climb's), and a climb under way is
    judged by the band it was chosen with. Not yet 2 m (docs/safety.md)."""
    from uavmpc.scenarios import LinkSettings

    res = World(RunSpec(vertical_swap(5, duration_s=30.0), seed=seed,
                        link=LinkSettings(loss=0.3, latency_s=0.2))).run()
    assert not res.collisions, res.collisions
    assert float(res.min_distance_m.min()) > 1.0
