"""GNSS position and velocity errors of N UAVs, compiled: a slowly varying bias plus white noise.

Model, per ENU axis j of UAV i (1σ figures per axis; east and north share the horizontal values,
up has its own, typically 1.5–2× larger because every satellite is above the horizon):

- position fix ``z_p = p + b + σ_w n``: ``b`` is a first-order Gauss–Markov process (stationary
  standard deviation σ_b, correlation time τ), ``n`` a standard normal drawn afresh per fix;
- velocity fix (Doppler) ``z_v = v + σ_v n'``: white. Receivers derive velocity from the carrier
  Doppler shift, whose errors do not accumulate: no bias worth modelling at this scale.

Why Gauss–Markov and not a pure random walk: the slowly varying part of a fix's error (residual
ionospheric and tropospheric delay, orbit and clock errors, multipath) is bounded — it wanders
around zero and decorrelates over minutes as the satellites move — while a random walk's
variance grows without bound, so a long campaign would see errors no receiver has. The
Gauss–Markov process is also stationary, so every UAV starts in its steady state
(:func:`initial_bias`) and statistics do not depend on when a run starts. It is stepped with its
exact discretization, ``b ← a b + σ_b √(1 − a²) n`` with ``a = exp(−dt/τ)``, so its statistics do
not depend on the step (a filter may step it at 100 Hz while fixes come at 10 Hz).

Presets (:meth:`GnssModel.preset`, the numbers in ``uavmpc/data/gnss.toml``), from the figures
receiver datasheets and GNSS textbooks typically give (rounded, our reading):

- ``single``: a single-band (L1) standalone receiver. Datasheets of such modules quote about
  1.5–2.5 m CEP horizontal, i.e. a per-axis σ of about 1.3–2 m (CEP ≈ 1.18 σ for a circular
  error): σ_b = 1.5 m horizontal, 2.5 m vertical, τ = 120 s (a few minutes is the usual choice
  for the combined slowly varying error of a standalone fix), fix-to-fix white noise 0.3 m
  horizontal, 0.5 m vertical. Speed accuracy is quoted at about 0.05 m/s: σ_v = 0.05 m/s
  horizontal, 0.08 m/s vertical. 10 Hz.
- ``rtk``: RTK with fixed ambiguities. Datasheets quote about 1 cm + 1 ppm horizontal and
  2 cm + 1 ppm vertical: σ_b = 1 cm / 2 cm, white 0.7 cm / 1.2 cm (so about 1.2 cm / 2.3 cm in
  all), τ = 60 s (multipath at the rover changes with the satellite geometry), the same Doppler
  velocity as ``single``. 5 Hz: RTK output rates are limited by the correction link and the
  RTK engine rather than by the receiver, and 5 Hz is a common setting on drones.

Every UAV's bias is independent of the others' here. Receivers close to each other share most of
the atmospheric part, so this is the pessimistic case for the distance between two UAVs.

The state is plain arrays owned by the caller: the bias ``(N, 3)`` and a :class:`GnssTable` of
per-row parameters (rows may mix receivers). :func:`gnss_step` takes standard normals the caller
drew from its own seeded ``numpy.random.Generator``: the kernel is a pure function of its inputs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from uavmpc.config import ConfigError, from_table, positive, read_packaged_toml
from uavmpc.jit import kernel

__all__ = ["GNSS_NORMALS", "PRESETS", "GnssModel", "GnssTable", "gnss_row", "gnss_step",
           "gnss_table", "initial_bias"]

#: Standard normals one fix of one UAV consumes: bias drive (3), position noise (3), velocity
#: noise (3), in that order.
GNSS_NORMALS = 9
#: The preset names (tables of ``uavmpc/data/gnss.toml``).
PRESETS = ("rtk", "single")

#: Sane upper bounds: a value beyond them is a unit mistake, not a receiver.
_MAX_SIGMA_M = 100.0
_MAX_SIGMA_MPS = 10.0
_MAX_TAU_S = 1.0e6
_MAX_RATE_HZ = 1000.0


@dataclass(frozen=True)
class GnssModel:
    """One receiver's error model (1σ per axis; horizontal = east and north each).

    Attributes:
        horizontal_bias_sigma_m, vertical_bias_sigma_m: stationary std of the slowly varying
            position error σ_b [m] (≥ 0).
        horizontal_white_sigma_m, vertical_white_sigma_m: std of the white position noise of
            each fix σ_w [m] (≥ 0).
        bias_tau_s: correlation time τ of the bias [s] (> 0).
        horizontal_velocity_sigma_mps, vertical_velocity_sigma_mps: std of the white velocity
            noise σ_v [m/s] (≥ 0).
        rate_hz: fix rate [Hz] (> 0).

    The defaults are the ``single`` preset. A σ of 0 is a perfect receiver (for tests); a
    filter assuming the model needs positive white σ's (checked by
    :class:`~uavmpc.estimation.observer.ObserverParams`).
    """

    horizontal_bias_sigma_m: float = 1.5
    vertical_bias_sigma_m: float = 2.5
    horizontal_white_sigma_m: float = 0.3
    vertical_white_sigma_m: float = 0.5
    bias_tau_s: float = 120.0
    horizontal_velocity_sigma_mps: float = 0.05
    vertical_velocity_sigma_mps: float = 0.08
    rate_hz: float = 10.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            name = f.name
            value = getattr(self, name)
            if name == "bias_tau_s":
                out = positive(value, f"gnss.{name}", upper=_MAX_TAU_S)
            elif name == "rate_hz":
                out = positive(value, f"gnss.{name}", upper=_MAX_RATE_HZ)
            else:
                upper = _MAX_SIGMA_MPS if name.endswith("_mps") else _MAX_SIGMA_M
                out = positive(value, f"gnss.{name}", upper=upper, allow_zero=True)
            object.__setattr__(self, name, out)

    @classmethod
    def preset(cls, name: str) -> GnssModel:
        """The packaged preset ``"single"`` or ``"rtk"`` (see the module docstring)."""
        if name not in PRESETS:
            raise ConfigError(
                f"gnss preset {name!r}: unknown (choices: {', '.join(PRESETS)})")
        return cls.from_table(read_packaged_toml("gnss.toml")[name], f"gnss.{name}")

    @classmethod
    def from_table(cls, table: dict[str, Any], prefix: str = "gnss") -> GnssModel:
        """From a TOML table (missing fields take the defaults; unknown ones are errors)."""
        return from_table(cls, table, prefix)

    @property
    def period_s(self) -> float:
        """Time between fixes [s]."""
        return 1.0 / self.rate_hz

    def ticks_per_fix(self, dt_s: float) -> int:
        """Control ticks of ``dt_s`` between two fixes; the period must be a whole number of
        ticks (a 10 Hz fix in a 100 Hz loop: 10)."""
        dt = positive(dt_s, "dt_s")
        k = round(self.period_s / dt)
        if k < 1 or abs(k * dt - self.period_s) > 1e-9 * self.period_s:
            raise ConfigError(
                f"gnss.rate_hz: a fix every {self.period_s} s is not a whole number of "
                f"{dt} s ticks")
        return k

    def bias_sigma_m(self) -> np.ndarray:
        """(3,) σ_b per ENU axis [m]."""
        return np.array([self.horizontal_bias_sigma_m] * 2 + [self.vertical_bias_sigma_m])

    def white_sigma_m(self) -> np.ndarray:
        """(3,) σ_w per ENU axis [m]."""
        return np.array([self.horizontal_white_sigma_m] * 2 + [self.vertical_white_sigma_m])

    def velocity_sigma_mps(self) -> np.ndarray:
        """(3,) σ_v per ENU axis [m/s]."""
        return np.array(
            [self.horizontal_velocity_sigma_mps] * 2 + [self.vertical_velocity_sigma_mps])

    def position_sigma_m(self) -> np.ndarray:
        """(3,) total stationary std of a position fix's error, √(σ_b² + σ_w²) [m]."""
        return np.hypot(self.bias_sigma_m(), self.white_sigma_m())


class GnssTable(NamedTuple):
    """Per-row receiver parameters of N UAVs (numba takes the record as an argument).

    Attributes:
        bias_sigma_m: (N, 3) σ_b [m]; white_sigma_m: (N, 3) σ_w [m];
        velocity_sigma_mps: (N, 3) σ_v [m/s]; bias_tau_s: (N,) τ [s].
    """

    bias_sigma_m: np.ndarray
    white_sigma_m: np.ndarray
    velocity_sigma_mps: np.ndarray
    bias_tau_s: np.ndarray


def _per_row(models: Any, n: int, kind: type, what: str) -> list[Any]:
    """``models`` (one, or one per row) as a list of n instances of ``kind``."""
    if isinstance(models, kind):
        return [models] * n
    out = list(models)
    if len(out) != n or not all(isinstance(m, kind) for m in out):
        raise ConfigError(f"{what}: need one {kind.__name__} or {n} of them, got {models!r}")
    return out


def gnss_table(models: GnssModel | Sequence[GnssModel], n: int) -> GnssTable:
    """The :class:`GnssTable` of ``n`` rows: one model for all, or one per row."""
    rows = _per_row(models, n, GnssModel, "gnss")
    return GnssTable(
        bias_sigma_m=np.array([m.bias_sigma_m() for m in rows]).reshape(n, 3),
        white_sigma_m=np.array([m.white_sigma_m() for m in rows]).reshape(n, 3),
        velocity_sigma_mps=np.array([m.velocity_sigma_mps() for m in rows]).reshape(n, 3),
        bias_tau_s=np.array([m.bias_tau_s for m in rows], dtype=float).reshape(n),
    )


def initial_bias(table: GnssTable, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) biases drawn from the stationary distribution [m]: no start-up transient."""
    return table.bias_sigma_m * rng.standard_normal(table.bias_sigma_m.shape)


@kernel
def gnss_row(i: int, bias: np.ndarray, true_pos: np.ndarray, true_vel: np.ndarray, dt: float,
             table: GnssTable, normals: np.ndarray, pos_out: np.ndarray,
             vel_out: np.ndarray) -> None:
    """One fix of row ``i``: advance its bias by ``dt`` [s] (the time since its last fix, > 0),
    then write the measured position ``pos_out[i]`` [m] and velocity ``vel_out[i]`` [m/s].

    ``bias`` (N, 3) [m] is updated in place; ``true_pos``, ``true_vel`` (N, 3) are the truth at
    the fix; ``normals`` (N, :data:`GNSS_NORMALS`) standard normals (bias drive, position noise,
    velocity noise)."""
    a = math.exp(-dt / table.bias_tau_s[i])
    # √(1 − a²) through expm1: exact to the last bits even for dt ≪ τ.
    drive = math.sqrt(-math.expm1(-2.0 * dt / table.bias_tau_s[i]))
    for j in range(3):
        b = a * bias[i, j] + table.bias_sigma_m[i, j] * drive * normals[i, j]
        bias[i, j] = b
        pos_out[i, j] = true_pos[i, j] + b + table.white_sigma_m[i, j] * normals[i, 3 + j]
        vel_out[i, j] = true_vel[i, j] + table.velocity_sigma_mps[i, j] * normals[i, 6 + j]


@kernel
def gnss_step(bias: np.ndarray, true_pos: np.ndarray, true_vel: np.ndarray, dt: float,
              table: GnssTable, normals: np.ndarray, pos_out: np.ndarray,
              vel_out: np.ndarray) -> None:
    """:func:`gnss_row` for every row (all N UAVs fix at once, ``dt`` after their last fix)."""
    for i in range(bias.shape[0]):
        gnss_row(i, bias, true_pos, true_vel, dt, table, normals, pos_out, vel_out)
