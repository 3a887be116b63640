"""Fly one trial of a campaign folder again from its seeds, optionally with other avoidance
parameters, and print its record (and write its flight log).

    python benchmarks/replay_trial.py out/r7/iid 141
    python benchmarks/replay_trial.py out/r7/iid 141 --avoidance-file my_avoidance.toml
    python benchmarks/replay_trial.py out/r7/iid 141 --log trial141.mcap   # open in Foxglove

The replays quoted in docs/campaign.md and docs/faults.md ("replayed: ...") are this.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from uavmpc.apps.campaign import RandomWalkSpec, avoidance_file, run_trial
from uavmpc.apps.campaign_engine import stored_spec
from uavmpc.config import ConfigError
from uavmpc.scenarios import avoidance_params


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("campaign", type=Path, help="a campaign folder (with campaign.json)")
    ap.add_argument("index", type=int, help="the trial's index")
    ap.add_argument("--avoidance-file", default=None,
                    help="fly this file's [avoidance] table instead of the campaign's")
    ap.add_argument("--log", type=Path, default=None, help="also write the flight log here")
    args = ap.parse_args()
    try:
        stored = stored_spec(args.campaign, RandomWalkSpec.kind)
        if stored is None:
            raise ConfigError(f"{args.campaign}: no campaign.json")
        spec = RandomWalkSpec.from_json(stored)
        if args.avoidance_file:
            spec = dataclasses.replace(spec, avoidance_params=avoidance_params(
                avoidance_file(args.avoidance_file)))
    except (OSError, ValueError, KeyError, ConfigError) as exc:
        print(f"replay_trial: {exc}", file=sys.stderr)
        return 2
    record = run_trial(spec, args.index, args.log)
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
