"""Encounters at scale: the spatial index finds exactly what comparing every pair finds, the box
test prunes only pairs that never come near, and the inbox store decodes each broadcast once."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uavmpc.avoidance import AvoidanceParams, HeightOffsetStrategy
from uavmpc.avoidance.encounters import EncounterFinder, pair_widening_m, silent_reach_m
from uavmpc.avoidance.proximity import align
from uavmpc.comms.inbox import InboxTable, accept_copies
from uavmpc.comms.message import SCHEMA_VERSION, InvalidMessageError, PredictionMessage, encode
from uavmpc.drivers.world import World
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec

HORIZON = np.cumsum(np.r_[0.01, np.full(39, 0.2)])


def _plan(rng: np.random.Generator, centre: np.ndarray, t0: float) -> tuple[np.ndarray, ...]:
    """A straight 40-point plan at a random speed and heading through ``centre``."""
    v = rng.uniform(0.0, 12.0) * np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
    xy = centre[:2] + (HORIZON - 4.0)[:, None] * v
    z = centre[2] + rng.uniform(-1.0, 1.0) * HORIZON / 8.0
    return t0 + HORIZON, np.column_stack([xy, z])


def _world_table(seed: int, n: int, area_m: float, receive: bool, sigma: bool = False):
    """N UAVs' inbox rows after one round of broadcasts (some lost, some stale, some silent;
    with ``sigma``, some with a position uncertainty), and their own plans."""
    rng = np.random.default_rng(seed)
    ids = [f"u{i}" for i in range(n)]
    table = InboxTable(ids, time_reference="receive" if receive else "stamp", max_age_s=20.0)
    centres = np.column_stack([rng.uniform(0, area_m, (n, 2)), rng.uniform(8, 14, n)])
    now = 100.0
    own_t = np.empty((n, 40))
    own_p = np.empty((n, 40, 3))
    for i in range(n):
        own_t[i], own_p[i] = _plan(rng, centres[i], now)
    for i in range(n):
        # Each sender's newest message is 0–12 s old: fresh, silent or ignored by the strategy.
        stamp = now - rng.choice([0.2, 0.6, 1.5, 4.0, 12.0])
        times, pos = _plan(rng, centres[i], stamp)
        # Whom it hears: some of the others, and UAVs this table has never heard of.
        others = [u for u in ids if u != ids[i]] + ["ghost1", "ghost2"]
        heard = tuple(rng.choice(others, size=rng.integers(0, min(len(others), 8) + 1),
                                 replace=False).tolist())
        sigma_m = tuple(rng.choice([0.0, 0.4, 1.5], size=2).tolist()) if sigma else (0.0, 0.0)
        msg = PredictionMessage(SCHEMA_VERSION, ids[i], i + 1, stamp, times, pos,
                                bool(rng.random() < 0.9), None, heard, sigma_m)
        slot = table.slot_for(encode(msg))
        receivers = np.flatnonzero(rng.random(n) < 0.8)  # the copies that got through
        accept_copies(table.rows, table.store, receivers, np.full(receivers.size, slot),
                      np.full(n, stamp + rng.uniform(0.0, 0.1)))
        table.unpin()
    return table, own_t, own_p, np.full(n, now), ids


#: The silent senders' protected radius and limits (it widens with their messages' ages).
SILENT_RADIUS_M, SILENT_SPEED_MPS, SILENT_ACCEL_MPS2 = 3.0, 8.3, 2.5


def _find(table, own_t, own_p, now, radius, overrides, use_index: bool, blocks: int = 1):
    finder = EncounterFinder(table, timeout_s=1.0, silent_hold_s=10.0,
                             use_received=table.time_reference == "receive",
                             silent_radius_m=SILENT_RADIUS_M,
                             silent_speed_mps=SILENT_SPEED_MPS,
                             silent_accel_mps2=SILENT_ACCEL_MPS2, use_index=use_index,
                             cell_m=None)
    finder.blocks = blocks
    due = np.arange(own_t.shape[0])
    return finder.find(due, own_t, own_p, now, radius, overrides)


def _same(a, b) -> None:
    assert a.ids == b.ids
    assert a.silent == b.silent
    assert np.array_equal(a.silent_row, b.silent_row)
    assert np.array_equal(a.near_xy, b.near_xy)
    assert np.array_equal(a.announced_xy, b.announced_xy)
    assert np.array_equal(a.dz_m, b.dz_m)
    assert np.array_equal(a.priority, b.priority)
    assert np.array_equal(a.hears_us, b.hears_us)
    assert np.array_equal(a.widen_v_m, b.widen_v_m)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 40), area=st.floats(20.0, 300.0),
       blocks=st.integers(1, 4))
def test_each_encounter_says_whether_its_sender_hears_us_and_how_far_the_pair_widens(
        seed, n, area, blocks) -> None:
    """hears_us: the sender's heard list (by name, as decoded) names the receiver;
    widen_v_m: pair_widening_m of the receiver's vertical σ and the sender's."""
    table, own_t, own_p, now, ids = _world_table(seed, n, area, False, sigma=True)
    own_sigma = np.random.default_rng(seed + 2).choice([0.0, 0.3, 1.2], size=(n, 2))
    finder = EncounterFinder(table, timeout_s=1.0, silent_hold_s=10.0, use_received=False,
                             silent_radius_m=SILENT_RADIUS_M, silent_speed_mps=SILENT_SPEED_MPS,
                             silent_accel_mps2=SILENT_ACCEL_MPS2, sigma_k=2.0)
    finder.blocks = blocks
    found = finder.find(np.arange(n), own_t, own_p, now, np.full(n, 30.0), None, own_sigma)
    checked = 0
    for j, enc in enumerate(found):
        for k, sender in enumerate(enc.ids):
            slot = int(table.rows.held_slot[j, table.col_of(sender)])
            assert bool(enc.hears_us[k]) == (ids[j] in table.heard_ids(slot))
            assert enc.widen_v_m[k] == pair_widening_m(
                float(own_sigma[j, 1]), float(table.store.sigma_m[slot, 1]), 2.0)
            checked += 1
    assert checked or n < 10 or area > 150.0  # (the comparison is not empty)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 60), area=st.floats(20.0, 800.0),
       receive=st.booleans(), radius=st.floats(1.0, 40.0))
def test_the_index_finds_exactly_the_encounters_of_the_all_pairs_comparison(
        seed, n, area, receive, radius) -> None:
    table, own_t, own_p, now, _ids = _world_table(seed, n, area, receive)
    rng = np.random.default_rng(seed + 1)
    overrides = [{int(c): float(rng.uniform(0.5, 2 * radius))
                  for c in rng.choice(n, size=min(n, 3), replace=False)} for _ in range(n)]
    radii = np.full(n, radius)
    indexed = _find(table, own_t, own_p, now, radii, overrides, True)
    every = _find(table, own_t, own_p, now, radii, overrides, False)
    for a, b in zip(indexed, every, strict=True):
        _same(a, b)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 60), area=st.floats(20.0, 400.0),
       receive=st.booleans(), use_index=st.booleans(), blocks=st.integers(2, 9))
def test_the_receivers_on_threads_find_exactly_what_one_thread_finds(
        seed, n, area, receive, use_index, blocks) -> None:
    """encounter_rows_threads: each block writes into its own share of the outputs, then the
    shares are moved together; a block that overflows its share (the outputs start small)
    makes the finder retry with larger ones."""
    table, own_t, own_p, now, _ids = _world_table(seed, n, area, receive)
    radii = np.full(n, 8.0)
    one = _find(table, own_t, own_p, now, radii, None, use_index)
    split = _find(table, own_t, own_p, now, radii, None, use_index, blocks)
    assert any(e.ids or e.silent for e in one) or n < 10  # (the comparison is not empty)
    for a, b in zip(one, split, strict=True):
        _same(a, b)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 30), area=st.floats(10.0, 300.0))
def test_the_box_test_prunes_only_senders_that_never_come_near(seed, n, area) -> None:
    """Against the alignment of every held message (no box, no index): a sender is an
    encounter exactly when some aligned point is horizontally within the radius, or for a
    silent one within its protected radius widened by how far it can have gone since (silent
    ones first, then the fresh ones)."""
    table, own_t, own_p, now, ids = _world_table(seed, n, area, False)
    radius = 5.0
    found = _find(table, own_t, own_p, now, np.full(n, radius), None, True)
    st_ = table.store
    for r in range(n):
        silent, fresh = [], []
        announced = {}
        for col in range(len(ids)):
            slot = table.rows.held_slot[r, col]
            if slot < 0:
                continue
            age = now[r] - st_.stamp_s[slot]
            if abs(age) > 1.0 and not 0.0 < age <= 10.0:
                continue
            reach = radius if abs(age) <= 1.0 else max(radius, SILENT_RADIUS_M + silent_reach_m(
                age - 1.0, SILENT_SPEED_MPS, SILENT_ACCEL_MPS2))
            k = st_.points[slot]
            aligned, known = align(st_.times_s[slot, :k], st_.positions_m[slot, :k], own_t[r],
                                   1.0)
            d2 = ((aligned[:, :2] - own_p[r, :, :2]) ** 2).sum(axis=1)
            if np.any(known & (d2 <= reach**2)):
                (fresh if abs(age) <= 1.0 else silent).append(ids[col])
                announced[ids[col]] = (known & (d2 <= radius**2),
                                       np.abs(np.sqrt(d2) - radius) > 1e-9)
        assert list(found[r].ids) == silent + fresh
        assert list(found[r].silent_row) == [True] * len(silent) + [False] * len(fresh)
        # The way up is checked along the plans as announced: a silent row's widening is
        # not in announced_xy (a fresh row's are the same points).
        for k, uid in enumerate(found[r].ids):
            expected, clear_of_edge = announced[uid]
            got = found[r].announced_xy[k]
            assert np.array_equal(got[clear_of_edge], expected[clear_of_edge])
            assert not np.any(got & ~found[r].near_xy[k])
            if not found[r].silent_row[k]:
                assert np.array_equal(got, found[r].near_xy[k])


def test_a_silent_plan_widens_by_how_far_its_uav_can_have_left_it() -> None:
    """From rest at the acceleration limit, then at the speed limit; nothing before the plan
    went stale counts."""
    v, a = 8.3, 2.5
    assert silent_reach_m(0.0, v, a) == 0.0
    assert silent_reach_m(-1.0, v, a) == 0.0
    assert silent_reach_m(2.0, v, a) == pytest.approx(0.5 * a * 2.0**2)
    t_a = v / a
    assert silent_reach_m(t_a + 1.0, v, a) == pytest.approx(0.5 * v * t_a + v)
    ages = np.linspace(0.0, 12.0, 200)
    reach = np.array([silent_reach_m(t, v, a) for t in ages])
    assert np.all(np.diff(reach) > 0)  # it only grows
    assert np.all(np.diff(reach) <= v * (ages[1] - ages[0]) + 1e-12)  # never faster than v
    assert silent_reach_m(5.0, 0.0, a) == 0.0 == silent_reach_m(5.0, v, 0.0)  # turned off


def test_update_from_messages_and_decide_from_a_table_agree() -> None:
    """The strategy's Mapping entry point (nodes, tests) and the world's table path decide the
    same, for every UAV of a dense round."""
    table, own_t, own_p, now, ids = _world_table(7, 25, 60.0, False)
    params = AvoidanceParams()
    found = _find(table, own_t, own_p, now, np.full(25, params.radius_m), None, True)
    for r in range(25):
        latest = {ids[c]: table.message(r, c) for c in range(25)
                  if table.rows.held_slot[r, c] >= 0}
        a = HeightOffsetStrategy(params).update(now[r], ids[r], r + 1, own_t[r], own_p[r],
                                                latest)
        b = HeightOffsetStrategy(params).decide(now[r], ids[r], r + 1, own_t[r], found[r],
                                                positions=own_p[r])
        assert a == b


def test_a_broadcast_is_decoded_once_and_its_slot_reused_after_the_last_holder() -> None:
    table = InboxTable(["a", "b", "c"])
    msg = PredictionMessage(SCHEMA_VERSION, "a", 1, 10.0, 10.0 + HORIZON, np.zeros((40, 3)), True)
    data = encode(msg)
    slot = table.slot_for(data)
    assert table.slot_for(bytes(data)) == slot  # equal bytes: the same slot, no decoding
    accept_copies(table.rows, table.store, np.array([1, 2]), np.array([slot, slot]),
                  np.full(3, 10.05))
    table.unpin()
    assert table.store.holders[slot] == 2
    newer = encode(PredictionMessage(SCHEMA_VERSION, "a", 1, 10.5, 10.5 + HORIZON,
                                     np.ones((40, 3)), True))
    slot2 = table.slot_for(newer)
    assert slot2 != slot
    accept_copies(table.rows, table.store, np.array([1, 2]), np.array([slot2, slot2]),
                  np.full(3, 10.55))
    table.unpin()
    assert table.store.holders[slot] == 0 and table.store.holders[slot2] == 2
    # A long flight: each new message replaces the last in every inbox, and the store keeps
    # reusing the slots nobody holds any more (it never grows).
    capacity = table.store.holders.shape[0]
    for j in range(200):
        stamp = 11.0 + 0.5 * j
        data_j = encode(PredictionMessage(SCHEMA_VERSION, "a", 1, stamp, stamp + HORIZON,
                                          np.ones((40, 3)), True))
        s = table.slot_for(data_j)
        accept_copies(table.rows, table.store, np.array([1, 2]), np.array([s, s]),
                      np.full(3, stamp + 0.05))
        table.unpin()
    assert table.store.holders.shape[0] == capacity
    assert table.store.holders.sum() == 2
    assert table.message(1, table.cols["a"]).stamp_s == 11.0 + 0.5 * 199
    with pytest.raises(InvalidMessageError, match="truncated"):
        table.slot_for(data[:30])


@pytest.mark.parametrize("receive", [False, True], ids=["stamp", "receive time"])
@pytest.mark.parametrize("blocks", [1, 2, 3, 7])
def test_the_inbox_rule_in_blocks_of_receivers_is_the_rule(receive: bool, blocks: int) -> None:
    """accept_copies_threads (receivers in blocks, holder counts per block added up after)
    leaves the rows, counters and holder counts exactly as accept_copies does, for copies
    in any order: several per receiver, a sender twice (older after newer), echoes, stale
    and future stamps."""
    from uavmpc.comms.inbox import accept_copies_threads

    n = 9
    ids = [f"u{i}" for i in range(n)]
    tables = [InboxTable(ids, time_reference="receive" if receive else "stamp")
              for _ in range(2)]
    rng = np.random.default_rng(blocks)
    for tick in range(12):
        slots = []
        for t in tables:
            slots.append([])
            for i in range(n):  # every sender twice a tick, the later message first
                for stamp in (10.0 + tick + 0.4, 10.0 + tick):
                    msg = PredictionMessage(SCHEMA_VERSION, ids[i], i, stamp, stamp + HORIZON,
                                            np.full((40, 3), float(i)), True)
                    slots[-1].append(t.slot_for(encode(msg)))
        k = 60
        receivers = rng.integers(0, n, k)
        which = rng.integers(0, 2 * n, k)
        clock = 10.0 + tick + rng.choice([0.1, 0.3, 2.5, -1.0], n)  # some stale, some future
        accept_copies(tables[0].rows, tables[0].store, receivers,
                      np.array(slots[0])[which], clock)
        accept_copies_threads(tables[1].rows, tables[1].store, receivers,
                              np.array(slots[1])[which], clock, blocks)
        for t in tables:
            t.unpin()
        for a, b in zip(tables[0].rows, tables[1].rows, strict=True):
            assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
        assert np.array_equal(tables[0].store.holders, tables[1].store.holders)
    assert tables[0].rows.accepted.sum() > 0 and tables[0].rows.superseded.sum() > 0
    assert tables[0].rows.stale.sum() + tables[0].rows.future.sum() > 0 or receive


def test_a_table_grows_for_new_senders_and_longer_messages() -> None:
    table = InboxTable(["a"], points=40)
    for j in range(20):
        m = 40 + 8 * j
        msg = PredictionMessage(SCHEMA_VERSION, f"s{j}", j, 1.0, 1.0 + np.arange(m) * 0.1,
                                np.full((m, 3), float(j)), True)
        slot = table.slot_for(encode(msg))
        accept_copies(table.rows, table.store, np.array([0]), np.array([slot]), np.full(1, 1.0))
        table.unpin()
    assert len(table.ids) == 21
    for j in range(20):
        got = table.message(0, table.cols[f"s{j}"])
        assert got.points == 40 + 8 * j and got.positions_m[0, 0] == j


@pytest.mark.slow
def test_a_world_flown_with_the_index_equals_the_same_world_flown_all_pairs() -> None:
    """A dense 30-UAV random walk (several UAVs climbing at once), 20 s."""
    def fly(index: bool):
        sc = random_walk(30, area_m=120.0, duration_s=30.0, seed=3)
        return World(RunSpec(sc, seed=3), index=index).run(20.0)  # 30 < 32: both forced

    a, b = fly(True), fly(False)
    assert np.array_equal(a.positions_m, b.positions_m)
    assert np.array_equal(a.z_offset_m, b.z_offset_m)
    assert a.per_uav == b.per_uav
    assert a.z_offset_m.max() > 0.0, "the scenario must make someone climb"


@pytest.mark.parametrize("use_index", [False, True])
def test_a_pair_widens_by_both_uavs_position_uncertainty(use_index: bool) -> None:
    """docs/safety.md, A3: the pair's radius widens by k √(σ_own² + σ_sender²) horizontally,
    its half height by the same of the vertical σ's; the index finds what the scan finds."""
    now = 100.0
    table = InboxTable(["a"])
    sigma = (1.5, 2.5)
    beside = np.tile([7.0, 0.0, 10.0], (40, 1))  # 7 m away: outside the bare 5 m radius
    msg = PredictionMessage(SCHEMA_VERSION, "b", 2, now, now + HORIZON, beside, True,
                            position_sigma_m=sigma)
    slot = table.slot_for(encode(msg))
    accept_copies(table.rows, table.store, np.array([0]), np.array([slot]), np.array([now]))
    table.unpin()
    own_t, own_p = (now + HORIZON)[None], np.tile([0.0, 0.0, 10.0], (1, 40, 1))

    def found(k: float, own_sigma: tuple[float, float]):
        finder = EncounterFinder(table, timeout_s=1.0, silent_hold_s=10.0, use_received=False,
                                 use_index=use_index, sigma_k=k)
        return finder.find(np.array([0]), own_t, own_p, np.array([now]), np.array([5.0]),
                           None, np.array([own_sigma]))[0]

    assert found(0.0, sigma).ids == ()  # no widening asked for
    assert found(2.0, (0.0, 0.0)).ids == ("b",)  # 2 × 1.5 m = 3 m: 8 m ≥ 7 m
    wide = found(2.0, sigma)
    assert wide.ids == ("b",) and wide.near_xy.all()
    assert wide.widen_v_m == pytest.approx([2.0 * np.hypot(2.5, 2.5)])
    assert found(0.4, sigma).ids == ()  # 0.4 × 2.12 m = 0.85 m: 5.85 m < 7 m


def test_a_message_lists_every_uav_whose_plan_it_counts_near_or_not() -> None:
    """docs/safety.md, A2: the heard list is what the inbox holds and counts (fresh, or silent
    within silent_hold_s), near or far — not only the encounters, which two UAVs can see at
    different moments (the burst-loss trial where a UAV that had heard us left us off its
    list). Beyond the limit, the nearest first."""
    now = 100.0
    table = InboxTable(["a"])
    table.col_of("a")
    for uav, stamp, x in (("far", now, 900.0), ("near", now - 0.2, 5.0),
                          ("silent", now - 4.0, 20.0), ("gone", now - 30.0, 1.0)):
        msg = PredictionMessage(SCHEMA_VERSION, uav, 2, stamp, stamp + HORIZON,
                                np.tile([x, 0.0, 10.0], (40, 1)), True)
        slot = table.slot_for(encode(msg))
        accept_copies(table.rows, table.store, np.array([0]), np.array([slot]),
                      np.array([stamp + 0.05]))
        table.unpin()
    finder = EncounterFinder(table, timeout_s=1.0, silent_hold_s=10.0, use_received=False)
    own_xy = np.array([0.0, 0.0])
    assert finder.heard(0, now, own_xy) == ("far", "near", "silent")  # column order
    assert finder.heard(0, now, own_xy, limit=2) == ("near", "silent")  # nearest first
    assert finder.heard(0, now + 20.0, own_xy) == ()  # all beyond silent_hold_s now


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 40), st.integers(2, 60))
def test_beyond_the_limit_the_heard_list_is_the_nearest_in_a_stable_order(
        seed: int, limit: int, senders: int) -> None:
    """The heard list beyond its limit: the first ``limit`` of the senders counted, sorted by
    horizontal distance with ties in column order (found without sorting them all). Senders
    on a coarse grid, so that many are at the same distance."""
    rng = np.random.default_rng(seed)
    now = 100.0
    table = InboxTable(["a"])
    table.col_of("a")
    for k in range(senders):
        stamp = now - rng.choice([0.2, 4.0, 30.0])  # fresh, silent, ignored
        x, y = rng.integers(-3, 4, 2) * 10.0
        msg = PredictionMessage(SCHEMA_VERSION, f"s{k}", k + 2, stamp, stamp + HORIZON,
                                np.tile([x, y, 10.0], (40, 1)), True)
        slot = table.slot_for(encode(msg))
        accept_copies(table.rows, table.store, np.array([0]), np.array([slot]),
                      np.array([stamp + 0.05]))
        table.unpin()
    finder = EncounterFinder(table, timeout_s=1.0, silent_hold_s=10.0, use_received=False)
    counted = []
    for col in range(1, len(table.ids)):
        slot = table.rows.held_slot[0, col]
        if now - table.store.stamp_s[slot] <= 10.0:
            x, y = table.store.positions_m[slot, 0, :2]
            counted.append((x * x + y * y, col))
    expected = tuple(table.ids[c] for _, c in sorted(counted)[:limit])
    if len(counted) <= limit:  # all of them, in column order
        expected = tuple(table.ids[c] for _, c in sorted(counted, key=lambda e: e[1]))
    assert finder.heard(0, now, np.zeros(2), limit=limit) == expected
