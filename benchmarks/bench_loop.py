"""Single-UAV loop benchmark: ``python benchmarks/bench_loop.py [--duration S] [--repeats N]``."""

import sys

from uavmpc.apps.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", "loop", *sys.argv[1:]]))
