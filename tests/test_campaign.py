"""The statistical protocol (SPEC §7): random_walk and resumable, deterministic campaigns.

Kept short: 3 UAVs in a 30 m area, trials of 20–40 simulated seconds.
"""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from uavmpc.apps.campaign import (
    CampaignError,
    Execution,
    RandomWalkSpec,
    aggregate,
    load_trials,
    merge_reports,
    report_rows,
    run_campaign,
    run_trial,
    trial_seeds,
)
from uavmpc.config import ConfigError
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.faults import Faults, FaultSpec
from uavmpc.scenarios.random_walk import (
    MIN_START_SEPARATION_M,
    STEP_S,
    hold_time_s,
    random_walk,
    walk_start_s,
    waypoints_reached,
)
from uavmpc.scenarios.run import RunSettings, RunSpec


def small(**kw) -> RandomWalkSpec:
    """A campaign of 3 UAVs in a 30 m area, the other fields (its own or its run settings')
    as given."""
    run = {k: kw.pop(k) for k in list(kw) if k in RUN_FIELDS}
    return RandomWalkSpec(**{"uavs": 3, "area_m": 30.0, "run": RunSettings(**run), **kw})


RUN_FIELDS = {f.name for f in dataclasses.fields(RunSettings)}


def quiet(workers: int = 1, **kw) -> Execution:
    """Flown on ``workers`` local processes without a progress bar."""
    return Execution(workers=workers, progress=False, **kw)


def test_random_walk_is_seeded_and_valid() -> None:
    a = random_walk(5, 100.0, 10.0, 300.0, seed=7)
    b = random_walk(5, 100.0, 10.0, 300.0, seed=7)
    c = random_walk(5, 100.0, 10.0, 300.0, seed=8)
    assert len(a.uavs) == 5 and a.duration_s == 300.0
    for ua, ub in zip(a.uavs, b.uavs, strict=True):
        assert ua.start_m == ub.start_m
        assert np.array_equal(ua.mission.times_s, ub.mission.times_s)
        assert np.array_equal(ua.mission.points, ub.mission.points)
    assert a.uavs[0].start_m != c.uavs[0].start_m
    starts = np.array([u.start_m for u in a.uavs])
    assert np.all(starts[:, 2] == 10.0)
    d = np.linalg.norm(starts[:, None] - starts[None], axis=2)
    assert d[np.triu_indices(5, 1)].min() >= MIN_START_SEPARATION_M
    assert len({u.priority for u in a.uavs}) == 5
    for u in a.uavs:
        m = u.mission
        assert np.all(np.abs(m.points[:, :2]) <= 50.0) and np.all(m.points[:, 2] == 10.0)
        assert np.all(np.abs(np.array(u.start_m[:2])) <= 50.0)
        assert m.times_s[0] == 0.0
        # two stamps per waypoint: a hold, then a step of STEP_S
        wps = m.points[::2, :2]
        assert np.allclose(m.points[1::2], m.points[0:-1:2])
        assert np.allclose(m.times_s[2::2] - m.times_s[1::2], STEP_S)
        legs = np.linalg.norm(np.diff(np.vstack([u.start_m[:2], wps]), axis=0), axis=1)
        assert np.allclose(np.diff(m.times_s[::2]), [hold_time_s(x) for x in legs[:-1]])
        assert m.times_s[-1] < 300.0 <= m.times_s[-1] + hold_time_s(legs[-1])
        # the reference holds a waypoint, then steps to the next
        mid = 0.5 * (m.times_s[0] + m.times_s[1])
        assert np.allclose(m.sample(np.array([mid]))[0, :2], wps[0])
    with pytest.raises(ConfigError, match="cannot place"):
        random_walk(50, 5.0, 10.0, 60.0, seed=0)


def test_trial_seeds_are_derived_from_the_campaign_seed() -> None:
    assert trial_seeds(0, 3) == trial_seeds(0, 3)
    assert trial_seeds(0, 3) != trial_seeds(0, 4) != trial_seeds(1, 4)
    child = np.random.SeedSequence(5).spawn(3)[2]
    assert trial_seeds(5, 2) == tuple(int(x) for x in child.generate_state(2, np.uint32))


@pytest.mark.slow
def test_without_avoidance_trials_stop_at_the_first_collision(tmp_path: Path) -> None:
    r = run_campaign(tmp_path, small(avoidance=False, length_s=40.0), quiet(),
                     trials=3)
    recs = sorted(load_trials(tmp_path, 0).values(), key=lambda x: x["index"])
    assert r["trials"] == 3 and r["collisions"] >= 1
    hit = [x for x in recs if x["first_collision_s"] is not None]
    assert len(hit) == r["trials_with_collision"] >= 1
    for x in hit:  # the flight ends at the first collision
        assert x["collisions"] == 1 and x["sim_s"] == x["first_collision_s"] < 40.0
        assert x["min_distance_m"] < 1.0
    ttc = r["time_to_first_collision_s"]
    assert ttc is not None and ttc["p50"] is not None and 0.0 < ttc["p50"] < 40.0
    assert r["simulated_hours"] == pytest.approx(sum(x["sim_s"] for x in recs) / 3600.0)
    # a single collided trial flown in one piece collides at the same time
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.random_walk import random_walk as rw

    x = hit[0]
    res = World(RunSpec(rw(3, 30.0, 10.0, 40.0, x["scenario_seed"]), avoidance=False,
                        seed=x["world_seed"])).run(x["first_collision_s"] + 0.1)
    assert res.collisions[0].t == x["first_collision_s"]


@pytest.mark.slow
def test_with_avoidance_no_collision(tmp_path: Path) -> None:
    r = run_campaign(tmp_path, small(length_s=20.0), quiet(), trials=3)
    assert r["trials"] == 3 and r["collisions"] == 0
    assert r["time_to_first_collision_s"] == {"p50": None, "p75": None, "p95": None,
                                              "p99": None}
    assert r["min_distance_m"] > 1.0
    assert r["simulated_hours"] == pytest.approx(3 * 20.0 / 3600.0)
    for name in ("report.json", "report.md", "ttc_cdf.png", "min_distance_hist.png",
                 "campaign.json", "trials.jsonl"):
        assert (tmp_path / name).stat().st_size > 0, name
    md = (tmp_path / "report.md").read_text()
    assert "| random_walk | without avoidance | with avoidance |" in md
    assert "| collisions | – | 0 |" in md
    assert "time to first collision, 99 %" in md
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert on_disk == json.loads(json.dumps(r))
    for key in ("trials", "simulated_hours", "collisions", "time_to_first_collision_s",
                "min_distance_m", "wall_s", "seed", "parameters"):
        assert key in on_disk


@pytest.mark.parametrize("workers", [1, 2])  # 2: the logs re-flown side by side too
def test_report_html_is_one_page_with_every_trial_and_the_closest_trials_logs(
        tmp_path: Path, workers: int) -> None:
    from html.parser import HTMLParser

    from uavmpc.log import read_topics

    r = run_campaign(tmp_path, small(length_s=12.0), quiet(workers), trials=4, logs=2)
    page = (tmp_path / "report.html").read_text()
    trials = {t["index"]: t for t in (json.loads(line) for line in
                                      (tmp_path / "trials.jsonl").read_text().splitlines())}

    class Page(HTMLParser):
        def __init__(self) -> None:
            super().__init__()
            self.srcs: list[str] = []
            self.links: list[str] = []
            self.rows = 0
            self.scripts = 0

        def handle_starttag(self, tag: str, attrs: list) -> None:
            a = dict(attrs)
            if tag == "img":
                self.srcs.append(a["src"])
            elif tag == "a":
                self.links.append(a["href"])
            elif tag == "tr":
                self.rows += 1
            elif tag in ("script", "link") and ("src" in a or "href" in a):
                self.scripts += 1  # fetched from elsewhere: not self-contained

    p = Page()
    p.feed(page)
    assert p.scripts == 0 and len(p.srcs) == 2
    assert all(s.startswith("data:image/png;base64,") for s in p.srcs)
    # the report table (header + its rows) and the trials table (header + one per trial)
    assert f"<td>{r['collisions']}</td>" in page and p.rows >= 1 + 4 + 1 + 10
    closest = sorted(trials.values(), key=lambda t: t["min_distance_m"])[:2]
    assert sorted(p.links) == sorted(f"logs/trial_{t['index']}.mcap" for t in closest)
    for t in closest:  # each log is that trial, re-flown from its seeds
        topics = read_topics(tmp_path / f"logs/trial_{t['index']}.mcap")
        d = min(m["min_distance_m"] for m in topics["/metrics"])
        assert d >= t["min_distance_m"] - 1e-9 and d < t["min_distance_m"] + 0.5
    assert not list((tmp_path / "logs").glob("*.part"))
    # a trial flown again from the folder's parameters is the same trial
    stored = json.loads((tmp_path / "campaign.json").read_text())["spec"]
    again = run_trial(RandomWalkSpec.from_json(stored), closest[0]["index"])
    assert {k: v for k, v in again.items() if k != "wall_s"} == {
        k: v for k, v in closest[0].items() if k != "wall_s"}
    with pytest.raises(CampaignError, match="logs: must be an integer"):
        run_campaign(tmp_path, small(length_s=12.0), quiet(), trials=4, logs=-1)


@pytest.mark.slow
def test_hours_stop_rule(tmp_path: Path) -> None:
    r = run_campaign(tmp_path, small(length_s=20.0), quiet(), hours=50.0 / 3600.0)
    assert r["trials"] == 3 and r["simulated_hours"] == pytest.approx(60.0 / 3600.0)


def test_resume_runs_only_the_missing_trials(tmp_path: Path, monkeypatch) -> None:
    # (no flight logs: those re-fly trials on purpose, this counts the campaign's own)
    spec = small(avoidance=False, length_s=20.0, seed=3)
    run_campaign(tmp_path, spec, quiet(), trials=2, logs=0)
    assert len((tmp_path / "trials.jsonl").read_text().splitlines()) == 2
    # a crash mid-write leaves a torn line: it is dropped and the trial re-run
    with open(tmp_path / "trials.jsonl", "a") as f:
        f.write('{"index": 2, "scen')
    import uavmpc.apps.campaign as campaign

    flown: list[int] = []

    def spy(spec, index):
        flown.append(index)
        return run_trial(spec, index)

    monkeypatch.setattr(campaign, "run_trial", spy)
    r = run_campaign(tmp_path, spec, quiet(), trials=4, logs=0)
    assert flown == [2, 3]
    assert r["trials"] == 4
    lines = (tmp_path / "trials.jsonl").read_text().splitlines()
    assert [json.loads(x)["index"] for x in lines] == [0, 1, 2, 3]
    # the same, done again: nothing to fly, same report
    flown.clear()
    again = run_campaign(tmp_path, spec, quiet(), trials=4, logs=0)
    assert flown == []
    assert again == r  # also the wall time: the sum over the invocations that flew trials
    runs = [json.loads(x) for x in (tmp_path / "runs.jsonl").read_text().splitlines()]
    assert [x["new_trials"] for x in runs] == [2, 2]
    assert r["wall_s"] == pytest.approx(sum(x["wall_s"] for x in runs))
    # fewer trials than done: the report covers the first ones
    assert run_campaign(tmp_path, spec, quiet(), trials=1, logs=0)["trials"] == 1


def test_changed_parameters_are_refused(tmp_path: Path) -> None:
    run_campaign(tmp_path, small(avoidance=False, length_s=10.0), quiet(), trials=1)
    with pytest.raises(CampaignError, match=r"other parameters \(loss: 0\.0 there, 0\.2 now"):
        run_campaign(tmp_path, small(avoidance=False, length_s=10.0,
                                     link=LinkSettings(loss=0.2)), quiet(), trials=2)
    with pytest.raises(CampaignError, match="avoidance"):
        run_campaign(tmp_path, small(length_s=10.0), quiet(), trials=2)
    assert len((tmp_path / "trials.jsonl").read_text().splitlines()) == 1


@pytest.mark.parametrize("spec, kw, match", [
    ({}, {}, "exactly one of hours"),
    ({}, {"trials": 2, "hours": 1.0}, "exactly one of hours"),
    ({}, {"trials": 0}, "trials"),
    ({"uavs": 1}, {"trials": 1}, "uavs"),
    ({"link": {"loss": 1.0}}, {"trials": 1}, "loss"),
    ({"avoidance": False, "length_s": -1.0}, {"trials": 1}, "cap_s"),
    ({"length_s": -1.0}, {"trials": 1}, "trial_s"),
    ({"seed": -1}, {"trials": 1}, "seed"),
    ({"wind_mps": 31.0}, {"trials": 1}, "wind_mps"),
    ({"launch_check_s": 30.0, "length_s": 20.0}, {"trials": 1},
     r"launch_check_s: .*the flight's 20 s\], got 30"),
    ({"faults": FaultSpec(silent=4)}, {"trials": 1}, "exceed the 3 UAVs"),
    ({"duration_s": 20.0}, {"trials": 1}, "run.duration_s: a trial's length is length_s"),
    ({"drawn": Faults.given(non_cooperative=["uav1"])}, {"trials": 1},
     "run.drawn: a campaign draws each trial's faults"),
    ({"link": {"range_m": 50.0}}, {"trials": 1}, "run.link: a campaign's link"),
])
def test_bad_parameters(tmp_path: Path, spec: dict, kw: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        if "link" in spec:
            spec = {**spec, "link": LinkSettings.from_dict(spec["link"])}
        run_campaign(tmp_path, small(**spec), quiet(), **kw)
    assert not any(tmp_path.iterdir())  # refused before a folder or a trial
    with pytest.raises(CampaignError, match="spec: must be a RandomWalkSpec"):
        run_campaign(tmp_path, {"uavs": 3}, quiet(), trials=1)  # type: ignore[arg-type]
    with pytest.raises(CampaignError, match="execution: must be an Execution"):
        run_campaign(tmp_path, small(), {"workers": 1}, trials=1)  # type: ignore[arg-type]
    with pytest.raises(CampaignError, match="run: must be RunSettings"):
        RandomWalkSpec(run=RunSpec(random_walk(3, duration_s=10.0)))


@pytest.mark.parametrize("given, match", [
    ({"workers": 0}, "workers: must be an integer ≥ 1, got 0"),
    ({"threads": 0}, "threads"), ({"threads": 1.5}, "threads"),
    ({"ray_address": ""}, "ray_address"), ({"progress": "no"}, "progress"),
])
def test_a_bad_execution_is_refused_by_name(given: dict, match: str) -> None:
    with pytest.raises(CampaignError, match=match):
        Execution(**given)


@pytest.mark.slow
def test_same_seed_same_report_with_1_or_2_workers(tmp_path: Path) -> None:
    spec = small(avoidance=False, length_s=20.0, seed=11)
    one = run_campaign(tmp_path / "one", spec, quiet(), trials=4)
    two = run_campaign(tmp_path / "two", spec, quiet(2), trials=4)
    one.pop("wall_s"), two.pop("wall_s")
    one.pop("trial_wall_s"), two.pop("trial_wall_s")
    assert json.dumps(one) == json.dumps(two)


def test_merge_reports_fills_both_columns(tmp_path: Path) -> None:
    run_campaign(tmp_path / "a", small(avoidance=False, length_s=10.0), quiet(),
                 trials=1)
    run_campaign(tmp_path / "b", small(length_s=10.0), quiet(), trials=1)
    md = merge_reports(tmp_path / "a", tmp_path / "b", out=tmp_path / "both.md")
    row = next(x for x in md.splitlines() if x.startswith("| trials |"))
    assert row == "| trials | 1 | 1 |"
    assert (tmp_path / "both.md").read_text() == md


# ------------------------------------------------------------- the start from the ground
def test_from_the_ground_a_random_walk_takes_off_then_walks_the_same_waypoints() -> None:
    from uavmpc.scenarios.traffic import take_off
    from uavmpc.tracker.params import DynamicLimits

    air = random_walk(5, 100.0, 10.0, 300.0, seed=7)
    ground = random_walk(5, 100.0, 10.0, 300.0, seed=7, ground_start=True)
    walk = walk_start_s(10.0)
    # the traffic's climb (90 % of 2 m/s, 80 % of 1.5 m/s²), then one tracker horizon
    assert walk == pytest.approx(2 * 1.5 + (10.0 - 1.8 * 1.5) / 1.8 + 7.81)
    assert ground.walk_start_s == walk and air.walk_start_s == 0.0
    for ua, ug in zip(air.uavs, ground.uavs, strict=True):
        assert ug.start_m == (*ua.start_m[:2], 0.0)  # on the ground below the same start
        m = ug.mission
        up = m.times_s < walk
        t, z = m.times_s[up], m.points[up, 2]
        assert np.all(m.points[up, :2] == ua.start_m[:2])  # straight up
        assert z[0] == 0.0 and z[-1] == 10.0 and np.all(np.diff(z) >= 0.0)
        np.testing.assert_allclose(z, take_off(10.0, t)[0], atol=1e-12)
        assert np.max(np.diff(z) / np.diff(t)) <= DynamicLimits().ascend_speed_mps
        # then the same walk, every switch later by walk_start_s, the length unchanged
        n = int(np.count_nonzero(~up))
        assert m.times_s[~up][0] == walk and 3 <= n < len(ua.mission.times_s)
        np.testing.assert_array_equal(m.points[~up], ua.mission.points[:n])
        np.testing.assert_allclose(m.times_s[~up], ua.mission.times_s[:n] + walk, atol=1e-9)
        assert m.times_s[-1] < 300.0 <= m.times_s[-1] + 60.0
    with pytest.raises(ConfigError, match="ground_start: must be true or false"):
        random_walk(3, ground_start="yes")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="ends before the walk"):
        random_walk(3, duration_s=10.0, ground_start=True)


def test_from_the_ground_the_uavs_climb_side_by_side_then_set_off() -> None:
    """Five UAVs on the ground 3 m apart or more (a 12 m square): they climb to the walk's
    height without a collision and without moving sideways, and only then fly their walk."""
    from uavmpc.drivers.world import World

    sc = random_walk(5, 12.0, 10.0, 30.0, seed=7, ground_start=True)
    res = World(RunSpec(sc, avoidance=False, seed=3)).run(30.0)
    t, p = res.t_s, res.positions_m
    assert np.all(p[0, :, 2] < 0.01)  # resting on the ground
    assert np.all(np.abs(p[(t > 9.0) & (t < sc.walk_start_s), :, 2] - 10.0) < 0.1)  # up in time
    sideways = np.hypot(p[..., 0] - p[0, :, 0], p[..., 1] - p[0, :, 1])  # (K, N)
    assert sideways[p[..., 2] < 9.5].max() < 0.1  # no waypoint flown before the height
    assert sideways[-1].min() > 1.0  # and then the walk
    # (the tracker sets off a few seconds before a step it sees coming: the walk's start)
    side_by_side = t < t[np.argmax(sideways.max(axis=1) > 0.1)]
    assert t[side_by_side][-1] > 8.0
    assert not [c for c in res.collisions if c.t <= t[side_by_side][-1]]
    assert res.min_distance_m[side_by_side].min() > MIN_START_SEPARATION_M - 0.2
    reached, due = waypoints_reached(sc, t, p)  # the take-off is no waypoint
    assert due >= 5 and reached == due


def test_a_campaign_from_the_ground_says_so_and_counts_from_the_ground(tmp_path: Path,
                                                                      capsys) -> None:
    from uavmpc.apps.cli import main
    from uavmpc.scenarios.traffic import take_off

    out = tmp_path / "ground"
    args = ["campaign", "random-walk", "--no-avoidance", "--trials", "3", "--cap-s", "40",
            "--workers", "1", "--no-progress", "--uavs", "3", "--area", "30", "--logs", "0"]
    assert main([*args, "--ground-start", "--out", str(out)]) == 0
    assert "random_walk, from the ground (walk from 14.9 s)" in capsys.readouterr().out
    r = json.loads((out / "report.json").read_text())
    walk = walk_start_s(10.0)
    assert r["parameters"]["ground_start"] is True
    assert r["ground_start"] is True and r["walk_start_s"] == walk
    assert "| start | on the ground, walk from 14.9 s | – |" in (out / "report.md").read_text()
    stored = json.loads((out / "campaign.json").read_text())["spec"]
    assert stored["ground_start"] is True
    # times count from t = 0 on the ground: none on the ground or in the climb (it ends at
    # 7.06 s), and each trial is the one flown again from the folder's parameters
    recs = load_trials(out, 0)
    hit = [x for x in recs.values() if x["first_collision_s"] is not None]
    climb_s = take_off(10.0, np.zeros(1))[1]
    assert hit and all(climb_s + 1.0 < x["first_collision_s"] < 40.0 for x in hit)
    again = run_trial(RandomWalkSpec.from_json(stored), hit[0]["index"])
    assert again["first_collision_s"] == hit[0]["first_collision_s"]
    # the folder is not continued from the air, nor a campaign with bad values started
    assert main([*args, "--out", str(out)]) == 2
    assert "ground_start: True there, None now" in capsys.readouterr().err
    short = [{"40": "10"}.get(a, a) for a in args]  # --cap-s 10
    assert main([*short, "--ground-start", "--out", str(tmp_path / "x")]) == 2
    assert "cap_s: 10 s ends before the walk" in capsys.readouterr().err
    assert main(["campaign", "traffic", "--trials", "1", "--ground-start"]) == 2
    assert "--ground-start: only for campaign random-walk" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*args, "--ground-start=yes", "--out", str(tmp_path / "y")])
    with pytest.raises(CampaignError, match="ground_start: must be true or false"):
        RandomWalkSpec(ground_start=1)  # type: ignore[arg-type]


def test_without_the_ground_start_the_protocol_is_unchanged() -> None:
    """Pinned from the code before the option existed: the same scenario and trial."""
    sc = random_walk(5, 100.0, 10.0, 300.0, seed=7)
    off = random_walk(5, 100.0, 10.0, 300.0, seed=7, ground_start=False)
    for a, b in zip(sc.uavs, off.uavs, strict=True):
        assert a.start_m == b.start_m and a.start_m[2] == 10.0
        np.testing.assert_array_equal(a.mission.times_s, b.mission.times_s)
        np.testing.assert_array_equal(a.mission.points, b.mission.points)
    u = sc.uavs[0]
    assert u.start_m == (29.785918684335627, -44.690611674359594, 10.0)
    assert u.mission.times_s[:3].tolist() == [0.0, 12.453405950530426, 12.463405950530426]
    assert u.mission.points[0].tolist() == [-1.9417994264188252, -44.04581933284578, 10.0, 0.0]
    assert len(u.mission.times_s) == 39
    spec = small(avoidance=False, length_s=30.0, seed=5)
    assert "ground_start" not in spec.to_json()
    rec = run_trial(spec, 2)
    assert rec["first_collision_s"] == pytest.approx(9.40, abs=1e-9)
    assert rec["first_collision_pair"] == ["uav1", "uav3"]
    assert rec["min_distance_m"] == pytest.approx(0.9279390351175146, rel=1e-9)
    report = aggregate([rec], spec.to_json(), 0.0)
    assert "ground_start" not in report and "walk_start_s" not in report
    assert not any(row[0] == "start" for row in report_rows(report))


@pytest.fixture
def local_ray():
    ray = pytest.importorskip("ray")
    yield ray
    ray.shutdown()  # do not keep a Ray instance on the 2 cores for the rest of the session


@pytest.mark.slow
def test_ray_path_on_a_local_ray_instance_gives_the_same_report(tmp_path: Path,
                                                                local_ray) -> None:
    spec = small(avoidance=False, length_s=10.0)
    r = run_campaign(tmp_path / "ray", spec, quiet(None, ray_address="local"), trials=3)
    assert local_ray.is_initialized()
    ref = run_campaign(tmp_path / "ref", spec, quiet(), trials=3)
    walls = ("wall_s", "trial_wall_s")
    assert {k: v for k, v in r.items() if k not in walls} == {
        k: v for k, v in ref.items() if k not in walls}
    assert r["trials"] == 3


def test_ray_missing_is_a_clear_error(tmp_path: Path, monkeypatch) -> None:
    import builtins

    real = builtins.__import__

    def no_ray(name, *a, **k):
        if name == "ray":
            raise ImportError("No module named 'ray'")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(CampaignError, match=r"pip install 'uavmpc\[cluster\]'"):
        run_campaign(tmp_path, small(avoidance=False, length_s=10.0),
                     quiet(None, ray_address="auto"), trials=1)


#: Collisions found by the first 24-hour runs of (b), each fixed by a rule of the strategy
#: (docs/campaign.md): (trial, loss, latency_s, flown up to s, what happened).
FOUND_BY_CAMPAIGNS = [
    (125, 0.0, 0.05, 360.0, "nominal link, 347.07 s: uav5 climbed two layers at once, through "
     "the layer of uav4 passing over it (the way up is now checked)"),
    (48, 0.3, 0.2, 230.0, "30 % loss, 210.65 s: uav4 lost ten messages of uav3 in a row, "
     "released its offset and came down onto it (no release while someone is silent)"),
    (78, 0.3, 0.2, 450.0, "30 % loss, 439.96 s: uav5 had missed two messages of uav2 and "
     "climbed into its layer (new offsets clear of silent UAVs too)"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("index", "loss", "latency_s", "duration_s", "story"),
                         FOUND_BY_CAMPAIGNS, ids=[f"trial-{t[0]}" for t in FOUND_BY_CAMPAIGNS])
def test_collisions_found_by_the_24_hour_campaigns_no_longer_happen(
        index: int, loss: float, latency_s: float, duration_s: float, story: str) -> None:
    """``uavmpc campaign random-walk --avoidance --hours 24 [--loss 0.3 --latency 0.2]``,
    seed 0: the trial that collided, flown past the moment of its collision."""
    link = LinkSettings(latency_s=latency_s, jitter_s=0.02, loss=loss)
    spec = RandomWalkSpec(run=RunSettings(avoidance=True, seed=0, link=link), uavs=5,
                          area_m=100.0, height_m=10.0, length_s=duration_s)
    record = run_trial(spec, index)
    assert record["collisions"] == 0, story
    assert record["min_distance_m"] > 2.0, story


def test_a_campaign_says_what_it_does_after_its_progress_bar(tmp_path: Path, capsys) -> None:
    """What a newcomer met: silence while the closest trials were flown again, more hours
    than asked without a word, "the 3 closest trials" of 2, and a slow split unannounced."""
    from uavmpc.apps.campaign_engine import split_cores
    from uavmpc.apps.cli import main
    from uavmpc.jit import available_threads

    out = tmp_path / "c"
    assert main(["campaign", "random-walk", "--hours", "0.005", "--trial-s", "12", "--uavs",
                 "3", "--area", "30", "--workers", "1", "--logs", "5", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "campaign: 0.01 h flown for --hours 0.005: the trials are whole (2 of up to 12 s " \
           "each)" in captured.err
    assert ("campaign: flying the 2 closest trial(s) again into flight logs (logs/trial_"
            in captured.err)
    assert "logs/ (the 2 closest trials)" in captured.out
    cores = available_threads()
    assert split_cores(2, cores, say=True) == (2, cores)
    err = capsys.readouterr().err
    assert f"campaign: 2 workers × {cores} threads = {2 * cores} threads on {cores} cores" in err
    split_cores(1, 1, say=True)
    assert "parks" not in capsys.readouterr().err
