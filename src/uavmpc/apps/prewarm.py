"""A first run's second core: on a cold cache, a process beside the command compiles the
kernels around the world's tick (deliveries, avoidance, broadcasts) while the command compiles
the tick itself, the longest chain; the command then loads them from the cache.

numba compiles one kernel at a time in a process, so a first run on its own uses one core
for about a minute (docs/scale.md, "The first run"). The kernels do not depend on the
scenario: any world's records have the same types, so the process beside rehearses a small
random walk (:meth:`uavmpc.drivers.world.World.rehearse`), whatever the command flies.

    python -m uavmpc.apps.prewarm    # what :func:`beside` starts
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from uavmpc.scenarios.run import RunSpec


def main() -> None:
    """Compile (into the cache) the kernels around the tick of a batched world with
    avoidance, without those of the tick."""
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.random_walk import random_walk

    World(RunSpec(random_walk(3, area_m=30.0, duration_s=10.0, seed=0), seed=0)).rehearse(1.0)


def cache_is_cold() -> bool:
    """Whether the kernel cache (:data:`uavmpc.jit.CACHE_DIR`) holds no kernel at all."""
    from uavmpc.jit import CACHE_DIR

    return not any(Path(CACHE_DIR).rglob("*.nbi"))


@contextlib.contextmanager
def beside() -> Iterator[bool]:
    """Within the block, :func:`main` runs in a second process when the cache is cold and
    the machine has a second core (yields whether it does). The process is stopped at the
    end of the block if it has not finished: what it compiled by then is cached, the rest
    the command compiles itself. Its output is discarded: it only fills the cache."""
    if (os.cpu_count() or 1) < 2 or not cache_is_cold():
        yield False
        return
    import numba

    from uavmpc.jit import THREADS_ENV

    # On the command's thread count: some kernels come in a plain and a threaded form, and
    # the process beside compiles the one the command will load.
    proc = subprocess.Popen([sys.executable, "-m", "uavmpc.apps.prewarm"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL,
                            env={**os.environ, THREADS_ENV: str(numba.get_num_threads())})
    try:
        yield True
    finally:
        if proc.poll() is None:
            proc.terminate()
        proc.wait()


if __name__ == "__main__":
    main()
