"""How uavmpc compiles its kernels (:func:`uavmpc.jit.kernel`): without numba's reference
counting unless a kernel says it allocates, and then no array a kernel makes is ever lost."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import NamedTuple

import numba
import numpy as np
import pytest
from numba.core.runtime import _nrt_python, rtsys

from uavmpc.avoidance.encounters import EncounterFinder
from uavmpc.comms.inbox import InboxTable, accept_copies
from uavmpc.comms.message import SCHEMA_VERSION, PredictionMessage, encode
from uavmpc.drivers.world import World
from uavmpc.jit import kernel, using_threads
from uavmpc.scenarios import load
from uavmpc.scenarios.faults import Faults
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec


@kernel
def _borrows(x: np.ndarray) -> float:
    return x[1:3].sum()


@kernel
def _makes(n: int) -> float:
    return np.zeros(n).sum()


@kernel(allocates=True)
def _new_array(n: int) -> np.ndarray:
    return np.zeros(n)


@kernel
def _drops_what_it_gets(n: int) -> float:
    # The mistake the flag cannot refuse at compile time: a new array received from a call.
    return _new_array(n)[0]


@kernel(allocates=True)
def _keeps_count(n: int) -> float:
    return _new_array(n)[0]


@contextmanager
def _allocation_count() -> Iterator[list[int]]:
    """[arrays numba's runtime allocated, arrays it freed] during the block."""
    was_on = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    before = rtsys.get_allocation_stats()
    counts = [0, 0]
    try:
        yield counts
    finally:
        after = rtsys.get_allocation_stats()
        counts[:] = [after.alloc - before.alloc, after.free - before.free]
        if not was_on:
            _nrt_python.memsys_disable_stats()


def test_a_kernel_borrows_arrays_without_the_runtime_and_must_say_when_it_makes_one() -> None:
    assert _borrows(np.arange(4.0)) == 3.0
    refused = r"NRT required|Only accept returning of array passed"
    with pytest.raises(numba.core.errors.NumbaError, match=refused):
        _makes(3)
    assert _keeps_count(3) == 0.0


def test_the_allocation_count_sees_an_array_lost_between_two_kernels() -> None:
    """The failure the flight test below looks for, made on purpose: it must show."""
    _drops_what_it_gets(2), _keeps_count(2)  # compiled before counting
    with _allocation_count() as lost:
        for _ in range(100):
            _drops_what_it_gets(2)
    assert lost[0] - lost[1] == 100
    with _allocation_count() as kept:
        for _ in range(100):
            _keeps_count(2)
    assert kept == [100, 100]


def _flights() -> list[tuple[str, World]]:
    landing = load("moving_target_landing")
    return [
        ("batched, avoidance", World(RunSpec(random_walk(6, area_m=60.0, duration_s=20.0, seed=2),
                                             avoidance=True, seed=2))),
        ("per object", World(RunSpec(random_walk(3, area_m=40.0, duration_s=20.0, seed=2),
                                     avoidance=True, seed=2), batched=False)),
        ("observer", World(RunSpec(random_walk(4, area_m=50.0, duration_s=20.0, seed=2),
                                   avoidance=True, seed=2, drawn=Faults.given(gnss="single")))),
        ("landing", World(RunSpec(landing, avoidance=True, seed=1))),
    ]


@pytest.mark.parametrize("threads", [1, 2])
def test_flights_free_every_array_their_kernels_make(threads) -> None:
    """Over whole flights (the tick, deliveries, avoidance rounds, broadcasts, observers, the
    deck), the arrays numba's runtime allocates are all freed: a kernel compiled without the
    runtime that received a new array would leave one behind at every call."""
    with using_threads(threads):
        for name, world in _flights():
            world.run(1.0)  # compiled (or loaded) and past the start
            with _allocation_count() as n:
                world.run(3.0)
            allocated, freed = n
            assert allocated > 1000, name  # the count is live: the kernels allocate
            # Arrays the world holds between ticks are replaced, not added: a few either way.
            assert abs(allocated - freed) < 50, (name, allocated, freed)


def test_the_encounter_search_allocates_per_block_not_per_pair() -> None:
    """The search's per-pair kernels work in the arrays their block made once
    (:class:`~uavmpc.avoidance.encounters.SearchScratch`): a kernel that made one per pair
    would also count the references of every array it passes on, around every pair (some
    760 000 atomic operations per round of a 300-UAV world; docs/scale.md)."""
    n, horizon = 24, np.cumsum(np.r_[0.01, np.full(39, 0.2)])
    ids = [f"u{i}" for i in range(n)]
    table = InboxTable(ids)
    now = 100.0
    rng = np.random.default_rng(0)
    plans = np.repeat(np.column_stack([rng.uniform(0.0, 5.0, (n, 2)), np.full(n, 10.0)]
                                      )[:, None, :], 40, axis=1)  # all within 10 m
    for i in range(n):
        slot = table.slot_for(encode(PredictionMessage(
            SCHEMA_VERSION, ids[i], i + 1, now - 0.1, now - 0.1 + horizon, plans[i], True)))
        accept_copies(table.rows, table.store, np.arange(n), np.full(n, slot),
                      np.full(n, now))
        table.unpin()
    finder = EncounterFinder(table, timeout_s=1.0, silent_hold_s=10.0, use_received=False)

    def search(receivers: int) -> tuple[int, list[int]]:
        """Pairs found near, [arrays allocated, freed] by a search of the first receivers
        (the same arrays passed in, the same blocks: only the pairs differ)."""
        args = (np.arange(receivers), np.tile(now + horizon, (receivers, 1)),
                plans[:receivers], np.full(receivers, now), np.full(receivers, 10.0))
        finder.find(*args)  # compiled, outputs grown
        with _allocation_count() as count:
            found = finder.find(*args)
        return sum(len(e.ids) for e in found), count

    for blocks in (1, 2):
        finder.blocks = blocks
        pairs_all, all_receivers = search(n)
        pairs_two, two_receivers = search(2)
        assert (pairs_all, pairs_two) == (n * (n - 1), 2 * (n - 1))  # every pair near
        assert all_receivers == two_receivers, blocks


class _Pair(NamedTuple):
    a: np.ndarray
    b: np.ndarray


def test_a_bound_kernel_binds_again_whenever_its_arguments_types_change() -> None:
    """:class:`~uavmpc.jit.Bound` skips numba's typing of records from call to call, and
    still gives what the kernel gives when a record is replaced or an argument's dtype,
    layout or writability changes (each bound again: a stale binding would refuse the
    argument or misread its memory)."""
    from uavmpc.jit import Bound, bound

    @numba.njit
    def total(rec: _Pair, x: np.ndarray, k: int) -> float:
        return float(rec.a.sum() + rec.b[0] + x[0] * k)

    b = Bound(total)
    one = _Pair(np.arange(3.0), np.ones(2))
    two = _Pair(np.arange(4, dtype=np.int64), np.full(1, 7.0))
    ints = np.array([5, 6], dtype=np.int64)
    frozen = np.array([1.5, 9.0])
    frozen.flags.writeable = False
    cases = [(one, ints, 2), (one, ints, 3), (two, ints, 2), (one, np.array([0.25]), 2),
             (one, np.arange(6.0)[::2], 2), (one, frozen, 2), (two, frozen, True)]
    for rec, x, k in cases:
        assert b(rec, x, k) == total(rec, x, k)
    assert bound(total) is bound(total) and isinstance(bound(total), Bound)
    assert bound(len) is len  # not a kernel: as it is (a test's or a profiler's stand-in)


@kernel
def _first_column_sum(a: np.ndarray) -> float:
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i, 0]
    return total


def test_a_bound_kernel_binds_once_for_full_and_empty_cuts_of_one_array(monkeypatch) -> None:
    """An empty cut of a C array is both C- and F-contiguous; numba types it as C, like the
    full one. The bound kernel must not bind again each time a call's rows come out empty
    (a world's rounds with nobody near did, costing ~100 µs a call)."""
    import uavmpc.jit as jit

    binds = []
    real_bind = jit.bind

    def counted(dispatcher, *args):
        binds.append(dispatcher)
        return real_bind(dispatcher, *args)

    monkeypatch.setattr(jit, "bind", counted)
    call = jit.Bound(_first_column_sum)
    full = np.arange(12.0).reshape(3, 4)
    assert full[:0].flags.c_contiguous and full[:0].flags.f_contiguous
    assert call(full) == 12.0 and call(full[:0]) == 0.0 and call(full[:2]) == 4.0
    assert len(binds) == 1
    assert call(np.asfortranarray(full)) == 12.0  # another layout: bound anew
    assert len(binds) == 2
