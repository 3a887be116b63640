"""Simulated sensors of the world around a UAV: position fixes of an observed target
(:class:`TargetSensor`). A UAV's own GNSS errors are :mod:`uavmpc.estimation`'s."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np


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
