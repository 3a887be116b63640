"""Degradation curves: the protocol's closest approach and collisions against loss and latency.

    python benchmarks/degradation.py --out out/degradation [--hours 0.5] [--workers 2]
        [--loss 0,0.15,0.3,0.45,0.6] [--latency 0,0.25,0.5,0.75,0.9,1.0]

Flies one random-walk campaign (the reference design's protocol, docs/campaign.md, launch
check 10 s) per loss probability (at the default 50 ms latency) and per latency (without
loss), each ``--hours`` of flight with the default avoidance, in ``OUT/loss_<p>`` and
``OUT/latency_<s>`` (a campaign folder each: an interrupted run continues where it stopped).
Prints one row per point, writes ``OUT/degradation.json`` and the figure
``OUT/degradation.png`` (closest approach, and collisions per hour, against each).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from uavmpc.apps.campaign import Execution, RandomWalkSpec, run_campaign
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.run import RunSettings

#: The launch check of the lossy rows of docs/safety.md: no UAV sets off before it has heard
#: every other one (at most this long).
LAUNCH_CHECK_S = 10.0


def _levels(text: str, name: str, upper: float) -> list[float]:
    try:
        out = [float(v) for v in text.split(",") if v]
    except ValueError:
        raise SystemExit(f"degradation: --{name}: comma-separated numbers, got {text!r}") from None
    if not out or not all(0.0 <= v <= upper for v in out):
        raise SystemExit(f"degradation: --{name}: each in [0, {upper:g}], got {text!r}")
    return out


def point(out: Path, kind: str, value: float, hours: float, workers: int) -> dict[str, Any]:
    """One campaign: ``kind`` is "loss" (probability, 50 ms latency) or "latency" [s]."""
    link = LinkSettings(loss=value) if kind == "loss" else LinkSettings(latency_s=value)
    spec = RandomWalkSpec(run=RunSettings(link=link, launch_check_s=LAUNCH_CHECK_S))
    report = run_campaign(out / f"{kind}_{value:g}", spec,
                          Execution(workers=workers, progress=False), hours=hours, logs=0)
    return {kind: value, **{k: report[k] for k in (
        "simulated_hours", "trials", "collisions", "trials_with_collision", "waypoints_reached",
        "waypoints_due")}, "closest_m": report["min_distance_m"]}


def figure(rows: dict[str, list[dict[str, Any]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex="col")
    for col, kind, label in ((0, "loss", "loss probability (50 ms latency)"),
                             (1, "latency", "latency [s] (no loss)")):
        pts = rows[kind]
        x = [p[kind] for p in pts]
        top, bottom = axes[0, col], axes[1, col]
        top.plot(x, [p["closest_m"] for p in pts], "o-")
        top.axhline(2.0, color="grey", lw=0.8, ls=":", label="2 m goal")
        top.axhline(1.0, color="red", lw=0.8, ls=":", label="collision (1 m)")
        top.set_ylim(0.0, 4.0)
        bottom.plot(x, [p["collisions"] / max(p["simulated_hours"], 1e-9) for p in pts],
                    "s-", color="tab:orange")
        bottom.set_ylim(0.0, max(1.0, 1.1 * max(p["collisions"] / max(p["simulated_hours"],
                                                                       1e-9) for p in pts)))
        bottom.set_xlabel(label)
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("closest approach [m]")
    axes[1, 0].set_ylabel("collisions per hour")
    axes[0, 0].legend(loc="lower left")
    fig.suptitle("The protocol (5 UAVs, random walks, 600 s trials) against loss and latency")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--hours", type=float, default=0.5, help="flight per point [h]")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--loss", default="0,0.15,0.3,0.45,0.6")
    ap.add_argument("--latency", default="0,0.25,0.5,0.75,0.9,1.0")
    args = ap.parse_args()
    if not 0.0 < args.hours <= 24.0:
        ap.error(f"--hours: in (0, 24], got {args.hours}")
    losses = _levels(args.loss, "loss", 0.95)
    latencies = _levels(args.latency, "latency", 5.0)
    rows: dict[str, list[dict[str, Any]]] = {"loss": [], "latency": []}
    print(f"{'point':>16s} {'hours':>6s} {'collisions':>10s} {'closest [m]':>11s} "
          f"{'waypoints':>11s}", flush=True)
    for kind, values in (("loss", losses), ("latency", latencies)):
        for v in values:
            p = point(args.out, kind, v, args.hours, args.workers)
            rows[kind].append(p)
            print(f"{kind + ' ' + format(v, 'g'):>16s} {p['simulated_hours']:6.2f} "
                  f"{p['collisions']:>10d} {p['closest_m']:11.2f} "
                  f"{p['waypoints_reached']:>5d}/{p['waypoints_due']:<5d}", flush=True)
    (args.out / "degradation.json").write_text(json.dumps(rows, indent=1))
    figure(rows, args.out / "degradation.png")
    print(f"wrote {args.out / 'degradation.json'} and {args.out / 'degradation.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
