"""What the section benchmarks share (prepare_sections.py, qp_sections.py): a kernel's own
source, cut short before a section and compiled again; the flight they are timed on; the
best of several timed calls; a record copied."""

from __future__ import annotations

import inspect
import math
import sys
import time
from typing import Any

from numba import njit

from uavmpc.drivers.world import World
from uavmpc.jit import set_threads
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec


def flown(uavs: int, seconds: float) -> World:
    """A random walk of ``uavs`` UAVs at the protocol's density (5 per 100 m × 100 m), with
    avoidance, flown ``seconds`` on one thread (10 s of its mission left)."""
    set_threads(1)
    area = 100.0 * math.sqrt(uavs / 5.0)
    w = World(RunSpec(random_walk(uavs, area_m=area, duration_s=seconds + 10.0, seed=1),
                      avoidance=True, seed=1))
    w.run(seconds)
    return w


def source_of(kernel: Any) -> str:
    """A compiled kernel's Python source from its ``def`` on (its decorator left out)."""
    src = inspect.getsource(kernel.py_func)
    return src[src.index(f"def {kernel.py_func.__name__}"):]


def compiled(source: str, namespace: dict[str, Any], name: str, fastmath: Any) -> Any:
    """The function ``name`` of ``source``, executed in ``namespace`` (which then holds the
    compiled function under that name, for the functions compiled after it), compiled."""
    exec(compile(source, f"<{name}>", "exec"), namespace)
    namespace[name] = njit(fastmath=fastmath)(namespace[name])
    return namespace[name]


def cut(source: str, anchor: str, ret: str, script: str) -> str:
    """``source`` with ``ret`` (a ``return`` line) inserted before ``anchor``, which must occur
    exactly once (else ``script`` stops, naming it)."""
    if source.count(anchor) != 1:
        sys.exit(f"{script}: section anchor not found once: {anchor!r}")
    return source.replace(anchor, ret + anchor)


def best(f: Any, *args: Any, repeat: int = 7) -> float:
    """The shortest of ``repeat`` timed calls ``f(*args)`` [s]."""
    out = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        f(*args)
        out = min(out, time.perf_counter() - t0)
    return out


def copied(record: Any) -> Any:
    """A record (a NamedTuple of arrays) with every array copied."""
    return type(record)(*[a.copy() for a in record])
