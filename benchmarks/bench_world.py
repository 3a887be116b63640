"""World benchmark: ``python benchmarks/bench_world.py [--duration S]``."""

import sys

from uavmpc.apps.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", "world", *sys.argv[1:]]))
