"""Wind: a constant mean plus seeded gusts (SPEC §4).

Gusts are an Ornstein–Uhlenbeck process per axis (exponentially correlated, stationary standard
deviation ``gust_sigma_mps``, correlation time ``gust_tau_s``), stepped with its exact
discretization so the statistics do not depend on the step size.
"""

from __future__ import annotations

import math

import numpy as np


class Wind:
    """Air velocity in the world frame ENU [m/s], the same everywhere (no spatial field).

    Args:
        mean_mps: (3,) constant part [m/s].
        gust_sigma_mps: (3,) or scalar stationary standard deviation of the gusts [m/s].
        gust_tau_s: correlation time of the gusts [s].
        seed: seeds the gust generator (runs are reproducible).
    """

    def __init__(
        self,
        mean_mps: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
        gust_sigma_mps: float | np.ndarray = 0.0,
        gust_tau_s: float = 2.0,
        seed: int = 0,
    ) -> None:
        self.mean_mps = np.asarray(mean_mps, dtype=float).reshape(3)
        self.gust_sigma_mps = np.broadcast_to(np.asarray(gust_sigma_mps, dtype=float), (3,)).copy()
        if np.any(self.gust_sigma_mps < 0.0) or not gust_tau_s > 0.0:
            raise ValueError("gust_sigma_mps must be ≥ 0 and gust_tau_s > 0")
        self.gust_tau_s = float(gust_tau_s)
        self._rng = np.random.default_rng(seed)
        # Start in the stationary distribution: no start-up transient in the statistics.
        self._gust = self.gust_sigma_mps * self._rng.standard_normal(3)

    def velocity(self) -> np.ndarray:
        """(3,) current wind velocity [m/s]."""
        return self.mean_mps + self._gust

    def update(self, dt_s: float) -> np.ndarray:
        """Advance the gusts by ``dt_s`` and return the new (3,) wind velocity [m/s]."""
        if np.any(self.gust_sigma_mps > 0.0):
            a = math.exp(-dt_s / self.gust_tau_s)
            self._gust = a * self._gust + self.gust_sigma_mps * math.sqrt(
                1.0 - a * a
            ) * self._rng.standard_normal(3)
        return self.velocity()
