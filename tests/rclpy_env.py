"""Real ROS 2 (rclpy, Jazzy, Fast DDS) in a venv of its own, for tests (test helper).

The ROS 2 Jazzy builds on PyPI (``ros-jazzy-rclpy[fastrtps]`` and the message packages, about
260 MB) install a bootstrapper that re-executes every Python started in their venv, so they stay
out of the project's venv: :func:`rclpy_python` builds one venv next to it once, keyed by the
requirement set and the Python version, under the user's cache folder
(``$XDG_CACHE_HOME`` or ``~/.cache``, ``uavmpc/rclpy-<key>``), and reuses it after. A build goes
into a temporary folder renamed into place when it imports rclpy, so an interrupted build leaves
nothing half made. Where no venv can be built (no registry, another platform), the reason is
returned for the tests to skip with.

:func:`run_probe` runs ``rclpy_probe.py`` (beside this file) in that venv, with a JSON request
on stdin and a JSON answer on stdout.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

#: What the venv holds: rclpy on Fast DDS (ROS 2's default middleware) and the message types
#: uavmpc writes.
REQUIREMENTS = ("ros-jazzy-rclpy[fastrtps]==7.1.6", "ros-jazzy-std-msgs==5.3.6",
                "ros-jazzy-geometry-msgs==5.3.6", "ros-jazzy-nav-msgs==5.3.6")
PROBE = Path(__file__).with_name("rclpy_probe.py")


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "uavmpc"


def venv_key() -> str:
    text = "\n".join([f"{sys.version_info.major}.{sys.version_info.minor}", sys.platform,
                      *REQUIREMENTS])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _python_of(venv: Path) -> Path:
    return venv / "bin" / "python"


def _imports_rclpy(python: Path) -> str | None:
    """None if ``python`` imports rclpy and the messages; else what went wrong."""
    try:
        done = subprocess.run(
            [str(python), "-c", "import rclpy, geometry_msgs.msg, nav_msgs.msg"],
            capture_output=True, text=True, timeout=120, env=clean_env())
    except (OSError, subprocess.TimeoutExpired) as exc:
        return str(exc)
    return None if done.returncode == 0 else (done.stderr.strip().splitlines() or ["?"])[-1]


def rclpy_python(build_timeout_s: float = 600.0) -> tuple[Path | None, str]:
    """(the venv's python, "") once built or found in the cache; (None, why) if it cannot be.
    One build at a time (a lock file beside the venv): a second caller waits for the first
    and then finds the venv built, e.g. a test waiting for the build the test session started
    in the background (``tests/conftest.py``)."""
    if not sys.platform.startswith("linux"):
        return None, f"the ROS 2 wheels on PyPI are built for Linux, not {sys.platform}"
    import fcntl

    venv = cache_root() / f"rclpy-{venv_key()}"
    venv.parent.mkdir(parents=True, exist_ok=True)
    with open(venv.parent / f"{venv.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _found_or_built(venv, build_timeout_s)


def _found_or_built(venv: Path, build_timeout_s: float) -> tuple[Path | None, str]:
    if _python_of(venv).exists() and _imports_rclpy(_python_of(venv)) is None:
        return _python_of(venv), ""
    work = Path(tempfile.mkdtemp(prefix="rclpy-build-", dir=venv.parent))
    try:
        subprocess.run([sys.executable, "-m", "venv", str(work)], check=True,
                       capture_output=True, timeout=120)
        pip = subprocess.run(
            [str(_python_of(work)), "-m", "pip", "install", "--disable-pip-version-check",
             "-q", *REQUIREMENTS],
            capture_output=True, text=True, timeout=build_timeout_s, env=clean_env())
        if pip.returncode != 0:
            tail = (pip.stderr.strip().splitlines() or ["?"])[-1]
            return None, f"cannot install ROS 2 Jazzy rclpy from PyPI: {tail}"
        why = _imports_rclpy(_python_of(work))
        if why is not None:
            return None, f"rclpy from PyPI does not import here: {why}"
        if _python_of(venv).exists() and _imports_rclpy(_python_of(venv)) is None:
            return _python_of(venv), ""  # another process built it meanwhile: keep theirs
        shutil.rmtree(venv, ignore_errors=True)
        # a venv's scripts name its folder; the interpreter itself does not, so `python`
        # (all we run) works after the rename
        work.rename(venv)
        return _python_of(venv), ""
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"cannot build the rclpy venv: {exc}"
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)


def clean_env(**extra: str) -> dict[str, str]:
    """The environment for the rclpy venv: without this project's PYTHONPATH or venv."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env.update(extra)
    return env


def run_probe(python: Path, request: dict[str, Any], *, domain_id: int,
              timeout_s: float = 120.0) -> dict[str, Any]:
    """Run the probe with ``request``; its JSON answer (fails the test with its stderr)."""
    done = subprocess.run(
        [str(python), str(PROBE)], input=json.dumps(request), capture_output=True, text=True,
        timeout=timeout_s,
        env=clean_env(ROS_DOMAIN_ID=str(domain_id), RMW_IMPLEMENTATION="rmw_fastrtps_cpp"))
    if done.returncode != 0:
        raise AssertionError(f"the rclpy probe failed ({done.returncode}):\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


if __name__ == "__main__":  # the background build of tests/conftest.py
    found, reason = rclpy_python()
    print(found or reason)
