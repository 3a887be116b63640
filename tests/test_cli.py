"""The command line, end to end: the demo writes its figure, the benchmark prints its JSON."""

import json
import math

import pytest

from uavmpc.apps.cli import main
from uavmpc.drivers.summary import RunStatus, RunSummary


def test_tracker_demo_writes_figure_and_summary(tmp_path, capsys) -> None:
    assert main(["tracker-demo", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert (tmp_path / "step_50m.png").stat().st_size > 10_000
    assert summary["overshoot_m"] <= 0.05
    assert summary["max_speed_mps"] <= summary["speed_limit_mps"] + 1e-6
    assert "50 m step" in capsys.readouterr().out


@pytest.mark.slow
def test_bench_tracker_prints_one_json_object_last(capsys) -> None:
    assert main(["bench", "tracker", "--ticks", "300"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    result = json.loads(last)
    for key, kind in [("ticks", int), ("step_median_us", float), ("step_p99_us", float),
                      ("limit_violations", int), ("max_violation", float), ("fallbacks", int),
                      ("reference_solver", str), ("reference_step_median_us", float),
                      ("max_solution_diff", float)]:
        assert isinstance(result[key], kind), key
    assert result["ticks"] == 300
    assert result["limit_violations"] == 0 and result["fallbacks"] == 0
    assert result["max_solution_diff"] < 1e-3
    assert result["qps_compared"] > 0


@pytest.mark.parametrize(
    "argv", [["tracker-demo", "--duration", "-1"], ["bench", "tracker", "--ticks", "0"],
             ["run", "swap_through_static", "--loss", "1.5"]]
)
def test_bad_cli_values_exit_with_a_message(argv, capsys) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "must be" in err or "link.loss" in err


def test_demo_flies_the_swap_without_collision(tmp_path, capsys) -> None:
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "status: complete, no collision" in out and "reached its goal" in out
    s = RunSummary.read(tmp_path / "summary.json")
    assert s.collisions == () and s.status is RunStatus.COMPLETE


def test_bench_loop_reports_realtime_factor_and_stages(capsys) -> None:
    assert main(["bench", "loop", "--duration", "2", "--repeats", "1"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    # how fast it ran is the benchmark's answer, not a test's: here only that it says so
    assert math.isfinite(result["realtime_factor"]) and result["realtime_factor"] > 0
    assert set(result["stage_us"]) == {"tracker", "se3", "attitude_and_plant"}
    assert result["tracking_rmse_m"] < 0.3


@pytest.mark.parametrize("kill", [["uav9", "3"], ["uav1", "soon"], ["uav1", "-1"]])
def test_swarm_kill_node_mistakes_are_one_line(kill: list[str], capsys, tmp_path) -> None:
    argv = ["swarm", "swap_through_static", "--out", str(tmp_path / "run"), "--kill-node", *kill]
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"uavmpc swarm: --kill-node {kill[0]} {kill[1]}")
    assert not (tmp_path / "run").exists()  # refused before anything flew


def test_a_run_writes_its_own_folder_and_leaves_nothing_of_an_earlier_run(
        tmp_path, monkeypatch, capsys) -> None:
    """Each scenario has its folder by default, and a run's folder holds that run's outputs
    only (a traffic run's figures beside a later swap's were read as the swap's)."""
    from uavmpc.apps.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("UAVMPC_THREADS", raising=False)
    monkeypatch.setattr("os.getloadavg", lambda: (9.0, 9.0, 9.0))
    out = tmp_path / "out" / "run" / "swap_through_static"
    out.mkdir(parents=True)
    for stale in ("traffic.png", "landing.png", "flight.mcap"):
        (out / stale).write_text("an earlier run's")
    (out / "notes.txt").write_text("mine")
    assert main(["run", "swap_through_static", "--duration", "2"]) == 0
    assert not (out / "traffic.png").exists() and not (out / "landing.png").exists()
    assert (out / "flight.mcap").read_bytes()[:8] != b"an earli"  # this run's log
    assert (out / "summary.json").exists() and (out / "top_view.png").exists()
    assert (out / "notes.txt").read_text() == "mine"  # not a run's output: left alone
    captured = capsys.readouterr()
    assert "uavmpc run: ticking on 1 thread(s), the cores idle now of" in captured.err
    assert "uav1: never climbed, avoiding for" in captured.out  # not "climbed up to 0 m"
