"""The reference design's Table II beside our campaigns without avoidance, and what moves the start.

    python benchmarks/table2_start.py --out out/table2 [--trials 500] [--workers 2]
        [--only NAME,NAME...]

Flies (or continues, or only reads: each is an ordinary campaign folder) one 500-trial
random-walk campaign without avoidance per start hypothesis of docs/campaign.md, in
``OUT/<name>``, every one from the same seed 0:

- ``air``: the protocol, in the air at the walk's height;
- ``ground``: from the ground, all taking off at once (``--ground-start``);
- ``stagger10``, ``stagger15``, ``stagger20``: taking off one after another, 10, 15 or
  20 s apart;
- ``clearance20``: each waypoint drawn again while within 20 m of another UAV's;
- ``first_waypoint``: no collision counted before every UAV's first waypoint was due;
- ``speed5``: the walk at 5 m/s instead of Table I's 8.3 m/s.

Prints a Markdown table (each percentile with its 95 % bootstrap interval, the spread
p95 − p50 that stands for the rate of collisions once they begin, and whether each of Table
II's four numbers lies inside our interval) and draws ``OUT/table2_start.png``: every
hypothesis's empirical CDF of the time to first collision with Table II's four points.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.apps.campaign import (
    PERCENTILES,
    Execution,
    RandomWalkSpec,
    load_trials,
    run_campaign,
)
from uavmpc.apps.published import PublishedResult, inside
from uavmpc.scenarios.random_walk import WalkVariant
from uavmpc.scenarios.run import RunSettings
from uavmpc.scenarios.stats import bootstrap_interval, percentile

#: name → (what it tests, the campaign's keywords beyond the protocol's).
HYPOTHESES: dict[str, tuple[str, dict[str, Any]]] = {
    "air": ("in the air (the protocol)", {}),
    "ground": ("from the ground, all at once", {"ground_start": True}),
    "stagger10": ("take-offs 10 s apart", {"ground_start": True,
                                           "walk": WalkVariant(takeoff_interval_s=10.0)}),
    "stagger15": ("take-offs 15 s apart", {"ground_start": True,
                                           "walk": WalkVariant(takeoff_interval_s=15.0)}),
    "stagger20": ("take-offs 20 s apart", {"ground_start": True,
                                           "walk": WalkVariant(takeoff_interval_s=20.0)}),
    "clearance20": ("waypoints ≥ 20 m from the others'", {
        "ground_start": True, "walk": WalkVariant(clearance_m=20.0)}),
    "first_waypoint": ("counted after the first waypoints", {
        "ground_start": True, "walk": WalkVariant(count_after_first=True)}),
    "speed5": ("the walk at 5 m/s", {"ground_start": True,
                                     "walk": WalkVariant(speed_mps=5.0)}),
}


def _row(name: str, what: str, firsts: list[float], table: PublishedResult) -> str:
    x = [np.inf if t is None else t for t in firsts]
    cells = []
    published = dict(table.time_to_first_collision_s)
    for q in PERCENTILES:
        v = percentile(x, q)
        lo, hi = bootstrap_interval(x, q)
        mark = "" if f"p{q}" not in published else (
            " ✓" if inside(published[f"p{q}"], (lo, hi)) == "yes" else "")
        fmt = (lambda t: "> cap" if t is None else f"{t:.1f}")  # noqa: E731
        cells.append(f"{fmt(v)} [{fmt(lo)}, {fmt(hi)}]{mark}")
    p50, p95 = percentile(x, 50), percentile(x, 95)
    spread = "–" if p50 is None or p95 is None else f"{p95 - p50:.1f}"
    return f"| {name}: {what} | " + " | ".join(cells) + f" | {spread} |"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/table2")
    ap.add_argument("--trials", type=int, default=500)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--only", default=",".join(HYPOTHESES),
                    help="comma-separated hypotheses (default: all)")
    args = ap.parse_args(argv)
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in names if n not in HYPOTHESES]
    if unknown:
        print(f"table2_start.py: unknown hypothesis {unknown[0]!r} (known: "
              f"{', '.join(HYPOTHESES)})", file=sys.stderr)
        return 2
    out = Path(args.out)
    table = PublishedResult.load("table2")
    published = dict(table.time_to_first_collision_s)
    print("| start | " + " | ".join(f"{q} % [95 % interval] (s)" for q in PERCENTILES)
          + " | p95 − p50 (s) |")
    print("|---" * (len(PERCENTILES) + 2) + "|")
    spread = published["p95"] - published["p50"]
    print(f"| {table.name} ({table.trials} trials, from take-off) | "
          + " | ".join(f"{published[f'p{q}']:g}" for q in PERCENTILES) + f" | {spread:g} |")
    from uavmpc.apps.plots import plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for name in names:
        what, kw = HYPOTHESES[name]
        folder = out / name
        run_campaign(folder, RandomWalkSpec(run=RunSettings(avoidance=False), **kw),
                     Execution(workers=args.workers, progress=False), trials=args.trials,
                     logs=0)
        firsts = [r["first_collision_s"] for r in
                  sorted(load_trials(folder, 0).values(), key=lambda r: r["index"])]
        print(_row(name, what, firsts, table), flush=True)
        t = np.sort([f for f in firsts if f is not None])
        ax.step(np.r_[0.0, t], np.arange(t.size + 1) / len(firsts), where="post",
                label=f"{name}: {what}")
    ax.plot(list(published.values()), [int(k[1:]) / 100.0 for k in published], "ko",
            ms=7, label=f"{table.name}: its percentiles")
    ax.set_xlim(0.0, 600.0)
    ax.set_ylim(0.0, 1.0)
    ax.set_xlabel("time to first collision, from t = 0 (take-off or the walk's start) [s]")
    ax.set_ylabel("fraction of trials")
    ax.set_title(f"random_walk without avoidance, {args.trials} trials each, seed 0")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(out / "table2_start.png", dpi=110)
    print(f"wrote {out / 'table2_start.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
