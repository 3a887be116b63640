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
