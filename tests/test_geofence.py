"""The operational volume: its distance law, the missions it refuses, the way back in."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from waiting import wait_until

from uavmpc.config import ConfigError
from uavmpc.geofence import Geofence, GeofenceError
from uavmpc.reference import Reference
from uavmpc.scenarios.run import RunSpec

BOX = Geofence.box((0.0, 100.0), (0.0, 50.0), (2.0, 40.0))
# An L: the square [0, 60]² without its quarter [30, 60] × [30, 60].
ELL = Geofence(np.array([[0, 0], [60, 0], [60, 30], [30, 30], [30, 60], [0, 60]], float),
               2.0, 40.0)


def test_margin_is_the_distance_to_the_nearest_face() -> None:
    pts = np.array([[50, 25, 20],   # centre: 20 m to the ceiling, 18 m to the floor, 25 m xy
                    [1, 25, 20],    # 1 m from the wall x = 0
                    [50, 25, 39.5],  # 0.5 m below the ceiling
                    [50, 25, 1.0],  # 1 m below the floor
                    [103, 25, 20],  # 3 m outside the wall x = 100
                    [np.nan, 0, 0]], float)
    d = BOX.margin(pts)
    assert d[:5] == pytest.approx([18.0, 1.0, 0.5, -1.0, -3.0])
    assert np.isnan(d[5])
    # The L's notch is outside, its arms inside.
    assert ELL.margin(np.array([[45, 45, 20]]))[0] == pytest.approx(-15.0)
    assert ELL.margin(np.array([[45, 15, 20]]))[0] == pytest.approx(15.0)
    assert ELL.contains(np.array([10, 50, 20]), margin_m=9.9)
    assert not ELL.contains(np.array([10, 50, 20]), margin_m=10.1)


@pytest.mark.parametrize(("points", "needle"), [
    ([[10, 10, 20], [110, 10, 20]], "point 1 .* outside the operational volume by 10.00 m"),
    ([[10, 10, 20], [10, 10, 45]], "point 1 .* outside .* by 5.00 m"),
    ([[10, 10, 20], [10, 10, 1.5]], "point 1 .* outside .* by 0.50 m"),
    ([[10, 10, 20], [10, 49.5, 20]], r"only 0\.50 m inside .* margin is 1\.00 m"),
])
def test_missions_outside_are_refused_naming_where(points, needle) -> None:
    pts = np.array([[*p, 0.0] for p in points], float)
    ref = Reference(np.arange(len(pts), dtype=float), pts)
    with pytest.raises(GeofenceError, match=needle):
        BOX.check_reference(ref)


def test_a_piece_between_two_points_inside_may_leave_a_non_convex_volume() -> None:
    # From the end of one arm to the end of the other: both points deep inside, the straight
    # line between them through the notch.
    cut = Reference(np.array([0.0, 10.0]), np.array([[55, 10, 20, 0], [10, 55, 20, 0]], float))
    with pytest.raises(GeofenceError, match=r"piece 0 .* leaves the operational volume"):
        ELL.check_reference(cut)
    # Grazing the notch's corner (30, 30) exactly: inside, but not by the margin.
    graze = Reference(np.array([0.0, 10.0]), np.array([[50, 10, 20, 0], [10, 50, 20, 0]],
                                                       float))
    with pytest.raises(GeofenceError, match="margin"):
        ELL.check_reference(graze)
    around = Reference(np.array([0.0, 10.0, 20.0]),
                       np.array([[50, 10, 20, 0], [10, 10, 20, 0], [10, 50, 20, 0]], float))
    ELL.check_reference(around)  # the same trip along the arms is inside
    # A loop closes back to its first point: that piece is checked too.
    loop = Reference(np.array([0.0, 10.0]), np.array([[50, 10, 20, 0], [10, 10, 20, 0]],
                                                      float), loop=True)
    ELL.check_reference(loop)  # back and forth along one arm: inside
    loop = Reference(np.array([0.0, 10.0, 20.0]),
                     np.array([[55, 10, 20, 0], [10, 10, 20, 0], [10, 55, 20, 0]], float),
                     loop=True)
    with pytest.raises(GeofenceError, match="leaves"):
        ELL.check_reference(loop)


def test_offset_ceiling_keeps_the_margin_below_the_top() -> None:
    assert BOX.offset_ceiling_m(np.array([10.0, 25.0, 30.0])) == pytest.approx(9.0)
    assert BOX.offset_ceiling_m(np.array([39.5])) == 0.0  # never negative


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.floats(-300, 300), st.floats(-300, 300), st.floats(-50, 100),
       st.sampled_from(["box", "ell"]))
def test_the_way_back_ends_inside_by_the_inset(x, y, z, which) -> None:
    fence = BOX if which == "box" else ELL
    target = fence.recovery_point(np.array([x, y, z]))
    assert fence.margin(target)[0] >= fence.inset_m - 1e-6
    # A point already deep inside is its own recovery point.
    inside = np.array([20.0, 10.0, 20.0])
    assert np.allclose(fence.recovery_point(inside), inside)


def test_bad_volumes_name_the_problem() -> None:
    with pytest.raises(GeofenceError, match="cross"):  # a bow tie
        Geofence(np.array([[0, 0], [10, 10], [10, 0], [0, 6]], float), 0.0, 10.0)
    with pytest.raises(GeofenceError, match="no area"):
        Geofence(np.array([[0, 0], [5, 5], [10, 10]], float), 0.0, 10.0)
    with pytest.raises(GeofenceError, match="above"):
        Geofence.box((0, 1), (0, 1), (10.0, 5.0))
    with pytest.raises(GeofenceError, match="too thin"):
        Geofence.box((0, 10), (0, 10), (0.0, 3.0))
    with pytest.raises(GeofenceError, match="margin_m"):
        Geofence.box((0, 10), (0, 10), (0.0, 30.0), margin_m=3.0, inset_m=2.0)
    cases = {
        "x": "unknown",
        "min_altitude_m": "exactly one of polygon",
        "box": "missing",
    }
    base = {"box": [0, 0, 10, 10], "min_altitude_m": 0.0, "max_altitude_m": 30.0}
    for field, needle in cases.items():
        t = dict(base)
        if field == "x":
            t["x"] = 1
        elif field == "min_altitude_m":
            t["polygon"] = [[0, 0], [1, 0], [0, 1]]
        else:
            del t["min_altitude_m"]
        with pytest.raises(ConfigError, match=needle):
            Geofence.from_dict(t)
    with pytest.raises(ConfigError, match=r"geofence\.box"):
        Geofence.from_dict({**base, "box": [0, 0, "a", 1]})
    with pytest.raises(ConfigError, match=r"geofence\.max_altitude_m.*finite"):
        Geofence.from_dict({**base, "max_altitude_m": float("nan")})
    with pytest.raises(ConfigError, match=r"geofence: .*cross"):
        Geofence.from_dict({"polygon": [[0, 0], [10, 10], [10, 0], [0, 6]],
                            "min_altitude_m": 0.0, "max_altitude_m": 30.0})
    fence = Geofence.from_dict({**base, "margin_m": 0.5})
    assert fence.margin_m == 0.5 and fence.contains(np.array([5.0, 5.0, 10.0]))


@pytest.mark.realtime
def test_a_node_refuses_missions_outside_and_flies_back_in() -> None:
    """Over Zenoh on loopback: a node that starts outside its volume flies back in and holds;
    a mission outside is refused and counted, one inside is flown."""
    import json
    import threading
    import time

    pytest.importorskip("zenoh")
    from uavmpc.comms.zenoh_link import ZenohTransport
    from uavmpc.drivers.node import Node
    from uavmpc.drivers.swarm import free_ports
    from uavmpc.plant import Airframe

    fence = Geofence.box((0.0, 50.0), (-25.0, 25.0), (1.0, 30.0))
    ports = free_ports(2)
    swarm = f"gf{ports[0]}"
    eps = [f"tcp/127.0.0.1:{p}" for p in ports]
    node_tx = ZenohTransport("uav1", swarm=swarm, listen=[eps[0]])
    gcs = ZenohTransport("gcs", swarm=swarm, listen=[eps[1]], connect=[eps[0]])
    node = Node("uav1", 1, Airframe.packaged("f550"), node_tx, start_m=(-5.0, 0.0, 5.0),
                geofence=fence)
    with pytest.raises(GeofenceError, match="outside"):  # from Python too
        node.set_mission(Reference.goto(60.0, 0.0, 5.0))
    states = gcs.subscribe("uav1/state", maxlen=100_000)
    thread = threading.Thread(target=node.run, args=(11.0,), daemon=True)
    thread.start()
    try:
        # the first flight after an edit compiles the kernels: it may take long to start
        wait_until(states.drain, 120.0, "the node's first state")

        def holding_inside() -> bool:
            at = node.vehicle.plant.state().position_m
            return node.stats.geofence["holding"] and np.linalg.norm(at - [2.0, 0.0, 5.0]) < 0.5

        wait_until(holding_inside, 20.0, "the node to fly back inside the fence and hold")
        held = node.vehicle.plant.state().position_m.copy()
        assert node.stats.geofence["breaches"] == 1 and node.stats.geofence["holding"]
        for goal in ([10.0, 0.0, 40.0, 0.0], [10.0, 0.0, 5.0, 0.0]):  # above the ceiling, fine
            gcs.send("uav1", "mission", json.dumps({"goto": goal}).encode())
            time.sleep(0.1)
        thread.join(timeout=20)
    finally:
        node.stop()
        thread.join(timeout=10)
        gcs.close()
        node_tx.close()
    assert np.linalg.norm(held - [2.0, 0.0, 5.0]) < 0.5  # 2 m (the inset) inside
    assert node.stats.geofence["missions_refused"] == 1
    assert node.stats.missions_rejected == 1
    assert not node.stats.geofence["holding"]
    assert np.linalg.norm(node.vehicle.plant.state().position_m - [10.0, 0.0, 5.0]) < 0.5


def _swap(fence: dict | None, start1: tuple[float, float, float] = (-25.0, 0.0, 5.0)) -> dict:
    """swap_through_static as a table, with a ``[geofence]``."""
    import tomllib
    from importlib import resources

    data = tomllib.loads(resources.files("uavmpc.scenarios").joinpath(
        "swap_through_static.toml").read_text())
    data["uavs"][0]["start"] = list(start1)
    if fence is not None:
        data["geofence"] = fence
    return data


def test_a_scenario_with_a_mission_outside_its_volume_is_refused() -> None:
    from uavmpc import scenarios

    with pytest.raises(ConfigError,
                       match=r"uavs\[1\] \(uav2\): mission point 0 .* outside .* by 5\.00 m"):
        scenarios.from_dict(_swap({"box": [-20, -10, 30, 10], "min_altitude_m": 1.0,
                                   "max_altitude_m": 30.0}))


def test_in_the_world_a_uav_outside_flies_back_in_and_offsets_respect_the_ceiling() -> None:
    from uavmpc import scenarios
    from uavmpc.drivers.world import World

    # uav1 starts 10 m beyond the wall x = −30; the ceiling leaves room for one layer (3 m)
    # above the 5 m missions, so uav3, which yields to both, cannot take the second (6 m).
    fence = {"box": [-30, -10, 30, 10], "min_altitude_m": 1.0, "max_altitude_m": 10.0}
    sc = scenarios.from_dict(_swap(fence, start1=(-40.0, 0.0, 5.0)))
    world = World(RunSpec(sc, seed=1))
    res = world.run(50.0)
    report = res.sections["geofence"]
    assert report["uav1"]["breaches"] == 1 and report["uav1"]["holding"]
    assert report["uav2"]["breaches"] == 0 and report["uav3"]["breaches"] == 0
    end = res.positions_m[-1, 0]
    assert np.linalg.norm(end - [-28.0, 0.0, 5.0]) < 0.5  # 2 m inside the wall, held
    ceiling = 10.0 - 1.0 - 5.0  # max altitude − margin − mission altitude
    assert all(o.max_z_offset_m <= ceiling + 1e-9 for o in res.per_uav.values())
    assert np.all(res.positions_m[:, :, 2] <= 10.0)
    # Without the volume uav1 flies its mission from outside, and uav3 climbs two layers.
    free = World(RunSpec(scenarios.from_dict(_swap(None, start1=(-40.0, 0.0, 5.0))),
                         seed=1)).run(50.0)
    assert "geofence" not in free.sections
    assert np.linalg.norm(free.positions_m[-1, 0] - [25.0, 0.0, 5.0]) < 0.5


def test_the_way_back_is_where_the_uav_is_to_be_with_its_offset_under_the_ceiling() -> None:
    """The way back is a point for the UAV, offset included: its trajectory (the mission's
    frame) lies the offset below, and the point no higher than the inset below the ceiling
    less how far above its estimate the UAV may be. (Before, the offset went on top of a point
    at the ceiling: under every fault at once UAVs held up to 30 m above a 40 m ceiling.)"""
    from uavmpc.supervisor import FenceGuard

    fence = Geofence.box((-30.0, 30.0), (-30.0, 30.0), (0.0, 40.0))
    guard = FenceGuard(fence)
    back = guard.recovery(3.0, np.array([0.0, 0.0, 41.0]), 0.5, offset_m=28.5)
    assert back is not None
    assert back.points[0].tolist() == [0.0, 0.0, 40.0 - fence.inset_m - 28.5, 0.5]
    assert back.times_s[0] == 3.0
    again = FenceGuard(fence).recovery(3.0, np.array([0.0, 0.0, 41.0]), 0.5, offset_m=28.5,
                                       sigma_above_m=4.0)
    assert again is not None and again.points[0, 2] == 40.0 - fence.inset_m - 4.0 - 28.5
    # the trajectory never goes below the floor's inset, whatever the offset
    low = FenceGuard(fence).recovery(0.0, np.array([0.0, 0.0, 41.0]), 0.0, offset_m=60.0)
    assert low is not None and low.points[0, 2] == fence.min_altitude_m + fence.inset_m
    # a UAV inside needs no way back
    assert FenceGuard(fence).recovery(0.0, np.array([0.0, 0.0, 20.0]), 0.0) is None


def test_a_uav_on_single_band_gnss_stays_under_the_ceiling_by_its_truth() -> None:
    """A3 at the ceiling: where its estimate is at the top, a UAV may truly be uncertainty_k σ
    above; its offsets keep that much more room (swap_through_static under a 10 m ceiling,
    seed 0: a layer of 3 m on 5 m took it to 15 m by its truth before). No room left for a
    layer, the UAVs hold instead of climbing."""
    from uavmpc import scenarios
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.faults import FaultSpec
    from uavmpc.scenarios.run import RunSpec

    fence = {"box": [-30, -10, 30, 10], "min_altitude_m": 1.0, "max_altitude_m": 10.0}
    sc = scenarios.from_dict(_swap(fence))
    world = World(RunSpec(sc, seed=0, faults=FaultSpec(gnss="single")))
    sigma_v = world.uavs[0].stack.position_sigma_m[1]
    assert sigma_v > 1.0  # single-band GNSS states metres
    res = world.run(50.0)
    assert res.positions_m[:, :, 2].max() <= 10.0
    room = 10.0 - 1.0 - 5.0 - sc.avoidance.uncertainty_k * sigma_v
    assert all(o.max_z_offset_m <= max(room, 0.0) + 1e-9 for o in res.per_uav.values())
    assert not res.collisions
