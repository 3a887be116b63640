"""``bench world``: the structure and internal consistency of its result (no timing thresholds:
the numbers depend on the machine)."""

import json
import math

import pytest

from uavmpc.apps.bench import bench_world
from uavmpc.apps.cli import main
from uavmpc.config import ConfigError
from uavmpc.jit import HAS_CYCLE_COUNTER, available_threads


@pytest.mark.slow
def test_bench_world_rows_are_consistent() -> None:
    lines: list[str] = []
    threads = (1, 2) if available_threads() >= 2 else (1,)
    result = bench_world(sizes=(2, 4), duration_s=1.0, threads=threads, profile=True,
                         progress=lines.append)
    json.dumps(result)  # the CLI prints it as one JSON line
    assert [(r["uavs"], r["threads"]) for r in result["worlds"]] == [
        (n, t) for n in (2, 4) for t in threads]
    for row in [*result["worlds"], result["reference"]]:
        n, factor = row["uavs"], row["realtime_factor"]
        assert row["duration_s"] == pytest.approx(1.0)
        assert factor == pytest.approx(row["duration_s"] / row["wall_s"], rel=2e-3)
        # µs per UAV-second × simulated seconds per wall second × UAVs = 1e6 µs per second
        assert row["us_per_uav_second"] * factor * n == pytest.approx(1e6, rel=2e-3)
        assert row["wall_s_per_simulated_s"] * factor == pytest.approx(1.0, rel=2e-3)
        assert row["peak_rss_mib"] >= row["baseline_rss_mib"] > 0
        assert row["flight_rss_mib"] == pytest.approx(
            row["peak_rss_mib"] - row["baseline_rss_mib"], abs=0.11)
        assert row["collisions"] >= 0 and row["min_distance_m"] > 0
    for row in result["worlds"]:  # the batched flights say where their wall time went
        assert 0.0 < row["compiled_share"] < 1.0
        phases = row["us_per_tick_by_phase"]
        assert set(phases) == {"receive_and_plan", "compiled_tick", "broadcast"}
        # the phases are parts of the flight's wall time: 100 ticks per simulated second
        assert sum(phases.values()) * 100 * row["duration_s"] <= row["wall_s"] * 1e6 * 1.01
        if HAS_CYCLE_COUNTER:
            stages = row["compiled_us_per_uav_tick"]
            assert set(stages) == {"prepare", "qp", "advance", "control", "plant", "trace"}
            assert all(stages[k] > 0 for k in ("prepare", "qp", "advance", "control", "plant"))
            assert stages["trace"] >= 0
            # (how the cycle counter's stages compare with the wall clock is a timing: the
            # benchmark prints both)
            assert math.isfinite(row["compiled_only_realtime_factor"])
            assert row["compiled_only_realtime_factor"] > 0
            # the threads' wait for the tick's slowest block: none on one thread
            wait = row["threads_wait_us_per_uav_tick"]
            assert wait == 0.0 if row["threads"] == 1 else 0.0 <= wait < sum(stages.values())
    assert result["reference"]["compiled_share"] is None  # no phases UAV by UAV
    assert result["reference"]["compiled_us_per_uav_tick"] is None
    assert result["reference"]["path"] == "per-object" and result["reference"]["uavs"] == 2
    # Too few sizes ≥ 20 for the protocol's fit: it falls back to all of them.
    assert result["fit_uavs"] == [2, 4]
    assert math.isfinite(result["growth_exponent"])
    cost = {r["uavs"]: r["us_per_uav_second"] for r in result["worlds"] if r["threads"] == 1}
    assert result["us_per_uav_second_ratio"] == pytest.approx(cost[4] / cost[2], rel=2e-3)
    assert result["identical_to_per_object"] is True
    # Every thread count flies the same flight, and its speedup is the factors' ratio.
    assert [(s["uavs"], s["threads"]) for s in result["thread_scaling"]] == [
        (n, t) for n in (2, 4) for t in threads[1:]]
    assert result["identical_across_threads"] is True
    factor = {(r["uavs"], r["threads"]): r["realtime_factor"] for r in result["worlds"]}
    for s in result["thread_scaling"]:
        assert s["speedup"] == pytest.approx(
            factor[s["uavs"], s["threads"]] / factor[s["uavs"], 1], rel=2e-3)
    # The header; per flight one line, its compiled tick's and its phases' (profile), per
    # extra thread count the speedup; the reference, the fit.
    per_flight = 3 if HAS_CYCLE_COUNTER else 2
    assert len(lines) == 1 + 2 * len(threads) * per_flight + 2 * (len(threads) - 1) + 2


@pytest.mark.slow
def test_bench_world_repeats_keep_each_thread_counts_fastest_flight() -> None:
    lines: list[str] = []
    result = bench_world(sizes=(2,), duration_s=0.5, threads=(1,), progress=lines.append,
                         repeats=2)
    (row,) = result["worlds"]
    assert result["repeats"] == row["repeats"] == 2
    assert row["slowest_over_fastest"] >= 1.0
    assert "fastest of 2" in lines[0] and "fastest of 2, slowest" in lines[1]


def test_bench_world_rejects_a_bad_duration() -> None:
    with pytest.raises(ConfigError, match="duration_large_s"):
        bench_world(sizes=(2,), duration_s=1.0, duration_large_s=0.0)
    with pytest.raises(ConfigError, match="repeats"):
        bench_world(sizes=(2,), duration_s=1.0, repeats=0)


@pytest.mark.parametrize("argv", [["bench", "world", "--sizes", "5,x"],
                                  ["bench", "world", "--sizes", "0,5"],
                                  ["bench", "world", "--sizes", "5,5"],
                                  ["bench", "world", "--threads", "0"],
                                  ["bench", "world", "--threads", "1,x"],
                                  ["bench", "world", "--threads", "1,1"],
                                  ["bench", "world", "--threads", "999"]])
def test_bench_world_bad_sizes_exit_with_a_message(argv, capsys) -> None:
    assert main(argv) == 2
    assert "bench world" in capsys.readouterr().err
