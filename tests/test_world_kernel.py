"""The compiled world step (uavmpc.world_kernel) against the plain per-UAV path it replaces."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uavmpc import scenarios
from uavmpc.avoidance.proximity import align_batch, near_and_dz
from uavmpc.log import FlightRecorder
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.world import World

#: Both paths solve the same QPs with different solvers (DAQP vs batchqp, equal to 1e-9) and
#: sum in different orders; in closed loop that stays far below a millimetre.
POSITION_TOL_M = 1e-6


def _both(make_scenario, duration_s: float, **kwargs):
    out = {}
    for backend in ("compiled", "plain"):
        world = World(make_scenario(), backend=backend, **kwargs)
        out[backend] = world.run(duration_s)
        assert world.backend_used == backend
    return out["compiled"], out["plain"]


def _assert_same_flight(a, b) -> None:
    assert np.abs(a.positions_m - b.positions_m).max() < POSITION_TOL_M
    assert np.array_equal(a.z_offset_m, b.z_offset_m)  # the same avoidance decisions
    assert np.allclose(a.min_distance_m, b.min_distance_m, atol=POSITION_TOL_M, rtol=0)
    assert [(c.t, c.a, c.b) for c in a.collisions] == [(c.t, c.a, c.b) for c in b.collisions]
    assert a.messages == b.messages
    for uav, pa in a.per_uav.items():
        pb = b.per_uav[uav]
        for key in ("avoidance_active_s", "reached_goal", "limit_violations",
                    "tracker_fallbacks", "messages_rejected", "max_z_offset_m"):
            assert pa[key] == pb[key], (uav, key)
        assert abs(pa["tracking_rmse_m"] - pb["tracking_rmse_m"]) < POSITION_TOL_M
        assert pa["max_limit_excess"] < 1e-6 and pb["max_limit_excess"] < 1e-6


def test_compiled_equals_plain_in_a_random_walk_with_avoidance() -> None:
    a, b = _both(lambda: random_walk(5, duration_s=30.0, seed=1), 15.0, avoidance=True, seed=1)
    _assert_same_flight(a, b)
    assert a.messages["delivered"] > 0


def test_compiled_equals_plain_through_a_conflict_with_faults() -> None:
    """Climbs, tightened limits (the virtual UAV brakes), a lossy late link and gusty wind."""
    link = LinkSettings(latency_s=0.2, jitter_s=0.02, loss=0.3)
    a, b = _both(lambda: scenarios.load("swap_through_static"), 30.0, avoidance=True, seed=3,
                 link=link, wind_mps=5.0)
    _assert_same_flight(a, b)
    assert a.z_offset_m.max() > 0.0, "the scenario must make someone climb"
    assert a.collisions == []


def test_compiled_equals_plain_without_avoidance_until_the_collision() -> None:
    a, b = _both(lambda: scenarios.load("swap_through_static"), 25.0, avoidance=False, seed=2)
    _assert_same_flight(a, b)
    assert a.collisions


def test_runs_in_chunks_continue_the_same_flight() -> None:
    """The objects are written back after each run: three runs equal one, and a plain run can
    follow a compiled one."""
    whole = World(random_walk(3, duration_s=20.0, seed=4), seed=4).run(9.0)
    world = World(random_walk(3, duration_s=20.0, seed=4), seed=4)
    parts = [world.run(3.0), world.run(3.0)]
    world.backend = "plain"
    parts.append(world.run(3.0))
    joined = np.concatenate([p.positions_m for p in parts])
    assert np.abs(joined - whole.positions_m).max() < POSITION_TOL_M
    assert np.allclose(np.concatenate([p.t_s for p in parts]), whole.t_s)


def test_a_world_the_kernel_does_not_cover_runs_plain(tmp_path) -> None:
    mixed = World(scenarios.load("converge_center"))  # f550 and x500 in one world
    mixed.run(0.5)
    assert mixed.backend_used == "plain"
    sc = random_walk(2, duration_s=5.0, seed=0)
    with FlightRecorder(tmp_path / "run.mcap", [u.uav_id for u in sc.uavs], {}) as rec:
        world = World(sc, recorder=rec)
        world.run(1.0)
    assert world.backend_used == "plain"
    with pytest.raises(ValueError, match="backend"):
        World(sc, backend="fast")


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 40), k=st.integers(1, 5),
       lag=st.floats(-2.0, 12.0))
def test_compiled_proximity_equals_align_batch(seed: int, n: int, k: int, lag: float) -> None:
    rng = np.random.default_rng(seed)
    m = 40
    at = 100.0 + np.cumsum(rng.uniform(0.01, 0.3, m))
    own = rng.uniform(-20.0, 20.0, (m, 3))
    times = 100.0 - lag + np.cumsum(rng.uniform(0.01, 0.4, (k, n)), axis=1)
    pos = rng.uniform(-20.0, 20.0, (k, n, 3))
    aligned, known = align_batch(times, pos, at, 1.0)
    d = aligned - own[None]
    near_ref = known & (d[..., 0] ** 2 + d[..., 1] ** 2 <= 5.0**2)
    near = np.empty(m, dtype=bool)
    dz = np.empty(m)
    for i in range(k):
        near_and_dz(times[i], pos[i], at, 1.0, own, 5.0, near, dz)
        assert np.array_equal(near, near_ref[i])
        assert np.array_equal(dz, -d[i, :, 2])
