"""Waiting on a condition, not on the clock (test helper).

A real-time test that sleeps a fixed time is either slow on a free machine or flaky on a loaded
one. :func:`wait_until` polls a condition and returns as soon as it holds; its timeout is only
the bound after which the test fails, saying what it waited for.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def wait_until(condition: Callable[[], T], timeout_s: float, what: str,
               poll_s: float = 0.02) -> T:
    """Call ``condition`` every ``poll_s`` until it returns a truthy value, and return it;
    after ``timeout_s`` without one, fail the test naming ``what`` was awaited."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"waited {timeout_s:g} s for {what}; it never happened")
        time.sleep(poll_s)
