"""The real PX4 firmware as software in the loop: a SITL build, and instances of it with SIH.

A PX4 SITL build is a folder with ``bin/px4`` (and its ``px4-*`` links, which PX4's start-up
scripts call) and ``etc/`` (``init.d-posix/rcS`` and the airframes); PX4's ``make px4_sitl``
leaves one in ``build/px4_sitl_default``, and a release archive (``.tar.gz``) holds one.
:class:`Px4SitlBuild` checks a folder is one; :class:`Px4Instance` runs one vehicle of it with
PX4's built-in SIH simulator (a quadrotor inside the px4 process), booted at a geodetic home.

Ports of instance ``i`` (PX4's ``px4-rc.mavlink``): the onboard/offboard-API link sends from
UDP 14580+i to 127.0.0.1:14540+i (:attr:`Px4Instance.offboard_port`) and answers whichever
address last talked to it; MAVLink system id i+1; the GCS link 18570+i → 14550. Two
instances with the same ``i`` on one machine cannot run: the second fails to start.

PX4 writes its parameters, mission storage (``dataman``) and flight log (``log/<date>/*.ulg``,
with SIH's ground truth) into the instance's working folder; the build itself is only read.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import signal
import socket
import subprocess
import tarfile
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uavmpc.config import ConfigError

__all__ = ["DEFAULT_GEO_ORIGIN", "Px4BuildError", "Px4Instance", "Px4SitlBuild",
           "Px4StartError", "extract_archive"]

#: PX4's default SITL home (Zürich): latitude, longitude [deg], altitude AMSL [m].
DEFAULT_GEO_ORIGIN: tuple[float, float, float] = (47.397742, 8.545594, 488.0)
#: The SIH quadrotor's airframe: ``PX4_SIM_MODEL`` selects it by the name after the number.
SIH_AIRFRAME = "10040_sihsim_quadx"
#: What PX4's commander prints once its pre-flight checks pass.
READY_LINE = "Ready for takeoff!"

_REQUIRED = ("bin/px4", "etc/init.d-posix/rcS", f"etc/init.d-posix/airframes/{SIH_AIRFRAME}")
_HINT = ("expected a PX4 build folder with bin/px4 and etc/, e.g. build/px4_sitl_default or the "
         "extracted archive")
#: Files of a previous run in a working folder that would carry its state into the next boot.
_STATE_FILES = ("parameters.bson", "parameters_backup.bson", "dataman")


class Px4BuildError(ConfigError):
    """A folder (or archive) that is not a PX4 SITL build; the message is one line."""


class Px4StartError(RuntimeError):
    """A PX4 instance that exited or did not become ready; the message ends with its log."""


@dataclass(frozen=True)
class Px4SitlBuild:
    """A validated PX4 SITL build folder (``root/bin/px4``, ``root/etc``)."""

    root: Path

    @property
    def px4(self) -> Path:
        return self.root / "bin" / "px4"

    @property
    def bin_dir(self) -> Path:
        return self.root / "bin"

    @property
    def etc(self) -> Path:
        return self.root / "etc"

    @classmethod
    def from_dir(cls, path: str | os.PathLike[str], *, flag: str = "--px4-sitl"
                 ) -> Px4SitlBuild:
        """The build in ``path``. Raises :class:`Px4BuildError` (one line, starting with
        ``flag`` and the path, naming what is missing)."""
        root = Path(path).expanduser()
        where = f"{flag} {path}" if flag else str(path)
        if not root.exists():
            raise Px4BuildError(f"{where}: no such file or folder ({_HINT})")
        if not root.is_dir():
            raise Px4BuildError(f"{where}: not a PX4 SITL build: not a folder ({_HINT})")
        missing = [r for r in _REQUIRED if not (root / r).is_file()]
        if missing:
            raise Px4BuildError(f"{where}: not a PX4 SITL build: {', '.join(missing)} missing "
                                f"({_HINT})")
        if not os.access(root / "bin" / "px4", os.X_OK):
            raise Px4BuildError(f"{where}: not a PX4 SITL build: bin/px4 is not executable "
                                f"({_HINT})")
        return cls(root.resolve())

    @classmethod
    def locate(cls, path: str | os.PathLike[str], *, flag: str = "--px4-sitl",
               cache_dir: str | os.PathLike[str] | None = None) -> Px4SitlBuild:
        """A build folder, or a ``.tar.gz`` archive of one extracted once into ``cache_dir``
        (default: a folder under the system's temporary directory, reused while the archive
        is unchanged)."""
        p = Path(path).expanduser()
        if p.is_file() and p.name.endswith((".tar.gz", ".tgz")):
            try:
                return cls.from_dir(extract_archive(p, cache_dir=cache_dir), flag=flag)
            except (tarfile.TarError, OSError) as exc:
                raise Px4BuildError(f"{flag} {path}: cannot extract: {exc}") from exc
        return cls.from_dir(p, flag=flag)


def extract_archive(archive: str | os.PathLike[str],
                    cache_dir: str | os.PathLike[str] | None = None) -> Path:
    """Extract a PX4 SITL archive once; returns the folder holding ``bin/`` and ``etc/``.

    The destination is named after the archive's size and modification time, so a changed
    archive is extracted again and an unchanged one is not; extraction goes to a temporary
    sibling that is renamed into place, so concurrent callers never see half a tree."""
    src = Path(archive).resolve()
    st = src.stat()
    key = hashlib.sha1(f"{src}|{st.st_size}|{st.st_mtime_ns}".encode()).hexdigest()[:12]
    base = Path(cache_dir) if cache_dir else Path(tempfile.gettempdir()) / "uavmpc-px4-sitl"
    dest = base / f"{src.name.split('.')[0]}-{key}"
    if not dest.is_dir():
        base.mkdir(parents=True, exist_ok=True)
        part = Path(tempfile.mkdtemp(prefix=".part-", dir=base))
        try:
            with tarfile.open(src, "r:gz") as tar:
                if hasattr(tarfile, "data_filter"):  # refuses absolute paths and ../ escapes
                    tar.extractall(part, filter="data")
                else:  # pragma: no cover - Python < 3.11.4
                    tar.extractall(part)
            with contextlib.suppress(OSError):  # another caller got there first: use theirs
                part.rename(dest)
        finally:
            if part.exists():
                shutil.rmtree(part, ignore_errors=True)
    return _build_root(dest)


def _build_root(folder: Path) -> Path:
    """``folder`` itself if it holds ``bin/px4``, else its one subfolder that does."""
    if (folder / "bin" / "px4").exists():
        return folder
    inner = [d for d in folder.iterdir() if (d / "bin" / "px4").exists()]
    return inner[0] if len(inner) == 1 else folder


#: The highest instance whose onboard link has a port of its own (14540 + i): PX4 SITL's
#: ``px4-rc.mavlink`` sends every instance above 9 to 14549.
MAX_INSTANCE = 9


class Px4Instance:
    """One PX4 SITL process with SIH: instance ``instance``, its own ``workdir``, booted at
    the geodetic ``home = (lat_deg, lon_deg, alt_m)`` (SIH's ``SIH_LOC_LAT0/LON0/H0``).

    ``start()`` then ``wait_ready()``; ``stop()`` ends the whole process group (PX4 runs its
    start-up script through ``sh``, which forks ``px4-*`` clients). Also a context manager.
    """

    def __init__(self, build: Px4SitlBuild, instance: int, workdir: str | os.PathLike[str],
                 home: tuple[float, float, float] = DEFAULT_GEO_ORIGIN, *,
                 model: str = "sihsim_quadx") -> None:
        if not 0 <= int(instance) <= MAX_INSTANCE:
            raise ValueError(
                f"PX4 instance number must be in 0..{MAX_INSTANCE}, got {instance}: PX4 SITL "
                "sends the onboard link of instance 10 and above to one shared port, 14549 "
                "(etc/init.d-posix/px4-rc.mavlink), so one machine flies at most 10 vehicles "
                "each with its own node")
        lat, lon, alt = (float(v) for v in home)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0 and abs(alt) < 1e5):
            raise ValueError(f"PX4 home must be (lat [-90, 90], lon [-180, 180], alt m), "
                             f"got {home}")
        self.build = build
        self.instance = int(instance)
        self.workdir = Path(workdir)
        self.home = (lat, lon, alt)
        self.model = model
        self.process: subprocess.Popen[bytes] | None = None
        self.ready_after_s: float | None = None
        self._started_at = 0.0

    # --- ports and identities (PX4's px4-rc.mavlink) ---------------------------------------
    @property
    def offboard_port(self) -> int:
        """UDP port on 127.0.0.1 PX4's onboard link sends to: where a node listens."""
        return 14540 + self.instance

    @property
    def onboard_local_port(self) -> int:
        """UDP port PX4's onboard link sends from (and listens on)."""
        return 14580 + self.instance

    @property
    def gcs_local_port(self) -> int:
        """UDP port of PX4's GCS link (it sends to 14550)."""
        return 18570 + self.instance

    @property
    def system_id(self) -> int:
        return self.instance + 1

    @property
    def mavlink_address(self) -> str:
        """The ``--mavlink`` address of the node that flies this instance."""
        return f"udp://:{self.offboard_port}"

    @property
    def log_path(self) -> Path:
        """PX4's console output (``px4.log`` in the working folder)."""
        return self.workdir / "px4.log"

    def ulog_paths(self) -> list[Path]:
        """The flight logs PX4 wrote in its working folder, oldest first."""
        return sorted(self.workdir.glob("log/*/*.ulg"))

    def log_tail(self, lines: int = 20) -> list[str]:
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return []
        # the console colours "Ready for takeoff!" and warnings: keep the text only
        return [_strip_ansi(ln) for ln in text.splitlines()[-lines:]]

    # --- life cycle ----------------------------------------------------------------------------
    def start(self, *, fresh: bool = True) -> None:
        """Start PX4 in the background. ``fresh``: forget the parameters and mission storage
        a previous run left in the working folder (logs are kept), so every boot is the
        airframe's defaults plus this home. Raises :class:`Px4StartError` if the instance's
        ports are taken (another PX4 with the same instance number)."""
        if self.process is not None:
            raise RuntimeError(f"PX4 instance {self.instance} already started")
        self._check_ports_free()
        self.workdir.mkdir(parents=True, exist_ok=True)
        if fresh:
            for name in _STATE_FILES:
                with contextlib.suppress(FileNotFoundError):
                    (self.workdir / name).unlink()
        env = dict(os.environ)
        env.update({
            "PX4_SIM_MODEL": self.model, "PX4_SIMULATOR": "sihsim",
            "PX4_HOME_LAT": repr(self.home[0]), "PX4_HOME_LON": repr(self.home[1]),
            "PX4_HOME_ALT": repr(self.home[2]),
            "PATH": f"{self.build.bin_dir}{os.pathsep}{env.get('PATH', '')}",
        })
        with open(self.log_path, "wb") as log:  # the child keeps its own descriptor
            self.process = subprocess.Popen(
                [str(self.build.px4), "-i", str(self.instance), "-d", str(self.build.etc)],
                cwd=self.workdir, env=env, stdin=subprocess.DEVNULL, stdout=log,
                stderr=subprocess.STDOUT, start_new_session=True)
        self._started_at = time.monotonic()

    def wait_ready(self, timeout_s: float = 30.0) -> float:
        """Block until PX4's console says it is ready for take-off; returns the seconds since
        :meth:`start`. Raises :class:`Px4StartError` if PX4 exits first or ``timeout_s``
        passes (the message ends with the end of its console log)."""
        if self.process is None:
            raise RuntimeError(f"PX4 instance {self.instance} not started")
        deadline = time.monotonic() + timeout_s
        ready = READY_LINE.encode()
        window = b""  # the end of what was read, so a line split across two reads is found
        with open(self.log_path, "rb") as log:
            while True:
                window = window[-len(ready):] + log.read()
                if ready in window:
                    self.ready_after_s = time.monotonic() - self._started_at
                    return self.ready_after_s
                if self.process.poll() is not None:
                    raise Px4StartError(self._why(f"exited with code {self.process.returncode} "
                                                  "before it was ready"))
                if time.monotonic() >= deadline:
                    raise Px4StartError(self._why(f"not ready after {timeout_s:g} s"))
                time.sleep(0.05)  # the console file gives no wake-up; 50 ms is ample

    def stop(self, timeout_s: float = 5.0) -> int | None:
        """End PX4 and every process of its group: SIGTERM (PX4 shuts its modules down and
        closes its log, ≈ 1 s), then SIGKILL after ``timeout_s``. Returns PX4's exit code;
        harmless to call twice or before :meth:`start`."""
        p = self.process
        if p is None:
            return None
        pgid = p.pid  # start_new_session: the group is the leader's pid
        if p.poll() is None:
            _signal_group(pgid, signal.SIGTERM)
            try:
                p.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                _signal_group(pgid, signal.SIGKILL)
                p.wait(timeout=5.0)
        # clients forked during start-up may outlive the server by a moment
        deadline = time.monotonic() + 2.0
        while _group_alive(pgid) and time.monotonic() < deadline:
            time.sleep(0.02)
        if _group_alive(pgid):
            _signal_group(pgid, signal.SIGKILL)
        return p.returncode

    def report(self) -> dict[str, Any]:
        """What a run keeps of this instance: where it ran, its ports, its logs."""
        ulogs = self.ulog_paths()
        return {
            "instance": self.instance, "system_id": self.system_id,
            "offboard_port": self.offboard_port, "home": list(self.home),
            "workdir": str(self.workdir), "log": str(self.log_path),
            "ulog": str(ulogs[-1]) if ulogs else None,
            "ready_after_s": self.ready_after_s,
            "exit_code": None if self.process is None else self.process.returncode,
            "log_tail": self.log_tail(),
        }

    def __enter__(self) -> Px4Instance:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _why(self, what: str) -> str:
        tail = "\n".join(self.log_tail(15))
        return f"PX4 instance {self.instance} in {self.workdir} {what}; px4.log ends:\n{tail}"

    def _check_ports_free(self) -> None:
        for port in (self.onboard_local_port, self.gcs_local_port):
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                try:
                    s.bind(("0.0.0.0", port))
                except OSError as exc:
                    raise Px4StartError(
                        f"PX4 instance {self.instance}: UDP port {port} is in use ({exc}); "
                        f"is another PX4 running as instance {self.instance}? Choose another "
                        "instance number") from None


def _strip_ansi(line: str) -> str:
    out, i = [], 0
    while i < len(line):
        if line[i] == "\x1b" and i + 1 < len(line) and line[i + 1] == "[":
            j = i + 2
            while j < len(line) and not line[j].isalpha():
                j += 1
            i = j + 1
            continue
        out.append(line[i])
        i += 1
    return "".join(out)


def _signal_group(pgid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, sig)


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
