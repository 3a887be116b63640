"""Faults in the world and the campaign: seeded draws, silent radios, GNSS estimates."""

from __future__ import annotations

import json

import numpy as np
import pytest

from uavmpc.apps.campaign import Execution, RandomWalkSpec, run_campaign
from uavmpc.apps.cli import main
from uavmpc.config import ConfigError
from uavmpc.drivers.summary import RunSummary
from uavmpc.drivers.world import World
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.faults import Faults, FaultSpec, draw_faults
from uavmpc.scenarios.random_walk import random_walk, waypoints_reached
from uavmpc.scenarios.run import RunSettings, RunSpec

IDS = [f"uav{i}" for i in range(1, 6)]


def test_draws_are_seeded_separate_and_within_their_bounds() -> None:
    spec = FaultSpec(clock_offset_s=0.5, non_cooperative=1, silent=2)
    a = draw_faults(spec, IDS, 600.0, 0.0, seed=11)
    assert a == draw_faults(spec, IDS, 600.0, 0.0, seed=11)
    assert a != draw_faults(spec, IDS, 600.0, 0.0, seed=12)
    assert a.clock_offsets_s is not None and all(abs(o) <= 0.5 for o in a.clock_offsets_s)
    assert len(a.non_cooperative) == 1 and len(a.silent_from_s) == 2
    assert not set(a.non_cooperative) & set(a.silent_from_s)  # a UAV has one fault of these
    assert all(0.0 <= t <= 600.0 for t in a.silent_from_s.values())
    assert draw_faults(FaultSpec(), IDS, 600.0, 0.0, 11).summary() == {}
    world = World(RunSpec(random_walk(5, duration_s=10.0, seed=1), drawn=a))
    assert world.non_cooperative == a.non_cooperative
    assert world.silent_from_s == a.silent_from_s
    assert [u.clock_offset_s for u in world.uavs] == list(a.clock_offsets_s)


@pytest.mark.parametrize(("kw", "needle"), [
    ({"clock_offset_s": -1.0}, "clock_offset_s"), ({"clock_offset_s": float("nan")}, "clock"),
    ({"gnss": "dgps"}, "gnss"), ({"burst_len": 0.5}, "burst_len"),
    ({"time_reference": "gps"}, "time_reference"), ({"silent": -1}, "silent"),
    ({"non_cooperative": 1.5}, "non_cooperative"),
])
def test_bad_fault_specs_name_the_field(kw, needle) -> None:
    with pytest.raises(ConfigError, match=needle):
        FaultSpec(**kw)
    with pytest.raises(ConfigError, match="leaves none cooperative"):
        FaultSpec(non_cooperative=5).check_uavs(5)


def test_a_silent_radio_sends_nothing_from_its_time_on_and_its_uav_flies_on() -> None:
    sc = random_walk(3, duration_s=20.0, seed=4)
    world = World(RunSpec(sc, seed=1, drawn=Faults.given(silent_from_s={"uav2": 8.0})))
    res = world.run(20.0)
    assert world.silenced == pytest.approx(24, abs=1)  # 2 Hz for the last 12 s
    heard = world.uavs[0].stack.inbox.latest["uav2"]
    assert 7.0 < heard.stamp_s < 8.0  # the last prediction before the radio died
    clean = World(RunSpec(sc, seed=1)).run(20.0)
    # uav2 itself flies its mission (its own stack never knew); at first the same flight.
    k = np.searchsorted(res.t_s, 8.0)
    assert np.array_equal(res.positions_m[:k], clean.positions_m[:k])
    # Then the others make way for it (it is silent, so it can be anywhere near its last
    # plan), and it still reaches the waypoint it was flying to when its radio died.
    waypoint = sc.uavs[1].mission.points[1, :3]
    assert sc.uavs[1].mission.times_s[1] > 8.0
    assert np.linalg.norm(res.positions_m[k:, 1] - waypoint, axis=1).min() < 1.0
    with pytest.raises(ValueError, match="'uav9' not UAVs"):
        World(RunSpec(sc, drawn=Faults.given(silent_from_s={"uav9": 1.0})))


def test_gnss_estimates_are_flown_the_same_batched_or_uav_by_uav() -> None:
    sc = random_walk(3, duration_s=15.0, seed=5)
    a = World(RunSpec(sc, seed=2, drawn=Faults.given(gnss="rtk")))
    ra = a.run(15.0)
    rb = World(RunSpec(sc, seed=2, drawn=Faults.given(gnss="rtk")), batched=False).run(15.0)
    assert np.array_equal(ra.positions_m, rb.positions_m)
    true = a.plants.x[:, 0:3]
    err = np.linalg.norm(a.estimator.estimate[:, 0:3] - true, axis=1)
    assert np.all(err < 0.1)  # RTK: centimetres
    s = World(RunSpec(sc, seed=2, drawn=Faults.given(gnss="single")))
    s.run(15.0)
    err = np.linalg.norm(s.estimator.estimate[:, 0:3] - s.plants.x[:, 0:3], axis=1)
    assert np.all(err < 10.0) and np.any(err > 0.2)  # metres, and not the truth
    assert not np.array_equal(ra.positions_m, World(RunSpec(sc, seed=2)).run(15.0).positions_m)


def test_waypoints_reached_counts_misses() -> None:
    sc = random_walk(2, duration_s=60.0, seed=3)
    res = World(RunSpec(sc, seed=1)).run(60.0)
    reached, due = waypoints_reached(sc, res.t_s, res.positions_m)
    assert due >= 4 and reached == due
    # A UAV that never moves reaches only the waypoint it starts at, if any.
    still = np.repeat(res.positions_m[:1], len(res.t_s), axis=0)
    assert waypoints_reached(sc, res.t_s, still)[0] < due


@pytest.mark.slow
def test_a_campaign_with_faults_records_them_and_counts_goals(tmp_path) -> None:
    spec = FaultSpec(clock_offset_s=0.5, time_reference="receive", burst_len=3.0,
                     non_cooperative=1, silent=1)
    campaign = RandomWalkSpec(run=RunSettings(link=LinkSettings(loss=0.3), faults=spec),
                              length_s=20.0)
    r = run_campaign(tmp_path / "c", campaign, Execution(workers=1, progress=False), trials=2)
    assert r["parameters"]["faults"] == spec.active()
    assert r["waypoints_due"] > 0 and 0 <= r["waypoints_reached"] <= r["waypoints_due"]
    trials = [json.loads(line) for line in (tmp_path / "c" / "trials.jsonl").read_text()
              .splitlines()]
    assert len({t["faults"]["non_cooperative_uavs"][0] for t in trials}) >= 1
    assert all(len(t["faults"]["clock_offsets_s"]) == 5 for t in trials)
    assert "faults" in (tmp_path / "c" / "report.md").read_text()
    # The same campaign with 2 workers: the same records (but wall times).
    r2 = run_campaign(tmp_path / "c2", campaign, Execution(workers=2, progress=False),
                      trials=2)
    assert r2["min_distance_m"] == r["min_distance_m"]
    assert r2["waypoints_reached"] == r["waypoints_reached"]
    with pytest.raises(ConfigError, match="burst-loss needs a loss rate"):
        RandomWalkSpec(run=RunSettings(faults=FaultSpec(burst_len=3.0)))


def test_the_fault_flags_reach_a_run(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert main(["run", "swap_through_static", "--out", str(out), "--duration", "10",
                 "--gnss", "rtk", "--clock-offset", "0.2", "--silent", "1"]) == 0
    faults = RunSummary.read(out / "summary.json").sections["faults"]
    assert faults["gnss"] == "rtk" and len(faults["silent_from_s"]) == 1
    assert main(["run", "swap_through_static", "--out", str(out), "--burst-loss", "3"]) == 2
    assert "--burst-loss needs a loss rate" in capsys.readouterr().err


@pytest.mark.slow
def test_a_campaign_flies_the_avoidance_file_it_is_given(tmp_path, capsys) -> None:
    """A coarser estimate needs a larger cylinder: ``--avoidance-file`` flies its table in
    every trial, records it with the campaign, and a bad field is named before any trial."""
    wide = tmp_path / "wide.toml"
    wide.write_text("[avoidance]\nradius_m = 9.0\nheight_m = 17.4\ndz_m = 9.0\n")
    args = ["campaign", "random-walk", "--trials", "1", "--trial-s", "60", "--workers", "1",
            "--no-progress", "--uavs", "5", "--area", "40"]
    assert main([*args, "--out", str(tmp_path / "plain")]) == 0
    assert main([*args, "--out", str(tmp_path / "wide"), "--avoidance-file", str(wide)]) == 0
    plain = json.loads((tmp_path / "plain" / "report.json").read_text())
    wider = json.loads((tmp_path / "wide" / "report.json").read_text())
    assert wider["parameters"]["avoidance_params"] == {"radius_m": 9.0, "height_m": 17.4,
                                                       "dz_m": 9.0}
    assert "avoidance_params" not in plain["parameters"]
    # The same seeded trial flown with a 9 m cylinder and layers 9 m apart: another flight (the
    # default table would give the same record, bit for bit).
    assert wider["min_distance_m"] != plain["min_distance_m"]
    # Resuming the folder with other parameters is refused.
    assert main([*args, "--out", str(tmp_path / "wide")]) == 2
    capsys.readouterr()
    bad = tmp_path / "bad.toml"
    bad.write_text("[avoidance]\nradius_m = -1.0\n")
    assert main([*args, "--out", str(tmp_path / "bad"), "--avoidance-file", str(bad)]) == 2
    assert "avoidance.radius_m" in capsys.readouterr().err
    bad.write_text("radius_m = 9.0\n")
    assert main([*args, "--out", str(tmp_path / "bad"), "--avoidance-file", str(bad)]) == 2
    assert "needs an [avoidance] table" in capsys.readouterr().err


def test_single_band_gnss_widens_every_pair_from_what_the_predictions_state() -> None:
    """No special geometry file: a UAV on single-band GNSS states its position uncertainty
    in its predictions, and every pair's cylinder widens by both (docs/safety.md, A3)."""
    from uavmpc.estimation.observer import ObserverParams

    world = World(RunSpec(random_walk(3, duration_s=4.0, seed=1),
                          drawn=Faults.given(gnss="single")))
    sigma = ObserverParams.preset("single").position_sigma_m
    assert sigma[0] > 1.0 and sigma[1] > sigma[0]  # metres, worse vertically
    np.testing.assert_array_equal(world.onboard.position_sigma_m, np.tile(sigma, (3, 1)))
    world.run(2.0)
    held = [world.inboxes.message(0, world.inboxes.col_of(u)) for u in ("uav2", "uav3")]
    assert all(m is not None and m.position_sigma_m == sigma for m in held)
    rtk = World(RunSpec(random_walk(3, duration_s=4.0, seed=1), drawn=Faults.given(gnss="rtk")))
    assert rtk.onboard.position_sigma_m.max() < 0.05  # centimetres: next to no widening


def test_the_launch_check_holds_each_uav_until_it_has_heard_every_other() -> None:
    """Found in the 24 h campaign with burst loss (trial 118): two UAVs 8 m apart set off
    towards each other before one had heard the other. With the launch check each hovers at
    its start until its inbox holds a prediction from every other UAV, or until the longest
    wait; a radio silent from the start is waited for that long, and named."""
    sc = random_walk(3, duration_s=30.0, seed=4)
    res = World(RunSpec(sc, seed=1, launch_check_s=5.0)).run(30.0)
    launch = res.sections["launch"]
    assert launch["max_wait_s"] == 5.0
    # A clean link: everyone heard within a broadcast period and the latency.
    assert all(0.0 < launch[u.uav_id]["launched_s"] < 1.0 and launch[u.uav_id]["not_heard"]
               == [] for u in sc.uavs)
    # uav2's radio is silent from the start: the others wait the full 5 s for it, uav2
    # itself (which hears them) sets off at once; everyone still flies its mission.
    world = World(RunSpec(sc, seed=1, launch_check_s=5.0,
                          drawn=Faults.given(silent_from_s={"uav2": 0.0})))
    res = world.run(30.0)
    launch = res.sections["launch"]
    assert launch["uav2"]["launched_s"] < 1.0 and launch["uav2"]["not_heard"] == []
    for i in (0, 2):
        uid = sc.uavs[i].uav_id
        assert launch[uid]["not_heard"] == ["uav2"]
        assert launch[uid]["launched_s"] == pytest.approx(5.0, abs=0.02)
        before = res.t_s < 5.0
        drift = np.linalg.norm(res.positions_m[before, i] - np.array(sc.uavs[i].start_m), axis=1)
        assert drift.max() < 0.05  # hovering where it started
        assert np.linalg.norm(res.positions_m[~before, i, :2]
                              - np.array(sc.uavs[i].start_m[:2]), axis=1).max() > 5.0
    # Batched or UAV by UAV: the same flight, the same launches.
    objects = World(RunSpec(sc, seed=1, launch_check_s=5.0,
                            drawn=Faults.given(silent_from_s={"uav2": 0.0})),
                    batched=False).run(30.0)
    assert np.array_equal(objects.positions_m, res.positions_m)
    assert objects.sections["launch"] == launch
    assert "launch" not in World(RunSpec(sc, seed=1)).run(1.0).sections
    # A UAV flying without avoidance ignores the others: it is not held.
    alone = World(RunSpec(sc, seed=1, launch_check_s=5.0,
                          drawn=Faults.given(non_cooperative=["uav1"]))).run(1.0)
    assert "uav1" not in alone.sections["launch"] and "uav2" in alone.sections["launch"]
    with pytest.raises(ValueError, match="launch_check_s"):
        World(RunSpec(sc, launch_check_s=-1.0))


def test_a_campaign_records_its_launch_check(tmp_path, capsys) -> None:
    args = ["campaign", "random-walk", "--trials", "1", "--trial-s", "20", "--workers", "1",
            "--no-progress", "--uavs", "3"]
    assert main([*args, "--out", str(tmp_path / "c"), "--launch-check", "4"]) == 0
    report = json.loads((tmp_path / "c" / "report.json").read_text())
    assert report["parameters"]["launch_check_s"] == 4.0
    assert "launch check" in (tmp_path / "c" / "report.md").read_text()
    # Resuming with another value (or none) is refused; a bad one is named.
    assert main([*args, "--out", str(tmp_path / "c")]) == 2
    assert main([*args, "--out", str(tmp_path / "d"), "--launch-check", "-1"]) == 2
    assert "launch check" in capsys.readouterr().err


def test_a_uav_nobody_hears_yields_to_the_one_that_does_not_list_it() -> None:
    """The acknowledgement (docs/safety.md, A2): high's radio is dead, low never hears it and
    never lists it; high, hearing low, yields to it though it has the priority."""
    from uavmpc import scenarios
    from uavmpc.drivers.world import World

    def head_on(grace_s: float):
        sc = scenarios.from_dict({
            "name": "head_on", "duration_s": 30.0,
            "avoidance": {"ack_grace_s": grace_s},
            "uavs": [
                {"id": "high", "priority": 1, "start": [-25.0, 0.0, 10.0],
                 "path": {"waypoints": [[-25.0, 0.0, 10.0], [25.0, 0.0, 10.0]],
                          "speed_mps": 3.0}},
                {"id": "low", "priority": 2, "start": [25.0, 0.0, 10.0],
                 "heading_rad": 3.14159,
                 "path": {"waypoints": [[25.0, 0.0, 10.0], [-25.0, 0.0, 10.0]],
                          "speed_mps": 3.0}},
            ]})
        # high's radio is dead from the start: low never hears it; high hears low
        return World(RunSpec(sc, seed=0, drawn=Faults.given(silent_from_s={"high": 0.0}))).run()

    off = head_on(0.0)  # low does not know high is there; high waits for low to climb
    assert off.collisions
    on = head_on(2.0)   # low's messages have not listed high for 2 s: high climbs instead
    assert not on.collisions and on.min_distance_m.min() > 2.9
    uavs = on.summary().uavs
    assert uavs["high"].max_z_offset_m == 3.0 and uavs["low"].max_z_offset_m == 0.0
    assert uavs["high"].reached_goal and uavs["low"].reached_goal


def test_apply_faults_is_the_one_split_of_a_spec() -> None:
    from uavmpc.avoidance import AvoidanceParams
    from uavmpc.scenarios import LinkSettings
    from uavmpc.scenarios.faults import apply_faults

    sc = random_walk(4, 60.0, 10.0, 30.0, seed=2)
    link = LinkSettings(latency_s=0.1, loss=0.2)
    spec = FaultSpec(clock_offset_s=0.4, time_reference="receive", gnss="rtk", burst_len=3.0,
                     non_cooperative=1, silent=1)
    out_sc, out_link, drawn = apply_faults(spec, sc, link, duration_s=30.0, seed=7)
    # the link gets the burst length, the scenario's avoidance the time reference, nothing else
    assert out_link == LinkSettings(latency_s=0.1, loss=0.2, burst_len=3.0)
    assert out_sc.avoidance.time_reference == "receive"
    assert out_sc.avoidance == AvoidanceParams(time_reference="receive")
    assert out_sc.uavs is sc.uavs and sc.avoidance.time_reference == "stamp"
    # the rest is the draw of the flight, as draw_faults makes it from the same seed
    assert drawn == draw_faults(spec, [u.uav_id for u in sc.uavs], 30.0, 0.0, 7)
    assert drawn.spec.gnss == "rtk"
    # Faults given (a test's, a replay's) are taken as they are, checked against the scenario
    given = Faults.given(clock_offsets_s=[0.1, -0.1, 0.0, 0.2], non_cooperative=["uav2"])
    assert apply_faults(given.spec, sc, link, duration_s=30.0, seed=7, given=given)[2] is given
    with pytest.raises(ConfigError, match="'uav9' not UAVs of the scenario"):
        RunSpec(sc, drawn=Faults.given(silent_from_s={"uav9": 1.0}))
    with pytest.raises(ConfigError, match="need 4 offsets"):
        RunSpec(sc, drawn=Faults.given(clock_offsets_s=[0.1]))
    with pytest.raises(ConfigError, match="not the string 'uav1'"):
        Faults.given(non_cooperative="uav1")
    with pytest.raises(ConfigError, match="burst-loss needs a loss rate"):
        apply_faults(spec, sc, LinkSettings(), duration_s=30.0, seed=7)
    with pytest.raises(ConfigError, match="non_cooperative"):
        apply_faults(FaultSpec(non_cooperative=4), sc, link, duration_s=30.0, seed=7)
