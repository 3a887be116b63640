"""The one campaign engine: specs stored and reloaded as they are, every campaign resumable,
one percentile definition, an old or unknown campaign file refused by name."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import uavmpc.apps.landing_campaign as landing
import uavmpc.apps.traffic_campaign as traffic
from uavmpc.apps.campaign import RandomWalkSpec, run_campaign
from uavmpc.apps.campaign_engine import (
    CAMPAIGN_FILE,
    FORMAT,
    CampaignError,
    Execution,
    open_campaign,
    stored_spec,
)
from uavmpc.avoidance import AvoidanceParams
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.faults import FaultSpec
from uavmpc.scenarios.random_walk import WalkVariant
from uavmpc.scenarios.run import RunSettings
from uavmpc.scenarios.stats import percentile

#: One local worker, nothing said on stderr.
ONE = Execution(workers=1, progress=False)
SPECS = [
    RandomWalkSpec(run=RunSettings(
        avoidance=True, seed=9, link=LinkSettings(latency_s=0.2, jitter_s=0.01, loss=0.3),
        wind_mps=2.5, launch_check_s=4.0,
        faults=FaultSpec(clock_offset_s=0.3, time_reference="receive", gnss="single",
                         burst_len=2.0, non_cooperative=1, silent=1)),
                   uavs=4, area_m=80.0, height_m=12.0, length_s=90.0,
                   avoidance_params=AvoidanceParams(radius_m=7.5, height_m=5.0)),
    RandomWalkSpec(run=RunSettings(avoidance=False), length_s=123.0),
    landing.LandingSpec("moving_target_landing_30kmh", seed=4, speed_kmh=25.0, duration_s=60.0),
    landing.LandingSpec(),
    traffic.TrafficSpec(uavs=12, seed=3, duration_s=45.0,
                        options=(("cruise_heights_m", [30.0, 40.0]), ("density_per_km2", 80.0))),
]


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: f"{s.kind}")
def test_a_spec_round_trips_through_campaign_json_exactly(tmp_path: Path, spec) -> None:
    open_campaign(tmp_path, spec, type(spec).from_json)
    data = json.loads((tmp_path / CAMPAIGN_FILE).read_text())
    assert data["format"] == FORMAT and data["kind"] == spec.kind
    back = type(spec).from_json(stored_spec(tmp_path, spec.kind))
    assert back == spec and back.to_json() == spec.to_json()
    open_campaign(tmp_path, spec, type(spec).from_json)  # the same spec: continued
    other = type(spec).from_json({**spec.to_json(), "seed": spec.to_json()["seed"] + 1})
    with pytest.raises(CampaignError, match=r"other parameters \(seed: "):
        open_campaign(tmp_path, other, type(spec).from_json)


def test_an_old_or_unknown_campaign_file_is_refused_naming_its_format(tmp_path: Path) -> None:
    spec = landing.LandingSpec()
    (tmp_path / CAMPAIGN_FILE).write_text(json.dumps({"format": 7, "version": "9.9",
                                                      "kind": "landing", "spec": {}}))
    with pytest.raises(CampaignError, match=r"format 7 \(written by uavmpc 9\.9\); this "
                                            rf"uavmpc reads format {FORMAT}"):
        open_campaign(tmp_path, spec, landing.LandingSpec.from_json)
    # format 1 was a random walk's parameters only: not a landing campaign's
    (tmp_path / CAMPAIGN_FILE).write_text(json.dumps({"format": 1, "version": "0.0.9",
                                                      "parameters": {"seed": 0}}))
    with pytest.raises(CampaignError, match="format 1 "):
        open_campaign(tmp_path, spec, landing.LandingSpec.from_json)
    # another kind of campaign in the folder
    (tmp_path / CAMPAIGN_FILE).unlink()
    open_campaign(tmp_path, traffic.TrafficSpec(uavs=4), traffic.TrafficSpec.from_json)
    with pytest.raises(CampaignError, match="a 'traffic' campaign, not 'landing'"):
        open_campaign(tmp_path, spec, landing.LandingSpec.from_json)
    # trials written before campaigns had a campaign.json
    old = tmp_path / "old"
    old.mkdir()
    (old / "trials.jsonl").write_text('{"index": 0}\n')
    with pytest.raises(CampaignError, match=r"holds trials but no campaign\.json"):
        landing.run_landing_campaign(old, trials=1, duration_s=1.0, execution=ONE)


#: A random walk's campaign.json spec as written before its run settings became a template
#: (RandomWalkSpec(avoidance=..., seed=..., link=..., ...)): the same fields, side by side.
WRITTEN_BEFORE = {
    "scenario": "random_walk", "uavs": 4, "area_m": 80.0, "height_m": 12.0, "avoidance": True,
    "seed": 9, "loss": 0.3, "latency_s": 0.2, "jitter_s": 0.01, "wind_mps": 2.5,
    "trial_s": 90.0, "faults": {"clock_offset_s": 0.3, "non_cooperative": 1},
    "avoidance_params": {"radius_m": 7.5}, "launch_check_s": 4.0, "ground_start": True,
    "walk": {"clearance_m": 20.0}}


def test_a_random_walk_written_before_the_run_template_reads_back_and_continues(
        tmp_path: Path) -> None:
    spec = RandomWalkSpec(
        run=RunSettings(avoidance=True, seed=9, wind_mps=2.5, launch_check_s=4.0,
                        link=LinkSettings(latency_s=0.2, jitter_s=0.01, loss=0.3),
                        faults=FaultSpec(clock_offset_s=0.3, non_cooperative=1)),
        uavs=4, area_m=80.0, height_m=12.0, length_s=90.0,
        avoidance_params=AvoidanceParams(radius_m=7.5), ground_start=True,
        walk=WalkVariant(clearance_m=20.0))
    assert spec.to_json() == WRITTEN_BEFORE
    assert RandomWalkSpec.from_json(WRITTEN_BEFORE) == spec
    (tmp_path / CAMPAIGN_FILE).write_text(json.dumps(
        {"format": FORMAT, "kind": "random_walk", "version": "0.0.0", "spec": WRITTEN_BEFORE}))
    open_campaign(tmp_path, spec, RandomWalkSpec.from_json)  # continued, not refused
    # one it cannot read is a CampaignError naming the field, not a traceback
    (tmp_path / CAMPAIGN_FILE).write_text(json.dumps(
        {"format": FORMAT, "kind": "random_walk", "version": "0.0.0",
         "spec": {**WRITTEN_BEFORE, "wind_mps": 45.0}}))
    with pytest.raises(CampaignError, match=r"unreadable campaign spec \(wind_mps: "):
        open_campaign(tmp_path, spec, RandomWalkSpec.from_json)
    (tmp_path / CAMPAIGN_FILE).write_text(json.dumps(
        {"format": FORMAT, "kind": "random_walk", "version": "0.0.0",
         "spec": {k: v for k, v in WRITTEN_BEFORE.items() if k != "seed"}}))
    with pytest.raises(CampaignError, match=r"unreadable campaign spec \('seed'\)"):
        open_campaign(tmp_path, spec, RandomWalkSpec.from_json)


def test_a_format_1_random_walk_folder_is_read_as_its_parameters(tmp_path: Path) -> None:
    spec = RandomWalkSpec(run=RunSettings(avoidance=False), uavs=3, area_m=30.0,
                          length_s=10.0)
    run_campaign(tmp_path, spec, ONE, trials=1, logs=0)
    new = json.loads((tmp_path / CAMPAIGN_FILE).read_text())
    (tmp_path / CAMPAIGN_FILE).write_text(json.dumps(
        {"format": 1, "version": "0.0.9", "parameters": new["spec"]}))
    assert run_campaign(tmp_path, spec, ONE, trials=2, logs=0)["trials"] == 2
    with pytest.raises(CampaignError, match="other parameters"):
        run_campaign(tmp_path, dataclasses.replace(spec, length_s=11.0), ONE, trials=2, logs=0)


def _records(out: Path) -> list[dict]:
    def clean(x):
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items() if k != "wall_s"}
        return x

    return [clean(json.loads(line)) for line in (out / "trials.jsonl").read_text().splitlines()]


class _Interrupt:
    """Wraps a trial function: Ctrl-C when it is called the ``at``-th time."""

    def __init__(self, function, at: int) -> None:
        self.function, self.at, self.calls = function, at, 0

    def __call__(self, *args):
        self.calls += 1
        if self.calls == self.at:
            raise KeyboardInterrupt
        return self.function(*args)


def test_a_landing_campaign_resumes_where_it_was_interrupted(tmp_path: Path,
                                                             monkeypatch) -> None:
    kw = dict(trials=3, seed=5, duration_s=6.0, execution=ONE)
    whole = landing.run_landing_campaign(tmp_path / "whole", **kw)
    real = landing.landing_trial
    # the first call is the scenario check before the campaign; Ctrl-C in the third trial
    monkeypatch.setattr(landing, "landing_trial", _Interrupt(real, 4))
    with pytest.raises(KeyboardInterrupt):
        landing.run_landing_campaign(tmp_path / "cut", **kw)
    assert [r["index"] for r in _records(tmp_path / "cut")] == [0, 1]
    flown = _Interrupt(real, 0)
    monkeypatch.setattr(landing, "landing_trial", flown)
    again = landing.run_landing_campaign(tmp_path / "cut", **kw)
    assert flown.calls == 1 + 1  # the check, then only the missing trial
    assert _records(tmp_path / "cut") == _records(tmp_path / "whole")
    assert again == whole


def test_a_traffic_campaign_resumes_where_it_was_interrupted(tmp_path: Path,
                                                             monkeypatch) -> None:
    kw = dict(trials=2, uavs=4, seed=2, duration_s=4.0, execution=ONE)
    whole = traffic.run_traffic_campaign(tmp_path / "whole", **kw)
    real = traffic.traffic_flight
    monkeypatch.setattr(traffic, "traffic_flight", _Interrupt(real, 4))  # trial 1's 2nd side
    with pytest.raises(KeyboardInterrupt):
        traffic.run_traffic_campaign(tmp_path / "cut", **kw)
    assert [r["index"] for r in _records(tmp_path / "cut")] == [0]
    flown = _Interrupt(real, 0)
    monkeypatch.setattr(traffic, "traffic_flight", flown)
    again = traffic.run_traffic_campaign(tmp_path / "cut", **kw)
    assert flown.calls == 2  # both sides of the missing trial, nothing else
    assert _records(tmp_path / "cut") == _records(tmp_path / "whole")
    for side in traffic.SIDES:
        a, b = dict(again[side]), dict(whole[side])
        a.pop("wall_s"), b.pop("wall_s")
        assert a == b


def test_one_percentile_definition_a_sample_value() -> None:
    x = [4.0, 1.0, 3.0, 2.0]
    # the empirical CDF: the smallest sample with at least q % of the samples at or below it
    assert [percentile(x, q) for q in (0, 10, 25, 26, 50, 51, 75, 100)] == [
        1.0, 1.0, 1.0, 2.0, 2.0, 3.0, 3.0, 4.0]
    rng = np.random.default_rng(1)
    sample = rng.normal(size=37)
    for q in (1, 5, 33.3, 50, 95, 99):
        expected = np.percentile(sample, q, method="inverted_cdf")
        assert percentile(sample, q) == expected
        assert percentile(sample, q) in sample
    assert percentile([], 50) is None
    censored = [1.0, 2.0, np.inf, np.inf]  # a trial without collision: later than any
    assert percentile(censored, 50) == 2.0 and percentile(censored, 75) is None
    with pytest.raises(ValueError, match="q must be in"):
        percentile(x, 101)
    with pytest.raises(ValueError, match="NaN"):
        percentile([1.0, float("nan")], 50)
