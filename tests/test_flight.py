"""One UAV end to end: tracker → SE(3) → attitude → motors → rigid body."""

import json

import numpy as np
import pytest

from uavmpc import Reference
from uavmpc.apps.cli import main
from uavmpc.drivers.flight import FlightStatus, demanding_reference, fly, summarize
from uavmpc.plant import Airframe, Wind


@pytest.mark.parametrize("name", ["f550", "x500"])
def test_demanding_reference_is_tracked_closely(name: str) -> None:
    airframe = Airframe.packaged(name)
    log = fly(airframe, demanding_reference(), 60.0)
    s = summarize(log, airframe)
    assert log.status is FlightStatus.COMPLETE
    assert s["tracking_rmse_m"] < 0.3
    assert s["max_tracking_error_m"] < 1.0
    assert s["max_tilt_deg"] <= s["tilt_limit_deg"] + 2.0  # the attitude loop's overshoot
    assert np.all(np.isfinite(log.actual)) and np.all(log.actual[:, 2] > 1.0)
    # the reference is partly infeasible: the virtual UAV (not the UAV) absorbs it
    ref_err = np.linalg.norm(log.reference[:, :3] - log.command[:, :3], axis=1)
    assert ref_err.max() > 10.0


def test_constant_wind_is_rejected_by_the_integrators() -> None:
    airframe = Airframe.packaged("f550")
    hold = Reference.goto(0.0, 0.0, 10.0)
    log = fly(airframe, hold, 40.0, wind=Wind(mean_mps=(5.0, 0.0, 0.0)))
    err = np.linalg.norm(log.actual[:, :3] - log.command[:, :3], axis=1)
    assert err[log.t_s < 3.0].max() > 0.05  # the wind does push the UAV at first
    assert err[log.t_s > 30.0].max() < 0.05


def test_track_cli_writes_figure_and_summary(tmp_path) -> None:
    assert main(["track", "--duration", "20", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    for key in ("tracking_rmse_m", "max_tracking_error_m", "max_tilt_deg",
                "motor_saturation_s", "realtime_factor"):
        assert isinstance(summary[key], float), key
    assert summary["duration_s"] == pytest.approx(20.0)
    assert (tmp_path / "tracking.png").stat().st_size > 20_000
