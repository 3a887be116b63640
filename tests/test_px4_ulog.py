"""PX4's flight logs read back as an independent witness: a file that is not one is named in
one line, tracks are placed, re-timed and compared as the swarm would, and the real PX4's log
puts a vehicle at rest where it was booted (SIH's truth) and EKF2 next to it."""

from __future__ import annotations

import json
import math
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from uavmpc.drivers.px4 import frames

pytest.importorskip("pyulog")

from uavmpc.drivers.px4.ulog import (
    Track,
    ULogError,
    closest_by_pair,
    on_wall_clock,
    read_estimate,
    read_truth,
    swarm_truth,
)

WORLD = (47.397742, 8.545594, 488.0)  # the world's geodetic origin (PX4's default home)


# --- a minimal ULog writer: the two local-position topics, enough for pyulog -----------------

_FIELDS = (("uint64_t", "timestamp", "Q"), ("float", "x", "f"), ("float", "y", "f"),
           ("float", "z", "f"), ("double", "ref_lat", "d"), ("double", "ref_lon", "d"),
           ("float", "ref_alt", "f"), ("bool", "xy_global", "?"), ("bool", "z_global", "?"))
_PACK = "<" + "".join(f[2] for f in _FIELDS)


def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(path: Path, topics: dict[str, list[tuple]]) -> Path:
    """A ULog with each topic's rows ``(t_us, x, y, z, ref_lat, ref_lon, ref_alt, xy, z)``."""
    out = b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0)
    out += _msg(b"B", bytes(40))  # flag bits: nothing incompatible
    fmt = ";".join(f"{t} {n}" for t, n, _ in _FIELDS) + ";"
    for name in topics:
        out += _msg(b"F", f"{name}:{fmt}".encode())
    for msg_id, name in enumerate(topics):
        out += _msg(b"A", struct.pack("<BH", 0, msg_id) + name.encode())
    for msg_id, rows in enumerate(topics.values()):
        for row in rows:
            out += _msg(b"D", struct.pack("<H", msg_id) + struct.pack(_PACK, *row))
    path.write_bytes(out)
    return path


def _rows(t_s: np.ndarray, enu_world: np.ndarray, ref: tuple[float, float, float],
          valid: bool = True) -> list[tuple]:
    """Rows placing ENU world points (m) in NED about ``ref``."""
    lat, lon, alt = frames.enu_to_geodetic(enu_world, WORLD)
    ned = frames.enu_to_ned(frames.geodetic_to_enu(lat, lon, alt, ref))
    return [(round(float(t) * 1e6), *map(float, p), *ref, valid, valid)
            for t, p in zip(t_s, ned, strict=True)]


# --- without PX4 -------------------------------------------------------------------------------

@pytest.mark.parametrize("content", [b"", b"not a flight log\n" * 10,
                                     b"ULog\x01\x12\x35\x01" + bytes(8) + b"\xff" * 64])
def test_a_file_that_is_not_a_ulog_is_one_line_naming_it(tmp_path: Path, content) -> None:
    path = tmp_path / "flight.ulg"
    path.write_bytes(content)
    for read in (read_truth, read_estimate):
        with pytest.raises(ULogError) as e:
            read(path, WORLD)
        msg = str(e.value)
        assert msg.startswith(f"{path}: ") and "\n" not in msg
        assert "not a PX4 flight log" in msg
    with pytest.raises(ULogError, match=r"nowhere\.ulg: no such flight log"):
        read_truth(tmp_path / "nowhere.ulg", WORLD)


def test_a_missing_topic_is_named(tmp_path: Path) -> None:
    t = np.array([1.0, 1.1])
    path = write_ulog(tmp_path / "no_truth.ulg", {
        "vehicle_local_position": _rows(t, np.zeros((2, 3)), WORLD)})
    with pytest.raises(ULogError, match=rf"^{path}: no vehicle_local_position_groundtruth "
                                        "in this flight log$"):
        read_truth(path, WORLD)
    assert read_estimate(path, WORLD).t_s.size == 2


def test_closest_by_pair_of_two_crossing_tracks() -> None:
    # a flies east along y = 0, b north along x = 3, 4 m above: closest at t = 3 s, where a
    # is at x = 3 and b at y = 0, 4 m apart (on the 0.02 s grid). c's track starts after the
    # window: its pairs are left out. Pairs in the dict's order: (b, a).
    t = np.linspace(0.0, 10.0, 11)
    a = Track(t, np.stack([t, 0 * t, 0 * t], axis=1))
    b = Track(t, np.stack([0 * t + 3.0, t - 3.0, 0 * t + 4.0], axis=1))
    c = Track(t + 20.0, np.zeros((11, 3)))
    got = closest_by_pair({"b": b, "a": a, "c": c}, 0.0, 10.0)
    assert got == {("b", "a"): pytest.approx(4.0, abs=1e-9)}
    # the window cuts: [5, 10] s, the nearest is at 5 s: (5, 0, 0) vs (3, 2, 4)
    assert closest_by_pair({"a": a, "b": b}, 5.0, 10.0)[("a", "b")] == pytest.approx(
        math.sqrt(4 + 4 + 16))
    with pytest.raises(ValueError, match="t1 >= t0"):
        closest_by_pair({"a": a, "b": b}, 2.0, 1.0)


def test_on_wall_clock_maps_px4_seconds_onto_ours() -> None:
    tr = Track(np.array([0.0, 10.0, 20.0]), np.arange(9.0).reshape(3, 3))
    wall = on_wall_clock(tr, 1.7e9, 1.02)
    np.testing.assert_allclose(wall.t_s, [1.7e9, 1.7e9 + 10.2, 1.7e9 + 20.4])
    np.testing.assert_array_equal(wall.position_m, tr.position_m)
    np.testing.assert_array_equal(tr.t_s, [0.0, 10.0, 20.0])  # the original is untouched
    with pytest.raises(ValueError, match="rate positive"):
        on_wall_clock(tr, 0.0, 0.0)


def test_a_swarm_run_is_judged_from_its_logs(tmp_path: Path) -> None:
    """Two UAVs' logs, each on its own boot clock and about its own references: the pair's
    closest approach comes out on the wall clock, EKF2's error per UAV, keys as the summary's."""
    # on the wall clock both fly over [100, 110] s: u2 passes 2.5 m above u1's path at 105 s
    wall = np.arange(100.0, 110.0001, 0.02)
    u1 = np.stack([wall - 105.0, 0 * wall, 0 * wall + 5.0], axis=1)
    u2 = np.stack([0 * wall, wall - 105.0, 0 * wall + 7.5], axis=1)
    sih_ref = [(47.3978, 8.5455, 490.0), (47.3976, 8.5457, 487.0)]
    ekf_ref = [(47.39781, 8.54551, 489.5), (47.39762, 8.54572, 487.2)]
    clock = [(90.0, 1.0), (50.0, 1.02)]  # our Unix time at PX4's 0, our s per PX4 s
    summary = {"uavs": {}, "sections": {"px4_sitl": {"geo_origin": list(WORLD)},
                                        "closest_by_pair_m": {"u2-u1": 2.5}}}
    for k, (uid, pos) in enumerate((("u2", u2), ("u1", u1))):
        px4_t = (wall - clock[k][0]) / clock[k][1]
        est = pos + np.array([0.3, -0.4, 0.2])  # 0.5 m off horizontally, 0.2 m vertically
        rows = _rows(px4_t, est, ekf_ref[k])
        rows[:5] = [(r[0], *r[1:4], math.nan, math.nan, math.nan, False, False)
                    for r in rows[:5]]  # before EKF2's origin: dropped
        folder = tmp_path / "px4" / uid / "log" / "2026-01-01"
        folder.mkdir(parents=True)
        write_ulog(folder / "01_02_03.ulg", {
            "vehicle_local_position_groundtruth": _rows(px4_t, pos, sih_ref[k]),
            "vehicle_local_position": rows})
        summary["uavs"][uid] = {"details": {
            "px4": {"ulog": f"elsewhere/px4/{uid}/log/2026-01-01/01_02_03.ulg"},  # moved run
            "node": {"vehicle": {"clock_offset_s": clock[k][0], "clock_rate": clock[k][1]}}}}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    got = swarm_truth(tmp_path)
    assert got["window_source"] == "overlap of the truth tracks"
    assert got["window_unix_s"] == pytest.approx([100.0, 110.0], abs=1e-4)
    assert got["closest_by_pair_m"] == {"u2-u1": pytest.approx(2.5, abs=1e-3)}
    assert got["min_distance_m"] == pytest.approx(2.5, abs=1e-3)
    for uid in ("u1", "u2"):
        u = got["uavs"][uid]
        assert "error" not in u, u
        assert u["horizontal_rms_m"] == pytest.approx(0.5, abs=2e-3)
        assert u["vertical_max_m"] == pytest.approx(0.2, abs=2e-3)
        assert u["truth_samples"] == wall.size
    # the swarm's own window, when it wrote one, is the one judged
    summary["sections"]["truth"] = {"window_unix_s": [106.0, 110.0]}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    got = swarm_truth(tmp_path)
    assert got["window_source"] == "sections.truth.window_unix_s"
    assert got["closest_by_pair_m"]["u2-u1"] == pytest.approx(math.sqrt(2.0 + 2.5 ** 2),
                                                              abs=1e-3)
    # a UAV whose log is gone is named, the others still judged
    summary["uavs"]["u3"] = {"details": {"px4": {"ulog": None}, "node": {}}}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    got = swarm_truth(tmp_path)
    assert "wrote no flight log" in got["uavs"]["u3"]["error"]
    assert got["closest_by_pair_m"]["u1-u3"] is None
    assert list(got["closest_by_pair_m"]) == ["u1-u3", "u2-u1", "u2-u3"]


# --- the real PX4 --------------------------------------------------------------------------------

@pytest.mark.realtime
def test_the_real_px4_log_puts_a_vehicle_at_rest_where_it_was_booted(px4_instances) -> None:
    """A PX4 booted 30 m east, 20 m south of the world's origin: its logged truth, placed
    through SIH's reference, is there (SIH keeps its home in 32-bit floats: decimetres off),
    EKF2's estimate, placed through its own origin, next to the truth."""
    home_enu = np.array([30.0, -20.0, 0.0])
    home = frames.enu_to_geodetic(home_enu, WORLD)
    (px4,) = px4_instances(1, first=7, homes=[home])
    time.sleep(3.0)
    px4.stop()
    (log,) = px4.ulog_paths()
    truth = read_truth(log, WORLD)
    estimate = read_estimate(log, WORLD)
    assert truth.t_s.size > 100 and estimate.t_s.size > 100
    rate_hz = 1.0 / float(np.median(np.diff(truth.t_s)))
    off = truth.position_m - home_enu
    print(f"\ntruth: {truth.t_s.size} samples over {truth.span_s} PX4 s ({rate_hz:.0f} Hz), "
          f"off the home by {np.round(off.mean(axis=0), 4)} m (largest "
          f"{np.linalg.norm(off, axis=1).max():.3f} m)")
    assert np.linalg.norm(off, axis=1).max() < 0.5
    # ... and the decimetres are exactly SIH's rounding of the home to float32: placed through
    # its reference, the truth sits at that rounded home to the millimetre
    home32 = frames.geodetic_to_enu(*(float(np.float32(v)) for v in home), WORLD)
    assert np.linalg.norm(truth.position_m - home32, axis=1).max() < 0.01
    # EKF2 against the truth over its last two seconds (settled at rest)
    settled = estimate.t_s > estimate.t_s[-1] - 2.0
    t = estimate.t_s[settled]
    truth_there = np.stack([np.interp(t, truth.t_s, truth.position_m[:, k]) for k in range(3)],
                           axis=1)
    err = np.linalg.norm(estimate.position_m[settled] - truth_there, axis=1)
    print(f"estimate: {estimate.t_s.size} samples from {estimate.t_s[0]:.3f} PX4 s, "
          f"last 2 s off the truth by {err.mean():.3f} m mean, {err.max():.3f} m largest")
    assert err.max() < 1.5
