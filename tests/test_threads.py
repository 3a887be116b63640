"""The world's tick on several threads: the same flight for any thread count, and the thread
counts a user can ask for (``--threads``), in the CLI and in a campaign's split of the cores."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from uavmpc.apps.campaign_engine import CampaignError, split_cores
from uavmpc.apps.cli import main
from uavmpc.drivers.world import World
from uavmpc.jit import CACHE_DIR, CompileWatch, available_threads, set_threads, thread_count
from uavmpc.scenarios.faults import Faults, FaultSpec
from uavmpc.scenarios.random_walk import random_walk
from uavmpc.scenarios.run import RunSpec

needs_two = pytest.mark.skipif(available_threads() < 2, reason="one core: nothing to split")


@pytest.fixture
def restore_threads():
    yield
    set_threads(None)


def _fly(threads: int, faults: FaultSpec) -> tuple[np.ndarray, ...]:
    set_threads(threads)
    # 12 UAVs in the protocol's density: encounters, climbs and releases within 8 s.
    sc = random_walk(12, area_m=155.0, duration_s=8.0, seed=4)
    r = World(RunSpec(sc, seed=4, faults=faults)).run(8.0)
    return r.positions_m, r.z_offset_m, r.min_distance_m


@needs_two
@pytest.mark.parametrize("faults", [FaultSpec(), FaultSpec(gnss="single")],
                         ids=["truth", "estimated"])
def test_flight_is_bit_identical_for_any_thread_count(faults, restore_threads) -> None:
    one = _fly(1, faults)
    two = _fly(2, faults)
    assert np.ptp(one[1]) > 0 or np.ptp(one[0][:, :, 2]) > 0  # something happened
    for a, b in zip(one, two, strict=True):
        assert a.shape == b.shape
        assert np.array_equal(a, b)


@needs_two
def test_a_large_world_on_threads_takes_its_copies_and_broadcasts_bit_identically(
        restore_threads) -> None:
    """120 UAVs: several broadcasts in a tick (written on the threads) and hundreds of copies
    (taken into the inbox rows on the threads): the same flight, the same inbox rows, the
    same holder counts, the same link as on one thread."""
    from uavmpc.comms.inbox import accept_copies_threads
    from uavmpc.onboard import broadcast_rows_threads

    out = []
    for threads in (1, 2):
        set_threads(threads)
        w = World(RunSpec(random_walk(120, area_m=490.0, duration_s=3.0, seed=6), seed=6))
        r = w.run(3.0)
        out.append((r.positions_m, r.z_offset_m, w.inboxes.rows.held_slot,
                    w.inboxes.rows.accepted, w.inboxes.store.holders,
                    np.array(list(vars(w.link.stats).values()))))
    for a, b in zip(*out, strict=True):
        assert np.array_equal(a, b)
    assert accept_copies_threads.signatures and broadcast_rows_threads.signatures  # they ran
    assert out[0][3].sum() > 120 * 119  # every UAV took copies of every other


@needs_two
def test_a_world_with_every_fault_flies_the_same_on_two_threads(restore_threads) -> None:
    """Burst loss, latency and jitter, clock offsets, UAVs without avoidance, radios silent
    from the start and from 2 s, controllers on a GNSS observer, the launch check: on two
    threads the flight, the inboxes, the link and the silenced broadcasts are those of one
    thread."""
    from uavmpc.scenarios import LinkSettings

    out = []
    for threads in (1, 2):
        set_threads(threads)
        sc = random_walk(30, area_m=245.0, duration_s=6.0, seed=7)
        ids = [u.uav_id for u in sc.uavs]
        link = LinkSettings(loss=0.3, burst_len=3.0, latency_s=0.05, jitter_s=0.02)
        faults = Faults.given(clock_offsets_s=list(np.linspace(-0.2, 0.2, 30)),
                              non_cooperative=ids[:2], silent_from_s={ids[3]: 2.0, ids[4]: 0.0},
                              gnss="single")
        w = World(RunSpec(sc, seed=7, link=link, launch_check_s=1.0, drawn=faults))
        r = w.run(6.0)
        out.append((r.positions_m, r.z_offset_m, r.min_distance_m, w.inboxes.rows.held_slot,
                    w.inboxes.rows.accepted, np.array(list(vars(w.link.stats).values())),
                    w.wire.silenced))
    assert out[0][6] > 0  # the silent radios swallowed broadcasts
    for a, b in zip(*out, strict=True):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("n", [0, -1, 10_000, 1.5, True])
def test_set_threads_names_the_bad_count(n, restore_threads) -> None:
    with pytest.raises(ValueError, match="threads must be an integer from 1 to"):
        set_threads(n)


def test_run_threads_out_of_range_exits_with_a_message(capsys) -> None:
    assert main(["run", "swap_through_static", "--threads", "0", "--duration", "1"]) == 2
    assert "--threads" in capsys.readouterr().err


def test_campaign_split_of_the_cores(monkeypatch) -> None:
    monkeypatch.delenv("UAVMPC_THREADS", raising=False)  # (the test session sets it to 1)
    cores = available_threads()
    assert split_cores(None, None) == (cores, 1)
    assert split_cores(1, None) == (1, cores)
    assert split_cores(None, cores) == (1, cores)
    assert split_cores(3 * cores, None) == (3 * cores, 1)
    assert split_cores(2, 1) == (2, 1)
    with pytest.raises(CampaignError, match="threads"):
        split_cores(None, cores + 1)
    with pytest.raises(CampaignError, match="workers"):
        split_cores(0, None)


def test_compile_watch_counts_announces_and_names_the_cache() -> None:
    lines: list[str] = []

    @numba.njit  # not cached: compiled in this test on every run
    def plus_one(x):
        return x + 1

    with CompileWatch(show=lines.append, every_s=60.0) as watch:
        assert plus_one(1) == 2
        assert plus_one(2) == 3  # the same types: nothing new to compile
        assert plus_one(1.5) == 2.5  # a second specialization
    assert watch.kernels == 2
    assert watch.seconds > 0.0
    assert len(lines) == 1 and lines[0].startswith("compiling") and CACHE_DIR in lines[0]


def test_compile_watch_says_when_the_compilation_is_over() -> None:
    """A slow run after a first compilation must not look like more compiling."""
    import time

    lines: list[str] = []

    @numba.njit  # not cached
    def plus_two(x):
        return x + 2

    with CompileWatch(show=lines.append, every_s=0.02) as watch:
        assert plus_two(1) == 3
        deadline = time.monotonic() + 60.0
        while not any("running" in x for x in lines) and time.monotonic() < deadline:
            time.sleep(0.01)
    over = [x for x in lines if "running" in x]
    assert lines[0].startswith("compiling") and len(over) == 1
    assert over[0].startswith(f"  compiled {watch.kernels} kernels in")


def test_a_run_ticks_on_the_cores_left_idle(monkeypatch) -> None:
    from uavmpc.jit import idle_threads

    top = available_threads()
    monkeypatch.delenv("UAVMPC_THREADS", raising=False)
    monkeypatch.setattr("uavmpc.jit.runnable_others", lambda: 0)
    monkeypatch.setattr("os.getloadavg", lambda: (5.0, 5.0, 5.0))
    assert idle_threads() == 1  # a busy machine: one thread, never a wait for a parked one
    monkeypatch.setattr("os.getloadavg", lambda: (0.3, 0.3, 0.3))
    assert idle_threads() == top
    monkeypatch.setattr("os.getloadavg", lambda: (top - 0.5, 1.0, 1.0))
    assert idle_threads() == 1
    # A load that began a moment ago is not yet in the average: the tasks runnable now count
    monkeypatch.setattr("os.getloadavg", lambda: (0.0, 0.0, 0.0))
    monkeypatch.setattr("uavmpc.jit.runnable_others", lambda: top)
    assert idle_threads() == 1
    monkeypatch.setenv("UAVMPC_THREADS", "1")
    monkeypatch.setattr("os.getloadavg", lambda: (0.0, 0.0, 0.0))
    assert idle_threads() == 1  # the environment decides


def test_compile_watch_is_silent_when_nothing_compiles() -> None:
    lines: list[str] = []
    with CompileWatch(show=lines.append) as watch:
        set_threads(None)  # a call into numba that compiles nothing
    assert (watch.kernels, watch.seconds, lines) == (0, 0.0, [])


def test_the_environment_sets_the_default_and_a_campaign_keeps_to_it(monkeypatch, capsys) -> None:
    from uavmpc.jit import default_threads

    monkeypatch.setenv("UAVMPC_THREADS", "1")
    assert default_threads() == 1
    assert split_cores(1, None) == (1, 1)  # one worker, but not more threads than asked
    monkeypatch.setenv("UAVMPC_THREADS", "lots")
    assert default_threads() == available_threads()
    assert "UAVMPC_THREADS='lots' is not an integer" in capsys.readouterr().err


def test_threads_set_for_a_block_come_back_after_it(restore_threads) -> None:
    from uavmpc.jit import using_threads

    set_threads(1)
    with using_threads(available_threads()) as n:
        assert numba.get_num_threads() == n == available_threads() == thread_count()
    assert numba.get_num_threads() == 1 == thread_count()


def test_the_thread_count_drivers_read_is_numbas_per_thread_of_python(restore_threads) -> None:
    """jit.thread_count (read at every tick instead of asking numba) follows set_threads in
    each thread of Python, as numba's own count does."""
    import threading

    set_threads(1)
    seen: list[tuple[int, int]] = []

    def other() -> None:
        seen.append((thread_count(), numba.get_num_threads()))
        set_threads(available_threads())
        seen.append((thread_count(), numba.get_num_threads()))

    t = threading.Thread(target=other)
    t.start()
    t.join()
    top = available_threads()
    assert seen == [(numba.config.NUMBA_NUM_THREADS,) * 2, (top, top)]
    assert thread_count() == numba.get_num_threads() == 1  # this thread's is its own


@needs_two
def test_the_demo_flies_on_one_thread_unless_told(monkeypatch, tmp_path, restore_threads) -> None:
    import uavmpc.apps.cli as cli

    seen: list[int] = []
    monkeypatch.setattr(cli, "_demo", lambda args: seen.append(numba.get_num_threads()) or 0)
    monkeypatch.delenv("UAVMPC_THREADS", raising=False)
    set_threads(available_threads())
    assert main(["demo", "--out", str(tmp_path)]) == 0
    assert main(["demo", "--out", str(tmp_path), "--threads", "2"]) == 0
    monkeypatch.setenv("UAVMPC_THREADS", "2")
    set_threads(None)
    assert main(["demo", "--out", str(tmp_path)]) == 0
    assert seen == [1, 2, 2]


def test_one_thread_flies_the_plain_tick_and_two_the_threaded_one() -> None:
    # In a fresh process (this one may have flown on two threads already): each thread count
    # compiles (or loads) only the tick it flies.
    import os
    import subprocess
    import sys

    code = ("from uavmpc.drivers.world import World\n"
            "from uavmpc.drivers.world_tick import world_tick, world_tick_threads\n"
            "from uavmpc.jit import set_threads\n"
            "from uavmpc.scenarios.random_walk import random_walk\n"
            "from uavmpc.scenarios.run import RunSpec\n"
            "World(RunSpec(random_walk(3, duration_s=1.0, seed=1), seed=1)).run(0.2)\n"
            "print(len(world_tick.overloads), len(world_tick_threads.overloads))\n"
            "set_threads(2)\n"
            "World(RunSpec(random_walk(3, duration_s=1.0, seed=1), seed=1)).run(0.2)\n"
            "print(len(world_tick.overloads), len(world_tick_threads.overloads))\n")
    env = {**os.environ, "UAVMPC_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["1", "0", "1", "1"]


def test_more_threads_than_cores_fly_the_same_flight() -> None:
    """At 3 and 4 threads (numba may run more threads than cores; blocks this 2-core machine
    never splits into on its own) the flight, the inboxes and the link are those of one
    thread."""
    import os
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "import uavmpc.drivers.world as wm\n"
        "from uavmpc.jit import set_threads\n"
        "from uavmpc.scenarios.random_walk import random_walk\n"
        "from uavmpc.scenarios.run import RunSpec\n"
        "def fly(threads):\n"
        "    set_threads(threads)\n"
        "    sc = random_walk(30, area_m=245.0, duration_s=3.0, seed=2)\n"
        "    w = wm.World(RunSpec(sc, seed=2))\n"
        "    r = w.run(3.0)\n"
        "    return (r.positions_m, r.z_offset_m, r.min_distance_m, w.inboxes.rows.held_slot,\n"
        "            w.inboxes.rows.accepted, np.array(list(vars(w.link.stats).values())))\n"
        "one = fly(1)\n"
        "for threads in (3, 4):\n"
        "    other = fly(threads)\n"
        "    assert all(np.array_equal(a, b) for a, b in zip(one, other, strict=True))\n"
        "print('same')\n")
    env = {**os.environ, "UAVMPC_THREADS": "1", "NUMBA_NUM_THREADS": "4"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["same"]
