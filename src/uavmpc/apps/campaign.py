"""Statistical campaigns (SPEC §7): many seeded random_walk trials, resumable, in parallel.

A campaign lives in one folder ``DIR``:

- ``campaign.json``: the parameters that define the trials (UAVs, area, avoidance, link, wind,
  trial length, seed). Re-running with other parameters in the same folder is refused.
- ``trials.jsonl``: one JSON line per finished trial, appended (flushed and fsynced) as soon as
  the trial ends. Re-running the same command skips the trials already there, so a crash or
  Ctrl-C loses nothing but the trials in flight.
- ``runs.jsonl``: the wall time of each invocation that ran trials (the report's ``wall_s`` is
  their sum).
- ``report.json``, ``report.md``, ``ttc_cdf.png``, ``min_distance_hist.png``: the aggregate;
  ``report.html`` the same in one self-contained page with every trial, sortable, and
  ``logs/trial_<index>.mcap`` the flight logs of the closest trials, re-flown from their seeds.

Trial ``i`` draws its seeds from ``numpy.random.SeedSequence(seed, spawn_key=(i,))`` (the same
as ``SeedSequence(seed).spawn(n)[i]``): one for the scenario's starts and waypoints, one for the
world (link and wind). The report aggregates the trials sorted by index, so it is bit-identical
(apart from ``wall_s`` and ``trial_wall_s``) for any number of workers and any interruption
pattern.

Without avoidance a trial runs until its first collision or ``cap_s`` simulated seconds (the
world is run in chunks and stopped at the first collision; chunked runs are bit-identical to one
run). With avoidance a trial flies ``trial_s`` seconds and records its collisions and the
minimal distance between any two UAVs.

Percentiles of the time to first collision are those of the empirical CDF (``inverted_cdf``: a
percentile is a sample value) over all trials, a trial without collision counting as "later
than its length" (right-censored). A percentile that falls among censored trials is reported as
``null`` (``report.md`` shows ``> cap``); all are ``null`` when no trial collided.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.config import ConfigError
from uavmpc.scenarios.faults import FaultSpec

FORMAT = 1
PERCENTILES = (50, 75, 95, 99)
#: Without avoidance, the world is run this many simulated seconds at a time between checks
#: for a collision.
CHUNK_S = 5.0
CAMPAIGN_FILE = "campaign.json"
TRIALS_FILE = "trials.jsonl"
#: One line per invocation that ran trials: its wall time (the report's ``wall_s`` is their sum,
#: so a campaign resumed after Ctrl-C reports all the time it took, not its last part).
RUNS_FILE = "runs.jsonl"


class CampaignError(ConfigError):
    """A campaign that cannot run as asked (the message says why and what to do)."""


@dataclass(frozen=True)
class TrialJob:
    """Everything a worker needs to fly one trial (picklable)."""

    index: int
    scenario_seed: int
    world_seed: int
    uavs: int
    area_m: float
    height_m: float
    avoidance: bool
    loss: float
    latency_s: float
    jitter_s: float
    wind_mps: float
    duration_s: float
    #: The active fields of a :class:`~uavmpc.scenarios.faults.FaultSpec` (none: a clean run).
    faults: dict[str, Any] = field(default_factory=dict)
    #: :class:`~uavmpc.avoidance.AvoidanceParams` fields that differ from the defaults.
    avoidance_params: dict[str, Any] = field(default_factory=dict)
    #: The world's launch check (longest wait at the start [s]; None: set off at once).
    launch_check_s: float | None = None


def trial_seeds(seed: int, index: int) -> tuple[int, int]:
    """(scenario seed, world seed) of trial ``index`` of a campaign seeded ``seed``."""
    words = np.random.SeedSequence(int(seed), spawn_key=(int(index),)).generate_state(
        2, np.uint32)
    return int(words[0]), int(words[1])


def trial_job(params: dict[str, Any], index: int,
              avoidance_params: dict[str, Any] | None = None) -> TrialJob:
    """Trial ``index`` of the campaign with ``params`` (its ``campaign.json`` parameters), to
    fly again with :func:`run_trial`; ``avoidance_params`` replace the campaign's own (a
    replay with another rule)."""
    s, w = trial_seeds(params["seed"], index)
    avoid = bool(params["avoidance"])
    lc = params.get("launch_check_s")
    return TrialJob(index, s, w, params["uavs"], float(params["area_m"]),
                    float(params["height_m"]), avoid, params["loss"], params["latency_s"],
                    params["jitter_s"], float(params["wind_mps"]),
                    float(params["trial_s" if avoid else "cap_s"]),
                    dict(params.get("faults", {})),
                    dict(params.get("avoidance_params", {}) if avoidance_params is None
                         else avoidance_params),
                    None if lc is None else float(lc))


def run_trial(job: TrialJob, log_path: Path | None = None) -> dict[str, Any]:
    """Fly one trial; returns its JSON record. ``log_path``: also write its flight log there
    (the flight is the same)."""
    from uavmpc.drivers.world import World, world_faults
    from uavmpc.scenarios import LinkSettings
    from uavmpc.scenarios.faults import draw_faults
    from uavmpc.scenarios.random_walk import random_walk

    wall0 = time.perf_counter()
    spec = FaultSpec(**job.faults)
    link = LinkSettings(latency_s=job.latency_s, jitter_s=job.jitter_s, loss=job.loss,
                        burst_len=spec.burst_len)
    sc = random_walk(job.uavs, job.area_m, job.height_m, job.duration_s, job.scenario_seed,
                     link=link)
    table = dict(job.avoidance_params)
    if spec.time_reference is not None:
        table["time_reference"] = spec.time_reference
    if table:
        sc = dataclasses.replace(sc, avoidance={**sc.avoidance, **table})
    faults = draw_faults(spec, [u.uav_id for u in sc.uavs], job.duration_s, 0.0,
                         job.world_seed)
    recorder = None
    if log_path is not None:
        from uavmpc.log import FlightRecorder

        recorder = FlightRecorder(log_path, [u.uav_id for u in sc.uavs],
                                  {"campaign_trial": job.index,
                                   "scenario_seed": job.scenario_seed,
                                   "world_seed": job.world_seed})
    world = World(sc, avoidance=job.avoidance, seed=job.world_seed, link=link,
                  wind_mps=job.wind_mps, launch_check_s=job.launch_check_s,
                  recorder=recorder, **world_faults(faults))
    try:
        return _fly_trial(job, sc, world, faults, wall0)
    finally:
        if recorder is not None:
            recorder.close()


def _fly_trial(job: TrialJob, sc: Any, world: Any, faults: Any, wall0: float
               ) -> dict[str, Any]:
    from uavmpc.scenarios.random_walk import waypoints_reached

    if job.avoidance:
        res = world.run(job.duration_s)
        collisions = [(c.t, c.a, c.b, c.distance_m) for c in res.collisions]
        dmin = float(res.min_distance_m.min())
        sim_s = res.duration_s
    else:  # run in chunks, stop at the first collision
        collisions, dmin, sim_s = [], math.inf, 0.0
        total = round(job.duration_s / world.period_s)
        chunk = max(1, round(CHUNK_S / world.period_s))
        done = 0
        while done < total and not collisions:
            k = min(chunk, total - done)
            res = world.run(k * world.period_s)
            done += k
            collisions = [(c.t, c.a, c.b, c.distance_m) for c in res.collisions]
            d = res.min_distance_m
            if collisions:  # the trial ends at the first collision
                d = d[res.t_s <= collisions[0][0] + 1e-9]
            dmin = min(dmin, float(d.min()))
        sim_s = done * world.period_s
        if collisions:  # flight time ends at the first collision, and so does the count
            sim_s = collisions[0][0]
            collisions = [c for c in collisions if c[0] <= sim_s + 1e-9]
    first = collisions[0] if collisions else None
    extra: dict[str, Any] = {}
    if job.avoidance:  # without, a trial ends at its first collision: no goals to count
        reached, due = waypoints_reached(sc, res.t_s, res.positions_m)
        extra = {"waypoints_reached": reached, "waypoints_due": due}
    if job.faults:
        extra["faults"] = faults.summary()
    return {
        "index": job.index,
        "scenario_seed": job.scenario_seed,
        "world_seed": job.world_seed,
        "sim_s": sim_s,
        "collisions": len(collisions),
        "first_collision_s": first[0] if first else None,
        "first_collision_pair": [first[1], first[2]] if first else None,
        "min_distance_m": dmin,
        "wall_s": time.perf_counter() - wall0,
        **extra,
    }


# ---------------------------------------------------------------------------- executors
class _Serial:
    """Runs trials in this process, one at a time (workers = 1)."""

    capacity = 1

    def __init__(self) -> None:
        self._queue: list[TrialJob] = []

    def submit(self, job: TrialJob) -> None:
        self._queue.append(job)

    def pending(self) -> int:
        return len(self._queue)

    def wait(self) -> list[dict[str, Any]]:
        return [run_trial(self._queue.pop(0))]

    def close(self, cancel: bool = False) -> None:
        self._queue.clear()


class _Pool:
    """A local process pool."""

    def __init__(self, workers: int) -> None:
        self.capacity = 2 * workers
        self._ex = cf.ProcessPoolExecutor(max_workers=workers)
        self._futures: set[cf.Future] = set()

    def submit(self, job: TrialJob) -> None:
        self._futures.add(self._ex.submit(run_trial, job))

    def pending(self) -> int:
        return len(self._futures)

    def wait(self) -> list[dict[str, Any]]:
        done, self._futures = cf.wait(self._futures, return_when=cf.FIRST_COMPLETED)
        return [f.result() for f in done]

    def close(self, cancel: bool = False) -> None:
        self._ex.shutdown(wait=not cancel, cancel_futures=cancel)


class _Ray:
    """A Ray cluster (``address``: 'auto', 'local' for a fresh local one, or ray://host:port)."""

    def __init__(self, address: str) -> None:
        try:
            import ray
        except ImportError:
            raise CampaignError(
                "--ray needs Ray, which is not installed: pip install 'uavmpc[cluster]'"
            ) from None
        self._ray = ray
        if not ray.is_initialized():
            # "local" is Ray's own word for "always start a new local instance" (None would
            # attach to a cluster that `ray start` left running on this machine)
            try:
                ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
            except (ConnectionError, ValueError) as exc:
                raise CampaignError(f"--ray {address}: cannot connect to Ray ({exc})") from None
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.capacity = 2 * max(cpus, 1)
        self._remote = ray.remote(num_cpus=1)(run_trial)
        self._refs: list[Any] = []

    def submit(self, job: TrialJob) -> None:
        self._refs.append(self._remote.remote(job))

    def pending(self) -> int:
        return len(self._refs)

    def wait(self) -> list[dict[str, Any]]:
        done, self._refs = self._ray.wait(self._refs, num_returns=1)
        return list(self._ray.get(done))

    def close(self, cancel: bool = False) -> None:
        if cancel:
            for ref in self._refs:
                self._ray.cancel(ref, force=True)
        self._refs = []


# ------------------------------------------------------------------------------ storage
def _check_parameters(out: Path, params: dict[str, Any]) -> None:
    path = out / CAMPAIGN_FILE
    if path.exists():
        try:
            stored = json.loads(path.read_text())["parameters"]
        except (ValueError, KeyError, TypeError) as exc:
            raise CampaignError(f"{path}: unreadable campaign file ({exc})") from None
        if stored != params:
            diff = ", ".join(f"{k}: {stored.get(k)!r} there, {params.get(k)!r} now"
                             for k in sorted(set(stored) | set(params))
                             if stored.get(k) != params.get(k))
            raise CampaignError(
                f"{out} holds a campaign with other parameters ({diff}); use another --out "
                f"folder, or the same parameters to continue it")
        return
    from uavmpc import __version__

    path.write_text(json.dumps({"format": FORMAT, "version": __version__,
                                "parameters": params}, indent=2) + "\n")


def load_trials(out_dir: str | Path, seed: int) -> dict[int, dict[str, Any]]:
    """The finished trials of the campaign in ``out_dir`` (a torn last line is dropped)."""
    path = Path(out_dir) / TRIALS_FILE
    if not path.exists():
        return {}
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    if end < len(data):  # a crash mid-write: drop the partial line so appends stay valid
        with open(path, "r+b") as f:
            f.truncate(end)
        data = data[:end]
    trials: dict[int, dict[str, Any]] = {}
    for n, line in enumerate(data.decode().splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            i = int(rec["index"])
        except (ValueError, KeyError, TypeError) as exc:
            raise CampaignError(f"{path}:{n}: not a trial record ({exc})") from None
        if (rec.get("scenario_seed"), rec.get("world_seed")) != trial_seeds(seed, i):
            raise CampaignError(f"{path}:{n}: trial {i} has seeds that do not derive from "
                                f"the campaign seed {seed}; the file belongs elsewhere")
        trials.setdefault(i, rec)
    return trials


def _append(f: Any, rec: dict[str, Any]) -> None:
    f.write(json.dumps(rec) + "\n")
    f.flush()
    os.fsync(f.fileno())


# ------------------------------------------------------------------------------ progress
class _Progress:
    def __init__(self, enabled: bool, stream: Any = None) -> None:
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.t0 = time.perf_counter()
        self.width = 0

    def show(self, done: int, total: int | None, sim_h: float, new: int) -> None:
        if not self.enabled:
            return
        el = time.perf_counter() - self.t0
        tot = f"{total}" if total is not None else "?"
        eta = "?"
        if new > 0 and total is not None:
            eta = _hms(el / new * max(total - done, 0))
        frac = done / total if total else 0.0
        bar = "#" * int(20 * min(frac, 1.0))
        line = (f"\r[{bar:<20}] {done}/{tot} trials, {sim_h:.2f} h simulated, "
                f"{_hms(el)} elapsed, ETA {eta}")
        self.width = max(self.width, len(line))
        self.stream.write(line.ljust(self.width))
        self.stream.flush()

    def end(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()


def _hms(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


# ------------------------------------------------------------------------------ selection
def _selected(trials: dict[int, dict[str, Any]], n_trials: int | None,
              target_s: float | None) -> tuple[list[dict[str, Any]], bool]:
    """The trials the report covers (an index prefix) and whether that prefix is complete."""
    out: list[dict[str, Any]] = []
    total = 0.0
    i = 0
    while True:
        if n_trials is not None and i >= n_trials:
            return out, True
        if target_s is not None and total >= target_s - 1e-9:
            return out, True
        rec = trials.get(i)
        if rec is None:
            return out, False
        out.append(rec)
        total += rec["sim_s"]
        i += 1


def _execute(out: Path, jobs: Callable[[int], TrialJob], trials: dict[int, dict[str, Any]],
             n_trials: int | None, target_s: float | None, max_trial_s: float, executor: Any,
             progress: _Progress) -> None:
    """Runs the missing trials until the selection is complete."""
    in_flight: set[int] = set()
    nxt = 0
    new = 0

    def status() -> None:
        sel, _ = _selected(trials, n_trials, target_s)
        sim_h = sum(r["sim_s"] for r in sel) / 3600.0
        total = n_trials
        if total is None and target_s is not None:
            mean = (sum(r["sim_s"] for r in trials.values()) / len(trials)) if trials else 0
            total = max(len(sel), math.ceil(target_s / mean)) if mean > 0 else None
        progress.show(len(sel), total, sim_h, new)

    def want_more() -> bool:
        if n_trials is not None:
            return nxt < n_trials
        # hours: submit while the done prefix plus in-flight trials at their longest might
        # still fall short of the target
        assert target_s is not None
        bound = sum(trials[i]["sim_s"] if i in trials else max_trial_s for i in range(nxt))
        return bound < target_s - 1e-9

    status()
    with open(out / TRIALS_FILE, "a") as f:
        try:
            while True:
                while executor.pending() < executor.capacity and want_more():
                    if nxt not in trials:
                        executor.submit(jobs(nxt))
                        in_flight.add(nxt)
                    nxt += 1
                if not executor.pending():
                    break
                for rec in executor.wait():
                    in_flight.discard(rec["index"])
                    trials[rec["index"]] = rec
                    _append(f, rec)
                    new += 1
                    status()
        except BaseException:
            executor.close(cancel=True)
            progress.end()
            raise
    executor.close()
    progress.end()


# ------------------------------------------------------------------------------ report
def _percentiles(times: list[float | None]) -> dict[str, float | None]:
    """Percentiles of the time to first collision; a trial without one counts as later than
    any, so a percentile beyond the share of trials with a collision is None (all None when
    no trial collided, as the report's schema asks)."""
    if not any(t is not None for t in times):
        return {f"p{q}": None for q in PERCENTILES}
    x = np.array([math.inf if t is None else t for t in times])
    out = {}
    for q in PERCENTILES:
        v = float(np.percentile(x, q, method="inverted_cdf"))
        out[f"p{q}"] = v if math.isfinite(v) else None
    return out


def aggregate(selected: list[dict[str, Any]], params: dict[str, Any],
              wall_s: float) -> dict[str, Any]:
    """The report dictionary of the trials ``selected`` (sorted by index)."""
    from uavmpc import __version__

    avoidance = params["avoidance"]
    length = params["trial_s" if avoidance else "cap_s"]
    firsts = [r["first_collision_s"] for r in selected]
    dmins = np.array([r["min_distance_m"] for r in selected])
    with_collision = sum(1 for t in firsts if t is not None)
    return {
        "scenario": "random_walk",
        "version": __version__,
        "seed": params["seed"],
        "avoidance": avoidance,
        "parameters": params,
        "trials": len(selected),
        "simulated_hours": float(sum(r["sim_s"] for r in selected) / 3600.0),
        "collisions": int(sum(r["collisions"] for r in selected)),
        "trials_with_collision": with_collision,
        "trials_censored": len(selected) - with_collision,
        "censored_at_s": length,
        "time_to_first_collision_s": _percentiles(firsts),
        "min_distance_m": float(dmins.min()) if dmins.size else None,
        "min_distance_per_trial_m": (
            {f"p{q}": float(np.percentile(dmins, q, method="inverted_cdf"))
             for q in (1, 5, 50)} if dmins.size else None),
        "wall_s": wall_s,
        "trial_wall_s": float(sum(r["wall_s"] for r in selected)),
        **_goals(selected),
    }


def _goals(selected: list[dict[str, Any]]) -> dict[str, Any]:
    """Waypoints reached over the trials that counted them (campaigns before they were
    counted have none)."""
    counted = [r for r in selected if "waypoints_due" in r]
    if not counted or len(counted) != len(selected):
        return {}
    reached = sum(r["waypoints_reached"] for r in counted)
    due = sum(r["waypoints_due"] for r in counted)
    return {"waypoints_reached": reached, "waypoints_due": due,
            "waypoints_reached_fraction": reached / due if due else None}


def _fmt_ttc(report: dict[str, Any], key: str) -> str:
    p = report["time_to_first_collision_s"]
    if p is None or not report["collisions"]:
        return "no collision"
    v = p[key]
    return f"{v:.1f} s" if v is not None else f"> {report['censored_at_s']:g} s"


def report_rows(*reports: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The rows of the report table in the reference design's layout: (quantity, without
    avoidance, with avoidance); each report fills its own column (give one report, or one of
    each to merge two campaigns)."""
    cols: dict[bool, dict[str, Any] | None] = {False: None, True: None}
    for r in reports:
        cols[bool(r["avoidance"])] = r

    def cell(avoid: bool, f: Callable[[dict[str, Any]], str]) -> str:
        r = cols[avoid]
        return f(r) if r is not None else "–"

    rows: list[tuple[str, Callable[[dict[str, Any]], str]]] = [
        ("trials", lambda r: str(r["trials"])),
        ("simulated hours", lambda r: f"{r['simulated_hours']:.2f}"),
        ("collisions", lambda r: str(r["collisions"])),
        ("trials with a collision", lambda r: f"{r['trials_with_collision']} / {r['trials']}"),
    ]
    rows += [(f"time to first collision, {q} %", lambda r, q=q: _fmt_ttc(r, f"p{q}"))
             for q in PERCENTILES]
    rows += [
        ("min. distance between UAVs", lambda r: f"{r['min_distance_m']:.2f} m"),
        ("UAVs / area", lambda r: f"{r['parameters']['uavs']} / "
                                  f"{r['parameters']['area_m']:g} m"),
        ("trial length", lambda r: f"{r['censored_at_s']:g} s"),
        ("link loss / latency", lambda r: f"{r['parameters']['loss']:g} / "
                                          f"{r['parameters']['latency_s']:g} s"),
        ("wind", lambda r: f"{r['parameters']['wind_mps']:g} m/s"),
        ("seed", lambda r: str(r["seed"])),
    ]
    if any("waypoints_due" in r for r in reports):
        rows.insert(-5, ("per-trial min. distance, 1 % / 5 % / 50 %", lambda r: (
            " / ".join(f"{r['min_distance_per_trial_m'][f'p{q}']:.2f}" for q in (1, 5, 50))
            + " m")))
        rows.insert(-5, ("waypoints reached", lambda r: (
            f"{r['waypoints_reached']} / {r['waypoints_due']}" if "waypoints_due" in r
            else "–")))
    if any(r["parameters"].get("faults") for r in reports):
        rows.append(("faults", lambda r: ", ".join(
            f"{k} {v}" for k, v in r["parameters"].get("faults", {}).items()) or "none"))
    if any(r["parameters"].get("launch_check_s") is not None for r in reports):
        rows.append(("launch check", lambda r: (
            f"up to {r['parameters']['launch_check_s']:g} s"
            if r["parameters"].get("launch_check_s") is not None else "none")))
    if any(r["parameters"].get("avoidance_params") for r in reports):
        rows.append(("avoidance parameters", lambda r: ", ".join(
            f"{k} {v}" for k, v in r["parameters"].get("avoidance_params", {}).items())
            or "defaults"))
    return [(name, cell(False, f), cell(True, f)) for name, f in rows]


def markdown_table(*reports: dict[str, Any]) -> str:
    """:func:`report_rows` as a Markdown table."""
    lines = ["| random_walk | without avoidance | with avoidance |", "|---|---|---|"]
    lines += [f"| {name} | {a} | {b} |" for name, a, b in report_rows(*reports)]
    return "\n".join(lines) + "\n"


def report_markdown(*reports: dict[str, Any]) -> str:
    head = ("# random_walk campaign\n\nA collision is a 3-D distance between centres below "
            "1 m. Percentiles are those of the empirical CDF over all trials; a trial without "
            "collision counts as later than its length (\"> …\").\n\n")
    return head + markdown_table(*reports)


def merge_reports(*paths: str | Path, out: str | Path | None = None) -> str:
    """Merge the report.json of a campaign without and one with avoidance into one table."""
    reports = [json.loads((Path(p) / "report.json" if Path(p).is_dir() else Path(p))
                          .read_text()) for p in paths]
    text = report_markdown(*reports)
    if out is not None:
        Path(out).write_text(text)
    return text


def _figures(out: Path, selected: list[dict[str, Any]], report: dict[str, Any]) -> None:
    from uavmpc.apps.plots import plt

    title = f"random_walk, {'with' if report['avoidance'] else 'without'} avoidance"
    n = len(selected)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    times = np.sort([r["first_collision_s"] for r in selected
                     if r["first_collision_s"] is not None])
    if times.size:
        levels = np.arange(times.size + 1) / n
        ax.step(np.r_[0.0, times, report["censored_at_s"]], np.r_[levels, levels[-1]],
                where="post")
    else:
        ax.text(0.5, 0.5, f"no collision in {n} trials", transform=ax.transAxes,
                ha="center", va="center")
    ax.set_xlim(0.0, report["censored_at_s"])
    ax.set_ylim(0.0, 1.0)
    ax.set_xlabel("time to first collision [s]")
    ax.set_ylabel("fraction of trials")
    ax.set_title(f"{title}: empirical CDF ({n} trials, censored at "
                 f"{report['censored_at_s']:g} s)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "ttc_cdf.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    d = np.array([r["min_distance_m"] for r in selected])
    if d.size:
        ax.hist(d, bins=min(50, max(5, n // 4)))
    ax.axvline(1.0, color="r", ls=":", label="collision (1 m)")
    ax.set_xlabel("minimal distance between any two UAVs in a trial [m]")
    ax.set_ylabel("trials")
    ax.set_title(f"{title}: per-trial minimal distance")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "min_distance_hist.png", dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------ the runner
def run_campaign(
    out_dir: str | Path,
    *,
    uavs: int = 5,
    avoidance: bool = True,
    hours: float | None = None,
    trials: int | None = None,
    seed: int = 0,
    workers: int | None = None,
    loss: float = 0.0,
    latency: float = 0.05,
    jitter: float = 0.02,
    wind: float = 0.0,
    trial_s: float = 600.0,
    cap_s: float = 600.0,
    area_m: float = 100.0,
    height_m: float = 10.0,
    ray_address: str | None = None,
    progress: bool = True,
    faults: FaultSpec | None = None,
    avoidance_params: dict[str, Any] | None = None,
    launch_check_s: float | None = None,
    logs: int = 3,
) -> dict[str, Any]:
    """Run (or continue) a random_walk campaign in ``out_dir``; returns the report.

    ``faults``: what goes wrong in every trial, drawn per trial from its world seed
    (:mod:`uavmpc.scenarios.faults`). ``avoidance_params``: fields of
    :class:`~uavmpc.avoidance.AvoidanceParams` to fly instead of the defaults (e.g. a larger
    cylinder for a coarser position estimate). ``launch_check_s``: every UAV holds at its
    start until it has heard every other one, at most this long
    (:class:`~uavmpc.drivers.world.World`'s ``launch_check_s``). ``logs``: the ``logs``
    trials with the closest approach are re-flown from their seeds into flight logs
    (``logs/trial_<index>.mcap``; a full campaign's would be gigabytes), linked from
    ``report.html``.

    Stops after ``trials`` trials, or once the trials cover ``hours`` of flight (the smallest
    prefix of trials, by index, whose flight time reaches it). With avoidance a trial lasts
    ``trial_s``; without, until its first collision or ``cap_s``.
    """
    from uavmpc.scenarios import LinkSettings

    _check_campaign_size(hours=hours, trials=trials, uavs=uavs, seed=seed, wind=wind,
                         lengths=(("trial_s", trial_s), ("cap_s", cap_s), ("area_m", area_m),
                                  ("height_m", height_m)))
    link = LinkSettings.from_dict({"loss": loss, "latency_s": latency, "jitter_s": jitter})
    fault_fields, avoidance_table = _check_faults_and_avoidance(faults, avoidance_params,
                                                                uavs=uavs, link_loss=link.loss)
    workers = _check_launch_logs_workers(launch_check_s, logs, workers, trial_s=trial_s)
    length = float(trial_s if avoidance else cap_s)
    params = _campaign_parameters(
        uavs=uavs, area_m=area_m, height_m=height_m, avoidance=avoidance, seed=seed, link=link,
        wind=wind, length=length, fault_fields=fault_fields, avoidance_table=avoidance_table,
        launch_check_s=launch_check_s)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _check_parameters(out, params)
    done = load_trials(out, seed)

    def job(i: int) -> TrialJob:
        return trial_job(params, i)

    target_s = None if hours is None else float(hours) * 3600.0
    wall0 = time.perf_counter()
    executor = _executor(done, trials, target_s, ray_address=ray_address, workers=workers)
    if executor is not None:
        before = len(done)
        try:
            _execute(out, job, done, trials, target_s, length, executor, _Progress(progress))
        finally:  # also when interrupted: the time was spent on this campaign
            with open(out / RUNS_FILE, "a") as f:
                _append(f, {"wall_s": time.perf_counter() - wall0,
                            "new_trials": len(done) - before, "workers": workers,
                            "ray": ray_address})
    selected, complete = _selected(done, trials, target_s)
    assert complete
    return _write_report(out, selected, params, _campaign_wall_s(out, wall0), job, logs)


def _write_report(out: Path, selected: list[dict[str, Any]], params: dict[str, Any],
                  wall_s: float, job: Callable[[int], TrialJob], logs: int) -> dict[str, Any]:
    """Write the selected trials' report, figures, flight logs and page to ``out``."""
    report = aggregate(selected, params, wall_s)
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    (out / "report.md").write_text(report_markdown(report))
    _figures(out, selected, report)
    _write_html(out, report, selected, _flight_logs(out, selected, job, logs))
    return report


def _check_campaign_size(*, hours: float | None, trials: int | None, uavs: int, seed: int,
                         wind: float, lengths: tuple[tuple[str, float], ...]) -> None:
    """Raise a CampaignError for a size, seed, length or wind out of range."""
    if (hours is None) == (trials is None):
        raise CampaignError("give exactly one of hours (--hours) or trials (--trials)")
    if trials is not None and (isinstance(trials, bool) or not isinstance(trials, int)
                               or trials < 1):
        raise CampaignError(f"trials: must be an integer ≥ 1, got {trials!r}")
    if hours is not None and not (math.isfinite(hours) and hours > 0):
        raise CampaignError(f"hours: must be > 0, got {hours}")
    if isinstance(uavs, bool) or not isinstance(uavs, int) or not 2 <= uavs <= 1000:
        raise CampaignError(f"uavs: must be an integer in [2, 1000], got {uavs!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise CampaignError(f"seed: must be a non-negative integer, got {seed!r}")
    for name, v in lengths:
        if not (math.isfinite(v) and v > 0):
            raise CampaignError(f"{name}: must be > 0, got {v}")
    if not (math.isfinite(wind) and wind >= 0):
        raise CampaignError(f"wind: must be ≥ 0, got {wind}")


def _check_faults_and_avoidance(faults: FaultSpec | None,
                                avoidance_params: dict[str, Any] | None, *, uavs: int,
                                link_loss: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """The active fault fields and the avoidance table, checked against the campaign."""
    fault_fields = (faults or FaultSpec()).active()
    if faults is not None:
        faults.check_uavs(uavs)
        if faults.burst_len and not link_loss:
            raise CampaignError("burst loss needs a loss rate: give --loss P with --burst-loss")
    avoidance_table = dict(avoidance_params or {})
    if avoidance_table:
        from uavmpc.avoidance import AvoidanceParams

        AvoidanceParams.from_dict(avoidance_table)  # a bad field fails here, not in a worker
        if faults is not None and faults.time_reference is not None \
                and "time_reference" in avoidance_table:
            raise CampaignError("time_reference: give it once, in the avoidance file or as "
                                "--time-reference")
    return fault_fields, avoidance_table


def _check_launch_logs_workers(launch_check_s: float | None, logs: int, workers: int | None,
                               *, trial_s: float) -> int:
    """Check the launch check, logs and workers; the workers (default: one per CPU)."""
    if launch_check_s is not None and not (math.isfinite(launch_check_s)
                                           and 0.0 <= launch_check_s <= trial_s):
        raise CampaignError(f"launch check: must be a time in [0, trial_s] [s], got "
                            f"{launch_check_s!r}")
    if isinstance(logs, bool) or not isinstance(logs, int) or not 0 <= logs <= 100:
        raise CampaignError(f"logs: must be an integer in [0, 100], got {logs!r}")
    if workers is None:
        workers = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise CampaignError(f"workers: must be an integer ≥ 1, got {workers!r}")
    return workers


def _campaign_parameters(*, uavs: int, area_m: float, height_m: float, avoidance: bool,
                         seed: int, link: Any, wind: float, length: float,
                         fault_fields: dict[str, Any], avoidance_table: dict[str, Any],
                         launch_check_s: float | None) -> dict[str, Any]:
    """The parameters that define a campaign's trials (stored in its campaign.json)."""
    params = {
        "scenario": "random_walk", "uavs": uavs, "area_m": float(area_m),
        "height_m": float(height_m), "avoidance": bool(avoidance), "seed": seed,
        "loss": link.loss, "latency_s": link.latency_s, "jitter_s": link.jitter_s,
        "wind_mps": float(wind),
    }
    # only the length that applies defines the trials
    params["trial_s" if avoidance else "cap_s"] = length
    if fault_fields:  # a clean campaign's parameters stay what they were
        params["faults"] = fault_fields
    if avoidance_table:
        params["avoidance_params"] = avoidance_table
    if launch_check_s is not None:
        params["launch_check_s"] = float(launch_check_s)
    return params


def _executor(done: dict[int, dict[str, Any]], trials: int | None, target_s: float | None, *,
              ray_address: str | None, workers: int) -> Any:
    """Where the missing trials run (Ray, here or a pool); None when none is missing."""
    if _selected(done, trials, target_s)[1]:
        return None
    if ray_address is not None:
        return _Ray(ray_address)
    if workers == 1:
        return _Serial()
    return _Pool(workers)


def _campaign_wall_s(out: Path, wall0: float) -> float:
    """The wall time spent on the campaign over all its runs so far."""
    runs = out / RUNS_FILE
    return (sum(json.loads(line)["wall_s"] for line in runs.read_text().splitlines()
                if line.strip()) if runs.exists() else time.perf_counter() - wall0)


def _flight_logs(out: Path, selected: list[dict[str, Any]], job: Callable[[int], TrialJob],
                 n: int) -> dict[int, str]:
    """The flight logs of the ``n`` closest trials (re-flown from their seeds when missing):
    trial index → path relative to ``out``."""
    closest = sorted(selected, key=lambda r: (r["min_distance_m"], r["index"]))[:n]
    logs = {}
    for rec in closest:
        i = int(rec["index"])
        rel = f"logs/trial_{i}.mcap"
        if not (out / rel).exists():
            part = out / f"{rel}.part"  # a log is there whole or not at all
            run_trial(job(i), part)
            part.rename(out / rel)
        logs[i] = rel
    return logs


def _write_html(out: Path, report: dict[str, Any], selected: list[dict[str, Any]],
                logs: dict[int, str]) -> None:
    from uavmpc.apps.report_html import report_html

    page = report_html(report, report_rows(report), selected,
                       [out / "ttc_cdf.png", out / "min_distance_hist.png"], logs)
    (out / "report.html").write_text(page)


def iter_trials(out_dir: str | Path) -> Iterator[dict[str, Any]]:
    """The trial records of a campaign folder, in file order."""
    path = Path(out_dir) / TRIALS_FILE
    if path.exists():
        for line in path.read_text().splitlines():
            if line.strip():
                yield json.loads(line)


# ------------------------------------------------------------------------------ CLI glue
def build_parser_campaign(subparsers: Any) -> argparse.ArgumentParser:
    """Adds ``campaign random-walk ...`` to the CLI's subparsers; sets ``func``."""
    p = subparsers.add_parser(
        "campaign", help="statistical campaign: many seeded random_walk trials (resumable), "
                         "many landings on the moving deck, or dense traffics flown with and "
                         "without avoidance")
    p.add_argument("kind", choices=["random-walk", "landing", "traffic"],
                   help="the campaign's scenario")
    p.add_argument("--scenario", default="moving_target_landing",
                   help="landing: the landing scenario (built-in name or TOML file)")
    p.add_argument("--speed-kmh", type=float, default=None,
                   help="landing: the car's speed (default: the scenario's)")
    p.add_argument("--duration", type=float, default=None,
                   help="landing, traffic: simulated seconds per flight (default: the "
                        "scenario's)")
    p.add_argument("--uavs", type=int, default=None,
                   help="UAVs per trial (default: random-walk 5, traffic 300)")
    p.add_argument("--avoidance", action=argparse.BooleanOptionalAction, default=True,
                   help="fly with collision avoidance (default) or without")
    stop = p.add_mutually_exclusive_group(required=True)
    stop.add_argument("--hours", type=float, help="total simulated flight hours")
    stop.add_argument("--trials", type=int, help="number of trials")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: CPU count)")
    p.add_argument("--out", default=None,
                   help="campaign folder (default out/campaign-{with,without}-avoidance); "
                        "re-run the same command to continue it")
    p.add_argument("--loss", type=float, default=0.0, help="message loss probability")
    p.add_argument("--latency", type=float, default=0.05, help="link latency [s]")
    p.add_argument("--wind", type=float, default=0.0, help="mean wind along x [m/s]")
    p.add_argument("--trial-s", type=float, default=600.0,
                   help="with avoidance: simulated seconds per trial (default 600)")
    p.add_argument("--cap-s", type=float, default=600.0,
                   help="without avoidance: stop a trial without collision after this")
    p.add_argument("--area", type=float, default=100.0, help="side of the square area [m]")
    p.add_argument("--avoidance-file", default=None, metavar="TOML",
                   help="random-walk: fly the [avoidance] table of this file (any "
                        "AvoidanceParams field) instead of the defaults")
    p.add_argument("--ray", default=None, metavar="ADDRESS",
                   help="run on Ray ('auto', 'local' or ray://host:port); "
                        "pip install 'uavmpc[cluster]'")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--logs", type=int, default=3, metavar="N",
                   help="random-walk: re-fly the N trials with the closest approach into "
                        "flight logs linked from report.html (default 3)")
    add_fault_arguments(p)
    p.set_defaults(func=campaign_command)
    return p


def add_fault_arguments(p: argparse.ArgumentParser) -> None:
    """The fault flags (:mod:`uavmpc.scenarios.faults`) and the launch check, shared by ``run``
    and ``campaign``."""
    g = p.add_argument_group("faults (each drawn per flight from its seed)")
    g.add_argument("--clock-offset", type=float, default=0.0, metavar="S",
                   help="every UAV's clock off by up to ±S seconds")
    g.add_argument("--time-reference", choices=["stamp", "receive"], default=None,
                   help="how receivers judge a prediction's age (default: the scenario's)")
    g.add_argument("--gnss", choices=["none", "single", "rtk"], default="none",
                   help="controllers fly on an observer fed with GNSS-like positions")
    g.add_argument("--burst-loss", type=float, default=0.0, metavar="MEAN_LEN",
                   help="with --loss P: losses in bursts of this mean length (Gilbert channel)")
    g.add_argument("--non-cooperative", type=int, default=0, metavar="K",
                   help="K of the UAVs fly without avoidance (flag down)")
    g.add_argument("--silent", type=int, default=0, metavar="K",
                   help="K of the UAVs' radios go silent at a random time; they fly on")
    s = p.add_argument_group("start-up")
    s.add_argument("--launch-check", type=float, default=None, metavar="S",
                   help="each UAV holds at its start until it has heard every other UAV, at "
                        "most S seconds (default: all set off at once)")


def fault_spec(args: argparse.Namespace) -> FaultSpec:
    """The :class:`FaultSpec` of the fault flags."""
    return FaultSpec(clock_offset_s=args.clock_offset, time_reference=args.time_reference,
                     gnss=args.gnss, burst_len=args.burst_loss,
                     non_cooperative=args.non_cooperative, silent=args.silent)


def _run_from_args(out: str, args: argparse.Namespace) -> dict[str, Any]:
    return run_campaign(out, uavs=5 if args.uavs is None else args.uavs,
                        avoidance=args.avoidance, hours=args.hours,
                        trials=args.trials, seed=args.seed, workers=args.workers,
                        loss=args.loss, latency=args.latency, wind=args.wind,
                        trial_s=args.trial_s, cap_s=args.cap_s, area_m=args.area,
                        ray_address=args.ray, progress=not args.no_progress,
                        faults=fault_spec(args),
                        avoidance_params=avoidance_file(args.avoidance_file),
                        launch_check_s=args.launch_check, logs=args.logs)


def avoidance_file(path: str | None) -> dict[str, Any]:
    """The ``[avoidance]`` table of a TOML file (none: {}); a file without one is an error."""
    if path is None:
        return {}
    from uavmpc.config import read_toml

    table = read_toml(path).get("avoidance")
    if not isinstance(table, dict):
        raise CampaignError(f"{path}: needs an [avoidance] table (AvoidanceParams fields)")
    return table


def _landing_command(args: argparse.Namespace) -> int:
    from uavmpc.apps.landing_campaign import run_landing_campaign

    if args.trials is None:
        raise CampaignError("campaign landing: give --trials N")
    out = args.out or "out/campaign-landing"
    r = run_landing_campaign(out, trials=args.trials, seed=args.seed, scenario=args.scenario,
                             speed_kmh=args.speed_kmh, duration_s=args.duration,
                             workers=args.workers)
    t = r["time_to_land_s"]
    fmt = (lambda v: "–" if v is None else f"{v:.1f} s")  # noqa: E731
    print(f"landing at {r['speed_kmh']:g} km/h: {r['landed']} of {r['trials']} landed "
          f"({100 * r['success_rate']:.0f} %); time to land p5 {fmt(t['p5'])}, "
          f"p50 {fmt(t['p50'])}, p95 {fmt(t['p95'])}, max {fmt(t['p100'])}; "
          f"{r['touchdowns_off_the_deck']} off the deck, {r['hard_touchdowns']} hard, "
          f"{r['not_landed_in_time']} not landed in time")
    print(f"wrote {out}/report.json, trials.jsonl")
    return 0


def _traffic_command(args: argparse.Namespace) -> int:
    from uavmpc.apps.traffic_campaign import report_lines, run_traffic_campaign

    if args.trials is None:
        raise CampaignError("campaign traffic: give --trials N")
    out = args.out or "out/campaign-traffic"
    r = run_traffic_campaign(out, trials=args.trials, uavs=300 if args.uavs is None
                             else args.uavs, seed=args.seed, duration_s=args.duration,
                             workers=args.workers)
    print("\n".join(report_lines(r)))
    print(f"wrote {out}/report.json, trials.jsonl")
    return 0 if r["with_avoidance"]["collisions"] == 0 else 1


def campaign_command(args: argparse.Namespace) -> int:
    if args.kind == "landing":
        return _landing_command(args)
    if args.kind == "traffic":
        return _traffic_command(args)
    out = args.out or f"out/campaign-{'with' if args.avoidance else 'without'}-avoidance"
    try:
        r = _run_from_args(out, args)
    except KeyboardInterrupt:
        n = sum(1 for _ in iter_trials(out))
        print(f"\ninterrupted: {n} finished trial(s) are saved in {out}/{TRIALS_FILE}; run "
              f"the same command again to continue", file=sys.stderr)
        return 130
    ttc = r["time_to_first_collision_s"]
    pct = ", ".join(f"{k} {_fmt_ttc(r, k)}" for k in ttc) if ttc else "none"
    print(f"random_walk, {'with' if r['avoidance'] else 'without'} avoidance: {r['trials']} "
          f"trials, {r['simulated_hours']:.2f} h simulated, {r['collisions']} collision(s), "
          f"closest approach {r['min_distance_m']:.2f} m; time to first collision: {pct}")
    logs = f", logs/ (the {args.logs} closest trials)" if args.logs else ""
    print(f"wrote {out}/report.html, report.json, report.md, ttc_cdf.png, "
          f"min_distance_hist.png{logs}")
    return 0 if (not r["avoidance"] or r["collisions"] == 0) else 1


__all__ = [
    "CampaignError",
    "TrialJob",
    "aggregate",
    "build_parser_campaign",
    "load_trials",
    "markdown_table",
    "merge_reports",
    "run_campaign",
    "run_trial",
    "trial_seeds",
]
