"""Simulated sensors: the state estimate given to the controller (SPEC §4) — the true state,
optionally with GNSS-like noise — and position fixes of an observed target (:class:`TargetSensor`).

Position gets white noise plus a slowly wandering bias (first-order Gauss–Markov, the typical
shape of GNSS error: an RTK fix wanders by centimetres, a plain fix by metres); velocity gets
white noise. Attitude and body rates come from the autopilot's own estimator and are passed
through unchanged (their errors are small next to GNSS's at the SE(3) controller's level).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from uavmpc.plant.interface import VehicleState


class GnssNoise:
    """Adds GNSS-like errors to a :class:`VehicleState`; seeded, so runs are reproducible.

    Args:
        position_sigma_m: (3,) or scalar white-noise standard deviation on position [m].
        velocity_sigma_mps: (3,) or scalar white-noise standard deviation on velocity [m/s].
        bias_sigma_m: (3,) or scalar stationary standard deviation of the position bias [m].
        bias_tau_s: correlation time of the bias [s].
        seed: seeds the generator.

    Defaults are an RTK-class receiver (≈ 1 cm horizontal, 2 cm vertical noise, a few cm bias).
    """

    def __init__(
        self,
        position_sigma_m: float | np.ndarray = (0.01, 0.01, 0.02),
        velocity_sigma_mps: float | np.ndarray = 0.02,
        bias_sigma_m: float | np.ndarray = (0.02, 0.02, 0.04),
        bias_tau_s: float = 60.0,
        seed: int = 0,
    ) -> None:
        def vec(v: float | np.ndarray, name: str) -> np.ndarray:
            out = np.broadcast_to(np.asarray(v, dtype=float), (3,)).copy()
            if not np.all(np.isfinite(out)) or np.any(out < 0.0):
                raise ValueError(f"{name} must be finite and ≥ 0, got {v!r}")
            return out

        self.position_sigma_m = vec(position_sigma_m, "position_sigma_m")
        self.velocity_sigma_mps = vec(velocity_sigma_mps, "velocity_sigma_mps")
        self.bias_sigma_m = vec(bias_sigma_m, "bias_sigma_m")
        if not bias_tau_s > 0.0:
            raise ValueError(f"bias_tau_s must be > 0, got {bias_tau_s}")
        self.bias_tau_s = float(bias_tau_s)
        self._rng = np.random.default_rng(seed)
        self.bias_m = self.bias_sigma_m * self._rng.standard_normal(3)
        self._t_s: float | None = None

    def apply(self, state: VehicleState) -> VehicleState:
        """The measured version of ``state`` (the bias advances to ``state.t_s``)."""
        if self._t_s is not None and state.t_s > self._t_s:
            a = math.exp(-(state.t_s - self._t_s) / self.bias_tau_s)
            self.bias_m = a * self.bias_m + self.bias_sigma_m * math.sqrt(
                1.0 - a * a
            ) * self._rng.standard_normal(3)
        self._t_s = state.t_s
        noise = self._rng.standard_normal(6)
        return VehicleState(
            t_s=state.t_s,
            position_m=state.position_m + self.bias_m + self.position_sigma_m * noise[:3],
            velocity_mps=state.velocity_mps + self.velocity_sigma_mps * noise[3:],
            attitude_wxyz=state.attitude_wxyz,
            body_rates_radps=state.body_rates_radps,
        )


class TargetFix(NamedTuple):
    """One position fix of an observed ground vehicle: when, and where (x, y) ENU [m]."""

    t_s: float
    position_m: np.ndarray


class TargetSensor:
    """Position fixes of a moving target (e.g. a ground vehicle's GNSS sent over a radio, or a
    camera's detections): at ``rate_hz``, each lost with probability ``dropout``, with white
    noise of ``sigma_m`` per horizontal axis; seeded.

    ``truth(t_s)`` gives the target's true (x, y, ...) position at ``t_s``."""

    def __init__(self, truth: Callable[[float], np.ndarray], *, rate_hz: float = 20.0,
                 sigma_m: float = 0.3, dropout: float = 0.1, seed: int = 0,
                 t0_s: float = 0.0) -> None:
        if not (math.isfinite(rate_hz) and 0.0 < rate_hz <= 1000.0):
            raise ValueError(f"rate_hz: must be in (0, 1000], got {rate_hz!r}")
        if not (math.isfinite(sigma_m) and sigma_m >= 0.0):
            raise ValueError(f"sigma_m: must be ≥ 0, got {sigma_m!r}")
        if not (math.isfinite(dropout) and 0.0 <= dropout < 1.0):
            raise ValueError(f"dropout: must be in [0, 1), got {dropout!r}")
        self.truth = truth
        self.period_s = 1.0 / rate_hz
        self.sigma_m = float(sigma_m)
        self.dropout = float(dropout)
        self._rng = np.random.default_rng(seed)
        self._k = 0
        self._t0 = float(t0_s)
        self.delivered = 0
        self.dropped = 0

    def fixes_until(self, t_s: float) -> list[TargetFix]:
        """The fixes taken since the last call, up to and including ``t_s``."""
        out = []
        while self._t0 + self._k * self.period_s <= t_s + 1e-9:
            t = self._t0 + self._k * self.period_s
            self._k += 1
            noise = self._rng.standard_normal(2) * self.sigma_m
            if self._rng.random() < self.dropout:
                self.dropped += 1
                continue
            self.delivered += 1
            out.append(TargetFix(t, np.asarray(self.truth(t), dtype=float)[:2] + noise))
        return out
