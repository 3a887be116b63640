"""The measurements behind docs/applications.md that are not a single CLI command.

    python benchmarks/applications.py member-rule          # formation with and without it
    python benchmarks/applications.py closing DIR          # a landing campaign's closing times
    python benchmarks/applications.py abort-sweep [--trials 50] [--radii 0.55 0.5 0.45]

``member-rule`` flies the built-in ``formation`` twice (seed 0): as built, and with a strategy
whose per-pair radii ignore the members (everyone meets the full cylinder). ``closing`` reads
the ``trials.jsonl`` of ``uavmpc campaign landing`` and relates each trial's closing time to
where the car was at t = 0 (the UAV's start from the scenario). ``abort-sweep`` runs the 30 km/h
campaign with other ``abort_radius_m`` values (120 s trials). The last line is JSON.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from uavmpc import scenarios
from uavmpc.scenarios.run import RunSpec


class _IgnoreMembers(dict):
    """Per-pair radii that stay empty: the members meet the full cylinder."""

    def update(self, *args: object, **kwargs: object) -> None:
        return None


def member_rule() -> dict:
    from uavmpc.avoidance import AvoidanceParams, HeightOffsetStrategy
    from uavmpc.drivers.world import World

    def without(params: AvoidanceParams) -> HeightOffsetStrategy:
        s = HeightOffsetStrategy(params)
        s.pair_radius_m = _IgnoreMembers()
        return s

    out = {}
    for name, strategy in (("with_member_cylinder", HeightOffsetStrategy),
                           ("without", without)):
        s = World(RunSpec(scenarios.load("formation"), seed=0), strategy=strategy).run().summary()
        assert s.formation is not None and s.formation.error is not None
        out[name] = {"formation_error_rms_m": s.formation.error.rms_m,
                     "formation_error_max_m": s.formation.error.max_m,
                     "collisions": len(s.collisions),
                     "yielded_to": {k: u.details["yielded_to"] for k, u in s.uavs.items()
                                    if u.details["yielded_to"]}}
        print(f"{name}: formation error rms {out[name]['formation_error_rms_m']:.2f} m, "
              f"max {out[name]['formation_error_max_m']:.2f} m; gave way: "
              f"{out[name]['yielded_to']}")
    return out


def closing(campaign_dir: str, scenario: str = "moving_target_landing") -> dict:
    from uavmpc.plant.ground_vehicle import GroundVehicle

    sc = scenarios.load(scenario)
    car0 = sc.ground_vehicle
    assert car0 is not None
    start = np.array(next(u for u in sc.uavs if u.uav_id == sc.landing[0]).start_m[:2])
    rows = []
    for line in (Path(campaign_dir) / "trials.jsonl").read_text().splitlines():
        t = json.loads(line)
        if not t["landed"]:
            continue
        car = GroundVehicle(car0.track, speed_mps=t["speed_kmh"] / 3.6,
                            start_arc_m=t["start_arc_m"]).state(0.0)
        rel = car.position_m[:2] - start
        d = float(np.linalg.norm(rel))
        rows.append((t["phases_s"]["closing"], d, float(car.velocity_mps[:2] @ rel / d),
                     t["time_to_land_s"]))
    a = np.array(rows)
    away, toward = a[a[:, 2] > 2.0], a[a[:, 2] < -2.0]
    out = {"landed": len(a), "closing_s_min": float(a[:, 0].min()),
           "closing_s_max": float(a[:, 0].max()),
           "corr_closing_vs_speed_away": float(np.corrcoef(a[:, 0], a[:, 2])[0, 1]),
           "corr_closing_vs_distance": float(np.corrcoef(a[:, 0], a[:, 1])[0, 1]),
           "away": {"trials": len(away), "closing_p50_s": float(np.median(away[:, 0])),
                    "landing_p50_s": float(np.median(away[:, 3]))},
           "toward": {"trials": len(toward), "closing_p50_s": float(np.median(toward[:, 0])),
                      "landing_p50_s": float(np.median(toward[:, 3]))},
           "share_slower_than_25_1_s": float(np.mean(a[:, 3] > 25.1))}
    print(json.dumps(out, indent=1))
    return out


def abort_sweep(trials: int, radii: list[float]) -> dict:
    from uavmpc.apps.landing_campaign import run_landing_campaign

    base = Path(scenarios.__file__).with_name("moving_target_landing_30kmh.toml")
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in radii:
            lines = []
            for line in base.read_text().splitlines():
                if line.startswith("abort_radius_m"):
                    line = f"abort_radius_m = {r}"
                elif line.startswith("duration_s"):
                    line = "duration_s = 120.0"
                lines.append(line)
            path = Path(tmp) / f"abort_{r}.toml"
            path.write_text("\n".join(lines) + "\n")
            rep = run_landing_campaign(Path(tmp) / f"out_{r}", trials=trials,
                                       scenario=str(path))
            out[str(r)] = {k: rep[k] for k in ("landed", "touchdowns_off_the_deck",
                                               "hard_touchdowns", "not_landed_in_time",
                                               "time_to_land_s")}
            print(f"abort_radius_m {r}: {rep['landed']} / {rep['trials']} landed, "
                  f"{rep['touchdowns_off_the_deck']} off the deck")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    sub.add_parser("member-rule")
    c = sub.add_parser("closing")
    c.add_argument("campaign_dir")
    c.add_argument("--scenario", default="moving_target_landing")
    s = sub.add_parser("abort-sweep")
    s.add_argument("--trials", type=int, default=50)
    s.add_argument("--radii", type=float, nargs="+", default=[0.55, 0.5, 0.45])
    a = ap.parse_args()
    if a.what == "member-rule":
        out = member_rule()
    elif a.what == "closing":
        out = closing(a.campaign_dir, a.scenario)
    else:
        out = abort_sweep(a.trials, a.radii)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
