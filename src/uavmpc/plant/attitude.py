"""The autopilot's attitude loop (SPEC §4), in the structure of PX4's multicopter loops:

    quaternion attitude error (tilt first, yaw weighted) → body-rate setpoint (P, rate-limited,
    + feedforward)
    → rate PID (D on the measured rate) → torques (× inertia, + gyroscopic term)
    → mixer (rotor geometry, yaw authority given up first on saturation) → rotor-speed commands.

It belongs to the plant: it runs at every plant substep (500 Hz by default) inside
:func:`uavmpc.plant.kernels.plant_step`, and the onboard stack only sends an
:class:`~uavmpc.plant.interface.AttitudeTarget`. The law exists once, as the compiled
:func:`attitude_kernel` (with :func:`mix`); ``tests/oracles.py`` holds a plain-numpy rendering
that the tests compare it with.

The kernels take a rotor count ``n`` and use only the first ``n`` rows of the mixer matrix, so a
row of a :class:`~uavmpc.plant.rows.PlantRows` record sized for more rotors flies exactly like a
record of its own width.
"""

from __future__ import annotations

import math

import numpy as np

from uavmpc.jit import kernel
from uavmpc.plant.airframe import Airframe, AttitudeGains

Quat = tuple[float, float, float, float]
"""A quaternion (w, x, y, z) as a tuple: the kernels keep small vectors in registers."""

__all__ = ["attitude_kernel", "mix", "mixer_matrices", "pack_attitude_gains", "qmul",
           "weighted_target"]


def pack_attitude_gains(g: AttitudeGains) -> np.ndarray:
    """(7, 3) gain table for :func:`attitude_kernel`: rows angle P (yaw already divided by the
    yaw weight), max rate, rate P, rate I, rate D, integral limit, [yaw weight, 0, 0]."""
    # The yaw-weighted target only carries yaw_weight of the yaw error; dividing the yaw gain by
    # it keeps the small-error yaw response at angle_p (as PX4 does).
    angle_p = g.angle_p_per_s / np.array([1.0, 1.0, g.yaw_weight])
    return np.vstack(
        [angle_p, g.max_rate_radps, g.rate_p_per_s, g.rate_i_per_s2, g.rate_d,
         g.rate_integral_limit_radps2, [g.yaw_weight, 0.0, 0.0]]
    ).astype(float)


def mixer_matrices(airframe: Airframe) -> tuple[np.ndarray, float, float]:
    """The mixer of ``airframe``: ``(inverse, lo, hi)``.

    ``inverse`` (n, 4) is the pseudo-inverse of the allocation matrix, ω² = inverse @
    [T, τx, τy, τz]; ``lo``, ``hi`` the allowed range of ω² while flying (idle² … max²)
    [(rad/s)²].
    """
    inverse = np.ascontiguousarray(np.linalg.pinv(airframe.allocation()))
    return inverse, airframe.omega_idle_radps**2, airframe.omega_max_radps**2


@kernel
def qmul(a: Quat, b: Quat) -> Quat:
    """Hamilton product a ⊗ b of two (w, x, y, z) tuples."""
    return (
        a[0] * b[0] - (a[1] * b[1] + a[2] * b[2] + a[3] * b[3]),
        a[0] * b[1] + b[0] * a[1] + (a[2] * b[3] - a[3] * b[2]),
        a[0] * b[2] + b[0] * a[2] + (a[3] * b[1] - a[1] * b[3]),
        a[0] * b[3] + b[0] * a[3] + (a[1] * b[2] - a[2] * b[1]),
    )


@kernel
def weighted_target(q: Quat, qd: Quat, yaw_weight: float) -> Quat:
    """PX4's yaw de-prioritization on (w, x, y, z) tuples: the target reached by first turning
    the thrust axis the shortest way onto the desired one, then only ``yaw_weight`` of the
    remaining heading error.

    Correcting a combined tilt + heading error along the single shortest rotation would swing the
    thrust axis sideways (and beyond its target tilt) while turning; this keeps it on course.
    """
    ex = 2.0 * (q[1] * q[3] + q[0] * q[2])
    ey = 2.0 * (q[2] * q[3] - q[0] * q[1])
    ez = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])
    dx = 2.0 * (qd[1] * qd[3] + qd[0] * qd[2])
    dy = 2.0 * (qd[2] * qd[3] - qd[0] * qd[1])
    dz = 1.0 - 2.0 * (qd[1] * qd[1] + qd[2] * qd[2])
    # Half-way quaternion from the current thrust axis to the desired one.
    r0 = ex * dx + ey * dy + ez * dz + 1.0
    r1 = ey * dz - ez * dy
    r2 = ez * dx - ex * dz
    r3 = ex * dy - ey * dx
    nr = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3)
    r0, r1, r2, r3 = r0 / nr, r1 / nr, r2 / nr, r3 / nr
    if abs(r1) > 1.0 - 1e-5 or abs(r2) > 1.0 - 1e-5:
        return qd  # thrust axes opposite: the full error already turns the right way
    red = qmul((r0, r1, r2, r3), q)
    # The remaining pure heading rotation, the short way round.
    m0, _, _, m3 = qmul((red[0], -red[1], -red[2], -red[3]), qd)
    if m0 < 0.0:
        m0, m3 = -m0, -m3
    w0 = min(max(m0, -1.0), 1.0)
    w3 = min(max(m3, -1.0), 1.0)
    return qmul(red, (math.cos(yaw_weight * math.acos(w0)), 0.0, 0.0,
                      math.sin(yaw_weight * math.asin(w3))))


@kernel
def mix(
    thrust_n: float, tx: float, ty: float, tz: float, mix_inv: np.ndarray, n: int, lo: float,
    hi: float, out: np.ndarray,
) -> None:
    """Rotor-speed commands [rad/s] of the first ``n`` rotors into ``out`` for the collective
    thrust [N] and body torque (tx, ty, tz) [N·m]; ``mix_inv``, ``lo``, ``hi`` from
    :func:`mixer_matrices`.

    On saturation the yaw torque is scaled down first (as PX4 does): losing yaw for a moment is
    harmless, losing roll/pitch is not. What remains out of range is clipped.
    """
    scale = 1.0
    for k in range(n):
        u = mix_inv[k, 0] * thrust_n + mix_inv[k, 1] * tx + mix_inv[k, 2] * ty
        uy = mix_inv[k, 3] * tz
        if uy > 0.0 and u + uy > hi:
            scale = min(scale, max(0.0, (hi - u) / uy))
        elif uy < 0.0 and u + uy < lo:
            scale = min(scale, max(0.0, (lo - u) / uy))
    for k in range(n):
        u = mix_inv[k, 0] * thrust_n + mix_inv[k, 1] * tx + mix_inv[k, 2] * ty
        u += scale * mix_inv[k, 3] * tz
        out[k] = math.sqrt(min(max(u, lo), hi))


@kernel
def attitude_kernel(
    q: np.ndarray,
    w: np.ndarray,
    qd: np.ndarray,
    thrust_n: float,
    ff: np.ndarray,
    ctrl: np.ndarray,
    gains: np.ndarray,
    inertia: np.ndarray,
    mix_inv: np.ndarray,
    n: int,
    lo: float,
    hi: float,
    dt: float,
    freeze: bool,
    out: np.ndarray,
    alpha: np.ndarray,
) -> None:
    """One step of the attitude loop; writes the rotor commands [rad/s] of the first ``n``
    rotors into ``out``.

    ``q`` (4,) attitude (w, x, y, z) and ``w`` (3,) body rates [rad/s] measured; ``qd`` (4,) unit
    target, ``thrust_n`` collective thrust [N], ``ff`` (3,) body-rate feedforward [rad/s].
    ``gains``: :func:`pack_attitude_gains`' table; ``inertia`` (3, 3); ``mix_inv``, ``lo``,
    ``hi``: :func:`mixer_matrices`. ``ctrl`` (7,) is the loop's state, updated in place: [0:3]
    rate integrator [rad/s²], [3:6] last measured rate, [6] 1.0 once [3:6] holds a measurement.
    ``freeze`` holds the rate integrator (set while the vehicle rests on the ground, where the
    rates cannot follow and the integrator would wind up). ``alpha`` (3,): work array (the
    angular acceleration commanded).
    """
    qc = (q[0], q[1], q[2], q[3])
    qdt = weighted_target(qc, (qd[0], qd[1], qd[2], qd[3]), gains[6, 0])
    e0, e1, e2, e3 = qmul((qc[0], -qc[1], -qc[2], -qc[3]), qdt)  # error in the body frame
    sgn = 1.0 if e0 >= 0.0 else -1.0  # the short way round
    ev = (sgn * e1, sgn * e2, sgn * e3)
    if ctrl[6] == 0.0:
        for i in range(3):
            ctrl[3 + i] = w[i]
        ctrl[6] = 1.0
    for i in range(3):
        sp = gains[0, i] * 2.0 * ev[i] + ff[i]
        lim = gains[1, i]
        sp = min(max(sp, -lim), lim)
        err = sp - w[i]
        rate_dot = (w[i] - ctrl[3 + i]) / dt
        # D on the measurement, not the error: a setpoint step does not kick the motors.
        alpha[i] = gains[2, i] * err + ctrl[i] - gains[4, i] * rate_dot
        if not freeze:
            ilim = gains[5, i]
            ctrl[i] = min(max(ctrl[i] + gains[3, i] * err * dt, -ilim), ilim)
        ctrl[3 + i] = w[i]
    # Torque = J α + Ω × J Ω.
    jw0 = inertia[0, 0] * w[0] + inertia[0, 1] * w[1] + inertia[0, 2] * w[2]
    jw1 = inertia[1, 0] * w[0] + inertia[1, 1] * w[1] + inertia[1, 2] * w[2]
    jw2 = inertia[2, 0] * w[0] + inertia[2, 1] * w[1] + inertia[2, 2] * w[2]
    tx = inertia[0, 0] * alpha[0] + inertia[0, 1] * alpha[1] + inertia[0, 2] * alpha[2]
    ty = inertia[1, 0] * alpha[0] + inertia[1, 1] * alpha[1] + inertia[1, 2] * alpha[2]
    tz = inertia[2, 0] * alpha[0] + inertia[2, 1] * alpha[1] + inertia[2, 2] * alpha[2]
    tx += w[1] * jw2 - w[2] * jw1
    ty += w[2] * jw0 - w[0] * jw2
    tz += w[0] * jw1 - w[1] * jw0
    mix(thrust_n, tx, ty, tz, mix_inv, n, lo, hi, out)
