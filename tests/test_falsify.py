"""uavmpc falsify: the search over scenario space, its files and its replay."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from uavmpc import scenarios
from uavmpc.apps.cli import main
from uavmpc.apps.falsify import Space, falsify, fly_case, write_results
from uavmpc.config import ConfigError
from uavmpc.drivers.world import World
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.run import RunSpec


def test_a_case_is_its_scenario_file_and_a_worst_case_replays_to_the_same_separation(
        tmp_path: Path) -> None:
    space = Space(uavs=3, area_m=30.0, duration_s=20.0)
    seen = []
    outcomes = falsify(space, 5, seed=4, generation=3, on_flight=seen.append)
    assert [o.index for o in outcomes] == [0, 1, 2, 3, 4] and seen == outcomes
    assert len({o.seed for o in outcomes}) == 5  # one flight seed per case
    for o in outcomes:
        assert space.valid(np.array(o.theta))
        assert 0.0 < o.min_distance_m < 60.0 and o.top_m <= space.ceiling_m
    paths = write_results(space, outcomes, tmp_path)
    record = json.loads((tmp_path / "cases.json").read_text())
    assert record["flights"] == 5 and len(record["cases"]) == 5
    assert record["min_distance_m"] == min(o.min_distance_m for o in outcomes)
    worst = min(outcomes, key=lambda o: o.min_distance_m)
    text = paths[0].read_text()
    assert f"--seed {worst.seed}" in text.splitlines()[1]
    # the file flies the case the search flew: the same closest approach, by the truth
    sc = scenarios.load(paths[0])
    res = World(RunSpec(sc, seed=worst.seed)).run()
    assert float(res.min_distance_m.min()) == pytest.approx(worst.min_distance_m, abs=1e-9)
    # and the search's own flight of it agrees (θ → the same file)
    again = fly_case(space, np.array(worst.theta), worst.seed)
    assert again.min_distance_m == pytest.approx(worst.min_distance_m, abs=1e-9)


def test_the_case_s_priorities_and_start_times_come_from_theta() -> None:
    space = Space(uavs=3, area_m=40.0)
    theta = np.array([0.0, 0.5, 0.0, 1.0, 0.5, 1.0, 0.0, 0.9,
                      0.5, 0.0, 0.5, 0.5, 1.0, 0.5, 1.0, 0.1,
                      1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.5, 0.5])
    starts, goals, delays, priorities = space.points(theta)
    assert starts[0].tolist() == [-20.0, 0.0, 5.0] and goals[0].tolist() == [20.0, 0.0, 20.0]
    assert priorities.tolist() == [3, 1, 2] and delays.tolist() == [0.0, 8.0, 4.0]
    data = tomllib.loads(space.toml(theta, "case"))
    assert [u["priority"] for u in data["uavs"]] == [3, 1, 2]
    assert [u["path"]["start_s"] for u in data["uavs"]] == [2.0, 10.0, 6.0]
    assert data["geofence"]["max_altitude_m"] == 30.0


@pytest.mark.parametrize(("kw", "named"), [
    ({"uavs": 1}, "uavs"), ({"ceiling_m": 21.0}, "ceiling_m"),
    ({"min_height_m": 30.0, "max_height_m": 20.0}, "max_height_m"), ({"area_m": -5.0}, "area_m"),
])
def test_a_bad_space_names_the_field(kw: dict, named: str) -> None:
    with pytest.raises(ConfigError, match=named):
        Space(**kw)


def test_a_space_too_crowded_to_draw_a_case_says_so() -> None:
    with pytest.raises(ConfigError, match="do not fit"):
        falsify(Space(uavs=40, area_m=1.0, min_height_m=5.0, max_height_m=5.0), 1)


@pytest.mark.parametrize(("argv", "named"), [
    (["--budget", "0"], "budget"), (["--loss", "1.5"], "link.loss"),
    (["--launch-check", "3"], "--launch-check"), (["--ceiling", "10"], "ceiling_m"),
    (["--workers", "0"], "workers"),
])
def test_cli_mistakes_are_one_line(argv: list[str], named: str, capsys, tmp_path) -> None:
    assert main(["falsify", "--out", str(tmp_path / "f"), *argv]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert named in line
    assert not (tmp_path / "f").exists()


@pytest.mark.parametrize("loss", [0.3, 0.0])
def test_the_falsifier_s_case_of_clocks_apart_keeps_2_m(loss: float) -> None:
    """A case the falsifier found (tests/data/falsify_clocks_apart.toml): with clocks up to
    0.86 s apart one UAV refused another's every message as future-stamped and came within
    1.08 m of it (0.94 m, a collision, on a loss-free link). The inbox now measures a sender's
    clock offset and puts its messages on the receiver's clock."""
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.faults import FaultSpec
    from uavmpc.scenarios.run import RunSpec

    sc = scenarios.load(Path(__file__).parent / "data" / "falsify_clocks_apart.toml")
    res = World(RunSpec(
        sc, seed=47, link=LinkSettings(loss=loss, latency_s=0.2),
        faults=FaultSpec(clock_offset_s=0.5, gnss="single",
                         burst_len=3.0 if loss else 0.0))).run()
    assert not res.collisions
    assert float(res.min_distance_m.min()) >= 2.0
    refused = {u: o.messages_rejected for u, o in res.per_uav.items()}
    assert max(refused.values()) < 20, refused  # was 239 for uav2: blind


@pytest.mark.parametrize("all_faults", [False, True])
def test_the_falsifier_s_case_of_a_uav_held_in_the_way_keeps_2_m(all_faults: bool) -> None:
    """A case the falsifier found (tests/data/falsify_held_in_the_way.toml): a UAV that
    could not climb clear held where a higher priority's descent passed through it (1.21 m
    with single-band GNSS on a clean link, 1.88 m with every fault). It now says it is
    stuck (its flag down) once the other closes in, and the other makes way."""
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.faults import FaultSpec
    from uavmpc.scenarios.run import RunSpec

    sc = scenarios.load(Path(__file__).parent / "data" / "falsify_held_in_the_way.toml")
    faults = (FaultSpec(clock_offset_s=0.5, gnss="single", burst_len=3.0) if all_faults
              else FaultSpec(gnss="single"))
    link = (LinkSettings(loss=0.3, latency_s=0.2) if all_faults
            else LinkSettings(loss=0.0, latency_s=0.05))
    res = World(RunSpec(sc, seed=16, link=link, faults=faults)).run()
    assert not res.collisions
    assert float(res.min_distance_m.min()) >= 2.0


def test_the_falsifier_s_case_of_a_uav_released_while_holding_keeps_2_m() -> None:
    """A case the falsifier found (tests/data/falsify_held_while_releasing.toml, every
    fault): a held UAV released its offset while holding and, hearing again the one it had
    yielded to, held still descending into it (0.81 m); with that fixed, it took the other,
    1.3 m above it within the pair's 7.2 m vertical uncertainty, as surely above and
    descended to escape it (1.64 m). A hold now keeps its offset, and a descent escapes only
    from one above by more than the pair's uncertainty."""
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.faults import FaultSpec
    from uavmpc.scenarios.run import RunSpec

    sc = scenarios.load(Path(__file__).parent / "data" / "falsify_held_while_releasing.toml")
    res = World(RunSpec(
        sc, seed=221, link=LinkSettings(loss=0.3, latency_s=0.2, jitter_s=0.02),
        faults=FaultSpec(clock_offset_s=0.5, gnss="single", burst_len=3.0))).run()
    assert not res.collisions
    assert float(res.min_distance_m.min()) >= 2.0


def test_flights_shared_among_processes_are_the_flights_of_one() -> None:
    """A generation's cases are drawn before any is flown, and a flight's seed is its index:
    two worker processes fly the search one does, case for case, to the last bit."""
    space = Space(uavs=3, area_m=30.0, duration_s=10.0, link=LinkSettings(loss=0.3))
    one = falsify(space, 4, seed=5, generation=2)
    two = falsify(space, 4, seed=5, generation=2, workers=2)
    assert two == one
    assert len({o.theta for o in one}) == 4


@pytest.mark.parametrize("family", ["vertical", "grid", "walk"])
def test_a_family_s_worst_case_replays_from_its_file_to_the_same_separation(
        family: str, tmp_path: Path) -> None:
    space = Space(uavs=3, area_m=30.0, duration_s=12.0, family=family)
    outcomes = falsify(space, 3, seed=2, generation=2)
    assert all(space.valid(np.array(o.theta)) for o in outcomes)
    assert all(len(o.theta) == space.dims for o in outcomes)
    paths = write_results(space, outcomes, tmp_path)
    worst = min(outcomes, key=lambda o: o.min_distance_m)
    head = paths[0].read_text().splitlines()
    assert f"family {family}" in head[0] and f"--seed {worst.seed}" in head[1]
    res = World(RunSpec(scenarios.load(paths[0]), seed=worst.seed)).run()
    assert float(res.min_distance_m.min()) == pytest.approx(worst.min_distance_m, abs=1e-9)
    assert json.loads((tmp_path / "cases.json").read_text())["space"]["family"] == family


def test_the_vertical_family_stacks_columns_across_the_height_range() -> None:
    space = Space(uavs=6, family="vertical")
    theta = np.concatenate([[0.0, 0.5, 1.0, 0.5],  # two columns: x = -30 and 30 m, y = 0
                            np.tile([0.0, 0.9, 0.0, 0.0, 0.5, 0.5, 0.0, 0.0], (6, 1)).ravel()])
    theta[4:].reshape(6, 8)[3:, 0:2] = [0.9, 0.0]  # uav4–6 from the east column to the west
    theta[4:].reshape(6, 8)[:, 2] = [0.0, 0.5, 1.0, 0.0, 0.5, 1.0]  # start heights, in order
    theta[4:].reshape(6, 8)[:, 3] = [1.0, 0.5, 0.0, 1.0, 0.5, 0.0]  # goal heights, inverted
    starts, goals, _, _ = space.points(theta)
    assert starts[:, 0].tolist() == [-30.0] * 3 + [30.0] * 3
    assert goals[:, 0].tolist() == [30.0] * 3 + [-30.0] * 3
    assert starts[:, 2].tolist() == [5.0, 12.5, 20.0] * 2  # 15 m spread, ≥ 5 m apart
    assert goals[:, 2].tolist() == [20.0, 12.5, 5.0] * 2  # two stacks swap and invert
    assert space.valid(theta)


def test_the_grid_family_s_goals_are_the_grid_s_points_shuffled() -> None:
    space = Space(uavs=6, family="grid", ceiling_m=25.0)
    keys = [0.5, 0.1, 0.9, 0.3, 0.7, 0.2]  # their order: 1, 5, 3, 0, 4, 2
    theta = np.column_stack([keys, np.zeros((6, 4))]).ravel()
    starts, goals, _, _ = space.points(theta)
    grid = [[-10.0, -5.0], [0.0, -5.0], [10.0, -5.0], [-10.0, 5.0], [0.0, 5.0], [10.0, 5.0]]
    assert starts[:, :2].tolist() == grid
    assert goals[:, :2].tolist() == [grid[k] for k in (1, 5, 3, 0, 4, 2)]
    assert not space.valid(theta)  # uav5 flies to its own start: drawn again
    keys = [0.9, 0.1, 0.2, 0.3, 0.4, 0.5]  # 1, 2, 3, 4, 5, 0: a cycle through all
    assert space.valid(np.column_stack([keys, np.zeros((6, 4))]).ravel())


def test_the_walk_family_flies_its_waypoints_in_one_band() -> None:
    space = Space(uavs=2, family="walk")
    theta = np.random.default_rng(0).random(space.dims)
    data = tomllib.loads(space.toml(theta, "walk"))
    for u in data["uavs"]:
        w = np.array(u["path"]["waypoints"])
        assert w.shape == (5, 3) and len(set(w[:, 2])) == 1
        assert 11.5 <= w[0, 2] <= 13.5 and w[0].tolist() == u["start"]


@pytest.mark.parametrize(("kw", "named"), [
    ({"family": "spiral"}, "family"),
    ({"family": "vertical", "uavs": 12, "min_height_m": 10.0, "max_height_m": 10.0},
     "family vertical"),
])
def test_a_bad_family_names_the_problem(kw: dict, named: str) -> None:
    with pytest.raises(ConfigError, match=named):
        Space(**kw)


@pytest.mark.parametrize(("argv", "named"), [
    (["--family", "spiral"], "--family"),
    (["--family", "vertical", "--uavs", "12", "--max-height", "5"], "family vertical"),
    (["--family", "grid", "--max-height", "24"], "ceiling_m"),  # the grid's 25 m ceiling
])
def test_cli_family_mistakes_are_one_line(argv: list[str], named: str, capsys,
                                          tmp_path) -> None:
    assert main(["falsify", "--out", str(tmp_path / "f"), *argv]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert named in line
    assert not (tmp_path / "f").exists()
