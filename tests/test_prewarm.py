"""A first run's second core: the kernels around the tick compiled in a process beside the
command (``uavmpc.apps.prewarm``)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from uavmpc.apps import prewarm
from uavmpc.jit import THREADS_ENV


@pytest.mark.parametrize("threads", [1, 2])
def test_the_rehearsal_runs_everything_around_the_tick_but_not_the_tick(threads) -> None:
    # A fresh process, to see which kernels the rehearsal itself needs (loaded from the cache
    # or compiled): the avoidance's and the link's, none of the tick's; the encounter search
    # in the form the command's thread count takes (beside() passes it on).
    if threads > (os.cpu_count() or 1):
        pytest.skip("needs a second core")
    code = ("from uavmpc.apps.prewarm import main\n"
            "from uavmpc.avoidance.encounters import encounter_rows, encounter_rows_threads\n"
            "from uavmpc.drivers.world_tick import world_tick, world_tick_threads, _tick_rows\n"
            "main()\n"
            "print(len(encounter_rows.overloads), len(encounter_rows_threads.overloads),\n"
            "      len(world_tick.overloads), len(world_tick_threads.overloads),\n"
            "      len(_tick_rows.overloads))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={**os.environ, THREADS_ENV: str(threads)}).stdout
    assert out.split() == (["1", "0"] if threads == 1 else ["0", "1"]) + ["0", "0", "0"]


def test_a_second_process_starts_only_on_a_cold_cache(tmp_path, monkeypatch) -> None:
    import uavmpc.jit

    warm, cold = tmp_path / "warm" / "uavmpc", tmp_path / "cold"
    warm.mkdir(parents=True)
    cold.mkdir()
    (warm / "kernels.step-10.py311.nbi").write_bytes(b"")  # what numba's index files look like
    monkeypatch.setattr(uavmpc.jit, "CACHE_DIR", str(tmp_path / "warm"))
    assert not prewarm.cache_is_cold()
    with prewarm.beside() as started:
        assert not started
    monkeypatch.setattr(uavmpc.jit, "CACHE_DIR", str(cold))
    assert prewarm.cache_is_cold()
    with prewarm.beside() as started:  # (the process fills the session's cache, not `cold`)
        assert started == ((os.cpu_count() or 1) >= 2)
