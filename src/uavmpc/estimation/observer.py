"""The state observer of N UAVs, compiled: a linear Kalman filter per UAV and ENU axis fusing the
world-frame accelerometer (every control tick) with GNSS position and Doppler velocity fixes.

State per axis, S = :data:`N_STATE` = 4: ``[p, v, b_a, b_g]`` — position [m] and velocity [m/s]
of the UAV (the truth, not the fix), the accelerometer's bias [m/s²] and the GNSS position bias
[m]. The model is the one the simulated sensors follow (:mod:`~uavmpc.estimation.gnss`,
:mod:`~uavmpc.estimation.imu`), discretized exactly for an acceleration held over each step:

- predict over ``dt`` with the measured acceleration ``a_meas`` (ENU, gravity removed), ``u =
  a_meas − b_a``: ``p += v dt + u dt²/2``, ``v += u dt``, ``b_a`` and ``b_g`` decay as their
  Gauss–Markov processes (``exp(−dt/τ)``); the accelerometer's white noise (density N_a, variance
  N_a²/dt per sample) enters p and v through ``[dt²/2, dt]``, the biases' drives through their
  stationary variances ``σ² (1 − exp(−2 dt/τ))``;
- correct at a fix: position ``z_p = p + b_g + w`` (R = σ_w²), velocity ``z_v = v + w'``
  (R = σ_v²), as two scalar updates (R is diagonal: the same result as one joint update).

Why the GNSS bias is in the state rather than folded into an inflated R: the bias wanders over
minutes, so consecutive fixes share almost all of it. A filter that took it for white noise, even
with R inflated to the fix's whole error variance σ_b² + σ_w², averages it away over a few fixes
and believes its position good to a fraction of σ_b while the truth is off by σ_b: for the
``single`` preset its NEES comes out over 100× too large (~10× over-confident in σ), and no constant
inflation of R fixes that without also making the filter ignore the fixes. With the bias in the
state the covariance is right (tests: NEES against the truth within χ² bounds). ``b_g`` is not
observable from the fixes alone: only ``p + b_g`` is, and the two separate only through the
bias's mean reversion, seen against the track that the accelerometer and the Doppler velocity
integrate. So the position estimate mostly follows the bias — nothing else tells where the UAV
is — and the ``p`` block of P carries the part of the bias the filter cannot remove. (For
``single`` the filter still removes about a quarter of the bias's variance: 1.28 m RMS per
horizontal axis against 1.58 m raw. That gain rests on the bias being exactly the zero-mean
Gauss–Markov process the filter assumes; a real receiver's slow error is less regular, so read it
as optimistic. Without velocity fixes there is no such gain: the error is 0.98–0.99 of the raw
fixes'.) What the estimate does remove is the white part of the fixes and their jitter: a
correction moves the position by ~2 cm where the raw fixes jump by 0.43 m (``single``), so the
controller sees a smooth estimate, and a downstream consumer (avoidance margins) can read its real
uncertainty from P. The velocity is observed by the Doppler fixes and the accelerometer and is
unaffected by the position bias (≈ 2 cm/s RMS).

Why ``b_a`` is in the state: a MEMS bias of 0.02 m/s² integrated between fixes, and unmodelled,
would show up as a velocity error of the same order as the Doppler noise; with it in the state the
filter learns it from the velocity fixes (to ≈ 0.007 m/s² RMS of the default 0.02 m/s²).

Rows may differ in parameters (a :class:`ObserverNoise` holds them per row). A row without a fix
this tick, or an axis whose fix is NaN (a dropout), is not corrected. Kernels use strict IEEE
arithmetic: a batched call equals N one-row calls bit for bit.

Shapes: ``x`` (N, 3, S), ``P`` (N, 3, S, S) (axis order east, north, up), fixes and
accelerations (N, 3). The controller reads ``x[:, :, 0]`` (position) and ``x[:, :, 1]``
(velocity).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from uavmpc.config import ConfigError
from uavmpc.estimation.gnss import GnssModel, GnssTable, _per_row, gnss_table
from uavmpc.estimation.imu import ImuModel, ImuTable, imu_table
from uavmpc.jit import kernel

__all__ = ["BA", "BG", "INITIAL_SPEED_SIGMA_MPS", "N_STATE", "POS", "VEL", "ObserverNoise",
           "ObserverParams", "observer_correct", "observer_correct_row", "observer_init",
           "observer_init_row", "observer_noise", "observer_predict", "observer_predict_row"]

#: State components per axis: position, velocity, accelerometer bias, GNSS position bias.
POS, VEL, BA, BG = 0, 1, 2, 3
N_STATE = 4
#: The prior std of the velocity when the filter starts without a velocity fix [m/s].
INITIAL_SPEED_SIGMA_MPS = 5.0


@dataclass(frozen=True)
class ObserverParams:
    """What one UAV's filter assumes about its sensors.

    Attributes:
        gnss: the receiver's error model (bias σ_b and τ, white σ_w, Doppler σ_v). Its white
            σ_w (and σ_v when ``use_velocity``) must be > 0: they are the filter's R.
        imu: the accelerometer's error model (noise density, bias σ and τ).
        use_velocity: fuse the receiver's Doppler velocity (default) or positions only.

    Matched to the simulated sensors the filter is optimal and consistent; pass other models to
    study a mistuned filter.
    """

    gnss: GnssModel = dataclasses.field(default_factory=GnssModel)
    imu: ImuModel = dataclasses.field(default_factory=ImuModel)
    use_velocity: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.gnss, GnssModel):
            raise ConfigError(f"observer.gnss: must be a GnssModel, got {self.gnss!r}")
        if not isinstance(self.imu, ImuModel):
            raise ConfigError(f"observer.imu: must be an ImuModel, got {self.imu!r}")
        if not isinstance(self.use_velocity, bool):
            raise ConfigError(f"observer.use_velocity: must be a bool, got {self.use_velocity!r}")
        needed = ["horizontal_white_sigma_m", "vertical_white_sigma_m"]
        if self.use_velocity:
            needed += ["horizontal_velocity_sigma_mps", "vertical_velocity_sigma_mps"]
        for name in needed:
            # A zero R would make the filter trust a fix exactly (and divide by ~0).
            if getattr(self.gnss, name) <= 0.0:
                raise ConfigError(f"observer.gnss.{name}: must be > 0 (the filter's measurement "
                                  f"noise), got {getattr(self.gnss, name)}")


    @property
    def position_sigma_m(self) -> tuple[float, float]:
        """How far a position estimate of this observer may be from the truth, 1σ per
        horizontal axis and vertically [m]: the receiver's slowly varying bias, which no
        filter removes without another reference, with its white noise on top (conservative:
        the filter averages the white part down); what a UAV flying on it states in its
        predictions (docs/safety.md, A3)."""
        g = self.gnss
        return (math.hypot(g.horizontal_bias_sigma_m, g.horizontal_white_sigma_m),
                math.hypot(g.vertical_bias_sigma_m, g.vertical_white_sigma_m))
    @classmethod
    def preset(cls, name: str, imu: ImuModel | None = None) -> ObserverParams:
        """The filter for GNSS preset ``name`` (``"single"``, ``"rtk"``) and ``imu`` (default
        :class:`ImuModel`)."""
        return cls(GnssModel.preset(name), ImuModel() if imu is None else imu)


class ObserverNoise(NamedTuple):
    """Per-row filter parameters of N UAVs (numba takes the record as an argument).

    Attributes:
        gnss: the receivers' :class:`~uavmpc.estimation.gnss.GnssTable`.
        imu: the accelerometers' :class:`~uavmpc.estimation.imu.ImuTable`.
        use_velocity: (N,) bool, the row fuses velocity fixes.
    """

    gnss: GnssTable
    imu: ImuTable
    use_velocity: np.ndarray


def observer_noise(params: ObserverParams | Sequence[ObserverParams], n: int) -> ObserverNoise:
    """The :class:`ObserverNoise` of ``n`` rows: one parameter set for all, or one per row."""
    rows = _per_row(params, n, ObserverParams, "observer")
    return ObserverNoise(
        gnss=gnss_table([p.gnss for p in rows], n),
        imu=imu_table([p.imu for p in rows], n),
        use_velocity=np.array([p.use_velocity for p in rows], dtype=np.bool_).reshape(n),
    )


@kernel
def observer_init_row(i: int, x: np.ndarray, P: np.ndarray, z_pos: np.ndarray,
                      z_vel: np.ndarray, noise: ObserverNoise) -> None:
    """Start row ``i`` from its first fix ``z_pos[i]`` [m] (and ``z_vel[i]`` [m/s] if the row
    uses velocity and it is finite): the exact posterior of a flat prior on p and v and the
    stationary priors of the biases. Since ``p = z_p − b_g − w``, p inherits the bias's variance
    and is anti-correlated with it (``P[p, b_g] = −σ_b²``): consistent from the first tick."""
    g = noise.gnss
    for j in range(3):
        sb2 = g.bias_sigma_m[i, j] * g.bias_sigma_m[i, j]
        sw2 = g.white_sigma_m[i, j] * g.white_sigma_m[i, j]
        xa = x[i, j]
        Pa = P[i, j]
        for m in range(N_STATE):
            xa[m] = 0.0
            for k in range(N_STATE):
                Pa[m, k] = 0.0
        xa[POS] = z_pos[i, j]
        Pa[POS, POS] = sb2 + sw2
        Pa[POS, BG] = -sb2
        Pa[BG, POS] = -sb2
        Pa[BG, BG] = sb2
        if noise.use_velocity[i] and math.isfinite(z_vel[i, j]):
            xa[VEL] = z_vel[i, j]
            Pa[VEL, VEL] = g.velocity_sigma_mps[i, j] * g.velocity_sigma_mps[i, j]
        else:
            Pa[VEL, VEL] = INITIAL_SPEED_SIGMA_MPS * INITIAL_SPEED_SIGMA_MPS
        Pa[BA, BA] = noise.imu.bias_sigma_mps2[i, j] * noise.imu.bias_sigma_mps2[i, j]


@kernel
def observer_predict_row(i: int, x: np.ndarray, P: np.ndarray, a_meas: np.ndarray, dt: float,
                         noise: ObserverNoise) -> None:
    """Advance row ``i`` by ``dt`` [s] (> 0) with its measured world-frame acceleration
    ``a_meas[i]`` [m/s²] (ENU, gravity removed, the mean over the step), in place."""
    h = 0.5 * dt * dt
    tau_a = noise.imu.bias_tau_s[i]
    tau_g = noise.gnss.bias_tau_s[i]
    fa = math.exp(-dt / tau_a)
    fg = math.exp(-dt / tau_g)
    drive_a = -math.expm1(-2.0 * dt / tau_a)
    drive_g = -math.expm1(-2.0 * dt / tau_g)
    for j in range(3):
        xa = x[i, j]
        Pa = P[i, j]
        u = a_meas[i, j] - xa[BA]
        xa[POS] = xa[POS] + xa[VEL] * dt + u * h
        xa[VEL] = xa[VEL] + u * dt
        xa[BA] = fa * xa[BA]
        xa[BG] = fg * xa[BG]
        # P ← F P Fᵀ, F = [[1, dt, −h, 0], [0, 1, −dt, 0], [0, 0, fa, 0], [0, 0, 0, fg]]: rows
        # first (each row reads only the rows below it, not yet changed), then columns.
        for k in range(N_STATE):
            Pa[POS, k] = Pa[POS, k] + dt * Pa[VEL, k] - h * Pa[BA, k]
            Pa[VEL, k] = Pa[VEL, k] - dt * Pa[BA, k]
            Pa[BA, k] = fa * Pa[BA, k]
            Pa[BG, k] = fg * Pa[BG, k]
        for k in range(N_STATE):
            Pa[k, POS] = Pa[k, POS] + dt * Pa[k, VEL] - h * Pa[k, BA]
            Pa[k, VEL] = Pa[k, VEL] - dt * Pa[k, BA]
            Pa[k, BA] = fa * Pa[k, BA]
            Pa[k, BG] = fg * Pa[k, BG]
        # Accelerometer white noise: variance N_a²/dt per sample, through G = [h, dt, 0, 0].
        qa = noise.imu.noise_density[i, j] * noise.imu.noise_density[i, j] / dt
        Pa[POS, POS] += qa * h * h
        Pa[POS, VEL] += qa * h * dt
        Pa[VEL, POS] += qa * h * dt
        Pa[VEL, VEL] += qa * dt * dt
        sa = noise.imu.bias_sigma_mps2[i, j]
        sg = noise.gnss.bias_sigma_m[i, j]
        Pa[BA, BA] += sa * sa * drive_a
        Pa[BG, BG] += sg * sg * drive_g
        # The two passes round the mirrored entries differently; keep P exactly symmetric.
        for m in range(N_STATE):
            for k in range(m + 1, N_STATE):
                s = 0.5 * (Pa[m, k] + Pa[k, m])
                Pa[m, k] = s
                Pa[k, m] = s


@kernel
def _scalar_update(xa: np.ndarray, Pa: np.ndarray, k0: int, k1: int, z: float,
                   r: float) -> None:
    """Kalman update of one axis with the scalar fix ``z = x[k0] (+ x[k1] if k1 ≥ 0) + w``,
    var(w) = r > 0. ``P − g gᵀ/s`` with ``g = P hᵀ`` stays exactly symmetric (each product
    ``g_m g_k`` is the same number both ways round)."""
    g0 = Pa[0, k0]
    g1 = Pa[1, k0]
    g2 = Pa[2, k0]
    g3 = Pa[3, k0]
    pred = xa[k0]
    if k1 >= 0:
        g0 += Pa[0, k1]
        g1 += Pa[1, k1]
        g2 += Pa[2, k1]
        g3 += Pa[3, k1]
        pred += xa[k1]
    g = (g0, g1, g2, g3)
    s = g[k0] + r
    if k1 >= 0:
        s += g[k1]
    nu = (z - pred) / s
    xa[0] += g0 * nu
    xa[1] += g1 * nu
    xa[2] += g2 * nu
    xa[3] += g3 * nu
    for m in range(N_STATE):
        for k in range(N_STATE):
            Pa[m, k] -= g[m] * g[k] / s


@kernel
def observer_correct_row(i: int, x: np.ndarray, P: np.ndarray, z_pos: np.ndarray,
                         z_vel: np.ndarray, noise: ObserverNoise) -> None:
    """Correct row ``i`` with its fix: position ``z_pos[i]`` [m], velocity ``z_vel[i]`` [m/s]
    (ignored unless the row uses velocity), in place. A NaN component is a missing fix on that
    axis and is skipped."""
    g = noise.gnss
    for j in range(3):
        xa = x[i, j]
        Pa = P[i, j]
        if math.isfinite(z_pos[i, j]):
            _scalar_update(xa, Pa, POS, BG, z_pos[i, j],
                           g.white_sigma_m[i, j] * g.white_sigma_m[i, j])
        if noise.use_velocity[i] and math.isfinite(z_vel[i, j]):
            _scalar_update(xa, Pa, VEL, -1, z_vel[i, j],
                           g.velocity_sigma_mps[i, j] * g.velocity_sigma_mps[i, j])


@kernel
def observer_init(x: np.ndarray, P: np.ndarray, z_pos: np.ndarray, z_vel: np.ndarray,
                  noise: ObserverNoise) -> None:
    """:func:`observer_init_row` for every row."""
    for i in range(x.shape[0]):
        observer_init_row(i, x, P, z_pos, z_vel, noise)


@kernel
def observer_predict(x: np.ndarray, P: np.ndarray, a_meas: np.ndarray, dt: float,
                     noise: ObserverNoise) -> None:
    """:func:`observer_predict_row` for every row (one control tick of all UAVs)."""
    for i in range(x.shape[0]):
        observer_predict_row(i, x, P, a_meas, dt, noise)


@kernel
def observer_correct(x: np.ndarray, P: np.ndarray, z_pos: np.ndarray, z_vel: np.ndarray,
                     noise: ObserverNoise) -> None:
    """:func:`observer_correct_row` for every row (rows without a fix this tick: NaN)."""
    for i in range(x.shape[0]):
        observer_correct_row(i, x, P, z_pos, z_vel, noise)
