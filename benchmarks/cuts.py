"""What the section benchmarks share (prepare_sections.py, qp_sections.py): a kernel's own
source cut short before a section, the best of several timed calls, a record copied."""

from __future__ import annotations

import math
import sys
import time
from typing import Any


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
