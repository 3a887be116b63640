"""The campaign beside a published result: bootstrap intervals on our percentiles, the reference
design's Table II as data, and the walk variants that test what explains the difference."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from uavmpc.apps.campaign import RandomWalkSpec, aggregate, report_markdown, run_trial
from uavmpc.apps.published import PublishedResult, comparison_rows, inside
from uavmpc.config import ConfigError
from uavmpc.scenarios.random_walk import (
    ACCEL_MPS2,
    SPEED_MPS,
    WalkVariant,
    hold_time_s,
    random_walk,
    walk_start_s,
)
from uavmpc.scenarios.run import RunSettings
from uavmpc.scenarios.stats import bootstrap_interval, percentile


def test_bootstrap_intervals_cover_the_true_percentile_about_as_often_as_they_say() -> None:
    """Over 200 seeded samples of 150 exponential times, the 95 % intervals of the median and
    of the 75 % point hold the true value in 88–99 % of the samples (a wrong resampling, a
    swapped tail or an off-by-one in the ends falls outside)."""
    rng = np.random.default_rng(3)
    truth = {50: 80.0 * np.log(2.0), 75: 80.0 * np.log(4.0)}
    hits = {q: 0 for q in truth}
    for k in range(200):
        x = rng.exponential(80.0, 150)
        for q, t in truth.items():
            lo, hi = bootstrap_interval(x, q, resamples=1000, seed=k)
            assert lo is not None and hi is not None and lo <= percentile(x, q) <= hi
            hits[q] += lo <= t <= hi
    for q in truth:
        assert 0.88 <= hits[q] / 200 <= 0.99, (q, hits[q])


def test_a_bootstrap_interval_is_seeded_narrows_with_more_trials_and_knows_censoring() -> None:
    x = np.random.default_rng(0).exponential(80.0, 100)
    assert bootstrap_interval(x, 50) == bootstrap_interval(x, 50)
    big = np.random.default_rng(0).exponential(80.0, 2000)
    lo, hi = bootstrap_interval(x, 50)
    blo, bhi = bootstrap_interval(big, 50)
    assert lo is not None and hi is not None and blo is not None and bhi is not None
    assert bhi - blo < 0.5 * (hi - lo)
    censored = np.r_[x[:20], np.full(80, np.inf)]  # 80 % "later than the trials lasted"
    lo, hi = bootstrap_interval(censored, 50)
    assert lo is None and hi is None
    lo, hi = bootstrap_interval(censored, 10)
    assert lo is not None and hi is not None
    assert bootstrap_interval([], 50) == (None, None)
    with pytest.raises(ValueError, match="NaN"):
        bootstrap_interval([1.0, float("nan")], 50)
    with pytest.raises(ValueError, match="level"):
        bootstrap_interval([1.0], 50, level=1.5)


def test_table_ii_ships_with_its_source_and_numbers() -> None:
    t = PublishedResult.load("table2")
    assert "IROS" in t.source and "Table II" in t.source and t.time_origin == "take-off"
    assert t.trials == 495
    assert dict(t.time_to_first_collision_s) == {"p50": 104.0, "p75": 152.0, "p95": 264.0,
                                                 "p99": 431.0}
    assert (t.hours, t.collisions, t.min_distance_m) == (24.0, 0, 1.21)
    assert PublishedResult.from_json(json.loads(json.dumps(t.to_json()))) == t


def test_a_bad_reference_table_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="neither a built-in table"):
        PublishedResult.load("table3")
    base = ('name = "x"\nsource = "y"\nsetup = "z"\ntime_origin = "take-off"\n')
    cases = [
        ("[without_avoidance]\ntrial = 4\n", "without_avoidance.trial: unknown field "
                                             "\\(did you mean 'trials'"),
        ("[without_avoidance]\ntime_to_first_collision_s = { p50 = \"104\" }\n",
         "time_to_first_collision_s.p50: must be a number"),
        ("[without_avoidance]\ntime_to_first_collision_s = { p60 = 1.0 }\n", "p60: unknown"),
        ("[with_avoidance]\nmin_distance_m = -1\n", "min_distance_m: must be a number ≥ 0"),
    ]
    for i, (extra, match) in enumerate(cases):
        f = tmp_path / f"t{i}.toml"
        f.write_text(base + extra)
        with pytest.raises(ConfigError, match=match):
            PublishedResult.load(f)
    f = tmp_path / "name.toml"
    f.write_text(base.replace('name = "x"\n', ""))
    with pytest.raises(ConfigError, match="name: must be a non-empty string"):
        PublishedResult.load(f)


def test_the_report_sets_our_percentiles_and_intervals_beside_the_published_ones() -> None:
    # 200 trials: first collisions at 1, 2, ..., 200 s (a trial per second)
    recs = [{"index": i, "first_collision_s": float(i + 1), "min_distance_m": 0.9,
             "sim_s": float(i + 1), "collisions": 1, "wall_s": 0.0} for i in range(200)]
    params = RandomWalkSpec(run=RunSettings(avoidance=False)).to_json()
    report = aggregate(recs, params, 0.0)
    report["reference"] = PublishedResult.load("table2").to_json()
    ci = report["time_to_first_collision_ci95_s"]
    assert ci["p50"][0] < 100.0 < ci["p50"][1] and ci["p99"][1] <= 200.0
    rows = {r[0]: r for r in comparison_rows(report)}
    # our median ~100 s: the published 104 s lies inside; 264 s and 431 s above everything
    assert rows["time to first collision, 50 %"][4] == "yes"
    assert rows["time to first collision, 95 %"][4] == "no: above"
    assert rows["time to first collision, 99 %"][3] == "431 s"
    assert rows["trials"][1:4:2] == ("200", "495")
    assert rows["times count from"][3] == "take-off"
    text = report_markdown(report)
    assert "## Beside the reference design, Table II" in text and "Báča" in text
    assert "| time to first collision, 95 % | 190.0 s | [" in text
    del report["reference"]
    assert "Beside" not in report_markdown(report) and comparison_rows(report) == []
    assert inside(5.0, (None, 4.0)) == "no: above" and inside(5.0, (6.0, None)) == "no: below"


def test_the_protocol_is_the_walk_without_a_variant() -> None:
    """Pinned from the code before the variants (its walks drawn UAV by UAV, now all in the
    order of their switch times): the same start from the ground, bit for bit."""
    b = random_walk(5, 100.0, 10.0, 300.0, seed=7, ground_start=True, variant=WalkVariant())
    u = b.uavs[2]
    assert len(u.mission.times_s) == 79
    assert u.mission.times_s[60:62].tolist() == [167.46920451954225, 183.38116913737719]
    assert u.mission.points[61].tolist() == [-18.72400244367253, -25.722952376961228, 10.0,
                                             0.0]
    assert not b.limits and b.count_from_s == 0.0 and WalkVariant().changed() == {}
    assert "walk" not in RandomWalkSpec().to_json()


def test_take_offs_one_after_another_each_walk_after_its_own() -> None:
    sc = random_walk(5, 100.0, 10.0, 300.0, seed=7, ground_start=True,
                     variant=WalkVariant(takeoff_interval_s=10.0))
    plain = random_walk(5, 100.0, 10.0, 300.0, seed=7, ground_start=True)
    walk = walk_start_s(10.0)
    for i, (u, p) in enumerate(zip(sc.uavs, plain.uavs, strict=True)):
        m = u.mission
        on_ground = m.times_s < i * 10.0
        assert np.all(m.points[on_ground | (m.times_s == i * 10.0), 2] == 0.0)
        first = int(np.searchsorted(m.times_s, walk + i * 10.0))
        assert m.times_s[first] == pytest.approx(walk + i * 10.0)
        # the same waypoints as the plain start from the ground, each switched i·10 s later
        np.testing.assert_array_equal(m.points[first::2, :2], p.mission.points[
            int(np.searchsorted(p.mission.times_s, walk))::2, :2][:len(m.points[first::2])])
    with pytest.raises(ConfigError, match="need a start from the ground"):
        random_walk(5, variant=WalkVariant(takeoff_interval_s=5.0))
    with pytest.raises(ConfigError, match="ends before the walk"):
        random_walk(5, duration_s=50.0, ground_start=True,
                    variant=WalkVariant(takeoff_interval_s=10.0))


def test_waypoints_drawn_apart_keep_their_clearance_from_the_others_held_ones() -> None:
    clearance = 20.0
    sc = random_walk(5, 100.0, 10.0, 600.0, seed=3, variant=WalkVariant(clearance_m=clearance))
    held: list[tuple[np.ndarray, np.ndarray]] = []  # per UAV: switch times, waypoints
    for u in sc.uavs:
        m = u.mission
        held.append((m.times_s[0::2], m.points[0::2, :2]))
    closest = np.inf
    for i, (times, wps) in enumerate(held):
        for t, w in zip(times, wps, strict=True):
            for j, (tj, wj) in enumerate(held):
                if j == i:
                    continue
                k = int(np.searchsorted(tj, t, side="right")) - 1  # what j holds at t
                other = wj[k] if k >= 0 else np.asarray(sc.uavs[j].start_m[:2])
                if k >= 0 and tj[k] == t and j > i:
                    continue  # j switches at the same instant, after i: drawn against i
                closest = min(closest, float(np.hypot(*(w - other))))
    assert closest >= clearance
    plain = random_walk(5, 100.0, 10.0, 600.0, seed=3)
    assert any(not np.array_equal(a.mission.points, b.mission.points)
               for a, b in zip(sc.uavs, plain.uavs, strict=True))


def test_a_slower_walk_sets_the_tracker_limits_and_holds_waypoints_longer() -> None:
    sc = random_walk(3, 100.0, 10.0, 300.0, seed=1, variant=WalkVariant(speed_mps=4.0,
                                                                        accel_mps2=1.5))
    assert dict(sc.limits.values) == {"horizontal_speed_mps": 4.0,
                                      "horizontal_accel_mps2": 1.5}
    m = sc.uavs[0].mission
    d = float(np.hypot(*(m.points[0, :2] - np.asarray(sc.uavs[0].start_m[:2]))))
    assert m.times_s[2] == pytest.approx(hold_time_s(d, 4.0, 1.5))
    assert hold_time_s(d, 4.0, 1.5) > hold_time_s(d, SPEED_MPS, ACCEL_MPS2)
    with pytest.raises(ConfigError, match=r"walk\.speed_mps: must be in"):
        WalkVariant(speed_mps=0.0)
    with pytest.raises(ConfigError, match=r"walk\.clearence_m: unknown field"):
        WalkVariant.from_dict({"clearence_m": 3.0})


def test_counting_after_the_first_waypoint_ignores_earlier_collisions() -> None:
    """5 UAVs in a 14 m square collide within seconds; counted from the first waypoints' end,
    the first collision counted comes after it, and the flight goes on through the earlier
    ones."""
    plain = RandomWalkSpec(run=RunSettings(avoidance=False, seed=1), uavs=5, area_m=14.0,
                           length_s=60.0)
    late = dataclasses.replace(plain, walk=WalkVariant(count_after_first=True))
    assert late.to_json()["walk"] == {"count_after_first": True}
    assert RandomWalkSpec.from_json(late.to_json()) == late
    sc = random_walk(5, 14.0, 10.0, 60.0, trial_seeds_of(late, 0),
                     variant=WalkVariant(count_after_first=True))
    a, b = run_trial(plain, 0), run_trial(late, 0)
    assert a["first_collision_s"] is not None and a["first_collision_s"] < sc.count_from_s
    assert b["first_collision_s"] is None or b["first_collision_s"] >= sc.count_from_s


def trial_seeds_of(spec: RandomWalkSpec, index: int) -> int:
    from uavmpc.apps.campaign import trial_seeds

    return trial_seeds(spec.run.seed, index)[0]


def test_the_campaign_cli_sets_its_report_beside_table_ii_or_a_file_or_nothing(
        tmp_path: Path, capsys) -> None:
    from uavmpc.apps.cli import main

    args = ["campaign", "random-walk", "--no-avoidance", "--trials", "3", "--cap-s", "40",
            "--workers", "1", "--no-progress", "--uavs", "3", "--area", "30", "--logs", "0"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    report = json.loads((tmp_path / "a" / "report.json").read_text())
    assert report["reference"]["trials"] == 495
    assert set(report["time_to_first_collision_ci95_s"]) == {"p50", "p75", "p95", "p99"}
    page = (tmp_path / "a" / "report.html").read_text()
    assert "Beside the reference design, Table II" in page and "published inside ours?" in page
    mine = tmp_path / "mine.toml"
    mine.write_text('name = "our lab"\nsource = "notes"\nsetup = "s"\ntime_origin = "arming"\n'
                    "[without_avoidance]\ntime_to_first_collision_s = { p50 = 12.0 }\n")
    assert main([*args, "--reference", str(mine), "--out", str(tmp_path / "b")]) == 0
    text = (tmp_path / "b" / "report.md").read_text()
    assert "## Beside the our lab" in text and "| 12 s |" in text and "arming" in text
    assert main([*args, "--reference", "none", "--out", str(tmp_path / "c")]) == 0
    assert "Beside" not in (tmp_path / "c" / "report.md").read_text()
    capsys.readouterr()
    assert main([*args, "--reference", "tabel2", "--out", str(tmp_path / "d")]) == 2
    assert "'tabel2' is neither a built-in table (table2) nor a TOML file" in (
        capsys.readouterr().err)
    assert main([*args, "--walk-speed", "-1", "--out", str(tmp_path / "e")]) == 2
    assert "--walk-speed: must be in (0, 30], got -1.0" in capsys.readouterr().err
    assert main(["campaign", "traffic", "--trials", "1", "--waypoint-clearance", "5"]) == 2
    assert "--waypoint-clearance: only for campaign random-walk" in capsys.readouterr().err


def test_the_paper_start_is_the_ground_start_with_take_offs_15_s_apart(tmp_path: Path,
                                                                       capsys) -> None:
    from uavmpc.apps.cli import main
    from uavmpc.scenarios.random_walk import PAPER_TAKEOFF_INTERVAL_S

    args = ["campaign", "random-walk", "--no-avoidance", "--trials", "1", "--cap-s", "100",
            "--workers", "1", "--no-progress", "--uavs", "3", "--area", "30", "--logs", "0"]
    assert main([*args, "--paper-start", "--out", str(tmp_path / "p")]) == 0
    spec = json.loads((tmp_path / "p" / "campaign.json").read_text())["spec"]
    assert spec["ground_start"] is True
    assert spec["walk"] == {"takeoff_interval_s": PAPER_TAKEOFF_INTERVAL_S} == {
        "takeoff_interval_s": 15.0}
    capsys.readouterr()
    assert main([*args, "--paper-start", "--takeoff-interval", "10", "--out",
                 str(tmp_path / "q")]) == 2
    assert "--paper-start takes off 15 s apart" in capsys.readouterr().err
    assert main(["campaign", "traffic", "--trials", "1", "--paper-start"]) == 2
    assert "--paper-start: only for campaign random-walk" in capsys.readouterr().err
