"""The world's batched tick against its UAVs ticked one by one: the same kernels, bit for bit."""

import dataclasses
import math

import numpy as np
import oracles
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uavmpc import scenarios
from uavmpc.avoidance.proximity import align_batch, near_and_dz
from uavmpc.drivers.world import World
from uavmpc.log import FlightRecorder
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec
from uavmpc.tracker import TrackerConfig


def _both(make_scenario, duration_s: float, tracker_config=None, **spec):
    out = {}
    for batched in (True, False):
        out[batched] = World(RunSpec(make_scenario(), **spec), batched=batched,
                             tracker_config=tracker_config).run(duration_s)
    return out[True], out[False]


def _assert_same_flight(a, b) -> None:
    """Bit for bit: positions, avoidance decisions, messages and every statistic."""
    assert np.array_equal(a.positions_m, b.positions_m)
    assert np.array_equal(a.z_offset_m, b.z_offset_m)
    assert np.array_equal(a.min_distance_m, b.min_distance_m)
    assert a.collisions == b.collisions
    assert a.messages == b.messages
    assert a.per_uav == b.per_uav


def test_batched_equals_per_object_in_a_random_walk_with_avoidance() -> None:
    a, b = _both(lambda: random_walk(5, duration_s=30.0, seed=1), 15.0, avoidance=True, seed=1)
    _assert_same_flight(a, b)
    assert a.messages["delivered"] > 0


def test_a_resting_uav_is_not_asked_again_and_flies_the_same(monkeypatch) -> None:
    """A round skips the UAVs at rest with nobody near or silent (OnboardBatch.resting): far
    fewer UAVs handed to the compiled decisions (those with someone near are handed over
    either way: 12 UAVs in 160 m × 160 m meet often), the same decisions at the same times
    and the same flight as asking every UAV every round."""
    import uavmpc.avoidance.round as round_module
    import uavmpc.drivers.world as world_module
    from uavmpc.jit import bound

    def fly(skip: bool):
        asked, decisions = [0], []
        decide_rows, avoidance_round = round_module.decide_rows, world_module.avoidance_round
        apply = round_module.Steering.apply

        def counted_decide_rows(strategies, rows, *args):
            asked[0] += rows.shape[0]
            return bound(decide_rows)(strategies, rows, *args)

        def every_round(batch, *args, **kwargs):
            if not skip:
                batch.resting[:] = False  # every UAV asked again
            return avoidance_round(batch, *args, **kwargs)

        def recorded_apply(self, decision):
            if decision != self.decision:
                decisions.append((self.uav_id, float(self.tracker.time_s), decision))
            apply(self, decision)

        with monkeypatch.context() as m:
            m.setattr(round_module, "decide_rows", counted_decide_rows)
            m.setattr(world_module, "avoidance_round", every_round)
            m.setattr(round_module.Steering, "apply", recorded_apply)
            r = World(RunSpec(random_walk(12, area_m=160.0, duration_s=20.0, seed=2),
                              avoidance=True, seed=2)).run(20.0)
        return r, asked[0], decisions

    skipping, asked_less, decided = fly(True)
    asking, asked_all, decided_all = fly(False)
    _assert_same_flight(skipping, asking)
    assert decided == decided_all and any(d.z_offset_m > 0 for _, _, d in decided)
    assert 0 < asked_less < asked_all / 2


def test_batched_equals_per_object_through_a_conflict_with_faults_and_mixed_airframes() -> None:
    """Climbs, tightened limits (the virtual UAV brakes), a lossy late link, gusty wind, a
    quadrotor and a hexacopter in one world, and a flight log being written."""
    link = LinkSettings(latency_s=0.2, jitter_s=0.02, loss=0.3)
    a, b = _both(lambda: scenarios.load("converge_center"), 30.0, avoidance=True, seed=3,
                 link=link, wind_mps=5.0)
    _assert_same_flight(a, b)
    assert a.z_offset_m.max() > 0.0, "the scenario must make someone climb"
    assert a.collisions == []


def test_batched_equals_per_object_without_avoidance_until_the_collision() -> None:
    a, b = _both(lambda: scenarios.load("swap_through_static"), 25.0, avoidance=False, seed=2)
    _assert_same_flight(a, b)
    assert a.collisions


def test_batched_equals_per_object_with_a_python_solver() -> None:
    """With DAQP behind the solver contract the world ticks in three compiled calls around the
    Python solves: still the same flight as the stacks ticked alone."""
    daqp = dataclasses.replace(TrackerConfig.from_toml(), solver="daqp")
    a, b = _both(lambda: random_walk(3, duration_s=10.0, seed=2), 5.0, seed=2,
                 tracker_config=daqp)
    _assert_same_flight(a, b)


def test_every_broadcast_decodes_to_the_message_its_receivers_take() -> None:
    """A tick's broadcasts are written in one compiled call, and the store slot their
    receivers take instead of decoding them is written from the same rows: field for field,
    the bytes decode to it (heard lists included), a sender's heard list names only UAVs it
    holds, and each slot is let go once its copies are delivered (the store does not grow
    with the broadcasts)."""
    from uavmpc.comms.message import decode

    world = World(RunSpec(random_walk(6, duration_s=40.0, seed=2), avoidance=True, seed=2))
    table = world.inboxes
    sent = []

    def publish(stacks, data, now, send=world.wire.publish):
        send(stacks, data, now)
        sent.extend((d, table.slot_for(d)) for d in data)  # found, not decoded: no error

    world.wire.publish = publish
    world.run(6.0)
    assert len(sent) > 50
    st = table.store
    for data, slot in sent[-12:]:  # the newest: their slots are not reused yet
        msg = decode(data)
        m = msg.points
        assert int(st.points[slot]) == m and table.ids[int(st.col[slot])] == msg.uav_id
        assert np.array_equal(st.times_s[slot, :m], msg.times_s)
        assert np.array_equal(st.positions_m[slot, :m], msg.positions_m)
        assert (float(st.stamp_s[slot]), int(st.priority[slot]), bool(st.avoiding[slot]),
                tuple(st.sigma_m[slot].tolist())) == (msg.stamp_s, msg.priority, msg.avoiding,
                                                      msg.position_sigma_m)
        assert table.heard[slot] is None  # written from the heard list's columns
        assert table.heard_ids(slot) == msg.heard and msg.uav_id not in msg.heard
    assert max(len(decode(d).heard) for d, _ in sent) == 5  # everyone heard everyone
    table.unpin()
    world.run(30.0)  # 360 more broadcasts
    n = len(world.uavs)
    holders = table.store.holders  # (the store as it is now: grown, if it grew)
    assert int(holders.sum()) <= n * (n - 1) + 2 * n  # the receivers' and those in flight
    # UAV by UAV, each takes its copies from the link itself: its slots are let go too.
    one_by_one = World(RunSpec(random_walk(6, duration_s=30.0, seed=2), avoidance=True, seed=2),
                       batched=False)
    one_by_one.run(30.0)
    assert int(one_by_one.inboxes.store.holders.sum()) <= n * (n - 1) + 2 * n


def test_a_broadcast_the_message_laws_refuse_is_named_not_sent() -> None:
    """A position uncertainty out of range (or a plan that is not finite) stops the compiled
    broadcast; the checked path then names the field, and nothing is published."""
    from uavmpc.comms.message import InvalidMessageError

    world = World(RunSpec(random_walk(3, duration_s=5.0, seed=1), avoidance=True, seed=1))
    world.run(1.0)
    world.onboard.position_sigma_m[1] = (150.0, 0.0)
    sent = world.uavs[1].stack.predictions_sent
    with pytest.raises(InvalidMessageError, match=r"position_sigma_m: each must be in \[0, 100\]"):
        world.run(1.0)
    assert world.uavs[1].stack.predictions_sent == sent  # it never went out


def test_runs_in_chunks_continue_the_same_flight() -> None:
    """State lives in the world's records: three runs equal one, whichever way they tick."""
    whole = World(RunSpec(random_walk(3, duration_s=20.0, seed=4), seed=4)).run(9.0)
    world = World(RunSpec(random_walk(3, duration_s=20.0, seed=4), seed=4))
    parts = [world.run(3.0), world.run(3.0)]
    world.batched = False
    parts.append(world.run(3.0))
    assert np.array_equal(np.concatenate([p.positions_m for p in parts]), whole.positions_m)
    assert np.allclose(np.concatenate([p.t_s for p in parts]), whole.t_s)


def test_a_recorder_does_not_change_the_flight(tmp_path) -> None:
    sc = random_walk(2, duration_s=5.0, seed=0)
    plain = World(RunSpec(sc)).run(2.0)
    with FlightRecorder(tmp_path / "run.mcap", [u.uav_id for u in sc.uavs], {}) as rec:
        logged = World(RunSpec(sc), recorder=rec).run(2.0)
    assert np.array_equal(plain.positions_m, logged.positions_m)
    assert (tmp_path / "run.mcap").stat().st_size > 1000


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 40), k=st.integers(1, 5),
       lag=st.floats(-2.0, 12.0))
def test_compiled_proximity_equals_the_numpy_oracle(seed: int, n: int, k: int,
                                                    lag: float) -> None:
    rng = np.random.default_rng(seed)
    m = 40
    at = 100.0 + np.cumsum(rng.uniform(0.01, 0.3, m))
    own = rng.uniform(-20.0, 20.0, (m, 3))
    times = 100.0 - lag + np.cumsum(rng.uniform(0.01, 0.4, (k, n)), axis=1)
    pos = rng.uniform(-20.0, 20.0, (k, n, 3))
    ref, ref_known = oracles.align_batch(times, pos, at, 1.0)
    aligned, known = align_batch(times, pos, at, 1.0)
    assert np.array_equal(aligned, ref) and np.array_equal(known, ref_known)
    d = ref - own[None]
    near_ref = ref_known & (d[..., 0] ** 2 + d[..., 1] ** 2 <= 5.0**2)
    near = np.empty(m, dtype=bool)
    dz = np.empty(m)
    dxy = np.empty(m)
    work = np.empty((m, 3))
    for i in range(k):
        near_and_dz(times[i], pos[i], at, 1.0, own, 5.0, near, dz, dxy, work)
        assert np.array_equal(near, near_ref[i])
        assert np.array_equal(dz, -d[i, :, 2])
        assert np.array_equal(dxy, np.sqrt(d[i, :, 0] ** 2 + d[i, :, 1] ** 2))


@pytest.mark.parametrize("threads", [1, 2])
def test_every_ticks_closest_distance_and_contacts_are_the_pairs_own(threads: int) -> None:
    """The tick writes only the closest distance (the smallest root of the pairs' squared
    distances, found over the threads with two); the contacts compute every pair's distance
    while one goes on. Both must be what the pairs of the traced positions give: the
    closest bit for bit, each contact a pair that came within the collision distance, at
    its smallest distance."""
    from scipy.spatial.distance import pdist

    from uavmpc.drivers.world_report import COLLISION_DISTANCE_M
    from uavmpc.drivers.world_tick import pair_distances
    from uavmpc.jit import available_threads, using_threads

    if threads > available_threads():
        pytest.skip("one core")
    with using_threads(threads):
        r = World(RunSpec(scenarios.load("antipodal_8"), avoidance=False)).run()
    n = len(r.uav_ids)
    a, b = np.triu_indices(n, 1)
    d = np.empty((r.t_s.shape[0], a.shape[0]))
    for k in range(r.t_s.shape[0]):
        pair_distances(r.positions_m[k], d[k])
    assert np.array_equal(r.min_distance_m, d.min(axis=1))
    np.testing.assert_allclose(d, [pdist(p) for p in r.positions_m], rtol=1e-15)
    close = d < COLLISION_DISTANCE_M
    assert close.any()  # the test needs contacts
    pairs = {(r.uav_ids[a[j]], r.uav_ids[b[j]]) for j in np.flatnonzero(close.any(axis=0))}
    assert {(c.a, c.b) for c in r.collisions} == pairs
    for j in np.flatnonzero(close.any(axis=0)):
        got = [c.distance_m for c in r.collisions if (c.a, c.b) == (r.uav_ids[a[j]],
                                                                    r.uav_ids[b[j]])]
        assert min(got) == d[close[:, j], j].min()


def test_the_sweep_finds_the_closest_pair_bit_for_bit() -> None:
    """The tick's closest distance (a sweep along x that leaves pairs out) is the smallest
    of every pair's distance, bit for bit: points spread over an area, in a cluster, on one
    line of equal x, with duplicates, with ties in x, a point with a coordinate not a
    number (passed over, as every pair's minimum passes it over), fewer than two points."""
    from uavmpc.drivers.world_tick import closest_distance, pair_distances

    def every_pair(pos: np.ndarray) -> float:
        d = np.empty(pos.shape[0] * (pos.shape[0] - 1) // 2)
        pair_distances(pos, d)
        d = d[~np.isnan(d)]
        return float(d.min()) if d.size else math.inf

    rng = np.random.default_rng(3)
    cases = [rng.uniform(-400.0, 400.0, (300, 3)), rng.normal(0.0, 2.0, (50, 3)),
             np.column_stack([np.full(20, 5.0), rng.uniform(0, 9, (20, 2))]),
             np.round(rng.uniform(0, 3, (40, 3))), np.zeros((2, 3)),
             np.array([[0.0, 0.0, 0.0], [0.0, 3.0, 0.0], [1e-3, 7.0, 0.0]])]
    with_nan = rng.uniform(-10.0, 10.0, (30, 3))
    with_nan[4, 0] = with_nan[9, 1] = np.nan
    cases.append(with_nan)
    for pos in cases:
        assert closest_distance(pos) == every_pair(pos)
    assert closest_distance(np.zeros((1, 3))) == math.inf
    assert closest_distance(np.zeros((0, 3))) == math.inf


def test_a_kernel_compiled_mid_flight_is_left_out_of_the_phases_as_of_the_wall_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The run's wall time leaves out what numba compiles during it (a kernel first called
    mid-flight on a cold cache), and so do the phases it is split into: the phases (sub-
    intervals of the run) add up to at most its wall time, not to it plus the compilation."""
    import numba

    import uavmpc.drivers.delivery as delivery

    @numba.njit  # a fresh function, not cached: compiles at its first call
    def first_call(x: float) -> float:
        return x + 1.0

    accept = delivery.accept_copies
    compiled = []

    def accept_compiling_once(*args):
        if not compiled:
            compiled.append(first_call(1.0))  # inside the delivery: the first phase
        return accept(*args)

    world = World(RunSpec(random_walk(3, area_m=30.0, duration_s=2.0, seed=1), avoidance=True,
                          seed=1))
    world.run(0.3)  # the world's own kernels compiled or loaded
    monkeypatch.setattr(delivery, "accept_copies", accept_compiling_once)
    result = world.run(1.0)
    assert compiled == [2.0]
    assert sum(world.phase_wall_s) <= result.wall_s


class _Delegating:
    """An encounter strategy that is not a HeightOffsetStrategy (its whole contract handed to
    one): a round cannot decide it in the compiled call, so each stack decides by itself."""

    def __init__(self, params):
        from uavmpc.avoidance import HeightOffsetStrategy

        self.inner = HeightOffsetStrategy(params)
        self.params = params
        self.pair_radius_m = self.inner.pair_radius_m
        self.decided = 0

    def update(self, *args, **kwargs):
        return self.inner.update(*args, **kwargs)

    def limit_offset(self, ceiling_m):
        self.inner.limit_offset(ceiling_m)

    def finder(self, table, *, use_index=True):
        return self.inner.finder(table, use_index=use_index)

    def overrides(self, table):
        return self.inner.overrides(table)

    def hold_probes(self, now_s, grid_t_s, here_m):
        return self.inner.hold_probes(now_s, grid_t_s, here_m)

    def rest(self, now_s):
        return self.inner.rest(now_s)

    def decide(self, *args, **kwargs):
        self.decided += 1
        return self.inner.decide(*args, **kwargs)


def test_another_encounter_strategy_decides_by_itself_and_flies_the_same() -> None:
    """A strategy that only honours the EncounterStrategy contract is decided stack by stack
    (from Encounters objects), not in the compiled call of the built-in one's rows: the same
    decisions, the same flight."""
    made = []

    def delegating(params):
        made.append(_Delegating(params))
        return made[-1]

    scenario = lambda: random_walk(8, area_m=110.0, duration_s=20.0, seed=3)  # noqa: E731
    built_in = World(RunSpec(scenario(), avoidance=True, seed=3)).run(20.0)
    own = World(RunSpec(scenario(), avoidance=True, seed=3), strategy=delegating).run(20.0)
    _assert_same_flight(built_in, own)
    assert len(made) == 8 and sum(s.decided for s in made) > 0
    assert np.max(own.z_offset_m) > 0.0  # someone climbed: the decisions mattered


def test_a_world_link_refuses_an_inbox_table_without_a_row_per_stack() -> None:
    # The delivery's receiver rule passes over receivers past the table's rows (copies
    # injected for members that are not the world's UAVs): that needs a row per stack.
    from uavmpc.comms.inbox import InboxTable
    from uavmpc.comms.link import SimulatedLink
    from uavmpc.drivers.delivery import WorldLink

    with pytest.raises(ValueError, match="1 stacks but 2 inbox rows"):
        WorldLink(SimulatedLink(["a", "b"]), InboxTable(["a", "b"]), [object()],  # type: ignore[list-item]
                  np.zeros(1), {}, None)


def test_a_height_offset_strategy_that_overrides_decide_is_decided_by_its_override() -> None:
    """The docstring of HeightOffsetStrategy invites a subclass to override ``decide``; the
    world's compiled round must not decide such a one by the built-in law behind its back.
    Here the override yields to nobody (it keeps offset 0): the UAVs it flies never climb,
    while the same world with the built-in strategy does."""
    from uavmpc.avoidance import AvoidanceDecision, HeightOffsetStrategy

    calls = []

    class NeverClimbs(HeightOffsetStrategy):
        def decide(self, now_s, own_id, own_priority, own_prediction_times, known,
                   climbed_m=None, *, positions=None, probes=None) -> AvoidanceDecision:
            calls.append(own_id)
            return AvoidanceDecision()

    scenario = lambda: random_walk(8, area_m=110.0, duration_s=20.0, seed=3)  # noqa: E731
    built_in = World(RunSpec(scenario(), avoidance=True, seed=3)).run(20.0)
    assert np.max(built_in.z_offset_m) > 0.0
    own = World(RunSpec(scenario(), avoidance=True, seed=3), strategy=NeverClimbs).run(20.0)
    assert calls and np.max(own.z_offset_m) == 0.0


def test_one_contact_watch_for_the_world_and_the_swarm() -> None:
    """Contacts (the world's, and the swarm's over its nodes' states or the truth) counts a
    contact once from when it begins, keeps its closest distance, ends it when the pair parts,
    and leaves a pair not seen now (NaN: a vehicle not heard) as it was."""
    from uavmpc.drivers.world_report import Contacts

    c = Contacts(["a", "b", "c"])  # pairs: a-b, a-c, b-c
    nan = float("nan")
    c.update_pairs(1.0, np.array([0.9, 5.0, 5.0]))
    c.update_pairs(1.1, np.array([0.6, 5.0, 5.0]))
    c.update_pairs(1.2, np.array([nan, 5.0, nan]))  # b unheard: the contact goes on
    c.update_pairs(1.3, np.array([0.8, 5.0, 5.0]))
    c.update_pairs(1.4, np.array([1.5, 0.5, 5.0]))  # a-b part, a-c meet
    c.update_pairs(1.5, np.array([0.7, 0.5, 5.0]))  # a-b meet again: a second contact
    assert [(x.t, x.a, x.b, x.distance_m) for x in c.collisions] == [
        (1.0, "a", "b", 0.6), (1.4, "a", "c", 0.5), (1.5, "a", "b", 0.7)]
    positions = np.array([[0.0, 0.0, 10.0], [0.0, 0.3, 10.0], [9.0, 0.0, 10.0]])
    w = Contacts(["a", "b", "c"])
    w.update(2.0, 0.3, positions)
    assert [(x.t, x.a, x.b) for x in w.collisions] == [(2.0, "a", "b")]
    assert w.collisions[0].distance_m == pytest.approx(0.3)
