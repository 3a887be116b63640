"""Tracker benchmark: ``python benchmarks/bench_tracker.py [--ticks N] [--seed S]``."""

import sys

from uavmpc.apps.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", "tracker", *sys.argv[1:]]))
