"""Is the default thread count ever slow? ``uavmpc run swap_through_static`` with its default
threads against ``--threads 1``, on idle cores and with every core kept busy by other
processes (docs/scale.md, "Threads want idle cores").

    python benchmarks/bench_default_threads.py [--repeats 3] [--scenario swap_through_static]

Each run is a fresh ``uavmpc run`` process; its flight's wall time is the one its summary
reports (compilation left out). The two kinds of run take turns, so a slow spell of the
machine falls on both. The default is read from what the run says it ticks on. Last line:
JSON, with each condition's ratio of the default's best wall time to ``--threads 1``'s.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_TICKING = re.compile(r"ticking on (\d+) thread")


def _run(scenario: str, out: Path, threads: int | None) -> tuple[float, int]:
    """One ``uavmpc run``: its flight's wall time [s] and the threads it ticked on."""
    env = {k: v for k, v in os.environ.items() if k != "UAVMPC_THREADS"}
    cmd = [sys.executable, "-c", "import sys; from uavmpc.apps.cli import main; "
           "sys.exit(main(sys.argv[1:]))", "run", scenario, "--no-liveness", "--out", str(out)]
    if threads is not None:
        cmd += ["--threads", str(threads)]
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    summary = json.loads((out / "summary.json").read_text())
    ticking = _TICKING.search(done.stderr + done.stdout)
    return float(summary["wall_s"]), int(ticking.group(1)) if ticking else (threads or 0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scenario", default="swap_through_static")
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    rows = []
    with tempfile.TemporaryDirectory(prefix="uavmpc-threads-") as tmp:
        _run(args.scenario, Path(tmp) / "warm", 1)  # kernels compiled before any clock
        for busy in (0, cores):
            hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    for _ in range(busy)]
            try:
                time.sleep(1.0 if busy else 0.0)  # the hogs running before the runs look
                walls: dict[str, list[float]] = {"default": [], "one": []}
                chosen = []
                for k in range(args.repeats):
                    wall, threads = _run(args.scenario, Path(tmp) / f"d{busy}{k}", None)
                    walls["default"].append(wall)
                    chosen.append(threads)
                    walls["one"].append(_run(args.scenario, Path(tmp) / f"o{busy}{k}", 1)[0])
            finally:
                for h in hogs:
                    h.kill()
                    h.wait()
            best = {m: min(w) for m, w in walls.items()}
            ratio = best["default"] / best["one"]
            rows.append({"busy_cores": busy, "default_threads": chosen,
                         "default_wall_s": [round(w, 3) for w in walls["default"]],
                         "one_thread_wall_s": [round(w, 3) for w in walls["one"]],
                         "default_over_one": round(ratio, 3)})
            print(f"{busy} of {cores} cores busy: default ticked on {chosen} thread(s), best "
                  f"{best['default']:.2f} s; --threads 1 best {best['one']:.2f} s; "
                  f"default / one = {ratio:.2f}", flush=True)
    print(json.dumps({"scenario": args.scenario, "cores": cores, "repeats": args.repeats,
                      "rows": rows}))


if __name__ == "__main__":
    main()
