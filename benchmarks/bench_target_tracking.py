"""How well the landing mission's filter tracks the car: errors of the CTRV filter's estimate
against the true car, at 15 and 30 km/h, from the default fixes (20 Hz, σ 0.3 m, 10 % dropped).

    python benchmarks/bench_target_tracking.py [--seeds 4] [--seconds 60]

Each seed starts the car at a random point of the figure eight; errors are taken after the
first 10 s. The last line is JSON.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from uavmpc.missions.target_tracking import CtrvFilter
from uavmpc.plant.ground_vehicle import KMH, GroundVehicle


def errors(speed_kmh: float, seeds: int, seconds: float) -> dict[str, float]:
    pos, vel, turn, ahead = [], [], [], []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        car = GroundVehicle(speed_mps=speed_kmh * KMH,
                            start_arc_m=float(rng.uniform(0.0, 300.0)))
        f = CtrvFilter(fix_sigma_m=0.3)
        for k in range(int(seconds * 20)):
            t = 0.05 * k
            if rng.random() < 0.1:
                continue
            s = car.state(t)
            f.update(t, s.position_m[:2] + rng.normal(0.0, 0.3, 2))
            if t < 10.0 or not f.ready:
                continue
            x = f.x
            pos.append(math.hypot(*(x[:2] - s.position_m[:2])))
            v = x[3] * np.array([math.cos(x[2]), math.sin(x[2])])
            vel.append(math.hypot(*(v - s.velocity_mps[:2])))
            turn.append(abs(x[4] - s.yaw_rate_radps))
            p2 = f.predict(np.array([t + 2.0]))[0]
            ahead.append(math.hypot(*(p2[:2] - car.state(t + 2.0).position_m[:2])))

    def rms(a: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(a))))

    return {"position_rms_m": rms(pos), "velocity_rms_mps": rms(vel),
            "velocity_p99_mps": float(np.percentile(vel, 99)), "turn_rate_rms_radps": rms(turn),
            "two_s_ahead_rms_m": rms(ahead)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=60.0)
    a = ap.parse_args()
    out = {}
    for kmh in (15.0, 30.0):
        e = errors(kmh, a.seeds, a.seconds)
        out[f"{kmh:g}_kmh"] = e
        print(f"{kmh:g} km/h: position {e['position_rms_m']:.2f} m rms, velocity "
              f"{e['velocity_rms_mps']:.2f} m/s rms (p99 {e['velocity_p99_mps']:.2f}), turn rate "
              f"{e['turn_rate_rms_radps']:.2f} rad/s rms, 2 s ahead {e['two_s_ahead_rms_m']:.2f} m "
              "rms")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
