"""Statistical campaigns (SPEC §7): many seeded random_walk trials, resumable, in parallel.

A campaign is a :class:`RandomWalkSpec` and a folder ``DIR`` kept by the one campaign engine
(:mod:`uavmpc.apps.campaign_engine`, shared with the landing and traffic campaigns):

- ``campaign.json``: the spec (UAVs, area, avoidance, link, wind, trial length, seed, faults,
  avoidance parameters, launch check, start from the ground), versioned. Re-running with other
  parameters in the same folder is refused.
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

With ``ground_start`` every UAV starts on the ground and takes off to the walk's height before
its walk (:mod:`uavmpc.scenarios.random_walk`); a trial's length and its time to first collision
still count from t = 0, the climb included (the report gives the walk's start, ``walk_start_s``).

Percentiles of the time to first collision are those of the empirical CDF
(:func:`uavmpc.scenarios.stats.percentile`: a percentile is a sample value) over all trials, a
trial without collision counting as "later than its length" (right-censored). A percentile that
falls among censored trials is reported as ``null`` (``report.md`` shows ``> cap``); all are
``null`` when no trial collided.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from uavmpc.apps.campaign_engine import (
    TRIALS_FILE,
    CampaignError,
    Execution,
    Task,
    iter_trials,
    load_records,
    run_trials,
)
from uavmpc.apps.published import PublishedResult
from uavmpc.avoidance import AvoidanceParams
from uavmpc.config import ConfigError
from uavmpc.scenarios import LinkSettings, Scenario, avoidance_params, changed_fields
from uavmpc.scenarios.faults import FaultSpec
from uavmpc.scenarios.random_walk import (
    ACCEL_MPS2,
    PAPER_TAKEOFF_INTERVAL_S,
    SPEED_MPS,
    WalkVariant,
)
from uavmpc.scenarios.run import RunSettings, RunSpec
from uavmpc.scenarios.stats import bootstrap_interval, percentile

if TYPE_CHECKING:
    from uavmpc.drivers.world import World

PERCENTILES = (50, 75, 95, 99)
#: Without avoidance, the world is run this many simulated seconds at a time between checks
#: for a collision.
CHUNK_S = 5.0


def trial_seeds(seed: int, index: int) -> tuple[int, int]:
    """(scenario seed, world seed) of trial ``index`` of a campaign seeded ``seed``."""
    words = np.random.SeedSequence(int(seed), spawn_key=(int(index),)).generate_state(
        2, np.uint32)
    return int(words[0]), int(words[1])


@dataclass(frozen=True)
class RandomWalkSpec:
    """What every trial of a random-walk campaign flies (validated, frozen; its ``to_json`` is
    the campaign's ``campaign.json`` spec and the report's ``parameters``): the run settings
    ``run`` over a random walk of its own."""

    kind: ClassVar[str] = "random_walk"

    #: How every trial flies (avoidance, link, faults, wind, launch check), its seed the
    #: campaign's: a trial flies it over its own walk with seeds of its own (:func:`trial_run`).
    #: Its link is latency, jitter and loss (a burst length comes with the faults; None: the
    #: walk's); its faults are drawn per trial and its length is ``length_s``, so neither
    #: ``drawn`` nor ``duration_s`` is given.
    run: RunSettings = field(default_factory=RunSettings)
    uavs: int = 5
    area_m: float = 100.0
    height_m: float = 10.0
    #: With avoidance: every trial's length; without: its cap (it ends at its first collision).
    length_s: float = 600.0
    #: The avoidance parameters every UAV flies (a fault's time reference over them).
    avoidance_params: AvoidanceParams = field(default_factory=AvoidanceParams)
    #: Start on the ground and take off to ``height_m`` before the walk (False: start in the
    #: air at ``height_m``, the protocol as it was).
    ground_start: bool = False
    #: How the walk departs from the protocol (take-offs one after another, waypoints drawn
    #: apart, slower limits, counting after the first waypoint); the default does not.
    walk: WalkVariant = field(default_factory=WalkVariant)

    def __post_init__(self) -> None:
        self._check_run()
        if isinstance(self.uavs, bool) or not isinstance(self.uavs, int) or not (
                2 <= self.uavs <= 1000):
            raise CampaignError(f"uavs: must be an integer in [2, 1000], got {self.uavs!r}")
        length = "trial_s" if self.run.avoidance else "cap_s"  # the flag that sets it
        for name in ("length_s", "area_m", "height_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise CampaignError(f"{length if name == 'length_s' else name}: must be > 0, "
                                    f"got {v}")
        if not isinstance(self.ground_start, bool):
            raise CampaignError(f"ground_start: must be true or false, got "
                                f"{self.ground_start!r}")
        if not isinstance(self.walk, WalkVariant):
            raise CampaignError(f"walk: must be a WalkVariant, got {type(self.walk).__name__}")
        if self.walk.takeoff_interval_s and not self.ground_start:
            raise CampaignError("take-offs one after another (--takeoff-interval) need a start "
                                "from the ground (--ground-start)")
        if self.ground_start:
            from uavmpc.scenarios.random_walk import walk_start_s

            walk = walk_start_s(self.height_m) + (self.uavs - 1) * self.walk.takeoff_interval_s
            if walk >= self.length_s:
                raise CampaignError(f"{length}: {self.length_s:g} s ends before the walk, which "
                                    f"begins {walk:.2f} s after the start from the ground")
        try:  # what a trial's RunSpec would refuse, refused before any trial flies
            from uavmpc.scenarios.random_walk import walk_ids

            self.run.check_flight(walk_ids(self.uavs), "random_walk", self.link, self.length_s)
        except ConfigError as exc:
            raise CampaignError(str(exc)) from None

    def _check_run(self) -> None:
        """Refuse a template that ``campaign.json`` could not hold; give it the walk's link."""
        if type(self.run) is not RunSettings:  # a RunSpec's scenario would be ignored
            raise CampaignError(f"run: must be RunSettings (the template every trial flies), "
                                f"got {type(self.run).__name__}")
        if self.run.drawn is not None:
            raise CampaignError("run.drawn: a campaign draws each trial's faults from "
                                "run.faults and the trial's seed; give none")
        if self.run.duration_s is not None:
            raise CampaignError(f"run.duration_s: a trial's length is length_s; give none, "
                                f"got {self.run.duration_s!r}")
        link = self.run.link
        if link is None:  # the walk's, written out so that campaign.json reads back the same
            object.__setattr__(self, "run", self.run.replace(link=LinkSettings()))
        elif link.range_m or link.burst_len:
            raise CampaignError(f"run.link: a campaign's link is its latency, jitter and loss "
                                f"(a burst length comes with run.faults), got range_m="
                                f"{link.range_m:g}, burst_len={link.burst_len:g}")

    @property
    def link(self) -> LinkSettings:
        """The link every trial flies (the template's, the walk's when it gave none)."""
        return self.run.link or LinkSettings()

    def to_json(self) -> dict[str, Any]:
        """The parameters that define the trials (``campaign.json``, the report)."""
        run = self.run
        # flat, the run settings beside the walk's: the format of every campaign before
        params: dict[str, Any] = {
            "scenario": "random_walk", "uavs": self.uavs, "area_m": float(self.area_m),
            "height_m": float(self.height_m), "avoidance": bool(run.avoidance),
            "seed": run.seed, "loss": self.link.loss, "latency_s": self.link.latency_s,
            "jitter_s": self.link.jitter_s, "wind_mps": float(run.wind_mps),
        }
        # only the length that applies defines the trials
        params["trial_s" if run.avoidance else "cap_s"] = float(self.length_s)
        if run.faults.active():  # a clean campaign's parameters stay what they were
            params["faults"] = run.faults.active()
        if changed_fields(self.avoidance_params):
            params["avoidance_params"] = changed_fields(self.avoidance_params)
        if run.launch_check_s is not None:
            params["launch_check_s"] = float(run.launch_check_s)
        if self.ground_start:  # absent: started in the air, as every campaign before it
            params["ground_start"] = True
        if self.walk.changed():  # absent: the protocol's walk
            params["walk"] = self.walk.changed()
        return params

    @classmethod
    def from_json(cls, params: dict[str, Any]) -> RandomWalkSpec:
        """The spec of :meth:`to_json`'s dictionary (a campaign.json's)."""
        avoid = bool(params["avoidance"])
        lc = params.get("launch_check_s")
        run = RunSettings(
            avoidance=avoid, seed=params["seed"],
            link=LinkSettings.from_dict({"loss": params["loss"],
                                         "latency_s": params["latency_s"],
                                         "jitter_s": params["jitter_s"]}),
            wind_mps=float(params["wind_mps"]), faults=FaultSpec(**params.get("faults", {})),
            launch_check_s=None if lc is None else float(lc))
        return cls(
            run=run, uavs=params["uavs"], area_m=float(params["area_m"]),
            height_m=float(params["height_m"]),
            length_s=float(params["trial_s" if avoid else "cap_s"]),
            avoidance_params=avoidance_params(params.get("avoidance_params", {}),
                                              "avoidance_params"),
            ground_start=params.get("ground_start", False),
            walk=WalkVariant.from_dict(params.get("walk", {})))

    def tasks(self, index: int) -> list[Task]:
        return [Task(index, 0, run_trial, (self, index))]

    def record(self, index: int, results: list[dict[str, Any]]) -> dict[str, Any]:
        return results[0]

    def foreign(self, index: int, record: dict[str, Any]) -> str | None:
        seed = self.run.seed
        if (record.get("scenario_seed"), record.get("world_seed")) != trial_seeds(seed, index):
            return f"has seeds that do not derive from the campaign seed {seed}"
        return None


def trial_run(spec: RandomWalkSpec, index: int) -> RunSpec:
    """Trial ``index`` of ``spec`` as the world flies it: the campaign's run settings over the
    trial's random walk (from the ground with ``ground_start``) for ``length_s``, seeded from
    the campaign's seed (:func:`trial_seeds`)."""
    from uavmpc.scenarios.random_walk import random_walk

    scenario_seed, world_seed = trial_seeds(spec.run.seed, index)
    sc = random_walk(spec.uavs, spec.area_m, spec.height_m, spec.length_s, scenario_seed,
                     link=spec.link, ground_start=spec.ground_start, variant=spec.walk)
    trial = spec.run.replace(seed=world_seed, duration_s=spec.length_s)
    return trial.for_scenario(dataclasses.replace(sc, avoidance=spec.avoidance_params))


def run_trial(spec: RandomWalkSpec, index: int, log_path: Path | None = None) -> dict[str, Any]:
    """Fly trial ``index`` of ``spec``; returns its JSON record. ``log_path``: also write its
    flight log there (the flight is the same)."""
    from uavmpc.drivers.world import World

    wall0 = time.perf_counter()
    scenario_seed, world_seed = trial_seeds(spec.run.seed, index)
    run = trial_run(spec, index)
    recorder = None
    if log_path is not None:
        from uavmpc.log import FlightRecorder

        recorder = FlightRecorder(log_path, [u.uav_id for u in run.scenario.uavs],
                                  {"campaign_trial": index, "scenario_seed": scenario_seed,
                                   "world_seed": world_seed})
    world = World(run, recorder=recorder)
    try:
        flown, extra = _fly_trial(spec, run.scenario, world)
        record = {"index": index, "scenario_seed": scenario_seed, "world_seed": world_seed,
                  **flown, "wall_s": time.perf_counter() - wall0, **extra}
        if spec.run.faults.active():
            record["faults"] = run.flown.faults.summary()
        return record
    finally:
        if recorder is not None:
            recorder.close()


def _fly_trial(spec: RandomWalkSpec, sc: Scenario, world: World
               ) -> tuple[dict[str, Any], dict[str, Any]]:
    """(what the trial's flight gave, the goals it reached when they count)."""
    from uavmpc.scenarios.random_walk import waypoints_reached

    count_from = float(getattr(sc, "count_from_s", 0.0))  # earlier collisions count for nothing
    if spec.run.avoidance:
        res = world.run(spec.length_s)
        collisions = [(c.t, c.a, c.b, c.distance_m) for c in res.collisions
                      if c.t >= count_from]
        dmin = float(res.min_distance_m[res.t_s >= count_from].min())
        sim_s = res.duration_s
    else:  # run in chunks, stop at the first collision
        collisions, dmin, sim_s = [], math.inf, 0.0
        total = round(spec.length_s / world.period_s)
        chunk = max(1, round(CHUNK_S / world.period_s))
        done = 0
        while done < total and not collisions:
            k = min(chunk, total - done)
            res = world.run(k * world.period_s)
            done += k
            collisions = [(c.t, c.a, c.b, c.distance_m) for c in res.collisions
                          if c.t >= count_from]
            counted = res.t_s >= count_from
            if collisions:  # the trial ends at the first collision
                counted &= res.t_s <= collisions[0][0] + 1e-9
            d = res.min_distance_m[counted]
            if d.size:
                dmin = min(dmin, float(d.min()))
        sim_s = done * world.period_s
        if collisions:  # flight time ends at the first collision, and so does the count
            sim_s = collisions[0][0]
            collisions = [c for c in collisions if c[0] <= sim_s + 1e-9]
    first = collisions[0] if collisions else None
    extra: dict[str, Any] = {}
    if spec.run.avoidance:  # without, a trial ends at its first collision: no goals to count
        reached, due = waypoints_reached(sc, res.t_s, res.positions_m)
        extra = {"waypoints_reached": reached, "waypoints_due": due}
    return {
        "sim_s": sim_s,
        "collisions": len(collisions),
        "first_collision_s": first[0] if first else None,
        "first_collision_pair": [first[1], first[2]] if first else None,
        "min_distance_m": dmin,
    }, extra



# ------------------------------------------------------------------------------ report
def _percentiles(times: list[float | None]) -> dict[str, float | None]:
    """Percentiles of the time to first collision; a trial without one counts as later than
    any, so a percentile beyond the share of trials with a collision is None (all None when
    no trial collided, as the report's schema asks)."""
    if not any(t is not None for t in times):
        return {f"p{q}": None for q in PERCENTILES}
    x = _censored(times)
    return {f"p{q}": percentile(x, q) for q in PERCENTILES}


def _intervals(times: list[float | None]) -> dict[str, list[float | None]] | None:
    """The 95 % bootstrap interval of each percentile of :func:`_percentiles` (None when no
    trial collided)."""
    if not any(t is not None for t in times):
        return None
    x = _censored(times)
    return {f"p{q}": list(bootstrap_interval(x, q)) for q in PERCENTILES}


def _censored(times: list[float | None]) -> list[float]:
    """Times to first collision with a trial without one as later than any (infinite)."""
    return [math.inf if t is None else t for t in times]


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
        "time_to_first_collision_ci95_s": _intervals(firsts),
        "min_distance_m": float(dmins.min()) if dmins.size else None,
        "min_distance_per_trial_m": (
            {f"p{q}": percentile(dmins, q) for q in (1, 5, 50)} if dmins.size else None),
        "wall_s": wall_s,
        "trial_wall_s": float(sum(r["wall_s"] for r in selected)),
        **_goals(selected),
        **_start(params),
    }


def _start(params: dict[str, Any]) -> dict[str, Any]:
    """With a start from the ground: when the walk began (times count from the ground)."""
    if not params.get("ground_start"):
        return {}
    from uavmpc.scenarios.random_walk import walk_start_s

    return {"ground_start": True, "walk_start_s": walk_start_s(params["height_m"])}


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
    def ttc(q: int) -> Callable[[dict[str, Any]], str]:
        return lambda r: _fmt_ttc(r, f"p{q}")

    rows += [(f"time to first collision, {q} %", ttc(q)) for q in PERCENTILES]
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
    if any(r["parameters"].get("ground_start") for r in reports):
        rows.append(("start", lambda r: (
            f"on the ground, walk from {r['walk_start_s']:.1f} s"
            if r["parameters"].get("ground_start") else "in the air")))
    if any(r["parameters"].get("walk") for r in reports):
        rows.append(("walk", lambda r: ", ".join(
            f"{k} {v}" for k, v in r["parameters"].get("walk", {}).items()) or "the protocol's"))
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
    from uavmpc.apps.published import comparison_markdown

    head = ("# random_walk campaign\n\nA collision is a 3-D distance between centres below "
            "1 m. Percentiles are those of the empirical CDF over all trials; a trial without "
            "collision counts as later than its length (\"> …\").\n\n")
    return head + markdown_table(*reports) + "".join(comparison_markdown(r) for r in reports)


def merge_reports(*paths: str | Path, out: str | Path | None = None) -> str:
    """Merge the report.json of a campaign without and one with avoidance into one table."""
    reports = [json.loads((Path(p) / "report.json" if Path(p).is_dir() else Path(p))
                          .read_text()) for p in paths]
    text = report_markdown(*reports)
    if out is not None:
        Path(out).write_text(text)
    return text


def _figures(out: Path, selected: list[dict[str, Any]], report: dict[str, Any]) -> None:
    import matplotlib.pyplot as plt

    import uavmpc.apps.plots  # noqa: F401  (selects the headless backend before any figure)

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
    ref = report.get("reference") or {}
    published = (ref.get("time_to_first_collision_s") or {}) if not report["avoidance"] else {}
    if published:  # its percentiles as points on its own (unknown) CDF
        ax.plot(list(published.values()), [int(k[1:]) / 100.0 for k in published], "o",
                color="C3", label=f"{ref['name']}: its percentiles")
        ax.legend(loc="lower right")
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
    if report["avoidance"] and ref.get("min_distance_m") is not None:
        ax.axvline(ref["min_distance_m"], color="C3", ls="--",
                   label=f"{ref['name']}: its closest approach")
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
    spec: RandomWalkSpec,
    execution: Execution,
    *,
    hours: float | None = None,
    trials: int | None = None,
    logs: int = 3,
    reference: str | Path | None = "table2",
) -> dict[str, Any]:
    """Run (or continue) the random-walk campaign ``spec`` in ``out_dir``; returns the report.

    ``spec`` is what every trial flies (:class:`RandomWalkSpec`: the run settings, UAVs, area,
    trial length, avoidance parameters, start, walk); ``execution`` how the trials are flown
    (:class:`~uavmpc.apps.campaign_engine.Execution`: workers, threads, Ray, progress; the
    report does not depend on it); the keywords how much to fly and what to write. Stops
    after ``trials`` trials, or once the trials cover ``hours`` of flight (the smallest prefix
    of trials, by index, whose flight time reaches it). ``logs``: the ``logs`` trials with
    the closest approach are re-flown from their seeds into flight logs
    (``logs/trial_<index>.mcap``; a full campaign's would be gigabytes), linked from
    ``report.html``. ``reference``: the published result the report is set beside
    (:class:`~uavmpc.apps.published.PublishedResult`: ``table2``, the reference design's, or
    a TOML file; None: none).
    """
    if not isinstance(spec, RandomWalkSpec):
        raise CampaignError(f"spec: must be a RandomWalkSpec, got {type(spec).__name__}")
    if not isinstance(execution, Execution):
        raise CampaignError(f"execution: must be an Execution, got {type(execution).__name__}")
    _check_size(hours=hours, trials=trials, logs=logs)
    published = None if reference is None else PublishedResult.load(reference)
    execution = execution.on_this_machine()
    workers, threads = execution.counts
    progress = execution.progress
    out = Path(out_dir)
    target_s = None if hours is None else float(hours) * 3600.0
    wall0 = time.perf_counter()
    selected = run_trials(out, spec, RandomWalkSpec.from_json, execution, trials=trials,
                          target_s=target_s, max_trial_s=spec.length_s)
    from uavmpc.apps.campaign_engine import campaign_wall_s

    flown_s = sum(r["sim_s"] for r in selected)
    if progress and target_s is not None and flown_s > 1.05 * target_s:
        print(f"campaign: {flown_s / 3600.0:.2f} h flown for --hours {hours:g}: the trials "
              f"are whole ({len(selected)} of up to {spec.length_s:g} s each), and the last "
              "one ends past the hours asked", file=sys.stderr)
    return _write_report(out, selected, spec, campaign_wall_s(out, wall0), logs,
                         workers=workers, threads=threads, published=published,
                         progress=progress)


def load_trials(out_dir: str | Path, seed: int) -> dict[int, dict[str, Any]]:
    """The finished trials of the random-walk campaign seeded ``seed`` in ``out_dir``."""
    return load_records(out_dir, RandomWalkSpec(run=RunSettings(seed=seed)).foreign)


def _write_report(out: Path, selected: list[dict[str, Any]], spec: RandomWalkSpec,
                  wall_s: float, logs: int, *, workers: int = 1, threads: int = 1,
                  published: PublishedResult | None = None,
                  progress: bool = False) -> dict[str, Any]:
    """Write the selected trials' report, figures, flight logs and page to ``out`` (the logs
    re-flown by ``workers`` local processes on ``threads`` threads each), set beside
    ``published`` when given."""
    report = aggregate(selected, spec.to_json(), wall_s)
    if published is not None:
        report["reference"] = published.to_json()
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    (out / "report.md").write_text(report_markdown(report))
    _figures(out, selected, report)
    _write_html(out, report, selected,
                _flight_logs(out, selected, spec, logs, workers=workers, threads=threads,
                             progress=progress))
    return report


def _check_size(*, hours: float | None, trials: int | None, logs: int) -> None:
    """Raise a CampaignError for a size or a number of logs out of range."""
    if (hours is None) == (trials is None):
        raise CampaignError("give exactly one of hours (--hours) or trials (--trials)")
    if trials is not None and (isinstance(trials, bool) or not isinstance(trials, int)
                               or trials < 1):
        raise CampaignError(f"trials: must be an integer ≥ 1, got {trials!r}")
    if hours is not None and not (math.isfinite(hours) and hours > 0):
        raise CampaignError(f"hours: must be > 0, got {hours}")
    if isinstance(logs, bool) or not isinstance(logs, int) or not 0 <= logs <= 100:
        raise CampaignError(f"logs: must be an integer in [0, 100], got {logs!r}")


def _avoidance(given: dict[str, Any] | AvoidanceParams | None,
               faults: FaultSpec | None) -> AvoidanceParams:
    """The avoidance parameters of a campaign (a bad field fails here, not in a worker)."""
    if isinstance(given, AvoidanceParams):
        return given
    table = dict(given or {})
    if faults is not None and faults.time_reference is not None and "time_reference" in table:
        raise CampaignError("time_reference: give it once, in the avoidance file or as "
                            "--time-reference")
    return avoidance_params(table)


def _flight_logs(out: Path, selected: list[dict[str, Any]], spec: RandomWalkSpec,
                 n: int, *, workers: int = 1, threads: int = 1,
                 progress: bool = False) -> dict[int, str]:
    """The flight logs of the ``n`` closest trials (re-flown from their seeds when missing,
    side by side on up to ``workers`` local processes): trial index → path relative to
    ``out``."""
    from uavmpc.apps.campaign_engine import Task, executor

    closest = sorted(selected, key=lambda r: (r["min_distance_m"], r["index"]))[:n]
    logs = {int(rec["index"]): f"logs/trial_{int(rec['index'])}.mcap" for rec in closest}
    missing = [i for i, rel in logs.items() if not (out / rel).exists()]
    if not missing:
        return logs
    if progress:  # minutes of flight after the progress bar's 100 %: say what they are
        print(f"campaign: flying the {len(missing)} closest trial(s) again into flight logs "
              f"({', '.join(logs[i] for i in missing)}; --logs 0 to skip)", file=sys.stderr)
    # A log is there whole or not at all: written as .part, renamed once its flight ended.
    part = {i: out / f"{logs[i]}.part" for i in missing}
    ex = executor(ray_address=None, workers=min(workers, len(missing)), threads=threads)
    try:
        for i in missing:
            ex.submit(Task(i, 0, run_trial, (spec, i, part[i])))
        while ex.pending():
            for i, _, _ in ex.wait():
                part[i].rename(out / logs[i])
    finally:
        ex.close(cancel=True)
    return logs


def _write_html(out: Path, report: dict[str, Any], selected: list[dict[str, Any]],
                logs: dict[int, str]) -> None:
    from uavmpc.apps.published import comparison_rows
    from uavmpc.apps.report_html import report_html

    page = report_html(report, report_rows(report), comparison_rows(report), selected,
                       [out / "ttc_cdf.png", out / "min_distance_hist.png"], logs)
    (out / "report.html").write_text(page)


# ------------------------------------------------------------------------------ CLI glue
def build_parser_campaign(
        subparsers: argparse._SubParsersAction[argparse.ArgumentParser]
) -> argparse.ArgumentParser:
    """Adds ``campaign random-walk ...`` to the CLI's subparsers; sets ``func``."""
    p = subparsers.add_parser(
        "campaign", help="statistical campaign (resumable): many seeded random_walk trials, "
                         "many landings on the moving deck, or dense traffics flown with and "
                         "without avoidance")
    _add_campaign_arguments(p)
    add_execution_arguments(p)
    _add_random_walk_arguments(p)
    _add_walk_arguments(p)
    add_fault_arguments(p)
    p.set_defaults(func=campaign_command)
    return p


def _add_campaign_arguments(p: argparse.ArgumentParser) -> None:
    """What every kind of campaign flies, how many and where it is kept."""
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
    p.add_argument("--out", default=None,
                   help="campaign folder (default out/campaign-{with,without}-avoidance, "
                        "out/campaign-landing, out/campaign-traffic); re-run the same command "
                        "to continue it")


def add_execution_arguments(p: argparse.ArgumentParser) -> None:
    """How the trials are flown (:func:`execution_of`): workers, threads, Ray, progress."""
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: CPU count, or the cores left by "
                        "--threads)")
    p.add_argument("--threads", type=int, default=None,
                   help="threads each trial's world ticks on (default: the cores left by "
                        "--workers, at least 1); the records do not depend on it")
    p.add_argument("--ray", default=None, metavar="ADDRESS",
                   help="run the trials on Ray ('auto', 'local' or ray://host:port); "
                        "pip install 'uavmpc[cluster]'")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def _add_random_walk_arguments(p: argparse.ArgumentParser) -> None:
    """A random-walk campaign's own: its link, wind, length, area, avoidance, start, logs and
    the published result beside it."""
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
    p.add_argument("--ground-start", action="store_true",
                   help="random-walk: every UAV starts on the ground and takes off vertically "
                        "to the walk's height before its walk, as the reference design's "
                        "Gazebo runs (default: start in the air at that height); times count "
                        "from the ground")
    p.add_argument("--logs", type=int, default=3, metavar="N",
                   help="random-walk: re-fly the N trials with the closest approach into "
                        "flight logs linked from report.html (default 3)")
    p.add_argument("--reference", default="table2", metavar="TABLE",
                   help="random-walk: the published result the report is set beside: 'table2' "
                        "(the reference design's Table II, default), a TOML file in its "
                        "format, or 'none'")


def _add_walk_arguments(p: argparse.ArgumentParser) -> None:
    """How a random walk departs from the protocol (:func:`walk_variant`)."""
    w = p.add_argument_group("random-walk: how the walk departs from the protocol (the start "
                             "hypotheses of docs/campaign.md; default: it does not)")
    w.add_argument("--paper-start", action="store_true",
                   help="the start that reproduces the reference design's Table II: from the "
                        f"ground, taking off one after another {PAPER_TAKEOFF_INTERVAL_S:g} s "
                        "apart (--ground-start --takeoff-interval "
                        f"{PAPER_TAKEOFF_INTERVAL_S:g})")
    w.add_argument("--takeoff-interval", type=float, default=0.0, metavar="S",
                   help="with --ground-start: the UAVs take off one after another, S seconds "
                        "apart; each walks after its own take-off")
    w.add_argument("--waypoint-clearance", type=float, default=0.0, metavar="M",
                   help="a waypoint closer than M to a waypoint another UAV holds is drawn "
                        "again")
    w.add_argument("--walk-speed", type=float, default=SPEED_MPS, metavar="MPS",
                   help=f"the walk's horizontal speed limit (default {SPEED_MPS:g}, Table I)")
    w.add_argument("--walk-accel", type=float, default=ACCEL_MPS2, metavar="MPS2",
                   help=f"the walk's horizontal acceleration limit (default {ACCEL_MPS2:g})")
    w.add_argument("--count-after-first-waypoint", action="store_true",
                   help="count no collision before every UAV's first waypoint was due")


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


def execution_of(args: argparse.Namespace) -> Execution:
    """The :class:`~uavmpc.apps.campaign_engine.Execution` of the flags of
    :func:`add_execution_arguments`."""
    return Execution(workers=args.workers, threads=args.threads, ray_address=args.ray,
                     progress=not args.no_progress)


def _run_from_args(out: str, args: argparse.Namespace) -> dict[str, Any]:
    return run_campaign(out, campaign_spec(args), execution_of(args), hours=args.hours,
                        trials=args.trials, logs=args.logs,
                        reference=None if args.reference == "none" else args.reference)


def campaign_spec(args: argparse.Namespace) -> RandomWalkSpec:
    """The :class:`RandomWalkSpec` of ``campaign random-walk``'s flags (a bad value fails
    here, named)."""
    for name in ("trial_s", "cap_s"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            raise CampaignError(f"{name}: must be > 0, got {v}")
    faults = fault_spec(args)
    run = run_settings(args, faults)
    params = _avoidance(avoidance_file(args.avoidance_file), faults)
    walk = walk_variant(args)
    try:
        return RandomWalkSpec(
            run=run, uavs=5 if args.uavs is None else args.uavs, area_m=args.area,
            length_s=float(args.trial_s if args.avoidance else args.cap_s),
            avoidance_params=params, ground_start=args.ground_start, walk=walk)
    except ConfigError as e:  # the run settings checked against the trials
        raise _by_flag(e) from None


#: Each RunSettings field's flag (the link's are named by LinkSettings).
_RUN_FLAGS = {"seed": "--seed", "wind_mps": "--wind", "launch_check_s": "--launch-check"}


def _by_flag(e: ConfigError) -> CampaignError:
    """``e`` with the :class:`RunSettings` field it names replaced by that field's flag."""
    msg = str(e)
    name = msg.split(":", 1)[0]
    return CampaignError(msg.replace(name, _RUN_FLAGS[name], 1) if name in _RUN_FLAGS else msg)


def run_settings(args: argparse.Namespace, faults: FaultSpec) -> RunSettings:
    """The :class:`~uavmpc.scenarios.run.RunSettings` every trial of ``campaign random-walk``
    flies (a bad value fails here, named by its flag)."""
    try:
        return RunSettings(
            avoidance=args.avoidance, seed=args.seed,
            link=LinkSettings.from_dict({"loss": args.loss, "latency_s": args.latency,
                                         "jitter_s": LinkSettings().jitter_s}),
            wind_mps=args.wind, faults=faults,
            launch_check_s=None if args.launch_check is None else float(args.launch_check))
    except ConfigError as e:
        raise _by_flag(e) from None


#: Each WalkVariant field's flag.
_WALK_FLAGS = {"takeoff_interval_s": "--takeoff-interval", "clearance_m": "--waypoint-clearance",
               "speed_mps": "--walk-speed", "accel_mps2": "--walk-accel",
               "count_after_first": "--count-after-first-waypoint"}


def walk_variant(args: argparse.Namespace) -> WalkVariant:
    """The :class:`WalkVariant` of the walk flags (a bad value fails here, named by its
    flag)."""
    try:
        return WalkVariant(takeoff_interval_s=args.takeoff_interval,
                           clearance_m=args.waypoint_clearance, speed_mps=args.walk_speed,
                           accel_mps2=args.walk_accel,
                           count_after_first=args.count_after_first_waypoint)
    except ConfigError as e:
        msg = str(e)
        for name, flag in _WALK_FLAGS.items():
            msg = msg.replace(f"walk.{name}", flag)
        raise CampaignError(msg) from None


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
    r = _interruptible(out, lambda: run_landing_campaign(
        out, trials=args.trials, seed=args.seed, scenario=args.scenario,
        speed_kmh=args.speed_kmh, duration_s=args.duration, execution=execution_of(args)))
    if r is None:
        return 130
    t = r["time_to_land_s"]

    def fmt(v: float | None) -> str:
        return "–" if v is None else f"{v:.1f} s"

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
    r = _interruptible(out, lambda: run_traffic_campaign(
        out, trials=args.trials, uavs=300 if args.uavs is None else args.uavs, seed=args.seed,
        duration_s=args.duration, execution=execution_of(args)))
    if r is None:
        return 130
    print("\n".join(report_lines(r)))
    print(f"wrote {out}/report.json, trials.jsonl")
    return 0 if r["with_avoidance"]["collisions"] == 0 else 1


def _interruptible(out: str, run: Callable[[], dict[str, Any]]) -> dict[str, Any] | None:
    """``run()``'s report; None after Ctrl-C (saying what is saved and how to go on)."""
    try:
        return run()
    except KeyboardInterrupt:
        n = sum(1 for _ in iter_trials(out))
        print(f"\ninterrupted: {n} finished trial(s) are saved in {out}/{TRIALS_FILE}; run "
              f"the same command again to continue", file=sys.stderr)
        return None


def campaign_command(args: argparse.Namespace) -> int:
    for flag, given in (("--ground-start", args.ground_start),
                        ("--paper-start", args.paper_start)):
        if args.kind != "random-walk" and given:
            raise CampaignError(f"{flag}: only for campaign random-walk (a {args.kind} "
                                "campaign flies its scenario's own start)")
    if args.paper_start:
        if args.takeoff_interval not in (0.0, PAPER_TAKEOFF_INTERVAL_S):
            raise CampaignError(f"--paper-start takes off {PAPER_TAKEOFF_INTERVAL_S:g} s "
                                f"apart: give it or --takeoff-interval "
                                f"{args.takeoff_interval:g}, not both")
        args.ground_start, args.takeoff_interval = True, PAPER_TAKEOFF_INTERVAL_S
    if args.kind != "random-walk" and walk_variant(args).changed():
        flags = ", ".join(_WALK_FLAGS[k] for k in walk_variant(args).changed())
        raise CampaignError(f"{flags}: only for campaign random-walk")
    if args.kind == "landing":
        return _landing_command(args)
    if args.kind == "traffic":
        return _traffic_command(args)
    out = args.out or f"out/campaign-{'with' if args.avoidance else 'without'}-avoidance"
    r = _interruptible(out, lambda: _run_from_args(out, args))
    if r is None:
        return 130
    ttc = r["time_to_first_collision_s"]
    pct = ", ".join(f"{k} {_fmt_ttc(r, k)}" for k in ttc) if ttc else "none"
    start = (f", from the ground (walk from {r['walk_start_s']:.1f} s)"
             if r.get("ground_start") else "")
    print(f"random_walk{start}, {'with' if r['avoidance'] else 'without'} avoidance: "
          f"{r['trials']} trials, {r['simulated_hours']:.2f} h simulated, "
          f"{r['collisions']} collision(s), "
          f"closest approach {r['min_distance_m']:.2f} m; time to first collision: {pct}")
    n_logs = min(args.logs, r["trials"])
    logs = (f", logs/ (the {n_logs} closest trial{'s' if n_logs > 1 else ''})" if n_logs
            else "")
    print(f"wrote {out}/report.html, report.json, report.md, ttc_cdf.png, "
          f"min_distance_hist.png{logs}")
    return 0 if (not r["avoidance"] or r["collisions"] == 0) else 1


__all__ = [
    "CampaignError",
    "Execution",
    "RandomWalkSpec",
    "aggregate",
    "build_parser_campaign",
    "iter_trials",
    "load_trials",
    "markdown_table",
    "merge_reports",
    "run_campaign",
    "run_trial",
    "trial_seeds",
]
