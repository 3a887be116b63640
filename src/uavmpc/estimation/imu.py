"""Accelerometer errors of N UAVs, compiled: white noise plus a slowly varying bias.

What the observer (:mod:`uavmpc.estimation.observer`) integrates is the *world-frame* acceleration
measurement, ENU, gravity removed: the body specific force rotated by the attitude estimate plus
g ẑ. Its error, per axis: ``a_meas = a + b + (N_a / √dt) n`` over a sample of ``dt`` seconds
(an IMU's Δv over the sample divided by dt, so its white part has density N_a), with ``b`` a
first-order Gauss–Markov bias (stationary σ_b, correlation time τ, exact discretization as in
:mod:`uavmpc.estimation.gnss`). The bias is modelled in the world frame: it really lives in the
body frame and turns with the heading, but it varies over minutes and the observer estimates it
continuously, so the difference is a slow change of the bias the observer already tracks.

Defaults (:class:`ImuModel`), a typical MEMS IMU on a multirotor:

- N_a = 0.035 m/s²/√Hz. The chips' datasheets quote far less (about 70–100 µg/√Hz, ≈ 0.001
  m/s²/√Hz), but on a multirotor the propellers' vibration that survives the IMU's low-pass
  filters dominates; autopilot EKFs assume about 0.35 m/s² per sample at 100 Hz (PX4's EKF2
  default accelerometer noise), i.e. 0.035 m/s²/√Hz.
- σ_b = 0.02 m/s², τ = 300 s: what remains of the turn-on bias and its temperature drift after
  the usual calibration, a couple of milli-g, wandering over minutes.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from uavmpc.config import positive
from uavmpc.estimation.gnss import _per_row
from uavmpc.jit import kernel

__all__ = ["IMU_NORMALS", "ImuModel", "ImuTable", "imu_row", "imu_step", "imu_table",
           "initial_accel_bias"]

#: Standard normals one sample of one UAV consumes: bias drive (3), white noise (3).
IMU_NORMALS = 6


@dataclass(frozen=True)
class ImuModel:
    """One accelerometer's error model (the same on all three world axes).

    Attributes:
        noise_density_mps2_rthz: white noise density N_a [m/s²/√Hz] (≥ 0).
        bias_sigma_mps2: stationary std of the bias σ_b [m/s²] (≥ 0).
        bias_tau_s: correlation time of the bias τ [s] (> 0).
    """

    noise_density_mps2_rthz: float = 0.035
    bias_sigma_mps2: float = 0.02
    bias_tau_s: float = 300.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "bias_tau_s":
                out = positive(value, f"imu.{f.name}", upper=1.0e6)
            else:
                out = positive(value, f"imu.{f.name}", upper=10.0, allow_zero=True)
            object.__setattr__(self, f.name, out)

    def sample_sigma_mps2(self, dt_s: float) -> float:
        """Std of the white part of one sample of ``dt_s`` seconds, N_a / √dt [m/s²]."""
        return self.noise_density_mps2_rthz / math.sqrt(positive(dt_s, "dt_s"))


class ImuTable(NamedTuple):
    """Per-row accelerometer parameters of N UAVs.

    Attributes:
        noise_density: (N, 3) N_a [m/s²/√Hz]; bias_sigma_mps2: (N, 3) σ_b [m/s²];
        bias_tau_s: (N,) τ [s].
    """

    noise_density: np.ndarray
    bias_sigma_mps2: np.ndarray
    bias_tau_s: np.ndarray


def imu_table(models: ImuModel | Sequence[ImuModel], n: int) -> ImuTable:
    """The :class:`ImuTable` of ``n`` rows: one model for all, or one per row."""
    rows = _per_row(models, n, ImuModel, "imu")
    return ImuTable(
        noise_density=np.repeat([[m.noise_density_mps2_rthz] for m in rows], 3, axis=1)
        .reshape(n, 3).astype(float),
        bias_sigma_mps2=np.repeat([[m.bias_sigma_mps2] for m in rows], 3, axis=1)
        .reshape(n, 3).astype(float),
        bias_tau_s=np.array([m.bias_tau_s for m in rows], dtype=float).reshape(n),
    )


def initial_accel_bias(table: ImuTable, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) biases drawn from the stationary distribution [m/s²]."""
    return table.bias_sigma_mps2 * rng.standard_normal(table.bias_sigma_mps2.shape)


@kernel
def imu_row(i: int, bias: np.ndarray, true_acc: np.ndarray, dt: float, table: ImuTable,
            normals: np.ndarray, out: np.ndarray) -> None:
    """One sample of row ``i`` over the next ``dt`` [s]: ``out[i]`` = the measured world-frame
    acceleration [m/s²] for the true mean acceleration ``true_acc[i]`` over the sample; then the
    bias ``bias`` (N, 3) [m/s²] advances by ``dt`` in place. ``normals`` (N,
    :data:`IMU_NORMALS`): bias drive, white noise."""
    a = math.exp(-dt / table.bias_tau_s[i])
    drive = math.sqrt(-math.expm1(-2.0 * dt / table.bias_tau_s[i]))
    root_dt = math.sqrt(dt)
    for j in range(3):
        out[i, j] = (true_acc[i, j] + bias[i, j]
                     + table.noise_density[i, j] / root_dt * normals[i, 3 + j])
        bias[i, j] = a * bias[i, j] + table.bias_sigma_mps2[i, j] * drive * normals[i, j]


@kernel
def imu_step(bias: np.ndarray, true_acc: np.ndarray, dt: float, table: ImuTable,
             normals: np.ndarray, out: np.ndarray) -> None:
    """:func:`imu_row` for every row."""
    for i in range(bias.shape[0]):
        imu_row(i, bias, true_acc, dt, table, normals, out)
