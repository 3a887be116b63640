import os
from pathlib import Path

# One thread per parallel kernel, here and in the processes the tests start: the pytest-xdist
# workers already fill the cores, and a tick split over threads that wait for each other on
# busy cores only waits longer (tests/test_threads.py asks for more on purpose).
os.environ.setdefault("UAVMPC_THREADS", "1")

import numpy as np
import pytest

from uavmpc.tracker import MpcTracker


def fly(tracker: MpcTracker, ticks: int) -> np.ndarray:
    """Step the tracker; returns (ticks, 4, 3) states after each step."""
    out = np.empty((ticks, 4, 3))
    for i in range(ticks):
        tracker.step()
        out[i] = tracker.state
    return out


def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: one worker per core, at most four. Many tests fly in real time and start
    processes of their own (nodes, PX4): more workers than that would starve them."""
    return max(1, min(os.cpu_count() or 1, 4))


def pytest_sessionstart(session) -> None:
    """Start building the real-rclpy venv (tests/rclpy_env.py) in the background while the
    computing tests run, when this session may run the real-time tests and the venv is not
    cached yet: on a fresh machine the build takes a minute or more, and the tests that need
    it wait for it (a lock) instead of building it on the real-time worker's critical path."""
    config = session.config
    if hasattr(config, "workerinput") or "not realtime" in (config.option.markexpr or ""):
        return  # an xdist worker (the controller starts it), or no real-time test
    import subprocess
    import sys

    import rclpy_env

    venv = rclpy_env.cache_root() / f"rclpy-{rclpy_env.venv_key()}"
    if sys.platform.startswith("linux") and not (venv / "bin" / "python").exists():
        subprocess.Popen([sys.executable, rclpy_env.__file__], stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, start_new_session=True)


def pytest_itemcollected(item) -> None:
    """The real-time tests run one after another on one worker, beside the computing ones on
    the others: two real-time flights at once (a swarm is a dozen processes) would starve
    each other on a small machine, and the real PX4's instances have fixed UDP ports
    (14540 + instance). A test that boots the real PX4 is a real-time one. (Marked here, as
    each test is collected: xdist reads the groups in its own collection hook.) Tried: only
    the fleets (swarms, real PX4s) on one worker, one-node real-time tests anywhere: the
    whole run took 957 s against 773 s, the other worker then the longer, and the live
    swarm's view went quiet under the load."""
    if "px4_sitl_build" in item.fixturenames:
        item.add_marker(pytest.mark.realtime)
    if item.get_closest_marker("realtime") is not None:
        item.add_marker(pytest.mark.xdist_group("realtime"))


@pytest.fixture
def tracker() -> MpcTracker:
    return MpcTracker(position_m=(0.0, 0.0, 10.0))


@pytest.fixture
def hover_pair(tmp_path):
    """A scenario file: uav1 (priority 1) and uav2 hover 2 m apart at 5 m, in conflict."""
    path = tmp_path / "pair.toml"
    path.write_text("""
name = "pair"
duration_s = 14.0
[[uavs]]
id = "uav1"
priority = 1
start = [0.0, 0.0, 5.0]
goto = [0.0, 0.0, 5.0, 0.0]
[[uavs]]
id = "uav2"
priority = 2
start = [2.0, 0.0, 5.0]
goto = [2.0, 0.0, 5.0, 0.0]
""")
    return path


# --- the real PX4 firmware (SITL with SIH) ------------------------------------------------------

_PX4_SKIP = ("real PX4 SITL not available: set UAVMPC_PX4_SITL to an extracted PX4 SITL build "
             "(bin/px4, etc/)")
_SHARED_PX4 = Path(__file__).resolve().parents[2] / "shared" / "px4-sitl"


@pytest.fixture(scope="session")
def px4_sitl_build():
    """The validated PX4 SITL build of ``$UAVMPC_PX4_SITL`` (CI extracts it); unset, the
    archive in the repository's sibling ``shared/px4-sitl/``, extracted once into a cache under
    the temporary directory; else the test is skipped."""
    from uavmpc.drivers.px4.firmware import Px4BuildError, Px4SitlBuild

    where = os.environ.get("UAVMPC_PX4_SITL")
    if where:  # set on purpose: a wrong value is an error, not a skip
        return Px4SitlBuild.locate(where, flag="UAVMPC_PX4_SITL")
    archives = sorted(_SHARED_PX4.glob("*.tar.gz"))
    if not archives:
        pytest.skip(_PX4_SKIP)
    try:
        return Px4SitlBuild.locate(archives[-1], flag="shared archive")
    except Px4BuildError:
        pytest.skip(_PX4_SKIP)


@pytest.fixture
def px4_instances(px4_sitl_build, tmp_path):
    """``start(n, first=7, homes=None)`` boots ``n`` PX4 SIH instances numbered from
    ``first`` (clear of instances 0–3 a developer may be running), each in its own folder
    under ``tmp_path``, and waits until every one is ready; all are stopped at teardown."""
    from uavmpc.drivers.px4.firmware import DEFAULT_GEO_ORIGIN, Px4Instance

    started: list[Px4Instance] = []

    def start(n: int, first: int = 7, homes=None) -> list[Px4Instance]:
        batch = [Px4Instance(px4_sitl_build, first + k, tmp_path / f"px4-{first + k}",
                             home=(homes[k] if homes else DEFAULT_GEO_ORIGIN))
                 for k in range(n)]
        for inst in batch:
            started.append(inst)
            inst.start()
        for inst in batch:  # they boot in parallel
            inst.wait_ready(timeout_s=30.0)
        return batch

    yield start
    for inst in started:
        inst.stop()


_HEAD_ON_PAIRS = """
# Two head-on pairs 60 m apart, all at 4 m: the first with avoidance, the second without.
name = "head_on_pairs"
duration_s = 14.0
{uavs}
"""
_UAV = """
[[uavs]]
id = "{id}"
priority = {priority}
airframe = "{airframe}"
avoidance = {avoidance}
start = [{x0}, {y}, 4.0]
heading_rad = {heading}
goto = [{x1}, {y}, 4.0, {heading}]
"""


@pytest.fixture
def head_on_pairs(tmp_path):
    """``make(airframe) -> Path``: a scenario file of two head-on pairs 60 m apart at 4 m, 14 m
    apart each: ``a1``/``a2`` with avoidance, ``b1``/``b2`` without (the PX4 swarm tests')."""

    def make(airframe: str) -> Path:
        uavs = "".join(
            _UAV.format(id=f"{pair}{k + 1}", priority=2 * p + k + 1, airframe=airframe,
                        avoidance=str(pair == "a").lower(), y=60.0 * p,
                        x0=-7.0 if k == 0 else 7.0, x1=7.0 if k == 0 else -7.0,
                        heading=0.0 if k == 0 else 3.141592653589793)
            for p, pair in enumerate("ab") for k in range(2))
        path = tmp_path / f"head_on_pairs_{airframe}.toml"
        path.write_text(_HEAD_ON_PAIRS.format(uavs=uavs))
        return path

    return make
