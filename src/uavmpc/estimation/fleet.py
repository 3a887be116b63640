"""The sensors and observers of N UAVs flown together: what their controllers see.

:class:`FleetEstimator` owns the state of every UAV's GNSS receiver (its slowly varying bias),
accelerometer (its bias) and Kalman observer (:mod:`uavmpc.estimation.observer`), and one seeded
generator for all their noise. Once per control tick it takes the true positions and velocities
(N, 3) of the plants and returns the estimates (N, 6) [p, v] the controllers fly on:

1. the accelerometer measures the mean acceleration of the tick just flown (the change of the
   true velocity over it), with its bias and white noise; every observer predicts with it;
2. on a fix tick (every ``ticks_per_fix`` ticks: 10 Hz for ``single``, 5 Hz for ``rtk``), every
   receiver measures position and velocity and every observer corrects.

All UAVs fix on the same ticks (receivers of one fleet share the GNSS time base). The first call
starts every observer from a first fix. Draws: per tick (N, 6) normals for the accelerometers,
per fix (N, 9) for the receivers, from ``SeedSequence(seed, spawn_key=(SENSOR_STREAM,))``, so
the estimates are a pure function of the seed and the true trajectories.
"""

from __future__ import annotations

import numpy as np

from uavmpc.estimation.gnss import GNSS_NORMALS, initial_bias
from uavmpc.estimation.gnss import gnss_step as _gnss_step
from uavmpc.estimation.imu import IMU_NORMALS, initial_accel_bias
from uavmpc.estimation.imu import imu_step as _imu_step
from uavmpc.estimation.observer import (
    N_STATE,
    ObserverParams,
    observer_correct,
    observer_init,
    observer_noise,
    observer_predict,
)

#: The spawn key of the sensors' noise (other streams of a flight do not use it).
SENSOR_STREAM = 0x5E45


class FleetEstimator:
    """Sensors and observers of ``n`` UAVs (one :class:`ObserverParams` for all, or one per
    UAV) at the control period ``dt_s``; see the module docstring."""

    def __init__(self, params: ObserverParams | list[ObserverParams], n: int, dt_s: float,
                 seed: int) -> None:
        rows = params if isinstance(params, list) else [params] * n
        ticks = {p.gnss.ticks_per_fix(dt_s) for p in rows}
        if len(ticks) != 1:
            raise ValueError(f"the UAVs' GNSS rates differ ({sorted(ticks)} ticks per fix); "
                             "a fleet fixes together")
        self.ticks_per_fix = ticks.pop()
        self.dt_s = float(dt_s)
        self.noise = observer_noise(rows, n)
        self._rng = np.random.default_rng(np.random.SeedSequence(int(seed),
                                                                 spawn_key=(SENSOR_STREAM,)))
        self.gnss_bias = initial_bias(self.noise.gnss, self._rng)
        self.accel_bias = initial_accel_bias(self.noise.imu, self._rng)
        self.x = np.zeros((n, 3, N_STATE))
        self.P = np.zeros((n, 3, N_STATE, N_STATE))
        #: The estimates of the last tick: (N, 6) [p (m), v (m/s)], ENU.
        self.estimate = np.zeros((n, 6))
        self._z_pos = np.empty((n, 3))
        self._z_vel = np.empty((n, 3))
        self._a_meas = np.empty((n, 3))
        self._v_prev: np.ndarray | None = None
        self._ticks = 0

    def step(self, p_true: np.ndarray, v_true: np.ndarray) -> np.ndarray:
        """The estimates (N, 6) for the true positions and velocities (N, 3) at this tick."""
        if self._v_prev is None:
            self._fix(p_true, v_true, self.ticks_per_fix * self.dt_s)
            observer_init(self.x, self.P, self._z_pos, self._z_vel, self.noise)
        else:
            a_true = (v_true - self._v_prev) / self.dt_s
            _imu_step(self.accel_bias, a_true, self.dt_s, self.noise.imu,
                      self._rng.standard_normal((len(a_true), IMU_NORMALS)), self._a_meas)
            observer_predict(self.x, self.P, self._a_meas, self.dt_s, self.noise)
            if self._ticks % self.ticks_per_fix == 0:
                self._fix(p_true, v_true, self.ticks_per_fix * self.dt_s)
                observer_correct(self.x, self.P, self._z_pos, self._z_vel, self.noise)
        self._v_prev = np.array(v_true, dtype=float)
        self._ticks += 1
        self.estimate[:, 0:3] = self.x[:, :, 0]
        self.estimate[:, 3:6] = self.x[:, :, 1]
        return self.estimate

    def _fix(self, p_true: np.ndarray, v_true: np.ndarray, dt_s: float) -> None:
        _gnss_step(self.gnss_bias, np.ascontiguousarray(p_true), np.ascontiguousarray(v_true),
                   dt_s, self.noise.gnss,
                   self._rng.standard_normal((len(p_true), GNSS_NORMALS)), self._z_pos,
                   self._z_vel)
