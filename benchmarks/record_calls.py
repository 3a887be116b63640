"""What a compiled call that takes a record costs inside a loop (docs/scale.md).

``python benchmarks/record_calls.py [COPIES]`` (default 1828, a tick's copies at 300 UAVs)
counts COPIES copies into a world's inbox rows (:class:`~uavmpc.comms.inbox.InboxRows`, a
record of 11 arrays) four ways: the receiver's rule as the package runs it
(:func:`~uavmpc.comms.inbox.accept_copies`, the rule written in its loop), a loop that only
increments each copy's counter past a check, the same check and increment done by a helper
that takes the record, called once per copy, and that helper again compiled without numba's
reference counting, as :func:`uavmpc.jit.kernel` compiles every kernel that allocates
nothing. numba counts references to every array of a record handed to a compiled function,
an atomic operation per array per call: the third pays them per copy, the fourth does not.
The first three are compiled with numba's defaults; best of 7 timed batches, µs per call of
the whole loop. The last line is JSON.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
from cuts import best
from numba import njit

from uavmpc.comms.inbox import InboxRows, InboxTable, accept_copies


@njit
def _count(rows: InboxRows, r: int) -> None:
    # A check with an early exit (never taken here), as a rule has: with a branch, LLVM
    # keeps the reference counting of the call.
    if rows.own_col[r] < 0:
        return
    rows.accepted[r] += 1


@njit
def _count_per_copy(rows: InboxRows, receivers: np.ndarray) -> None:
    for k in range(receivers.shape[0]):
        _count(rows, receivers[k])


@njit(_nrt=False)
def _count_borrowing(rows: InboxRows, r: int) -> None:
    if rows.own_col[r] < 0:
        return
    rows.accepted[r] += 1


@njit(_nrt=False)
def _count_per_copy_borrowing(rows: InboxRows, receivers: np.ndarray) -> None:
    for k in range(receivers.shape[0]):
        _count_borrowing(rows, receivers[k])


@njit
def _count_in_loop(rows: InboxRows, receivers: np.ndarray) -> None:
    for k in range(receivers.shape[0]):
        r = receivers[k]
        if rows.own_col[r] < 0:
            continue
        rows.accepted[r] += 1


def _us_per_call(f: Callable[..., Any], args: tuple[Any, ...], number: int = 50) -> float:
    """µs per call of ``f(*args)``: the best of 7 batches of ``number`` calls (:func:`best`)."""
    f(*args)

    def batch() -> None:
        for _ in range(number):
            f(*args)

    return best(batch) / number * 1e6


def main(copies: int = 1828) -> None:
    n = 300
    table = InboxTable([f"u{i}" for i in range(n)])
    receivers = np.random.default_rng(0).integers(0, n, copies)
    slots = np.zeros(copies, dtype=np.int64)  # one broadcast's copies: u0's message
    table.store.col[0] = 0
    table.store.stamp_s[0] = 10.0
    rule = _us_per_call(accept_copies,
                        (table.rows, table.store, receivers, slots, np.full(n, 10.05)))
    in_loop = _us_per_call(_count_in_loop, (table.rows, receivers))
    per_copy = _us_per_call(_count_per_copy, (table.rows, receivers))
    borrowing = _us_per_call(_count_per_copy_borrowing, (table.rows, receivers))
    print(f"{copies} copies: the receiver's rule {rule:.1f} µs; a counter incremented in the "
          f"loop {in_loop:.1f} µs, by a helper taking the record {per_copy:.1f} µs "
          f"({per_copy / in_loop:.0f}×), by that helper without reference counting "
          f"{borrowing:.1f} µs")
    print(json.dumps({"copies": copies, "rule_us": rule, "in_loop_us": in_loop,
                      "per_copy_us": per_copy, "per_copy_borrowing_us": borrowing}))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1828)
