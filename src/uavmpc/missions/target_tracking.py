"""Tracking a ground vehicle from noisy position fixes, and predicting its path.

A car on curves keeps its speed and turn rate for a while, so the filter is an extended Kalman
filter on the CTRV model (constant turn rate and velocity): state ``[x, y, ψ, v, ω]`` (ENU
position [m], heading [rad], speed [m/s], turn rate [rad/s]), driven by white noise in
longitudinal acceleration and in yaw acceleration. Measurements are (x, y) fixes; a fix whose
innovation is implausible (χ², 2 d.o.f., p < 0.001) is rejected and counted, so one bad fix
cannot throw the estimate; after :data:`LOST_AFTER` rejections in a row the track is taken as
lost and the filter starts again from the next fixes. :meth:`CtrvFilter.predict` integrates the
same model over the tracker's horizon: the path the UAV is asked to follow.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CtrvFilter", "ctrv_step"]

#: χ²(2) at p = 0.001: the innovation gate.
GATE = 13.8155
_STRAIGHT = 1e-3  # |ω| below this: the model's expansion for small turn rates
#: Rejected fixes in a row after which the track is lost and the filter restarts.
LOST_AFTER = 10


def ctrv_step(x: np.ndarray, dt: float) -> np.ndarray:
    """The CTRV model: state ``x`` (5,) after ``dt`` seconds."""
    px, py, psi, v, w = x
    if abs(w) > _STRAIGHT:
        px += v / w * (math.sin(psi + w * dt) - math.sin(psi))
        py += v / w * (math.cos(psi) - math.cos(psi + w * dt))
    else:  # first order in ω: the same values, and the right ∂/∂ω (the filter learns ω)
        px += v * dt * (math.cos(psi) - 0.5 * w * dt * math.sin(psi))
        py += v * dt * (math.sin(psi) + 0.5 * w * dt * math.cos(psi))
    return np.array([px, py, psi + w * dt, v, w])


class CtrvFilter:
    """EKF on the CTRV model.

    Args:
        fix_sigma_m: standard deviation of a position fix.
        accel_sigma_mps2: of the longitudinal acceleration (process noise).
        yaw_accel_sigma_radps2: of the yaw acceleration (process noise).
    """

    def __init__(self, fix_sigma_m: float = 0.3, accel_sigma_mps2: float = 1.0,
                 yaw_accel_sigma_radps2: float = 1.0) -> None:
        for name, v in (("fix_sigma_m", fix_sigma_m), ("accel_sigma_mps2", accel_sigma_mps2),
                        ("yaw_accel_sigma_radps2", yaw_accel_sigma_radps2)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be > 0, got {v!r}")
        self.r = np.eye(2) * fix_sigma_m**2
        self.q = np.diag([accel_sigma_mps2**2, yaw_accel_sigma_radps2**2])
        self.x: np.ndarray | None = None
        self.p = np.eye(5)
        self.t_s: float | None = None
        self._first: tuple[float, np.ndarray] | None = None
        self.accepted = 0
        self.rejected = 0
        self.restarts = 0
        self._in_a_row = 0

    @property
    def ready(self) -> bool:
        """True once the state is initialised (two fixes far enough apart)."""
        return self.x is not None

    def update(self, t_s: float, fix_m: np.ndarray) -> bool:
        """Take a position fix (x, y) at ``t_s``; False if rejected (not finite, out of order,
        or failing the innovation gate)."""
        z = np.asarray(fix_m, dtype=float).reshape(-1)[:2]
        if z.shape != (2,) or not np.all(np.isfinite(z)) or not math.isfinite(t_s) \
                or (self.t_s is not None and t_s <= self.t_s):
            self.rejected += 1
            return False
        if self.x is None:
            return self._initialise(t_s, z)
        self._propagate(t_s)
        h = np.zeros((2, 5))
        h[0, 0] = h[1, 1] = 1.0
        innovation = z - self.x[:2]
        s = h @ self.p @ h.T + self.r
        if innovation @ np.linalg.solve(s, innovation) > GATE:
            self.rejected += 1
            self._in_a_row += 1
            if self._in_a_row >= LOST_AFTER:  # lost: start again from what we see now
                self.restarts += 1
                self.x, self.t_s, self._first, self._in_a_row = None, None, (t_s, z), 0
            return False
        self._in_a_row = 0
        k = self.p @ h.T @ np.linalg.inv(s)
        self.x = self.x + k @ innovation
        self.p = (np.eye(5) - k @ h) @ self.p
        self.accepted += 1
        return True

    def _initialise(self, t_s: float, z: np.ndarray) -> bool:
        if self._first is None or t_s - self._first[0] < 0.2:
            if self._first is None:
                self._first = (t_s, z)
            self.accepted += 1
            return True
        t0, z0 = self._first
        d = z - z0
        dt = t_s - t0
        self.x = np.array([z[0], z[1], math.atan2(d[1], d[0]), float(np.linalg.norm(d)) / dt,
                           0.0])
        sigma2 = self.r[0, 0]
        self.p = np.diag([sigma2, sigma2, 2.0 * sigma2 / max(float(d @ d), 1e-6) + 0.05,
                          2.0 * sigma2 / dt**2 + 1.0, 0.25])
        self.t_s = t_s
        self.accepted += 1
        return True

    def _propagate(self, t_s: float) -> None:
        assert self.x is not None and self.t_s is not None
        dt = t_s - self.t_s
        x0 = self.x
        x1 = ctrv_step(x0, dt)
        f = np.empty((5, 5))  # the Jacobian by central differences: exact enough, no algebra
        for j in range(5):
            e = np.zeros(5)
            e[j] = 1e-6
            f[:, j] = (ctrv_step(x0 + e, dt) - ctrv_step(x0 - e, dt)) / 2e-6
        psi = x0[2]
        g = np.array([[0.5 * dt**2 * math.cos(psi), 0.0], [0.5 * dt**2 * math.sin(psi), 0.0],
                      [0.0, 0.5 * dt**2], [dt, 0.0], [0.0, dt]])
        self.x = x1
        self.p = f @ self.p @ f.T + g @ self.q @ g.T
        self.t_s = t_s

    def predict(self, times_s: np.ndarray, turn_decay_s: float | None = None) -> np.ndarray:
        """Predicted states (n, 5) at absolute ``times_s`` (increasing, ≥ the last fix), by
        the model; with ``turn_decay_s``, the turn rate decays with that time constant from
        the first time on (a car does not turn forever: over an 8 s horizon a constant turn
        rate would bring it all the way round)."""
        if self.x is None or self.t_s is None:
            raise RuntimeError("predict: the filter has not been initialised (needs two fixes)")
        times = np.asarray(times_s, dtype=float)
        out = np.empty((len(times), 5))
        x, t = self.x, self.t_s
        for i, t_i in enumerate(times):
            dt = max(t_i - t, 0.0)
            if turn_decay_s is None or i == 0:
                x = ctrv_step(x, dt)
            else:  # the turn rate decays over the step: turn at its mean, then decay it
                decay = math.exp(-dt / turn_decay_s)
                w = x[4]
                mean = w * (1.0 - decay) * turn_decay_s / dt if dt > 0 else w
                x = ctrv_step(np.array([x[0], x[1], x[2], x[3], mean]), dt)
                x[4] = w * decay
            t = max(t_i, t)
            out[i] = x
        return out
