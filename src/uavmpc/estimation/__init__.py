"""State estimation under sensor errors: what a UAV's controller would fly on instead of the
true state.

- :mod:`~uavmpc.estimation.gnss`: GNSS position (bias + white noise) and Doppler velocity errors,
  presets ``single`` (L1 standalone) and ``rtk``;
- :mod:`~uavmpc.estimation.imu`: world-frame accelerometer errors (white noise + bias);
- :mod:`~uavmpc.estimation.observer`: a Kalman filter per UAV and axis, state [p, v, b_a, b_g],
  predicting with the accelerometer every tick and correcting at each fix.

Everything is batched over N UAVs: parameters as per-row tables, state as plain arrays owned by
the caller, compiled kernels (``*_step``, ``observer_*``) over all rows and their one-row
versions (``*_row``) for a caller's own compiled loop. Random numbers are drawn by the caller
from its seeded generator and passed in, so the kernels are pure functions of their arguments.

- :mod:`~uavmpc.estimation.fleet`: :class:`FleetEstimator`, the sensors and observers of a
  world's UAVs, one call per tick (a run spec's ``FaultSpec(gnss=...)``);
- :mod:`~uavmpc.estimation.receiver`: :class:`GnssNoise`, one receiver on one vehicle (a
  one-row view of the GNSS law, for single-UAV flights).

The laws depend on nothing of uavmpc but its configuration helpers and :mod:`uavmpc.jit`; the
receiver view reads a vehicle's state (:class:`~uavmpc.plant.VehicleState`).
"""

from __future__ import annotations

from uavmpc.estimation.gnss import (
    GNSS_NORMALS,
    PRESETS,
    GnssModel,
    GnssTable,
    gnss_row,
    gnss_step,
    gnss_table,
    initial_bias,
)
from uavmpc.estimation.imu import (
    IMU_NORMALS,
    ImuModel,
    ImuTable,
    imu_row,
    imu_step,
    imu_table,
    initial_accel_bias,
)
from uavmpc.estimation.observer import (
    BA,
    BG,
    N_STATE,
    POS,
    VEL,
    ObserverNoise,
    ObserverParams,
    observer_correct,
    observer_correct_row,
    observer_init,
    observer_init_row,
    observer_noise,
    observer_predict,
    observer_predict_row,
)

__all__ = [
    "BA",
    "BG",
    "GNSS_NORMALS",
    "IMU_NORMALS",
    "N_STATE",
    "POS",
    "PRESETS",
    "VEL",
    "GnssModel",
    "GnssTable",
    "ImuModel",
    "ImuTable",
    "ObserverNoise",
    "ObserverParams",
    "gnss_row",
    "gnss_step",
    "gnss_table",
    "imu_row",
    "imu_step",
    "imu_table",
    "initial_accel_bias",
    "initial_bias",
    "observer_correct",
    "observer_correct_row",
    "observer_init",
    "observer_init_row",
    "observer_noise",
    "observer_predict",
    "observer_predict_row",
]
