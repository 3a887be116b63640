"""Batched QP solver vs DAQP per call: ``python benchmarks/bench_batchqp.py [--ticks N]``.

The QPs come from a recorded flight (the tracker benchmark's demanding events, DAQP in the loop):
each axis' sequence of QPs that reached the solver. K problem slots stand for K/4 UAVs: slot k
replays axis k % 4 from its own offset in time, so the slots hold different, realistic problems.
Every tick, one batched call solves all K (warm-started from each slot's previous working set),
and K warm-started DAQP instances (one per slot, as the tracker uses them) solve the same QPs
one call each. The last line of output is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

from uavmpc.apps.bench import _fly, demanding_events
from uavmpc.solvers.batchqp import OPTIMAL, BatchQpSolver
from uavmpc.tracker import CondensedModel, DaqpSolver, MpcTracker, QpResult, TrackerConfig


class _Recorder:
    """DAQP for the tracker, keeping a copy of every QP it is given."""

    def __init__(self, model: CondensedModel) -> None:
        self.name = "daqp"
        self._inner = DaqpSolver(model)
        self.qps: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def solve(self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QpResult:
        self.qps.append((f.copy(), lower.copy(), upper.copy()))
        return self._inner.solve(f, lower, upper)


def record(config: TrackerConfig, ticks: int = 3000, seed: int = 1) -> list[np.ndarray]:
    """Per axis, the QPs of one flight stacked as (count, m + 2n): [f | lower | upper]."""
    model = CondensedModel.build(config)
    recorders = [_Recorder(model) for _ in range(4)]
    tracker = MpcTracker(config, position_m=(0.0, 0.0, 10.0), solvers=list(recorders))
    for _ in _fly(tracker, demanding_events(ticks, seed), ticks, timed=False):
        pass
    return [np.array([np.concatenate(qp) for qp in r.qps]) for r in recorders]


def bench(k: int, sequences: list[np.ndarray], model: CondensedModel, ticks: int) -> dict:
    """µs per problem for K = k slots over ``ticks`` ticks, batched and DAQP."""
    m, n = model.config.steps, 2 * model.config.steps + 1
    rng = np.random.default_rng(k)
    axes = np.arange(k) % 4
    offsets = [int(rng.integers(0, sequences[a].shape[0])) for a in axes]
    # Problems per tick: (ticks, K, m + 2n), built before timing.
    data = np.empty((ticks, k, m + 2 * n))
    for slot, (a, off) in enumerate(zip(axes, offsets, strict=True)):
        seq = sequences[a]
        data[:, slot] = seq[(off + np.arange(ticks)) % seq.shape[0]]
    f = np.ascontiguousarray(data[:, :, :m])
    lower = np.ascontiguousarray(data[:, :, m:m + n])
    upper = np.ascontiguousarray(data[:, :, m + n:])

    solver = BatchQpSolver(model)
    ws = np.zeros((k, n), dtype=np.int8)
    u = np.empty((ticks, k, m))
    status = np.empty(k, dtype=np.int64)
    iterations = np.empty(k, dtype=np.int64)
    failures, total_iterations = 0, 0
    t0 = time.perf_counter()
    for t in range(ticks):
        solver.solve_into(f[t], lower[t], upper[t], ws, u[t], status, iterations, ws)
        failures += int(np.sum(status != OPTIMAL))
        total_iterations += int(iterations.sum())
    batch_s = time.perf_counter() - t0

    daqp = [DaqpSolver(model) for _ in range(k)]
    u_daqp = np.empty((ticks, k, m))
    t0 = time.perf_counter()
    for t in range(ticks):
        ft, lt, ut, out = f[t], lower[t], upper[t], u_daqp[t]
        for slot in range(k):
            res = daqp[slot].solve(ft[slot], lt[slot], ut[slot])
            if res.inputs is not None:
                out[slot] = res.inputs
    daqp_s = time.perf_counter() - t0
    per = 1e6 / (ticks * k)
    return {
        "K": k,
        "batch_us_per_problem": round(batch_s * per, 3),
        "daqp_us_per_problem": round(daqp_s * per, 3),
        "speedup": round(daqp_s / batch_s, 2),
        "batch_us_per_call": round(batch_s * 1e6 / ticks, 2),
        "mean_iterations": round(total_iterations / (ticks * k), 3),
        "failures": failures,
        "max_u0_diff_vs_daqp": float(np.max(np.abs(u[:, :, 0] - u_daqp[:, :, 0]))),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=300, help="ticks timed per K")
    parser.add_argument("--flight-ticks", type=int, default=3000, help="ticks of the recording")
    parser.add_argument("--sizes", type=int, nargs="+", default=[4, 20, 80, 400])
    args = parser.parse_args()
    config = TrackerConfig.from_toml()
    model = CondensedModel.build(config)
    sequences = record(config, args.flight_ticks)
    print(f"recorded {sum(s.shape[0] for s in sequences)} QPs over {args.flight_ticks} ticks")
    bench(4, sequences, model, 5)  # compile (or load the numba cache) outside the timing
    results = []
    for k in args.sizes:
        r = bench(k, sequences, model, args.ticks)
        results.append(r)
        print(f"K={k:4d}: batch {r['batch_us_per_problem']:7.3f} µs/problem "
              f"({r['batch_us_per_call']:9.1f} µs/call), DAQP {r['daqp_us_per_problem']:7.3f} "
              f"µs/problem, ×{r['speedup']:.1f}, iterations {r['mean_iterations']:.2f}, "
              f"failures {r['failures']}, max |Δu₀| {r['max_u0_diff_vs_daqp']:.1e}")
    print(json.dumps({"benchmark": "batchqp", "ticks": args.ticks,
                      "flight_ticks": args.flight_ticks, "results": results,
                      "python": platform.python_version(), "machine": platform.machine()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
