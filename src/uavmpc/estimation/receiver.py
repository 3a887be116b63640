"""One GNSS receiver on one vehicle: the measured version of its true state.

Position gets white noise plus a slowly wandering bias (first-order Gauss–Markov, the typical
shape of GNSS error: an RTK fix wanders by centimetres, a plain fix by metres); velocity gets
white noise. The law is :func:`uavmpc.estimation.gnss.gnss_row`, on a one-row table. Attitude
and body rates come from the autopilot's own estimator and are passed through unchanged (their
errors are small next to GNSS's at the SE(3) controller's level).
"""

from __future__ import annotations

import numpy as np

from uavmpc.estimation.gnss import GNSS_NORMALS, GnssTable, gnss_step, initial_bias
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
        position_sigma_m: float | tuple[float, float, float] | np.ndarray = (0.01, 0.01, 0.02),
        velocity_sigma_mps: float | tuple[float, float, float] | np.ndarray = 0.02,
        bias_sigma_m: float | tuple[float, float, float] | np.ndarray = (0.02, 0.02, 0.04),
        bias_tau_s: float = 60.0,
        seed: int = 0,
    ) -> None:
        def vec(v: float | tuple[float, float, float] | np.ndarray, name: str) -> np.ndarray:
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
        self._table = GnssTable(bias_sigma_m=self.bias_sigma_m[None, :],
                                white_sigma_m=self.position_sigma_m[None, :],
                                velocity_sigma_mps=self.velocity_sigma_mps[None, :],
                                bias_tau_s=np.array([self.bias_tau_s]))
        self._bias = initial_bias(self._table, self._rng)
        self._pos = np.empty((1, 3))
        self._vel = np.empty((1, 3))
        self._t_s: float | None = None

    def apply(self, state: VehicleState) -> VehicleState:
        """The measured version of ``state`` (the bias advances to ``state.t_s``): one fix of
        the GNSS error law, :func:`uavmpc.estimation.gnss.gnss_row`, on this receiver's row."""
        dt = 0.0 if self._t_s is None else max(state.t_s - self._t_s, 0.0)
        self._t_s = state.t_s
        gnss_step(self._bias, state.position_m[None, :].astype(float),
                  state.velocity_mps[None, :].astype(float), dt, self._table,
                  self._rng.standard_normal((1, GNSS_NORMALS)), self._pos, self._vel)
        return VehicleState(
            t_s=state.t_s,
            position_m=self._pos[0].copy(),
            velocity_mps=self._vel[0].copy(),
            attitude_wxyz=state.attitude_wxyz,
            body_rates_radps=state.body_rates_radps,
        )

    @property
    def bias_m(self) -> np.ndarray:
        """(3,) the position bias now [m]."""
        return self._bias[0].copy()
