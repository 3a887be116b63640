"""PX4's own flight logs (ULog) as a second witness of where the vehicles were.

A swarm flying the real PX4 judges its separation live, from what the vehicles tell it over
MAVLink and through a clock map it fitted itself; an error in that chain (a frame, an origin,
a clock) would show up as a wrong figure nobody can see. PX4 logs SIH's ground truth
(``vehicle_local_position_groundtruth``) into each instance's ULog on its own boot clock; read
back here, independently of the MAVLink path, it gives the same figures from PX4's side.

Frames: every local topic is NED about its own reference (``ref_lat``/``ref_lon``/``ref_alt``,
SIH's ``SIH_LOC_LAT0/LON0/H0`` for the truth, EKF2's origin for the estimate), and the two differ
by metres. Each sample is placed through its own reference into the world (ENU, metres, about
the world's ``geo_origin``) by PX4's projection (:mod:`.frames`), so an estimator that moves its
origin mid-flight is followed. Times: PX4 seconds (``timestamp`` / 1e6, its boot clock, which
runs slow in lockstep SITL) until :func:`on_wall_clock` maps them through a node's clock map.

pyulog is an optional dependency (the ``px4`` extra), imported when a log is read.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from uavmpc.drivers.px4.frames import enu_to_geodetic, geodetic_to_enu, ned_to_enu
from uavmpc.drivers.px4.truth import Track, closest_by_pair, resample, time_grid

__all__ = ["ESTIMATE_TOPIC", "TRUTH_TOPIC", "Track", "ULogError", "closest_by_pair",
           "on_wall_clock", "read_estimate", "read_truth", "swarm_truth"]

#: SIH's ground truth, NED about SIH's home (logged at about 50 Hz).
TRUTH_TOPIC = "vehicle_local_position_groundtruth"
#: EKF2's estimate, NED about the estimator's own origin.
ESTIMATE_TOPIC = "vehicle_local_position"

_PYULOG_HINT = "reading PX4 flight logs needs pyulog: pip install 'uavmpc[px4]'"


class ULogError(ValueError):
    """A file that is not a readable PX4 flight log, or lacks what was asked of it; the
    message is one line naming the file."""


def _datasets(path: str | Path, topics: tuple[str, ...]) -> dict[str, dict[str, np.ndarray]]:
    """The fields of each of ``topics`` (its first instance) in the ULog at ``path``."""
    try:
        from pyulog import ULog
    except ImportError as exc:
        raise ImportError(_PYULOG_HINT) from exc
    p = Path(path)
    if not p.is_file():
        raise ULogError(f"{path}: no such flight log")
    try:
        log = ULog(str(p), list(topics))
    except Exception as exc:  # pyulog's ULogException, and OSError/IndexError on garbage
        raise ULogError(f"{path}: not a PX4 flight log (ULog): "
                        f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                        ) from None
    found: dict[str, dict[str, np.ndarray]] = {}
    for d in sorted(log.data_list, key=lambda d: d.multi_id):
        found.setdefault(d.name, d.data)
    missing = [t for t in topics if t not in found or "timestamp" not in found[t]]
    if missing:
        # a topic PX4 subscribed has its format in the header even if no sample followed
        declared = [t for t in missing if t in log.message_formats]
        why = (" (declared but no sample logged: cut short?)" if declared == missing
               else "")
        raise ULogError(f"{path}: no {', '.join(missing)} in this flight log{why}")
    return found


_PLACE_FIELDS = ("timestamp", "x", "y", "z", "ref_lat", "ref_lon", "ref_alt")


def _place(data: dict[str, np.ndarray], geo_origin: tuple[float, float, float],
           path: str | Path, topic: str) -> Track:
    """A local-position topic's referenced samples as a world ENU track: each placed through
    its own reference, in PX4 seconds."""
    lacking = [f for f in _PLACE_FIELDS if f not in data]
    if lacking:
        raise ULogError(f"{path}: {topic} has no field {', '.join(lacking)} (another PX4 "
                        "message version?)")
    keep = _referenced(data)
    t = data["timestamp"].astype(np.int64)
    ned = np.stack([data[k].astype(float) for k in ("x", "y", "z")], axis=-1)
    ref = np.stack([data[k].astype(float) for k in ("ref_lat", "ref_lon", "ref_alt")], axis=-1)
    keep = keep & np.all(np.isfinite(ned), axis=1) & np.all(np.isfinite(ref), axis=1)
    t, ned, ref = t[keep], ned[keep], ref[keep]
    # A log's time stamps only grow, but a topic published twice in one microsecond would
    # make an interpolation ambiguous: the first sample of each stamp is kept.
    t, first = np.unique(t, return_index=True)
    ned, ref = ned[first], ref[first]
    world = np.empty_like(ned)
    # Few distinct references (SIH: one; EKF2: one per origin reset), each mapped as a block.
    refs, which = np.unique(ref, axis=0, return_inverse=True)
    which = which.reshape(-1)
    for k, r in enumerate(refs):
        rows = which == k
        if not -90.0 <= r[0] <= 90.0:
            raise ULogError(f"{path}: {topic} has a reference latitude of {r[0]!r}")
        lat, lon, alt = enu_to_geodetic(ned_to_enu(ned[rows]), (r[0], r[1], r[2]))
        world[rows] = geodetic_to_enu(lat, lon, alt, geo_origin)
    return Track(t * 1e-6, world)


def read_truth(path: str | Path, geo_origin: tuple[float, float, float]) -> Track:
    """SIH's ground truth in the ULog at ``path``: world ENU [m] about ``geo_origin``
    ``(lat_deg, lon_deg, alt_m AMSL)``, times in PX4 seconds. Raises :class:`ULogError` (not
    a ULog, no truth topic: a PX4 without SIH logs none) and ``ImportError`` without pyulog."""
    return _place(_datasets(path, (TRUTH_TOPIC,))[TRUTH_TOPIC], geo_origin, path, TRUTH_TOPIC)


def read_estimate(path: str | Path, geo_origin: tuple[float, float, float]) -> Track:
    """EKF2's position estimate in the ULog at ``path``, placed like :func:`read_truth`.
    Samples before the estimator had a global reference (``ref_lat``/``ref_lon`` not finite
    or zero, which PX4 logs as NaN before its first GNSS fix, or ``xy_global`` false) are
    dropped: they have no place in the world."""
    return _place(_datasets(path, (ESTIMATE_TOPIC,))[ESTIMATE_TOPIC], geo_origin, path,
                  ESTIMATE_TOPIC)


def _referenced(data: dict[str, np.ndarray]) -> npt.NDArray[np.bool_]:
    """The samples whose local frame has a place on the globe (a reference of exactly
    (0, 0) is PX4's "none yet"; either alone is a real place)."""
    lat = data["ref_lat"].astype(float)
    lon = data["ref_lon"].astype(float)
    ok: npt.NDArray[np.bool_] = (np.isfinite(lat) & np.isfinite(lon)
                                 & ~((lat == 0.0) & (lon == 0.0)))
    for flag in ("xy_global", "z_global"):
        if flag in data:
            ok &= data[flag].astype(bool)
    return ok


# --- clocks and separation -------------------------------------------------------------------

def on_wall_clock(track: Track, clock_offset_s: float, clock_rate: float) -> Track:
    """``track`` with its PX4 times on our Unix clock: ``clock_offset_s + clock_rate · t``
    (a node's clock map, :class:`~.vehicle.Px4Vehicle` ``report()``)."""
    offset, rate = float(clock_offset_s), float(clock_rate)
    if not (math.isfinite(offset) and math.isfinite(rate) and rate > 0.0):
        raise ValueError(f"clock map: offset must be finite and rate positive, got "
                         f"{clock_offset_s!r}, {clock_rate!r}")
    return Track(offset + rate * track.t_s, track.position_m)


# --- a swarm run -----------------------------------------------------------------------------

def _uav_tracks(run: Path, uav: str, details: dict[str, Any],
                origin: tuple[float, float, float]
                ) -> tuple[dict[str, Any], tuple[Track, Track] | None]:
    """One UAV of a run: what its entry of :func:`swarm_truth` says (its ULog, its truth's
    samples and largest gap, or why it could not be read) and its (truth, estimate) tracks
    on the wall clock, or None."""
    entry: dict[str, Any] = {}
    try:
        path = _ulog_path(run, uav, (details.get("px4") or {}).get("ulog"))
        entry["ulog"] = str(path)
        vehicle = (details.get("node") or {}).get("vehicle") or {}
        offset, rate = vehicle.get("clock_offset_s"), vehicle.get("clock_rate", 1.0)
        if offset is None:
            raise ValueError("its node reported no clock map (clock_offset_s): PX4 "
                             "stamps cannot be placed on our clock")
        data = _datasets(path, (TRUTH_TOPIC, ESTIMATE_TOPIC))
        tr = on_wall_clock(_place(data[TRUTH_TOPIC], origin, path, TRUTH_TOPIC), offset, rate)
        es = on_wall_clock(_place(data[ESTIMATE_TOPIC], origin, path, ESTIMATE_TOPIC),
                           offset, rate)
    except (ValueError, TypeError, OSError) as exc:  # ULogError is a ValueError
        entry["error"] = str(exc)
        return entry, None
    entry["truth_samples"] = int(tr.t_s.size)
    entry["truth_max_gap_s"] = (round(float(np.diff(tr.t_s).max()), 4)
                                if tr.t_s.size > 1 else None)
    return entry, (tr, es)


def _truth_window(run: Path, truth_section: object, truth: dict[str, Track]
                  ) -> tuple[float, float, str]:
    """The window [t0, t1] (wall clock [s]) a run's truth is judged over, and where it came
    from: the swarm's own, else the overlap of the truth tracks (NaN without any)."""
    window = (truth_section.get("window_unix_s") if isinstance(truth_section, dict)
              else None)
    spans = [tr.span_s for tr in truth.values() if tr.t_s.size]
    if window is not None:
        try:
            t0, t1 = (float(v) for v in window)
        except (TypeError, ValueError):
            raise ValueError(f"{run}: sections.truth.window_unix_s must be [t0, t1], got "
                             f"{window!r}") from None
        return t0, t1, "sections.truth.window_unix_s"
    if spans:
        return (max(s[0] for s in spans), min(s[1] for s in spans),
                "overlap of the truth tracks")
    return math.nan, math.nan, "none: no truth track was read"


def swarm_truth(run_dir: str | Path, step_s: float = 0.02) -> dict[str, Any]:
    """A real-PX4 swarm run's separation as PX4's own logs saw it.

    Reads ``run_dir/summary.json`` (a ``uavmpc swarm --px4-sitl`` run): each UAV's ULog, its
    node's clock map and the world's ``geo_origin``; over the window the swarm judged
    (``sections.truth.window_unix_s``, else the overlap of every truth track), returns

    - ``closest_by_pair_m``: ``{"a-b": m}`` by SIH's truth, keys as the summary's (``None``
      for a pair lacking a track or overlap), and ``min_distance_m``;
    - ``uavs``: per UAV its ULog, truth sample count and largest gap [s], and EKF2's error
      against the truth on the same grid: ``horizontal_rms_m``, ``vertical_max_m``
      (absolute), or ``error`` saying why the UAV could not be read;
    - ``window_unix_s`` and ``window_source``.

    Raises ``ValueError`` (one line) for a run folder without a readable summary or not
    flown on the real PX4."""
    run = Path(run_dir)
    summary = _load_summary(run)
    sections = summary.get("sections") or {}
    try:
        geo_origin = tuple(float(v) for v in sections["px4_sitl"]["geo_origin"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{run}: summary.json has no sections.px4_sitl.geo_origin (not a "
                         "swarm flown on the real PX4 with --px4-sitl)") from None
    if len(geo_origin) != 3:
        raise ValueError(f"{run}: sections.px4_sitl.geo_origin must be [lat, lon, alt], got "
                         f"{list(geo_origin)}")
    origin = (geo_origin[0], geo_origin[1], geo_origin[2])
    uav_ids = list(summary.get("uavs") or {})
    truth: dict[str, Track] = {}
    estimate: dict[str, Track] = {}
    per_uav: dict[str, dict[str, Any]] = {}
    for uav in uav_ids:
        details = (summary["uavs"][uav] or {}).get("details") or {}
        per_uav[uav], tracks = _uav_tracks(run, uav, details, origin)
        if tracks is not None:
            truth[uav], estimate[uav] = tracks
    t0, t1, source = _truth_window(run, sections.get("truth"), truth)
    pairs = [(uav_ids[i], b) for i in range(len(uav_ids)) for b in uav_ids[i + 1:]]
    closest: dict[tuple[str, str], float] = {}
    if truth and math.isfinite(t0) and math.isfinite(t1) and t1 >= t0:
        closest = closest_by_pair(truth, t0, t1, step_s)
        grid = time_grid(t0, t1, step_s)
        for uav, tr in truth.items():
            per_uav[uav].update(_estimate_error(tr, estimate[uav], grid))
    by_pair = {f"{a}-{b}": (round(closest[(a, b)], 3) if (a, b) in closest else None)
               for a, b in sorted(pairs)}
    return {
        "source": f"PX4 ULog {TRUTH_TOPIC} (SIH), on each node's clock map",
        "window_unix_s": [t0, t1] if math.isfinite(t0) and math.isfinite(t1) else None,
        "window_source": source,
        "closest_by_pair_m": by_pair,
        "min_distance_m": round(min(closest.values()), 3) if closest else None,
        "uavs": per_uav,
    }


def _estimate_error(truth: Track, estimate: Track, grid: np.ndarray) -> dict[str, Any]:
    """EKF2 against the truth on ``grid`` where both have samples: horizontal RMS, largest
    vertical error [m]."""
    err = resample(estimate, grid) - resample(truth, grid)
    both = np.all(np.isfinite(err), axis=1)
    if not both.any():
        return {"estimate_compared_s": 0.0, "horizontal_rms_m": None, "vertical_max_m": None}
    err = err[both]
    return {
        "estimate_compared_s": round(float(np.ptp(grid[both])), 3),
        "horizontal_rms_m": round(float(np.sqrt(np.mean(err[:, 0] ** 2 + err[:, 1] ** 2))), 4),
        "vertical_max_m": round(float(np.abs(err[:, 2]).max()), 4),
    }


def _load_summary(run: Path) -> dict[str, Any]:
    path = run / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{run}: no summary.json (not a run folder)") from None
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: unreadable: {exc}") from None
    if not isinstance(summary, dict):
        raise ValueError(f"{path}: not a JSON object")
    return summary


def _ulog_path(run: Path, uav: str, recorded: str | None) -> Path:
    """The ULog the summary names, found where it was written or inside the run folder (a run
    written with a relative ``--out`` and read from elsewhere, or moved)."""
    if not recorded:
        raise ULogError(f"{run}: UAV {uav}'s PX4 wrote no flight log (details.px4.ulog)")
    p = Path(recorded)
    tail = p.parts[-3:]  # log/<date>/<name>.ulg
    for candidate in (p, run / p, run / "px4" / uav / Path(*tail)):
        if candidate.is_file():
            return candidate
    raise ULogError(f"{recorded}: no such flight log (UAV {uav})")
