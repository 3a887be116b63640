"""The real PX4 firmware (SITL with SIH): a build folder is checked with a one-line error, and
one instance boots where it was told, speaks as PX4 on its port and leaves nothing behind."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from uavmpc.apps.cli import main
from uavmpc.drivers.px4 import frames
from uavmpc.drivers.px4.firmware import Px4BuildError, Px4Instance, Px4SitlBuild

HOME = (46.51853, 6.56588, 412.0)  # not PX4's default: the home must come from us


def test_a_folder_that_is_not_a_build_is_one_line_from_the_cli() -> None:
    r = subprocess.run([sys.executable, "-m", "uavmpc.apps.cli", "swarm", "swap_through_static",
                        "--px4-sitl", "/nonexistent"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith("uavmpc: --px4-sitl /nonexistent: ")
    assert "bin/px4" in line and "etc/" in line
    assert r.stdout == ""


def test_what_is_missing_is_named(tmp_path: Path, capsys) -> None:
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "px4").write_text("#!/bin/sh\n")
    (tmp_path / "bin" / "px4").chmod(0o755)
    assert main(["swarm", "swap_through_static", "--px4-sitl", str(tmp_path)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (f"uavmpc: --px4-sitl {tmp_path}: not a PX4 SITL build: "
                    "etc/init.d-posix/rcS, etc/init.d-posix/airframes/10040_sihsim_quadx "
                    "missing (expected a PX4 build folder with bin/px4 and etc/, e.g. "
                    "build/px4_sitl_default or the extracted archive)")
    with pytest.raises(Px4BuildError, match=r"build: bin/px4, .* missing \(expected"):
        Px4SitlBuild.from_dir(tmp_path / "bin")


def test_more_vehicles_than_px4_sitl_has_onboard_ports_is_one_line(tmp_path: Path,
                                                                  capsys) -> None:
    """PX4 SITL sends the onboard link of every instance above 9 to one port (14549): three
    UAVs from instance 8 would need instance 10."""
    for f in ("bin/px4", "etc/init.d-posix/rcS", "etc/init.d-posix/airframes/10040_sihsim_quadx"):
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_text("#!/bin/sh\n")
    (tmp_path / "bin" / "px4").chmod(0o755)
    argv = ["swarm", "swap_through_static", "--px4-sitl", str(tmp_path), "--out",
            str(tmp_path / "run"), "--px4-first-instance", "8"]
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "instances 8..10" in line and "0..9" in line and "14549" in line
    with pytest.raises(ValueError, match="14549"):
        Px4Instance(Px4SitlBuild.from_dir(tmp_path), 10, tmp_path / "w")


@pytest.mark.parametrize("argv, words", [
    (["--px4-sitl", "/x", "--mavlink"], "--px4-sitl and --mavlink are exclusive"),
    (["--geo-origin", "47", "8", "400"], "--geo-origin needs --px4-sitl"),
    (["--px4-sitl", "/x", "--geo-origin", "95", "8", "400"], "--geo-origin: "),
])
def test_px4_sitl_flag_mistakes_are_one_line(argv, words, capsys) -> None:
    assert main(["swarm", "swap_through_static", *argv]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert words in line


def _pids_of(workdir: Path) -> list[int]:
    """Processes whose working folder is ``workdir`` (PX4 and anything it forked)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if Path(os.readlink(entry / "cwd")) == workdir.resolve():
                    pids.append(int(entry.name))
            except OSError:
                continue
    return pids


def test_a_real_px4_boots_at_its_home_speaks_px4_and_stops_clean(px4_instances) -> None:
    mavutil = pytest.importorskip("pymavlink.mavutil")
    (px4,) = px4_instances(1, first=7, homes=[HOME])
    assert px4.offboard_port == 14547 and px4.system_id == 8
    assert px4.ready_after_s is not None and px4.ready_after_s < 20.0
    assert _pids_of(px4.workdir)
    link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{px4.offboard_port}",
                                      source_system=250, source_component=191)
    try:
        hb = link.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
        assert hb is not None, "no HEARTBEAT from PX4"
        assert hb.get_srcSystem() == px4.system_id
        assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4
        # PX4 answers MAV_CMD_REQUEST_MESSAGE through the message's stream, creating it at
        # rate 0 if it has none (MavlinkReceiver::handle_request_message_command): one message
        # and an ACCEPTED ACK; UDP can lose either, so the request is repeated until it comes.
        got = {}
        deadline = time.monotonic() + 10.0
        wanted = {"GPS_GLOBAL_ORIGIN": 49, "HOME_POSITION": 242}
        while set(got) != set(wanted) and time.monotonic() < deadline:
            for name, msg_id in wanted.items():  # UDP: ask again until it answers
                if name not in got:
                    link.mav.command_long_send(px4.system_id, 1,
                                               mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                               msg_id, 0, 0, 0, 0, 0, 0)
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                m = link.recv_match(type=list(wanted), blocking=True, timeout=0.1)
                if m is not None and m.get_srcSystem() == px4.system_id:
                    got[m.get_type()] = m
        assert set(got) == set(wanted), f"PX4 did not answer for {set(wanted) - set(got)}"
        for name, m in got.items():
            lat, lon, alt = m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3
            off = frames.geodetic_to_enu(lat, lon, alt, HOME)
            # SIH's GPS noise and EKF2's settling: metres, not the kilometres of a wrong home
            assert np.hypot(off[0], off[1]) < 3.0, (name, off)
            assert abs(off[2]) < 5.0, (name, off)
    finally:
        link.close()
        px4.stop()
    assert px4.process is not None and px4.process.returncode is not None
    assert _pids_of(px4.workdir) == []
    assert px4.ulog_paths(), "PX4 wrote no flight log in its working folder"
    assert px4.stop() == px4.process.returncode  # twice is harmless


def test_an_instance_number_in_use_is_refused_clearly(px4_instances, tmp_path) -> None:
    (px4,) = px4_instances(1, first=8)
    twin = Px4Instance(px4.build, 8, tmp_path / "twin")
    with pytest.raises(Exception, match="instance 8: UDP port 14588 is in use"):
        twin.start()
    assert twin.process is None
