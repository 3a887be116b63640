"""Fly one trial of a campaign folder again from its seeds, optionally with other avoidance
parameters, and print its record (and write its flight log).

    python benchmarks/replay_trial.py out/r7/iid 141
    python benchmarks/replay_trial.py out/r7/iid 141 \
        --avoidance-file configs/avoidance_unheard_grace.toml
    python benchmarks/replay_trial.py out/r7/iid 141 --log trial141.mcap   # open in Foxglove

The replays quoted in docs/campaign.md and docs/faults.md ("replayed: ...") are this.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from uavmpc.apps.campaign import avoidance_file, run_trial, trial_job
from uavmpc.config import ConfigError


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("campaign", type=Path, help="a campaign folder (with campaign.json)")
    ap.add_argument("index", type=int, help="the trial's index")
    ap.add_argument("--avoidance-file", default=None,
                    help="fly this file's [avoidance] table instead of the campaign's")
    ap.add_argument("--log", type=Path, default=None, help="also write the flight log here")
    args = ap.parse_args()
    try:
        params = json.loads((args.campaign / "campaign.json").read_text())["parameters"]
        table = avoidance_file(args.avoidance_file) if args.avoidance_file else None
        job = trial_job(params, args.index, table)
    except (OSError, ValueError, KeyError, ConfigError) as exc:
        print(f"replay_trial: {exc}", file=sys.stderr)
        return 2
    record = run_trial(job, args.log)
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
