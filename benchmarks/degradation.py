"""Degradation curves: the protocol's closest approach and collisions against loss and latency.

    python benchmarks/degradation.py --out out/degradation [--hours 0.5] [--workers 2]
        [--loss 0,0.15,0.3,0.45,0.6] [--latency 0,0.25,0.5,0.75,1.0]

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

from uavmpc.apps.campaign import run_campaign

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
    link = {"loss": value} if kind == "loss" else {"latency": value, "loss": 0.0}
    report = run_campaign(out / f"{kind}_{value:g}", hours=hours, workers=workers,
                          launch_check_s=LAUNCH_CHECK_S, logs=0, progress=False, **link)
    return {kind: value, **{k: report[k] for k in (
        "simulated_hours", "trials", "collisions", "trials_with_collision", "waypoints_reached",
        "waypoints_due")}, "closest_m": report["min_distance_m"]}


def figure(rows: dict[str, list[dict[str, Any]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, kind, label in ((axes[0], "loss", "loss probability (50 ms latency)"),
                            (axes[1], "latency", "latency [s] (no loss)")):
        pts = rows[kind]
        x = [p[kind] for p in pts]
        ax.plot(x, [p["closest_m"] for p in pts], "o-", label="closest approach [m]")
        ax.plot(x, [p["collisions"] / max(p["simulated_hours"], 1e-9) for p in pts], "s--",
                label="collisions per hour")
        ax.axhline(2.0, color="grey", lw=0.8, ls=":")
        ax.axhline(1.0, color="red", lw=0.8, ls=":")
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("metres / collisions per hour")
    axes[0].legend(loc="upper right")
    fig.suptitle("5 UAVs, random walks, 600 s trials: 2 m goal (grey), collision (red)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--hours", type=float, default=0.5, help="flight per point [h]")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--loss", default="0,0.15,0.3,0.45,0.6")
    ap.add_argument("--latency", default="0,0.25,0.5,0.75,1.0")
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
