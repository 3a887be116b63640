"""The traffic scenario: its layout and references, its outcome, ``run traffic`` and
``campaign traffic``. Small worlds (6–10 UAVs, dense, short trips) keep it to seconds."""

import json
import math

import numpy as np
import pytest

from uavmpc.apps.campaign_engine import Execution
from uavmpc.apps.cli import main
from uavmpc.apps.traffic_campaign import run_traffic_campaign
from uavmpc.config import ConfigError
from uavmpc.drivers.summary import RunSummary
from uavmpc.drivers.world import World
from uavmpc.scenarios.run import RunSpec
from uavmpc.scenarios.traffic import (
    ARRIVAL_TOLERANCE_M,
    DEPARTURE_START_S,
    SAMPLE_PERIOD_S,
    cruise_height,
    traffic,
    traffic_outcome,
)
from uavmpc.tracker.params import DynamicLimits

#: A dense little traffic: 10 UAVs in a ~90 m square, one layer, trips of 40–80 m (~30 s).
SMALL = {"density_per_km2": 1200.0, "min_trip_m": 40.0, "max_trip_m": 80.0,
         "cruise_heights_m": (10.0,), "departure_window_s": 4.0}


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"n_uavs": 0}, "n_uavs"),
    ({"n_uavs": 2.5}, "n_uavs"),
    ({"density_per_km2": -1.0}, "density_per_km2"),
    # 20 pads cannot be 15 m apart in a 22 m square
    ({"density_per_km2": 2e4, "min_trip_m": 20.0, "max_trip_m": 30.0}, "density_per_km2"),
    ({"duration_s": 0.0}, "duration_s"),
    ({"cruise_heights_m": []}, "cruise_heights_m"),
    ({"cruise_heights_m": [30.0, 30.0]}, r"cruise_heights_m\[1\]"),
    ({"cruise_heights_m": [1.0]}, r"cruise_heights_m\[0\]"),
    ({"min_trip_m": 300.0, "max_trip_m": 200.0}, "max_trip_m"),
    ({"min_trip_m": 5.0}, "min_trip_m"),  # below the pad separation
    ({"min_trip_m": 5000.0, "max_trip_m": 6000.0}, "min_trip_m"),  # beyond the area
    ({"min_pad_separation_m": 0.0}, "min_pad_separation_m"),
    ({"departure_window_s": -1.0}, "departure_window_s"),
    ({"pad_height_m": -0.5}, "pad_height_m"),
    ({"seed": -1}, "seed"),
])
def test_bad_parameters_name_the_field(kwargs, field) -> None:
    args = {"n_uavs": 10, **kwargs}
    with pytest.raises(ConfigError, match=f"^{field}"):
        traffic(**args)


def test_layout_is_seeded_separated_and_flyable() -> None:
    a, b, c = traffic(40, 5), traffic(40, 5), traffic(40, 6)
    for ua, ub in zip(a.uavs, b.uavs, strict=True):
        assert ua.start_m == ub.start_m and ua.goal_m == ub.goal_m
        assert ua.priority == ub.priority
        assert np.array_equal(ua.mission.points, ub.mission.points)
    assert a.duration_s == b.duration_s
    assert [u.start_m for u in a.uavs] != [u.start_m for u in c.uavs]
    # A UAV's departure is its own draw: the same whatever the number of UAVs.
    assert traffic(20, 5).departures_s == a.departures_s[:20]

    n = len(a.uavs)
    assert math.isclose(a.area_km2, n / 50.0)
    assert sorted(u.priority for u in a.uavs) == list(range(1, n + 1))
    pads = np.array([u.start_m for u in a.uavs] + [u.goal_m for u in a.uavs])
    d = np.linalg.norm(pads[:, None, :2] - pads[None, :, :2], axis=2)
    assert d[np.triu_indices(2 * n, 1)].min() >= 15.0  # origins and goals, all distinct
    assert np.all(np.abs(pads[:, :2]) <= 0.5 * a.area_side_m + 1e-9)
    assert np.all(pads[:, 2] == 0.0)  # on the ground
    lim = DynamicLimits()
    for i, u in enumerate(a.uavs):
        m = u.mission
        trip = math.dist(u.start_m[:2], u.goal_m[:2])
        assert 200.0 <= trip <= 1000.0 and math.isclose(trip, a.trip_m[i])
        assert DEPARTURE_START_S <= a.departures_s[i] <= DEPARTURE_START_S + 60.0 + 1e-9
        assert np.allclose(m.points[0, :3], u.start_m) and np.allclose(m.points[-1, :3], u.goal_m)
        assert m.uniform_period_s == pytest.approx(SAMPLE_PERIOD_S)
        assert m.points[:, 2].max() == pytest.approx(a.cruise_m[i])
        assert a.cruise_m[i] == 30.0  # one layer by default
        # On the pad until its departure, then within the tracker's limits (per axis).
        moving = np.flatnonzero(np.any(m.points[:, :3] != m.points[0, :3], axis=1))
        assert m.times_s[moving[0] - 1] == pytest.approx(a.departures_s[i])
        v = np.diff(m.points[:, :3], axis=0) / SAMPLE_PERIOD_S
        assert np.abs(v[:, :2]).max() <= lim.horizontal_speed_mps
        assert v[:, 2].max() <= lim.ascend_speed_mps and -v[:, 2].min() <= lim.descend_speed_mps
        # The default duration leaves every trip room to finish, late.
        assert a.duration_s > a.departures_s[i] + a.nominal_trip_s[i]
    assert cruise_height(math.radians(350.0), (10.0, 20.0, 30.0, 40.0)) == 40.0


def test_two_heights_follow_the_semicircular_rule() -> None:
    """Eastbound (compass bearing in [0°, 180°)) flies the lower layer, westbound the upper."""
    a = traffic(60, 5, cruise_heights_m=(30.0, 40.0))
    for i, u in enumerate(a.uavs):
        east = u.goal_m[0] > u.start_m[0]
        assert a.cruise_m[i] == (30.0 if east else 40.0)
        assert u.mission.points[:, 2].max() == pytest.approx(a.cruise_m[i])


def test_small_traffic_with_avoidance_has_no_collision_and_the_outcome_adds_up() -> None:
    sc = traffic(10, 3, **SMALL)
    without = World(RunSpec(sc, avoidance=False, seed=0)).run(40.0)
    assert without.collisions  # the traffic is dense enough to need avoiding
    assert traffic_outcome(without, sc)["collisions"] == len(without.collisions)

    result = World(RunSpec(sc, avoidance=True, seed=0)).run()
    o = traffic_outcome(result, sc)
    assert not result.collisions and o["collisions"] == 0
    assert o["closest_approach_m"] == pytest.approx(result.min_distance_m.min())
    assert o["closest_approach_m"] >= 1.0
    reached = [uid for uid, u in result.per_uav.items() if u.reached_goal]
    assert o["goals_reached"] == len(reached) and o["goals_reached_share"] == len(reached) / 10
    assert len(reached) == 10  # everybody landed on its destination pad
    trips = o["per_uav_trip_s"]
    assert o["arrived"] == sum(t is not None for t in trips.values()) >= len(reached)
    for i, u in enumerate(sc.uavs):
        k = result.uav_ids.index(u.uav_id)
        gap = np.linalg.norm(result.positions_m[:, k] - np.array(u.goal_m), axis=1)
        arrive = sc.departures_s[i] + trips[u.uav_id]
        first = int(np.searchsorted(result.t_s, arrive - 1e-6))
        assert gap[first] < ARRIVAL_TOLERANCE_M and np.all(gap[:first] >= ARRIVAL_TOLERANCE_M)
    done = sorted(t for t in trips.values() if t is not None)
    assert o["trip_s"]["max"] == pytest.approx(done[-1], abs=1e-3)
    # the one percentile definition: a flown trip's own time (the empirical CDF's; the
    # per-UAV trips are rounded to the millisecond)
    p50 = np.percentile(done, 50, method="inverted_cdf")
    assert p50 in done and o["trip_s"]["p50"] == pytest.approx(p50, abs=1e-3)
    assert o["airborne"]["peak"] <= 10 and o["airborne"]["mean"] > 0.0


def test_cli_run_traffic_writes_the_traffic_block(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert main(["run", "traffic", "--uavs", "6", "--duration", "15", "--seed", "2",
                 "--out", str(out)]) == 0
    s = RunSummary.read(out / "summary.json")
    t = s.sections["traffic"]
    assert t["uavs"] == 6 == len(s.uavs) and t["collisions"] == len(s.collisions)
    assert set(t["per_uav_trip_s"]) == set(s.uavs) and s.duration_s == pytest.approx(15.0)
    assert t["airborne"]["peak"] >= 1  # departures from 2 s on: some are climbing by 15 s
    for name in ("top_view.png", "altitude.png", "traffic.png", "min_distance.png"):
        assert (out / name).stat().st_size > 5_000
    printed = capsys.readouterr().out
    assert "traffic: 6 UAVs" in printed and "goals reached" in printed
    assert main(["run", "swap_through_static", "--uavs", "3"]) == 2
    assert "--uavs" in capsys.readouterr().err
    assert main(["run", "traffic", "--uavs", "3", "--cruise-heights", "30,x"]) == 2
    assert "--cruise-heights" in capsys.readouterr().err
    assert main(["run", "traffic", "--uavs", "3", "--cruise-heights", "30,30",
                 "--out", str(tmp_path / "bad")]) == 2
    assert "cruise_heights_m[1]" in capsys.readouterr().err


def test_cli_run_traffic_with_two_layers_and_without_a_log_above_the_limit(tmp_path, capsys,
                                                                          monkeypatch) -> None:
    import uavmpc.apps.cli as cli

    monkeypatch.setattr(cli, "MAX_LOGGED_UAVS", 4)  # a big world's run writes no flight log
    out = tmp_path / "two"
    assert main(["run", "traffic", "--uavs", "6", "--duration", "4", "--cruise-heights",
                 "30,40", "--out", str(out)]) == 0
    assert not (out / "flight.mcap").exists()
    s = RunSummary.read(out / "summary.json")
    assert s.sections["flight_log"] is None and "no flight.mcap" in capsys.readouterr().out


def test_campaign_flies_each_trial_with_and_without_avoidance(tmp_path, capsys) -> None:
    out = tmp_path / "api"
    r = run_traffic_campaign(out, trials=1, uavs=8, seed=1, scenario_options=SMALL,
                             execution=Execution(workers=1, progress=False))
    lines = (out / "trials.jsonl").read_text().splitlines()
    assert len(lines) == 1
    trial = json.loads(lines[0])
    w, wo = trial["with_avoidance"], trial["without_avoidance"]
    assert w["avoidance"] is True and wo["avoidance"] is False
    assert w["scenario_seed"] == wo["scenario_seed"] and w["world_seed"] == wo["world_seed"]
    assert json.loads((out / "report.json").read_text()) == json.loads(json.dumps(r))
    assert r["with_avoidance"]["collisions"] == 0
    assert r["without_avoidance"]["collisions"] == wo["collisions"]
    both = [k for k in w["per_uav_trip_s"]
            if w["per_uav_trip_s"][k] is not None and wo["per_uav_trip_s"][k] is not None]
    p = r["avoidance_trip_penalty_s"]
    assert p["uavs"] == len(both) > 0
    diffs = [w["per_uav_trip_s"][k] - wo["per_uav_trip_s"][k] for k in both]
    assert p["mean"] == pytest.approx(np.mean(diffs))
    # The command line's wiring, on a flight too short to matter.
    cli_out = tmp_path / "cli"
    assert main(["campaign", "traffic", "--uavs", "4", "--trials", "1", "--duration", "3",
                 "--workers", "1", "--out", str(cli_out)]) == 0
    report = json.loads((cli_out / "report.json").read_text())
    assert report["trials"] == 1 and report["uavs"] == 4
    assert "trip-time penalty" in capsys.readouterr().out
