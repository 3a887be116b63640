"""Compiled (numba) inner loop of the plant: attitude controller, mixer, RK4 rigid body, ground.

All kernels live in this one file on purpose: numba's ``cache=True`` invalidates a cached
function only when *its own* source file changes, so a kernel calling a kernel from another file
could silently keep running stale code. The readable references are
:class:`uavmpc.control.attitude.AttitudeController` and the numpy functions in
:mod:`uavmpc.plant.multirotor`; tests prove both paths agree to 1e-9.
"""

from __future__ import annotations

import math

import numba
import numpy as np

N_RIGID = 13
"""Rigid-body part of the state vector: p (3), v (3), q (4), Ω (3)."""


@numba.njit(cache=True)
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
    lo: float,
    hi: float,
    dt: float,
    freeze: bool,
    out: np.ndarray,
) -> None:
    """Compiled :meth:`uavmpc.control.attitude.AttitudeController.update`; writes the (n,)
    rotor commands [rad/s] into ``out``.

    ``gains`` is :func:`uavmpc.control.attitude.pack_gains`' table. ``ctrl`` (7,) is the
    controller's state, updated in place: [0:3] rate integrator, [3:6] last measured rate,
    [6] 1.0 once [3:6] holds a measurement.
    """
    qc = (q[0], q[1], q[2], q[3])
    qdt = _weighted_target_k(qc, (qd[0], qd[1], qd[2], qd[3]), gains[6, 0])
    e0, e1, e2, e3 = _qmul((qc[0], -qc[1], -qc[2], -qc[3]), qdt)  # conj(q) ⊗ qd
    sgn = 1.0 if e0 >= 0.0 else -1.0
    ev = (sgn * e1, sgn * e2, sgn * e3)
    if ctrl[6] == 0.0:
        for i in range(3):
            ctrl[3 + i] = w[i]
        ctrl[6] = 1.0
    alpha = np.empty(3)
    for i in range(3):
        sp = gains[0, i] * 2.0 * ev[i] + ff[i]
        lim = gains[1, i]
        sp = min(max(sp, -lim), lim)
        err = sp - w[i]
        rate_dot = (w[i] - ctrl[3 + i]) / dt
        alpha[i] = gains[2, i] * err + ctrl[i] - gains[4, i] * rate_dot
        if not freeze:
            ilim = gains[5, i]
            ctrl[i] = min(max(ctrl[i] + gains[3, i] * err * dt, -ilim), ilim)
        ctrl[3 + i] = w[i]
    jw0 = inertia[0, 0] * w[0] + inertia[0, 1] * w[1] + inertia[0, 2] * w[2]
    jw1 = inertia[1, 0] * w[0] + inertia[1, 1] * w[1] + inertia[1, 2] * w[2]
    jw2 = inertia[2, 0] * w[0] + inertia[2, 1] * w[1] + inertia[2, 2] * w[2]
    tx = inertia[0, 0] * alpha[0] + inertia[0, 1] * alpha[1] + inertia[0, 2] * alpha[2]
    ty = inertia[1, 0] * alpha[0] + inertia[1, 1] * alpha[1] + inertia[1, 2] * alpha[2]
    tz = inertia[2, 0] * alpha[0] + inertia[2, 1] * alpha[1] + inertia[2, 2] * alpha[2]
    tx += w[1] * jw2 - w[2] * jw1
    ty += w[2] * jw0 - w[0] * jw2
    tz += w[0] * jw1 - w[1] * jw0
    n = mix_inv.shape[0]
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


@numba.njit(cache=True)
def _qmul(a, b):
    """Hamilton product of two (w, x, y, z) tuples (as :func:`uavmpc.control.attitude.quat_mul`)."""
    return (
        a[0] * b[0] - (a[1] * b[1] + a[2] * b[2] + a[3] * b[3]),
        a[0] * b[1] + b[0] * a[1] + (a[2] * b[3] - a[3] * b[2]),
        a[0] * b[2] + b[0] * a[2] + (a[3] * b[1] - a[1] * b[3]),
        a[0] * b[3] + b[0] * a[3] + (a[1] * b[2] - a[2] * b[1]),
    )


@numba.njit(cache=True)
def _weighted_target_k(q, qd, yaw_weight):
    """Compiled :func:`uavmpc.control.attitude.weighted_target` on (w, x, y, z) tuples."""
    ex = 2.0 * (q[1] * q[3] + q[0] * q[2])
    ey = 2.0 * (q[2] * q[3] - q[0] * q[1])
    ez = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])
    dx = 2.0 * (qd[1] * qd[3] + qd[0] * qd[2])
    dy = 2.0 * (qd[2] * qd[3] - qd[0] * qd[1])
    dz = 1.0 - 2.0 * (qd[1] * qd[1] + qd[2] * qd[2])
    r0 = ex * dx + ey * dy + ez * dz + 1.0
    r1 = ey * dz - ez * dy
    r2 = ez * dx - ex * dz
    r3 = ex * dy - ey * dx
    nr = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3)
    r0, r1, r2, r3 = r0 / nr, r1 / nr, r2 / nr, r3 / nr
    if abs(r1) > 1.0 - 1e-5 or abs(r2) > 1.0 - 1e-5:
        return qd
    red = _qmul((r0, r1, r2, r3), q)
    m0, _, _, m3 = _qmul((red[0], -red[1], -red[2], -red[3]), qd)
    if m0 < 0.0:
        m0, m3 = -m0, -m3
    w0 = min(max(m0, -1.0), 1.0)
    w3 = min(max(m3, -1.0), 1.0)
    return _qmul(red, (math.cos(yaw_weight * math.acos(w0)), 0.0, 0.0,
                       math.sin(yaw_weight * math.asin(w3))))




@numba.njit(cache=True, inline="always")
def _rotation(w, x, y, z):
    """Row-major entries of the rotation matrix of the unit quaternion (w, x, y, z)."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))


@numba.njit(cache=True)
def _rhs(x, cmd, phys, inertia, inertia_inv, alloc, wind, dx):
    """dx = f(x, cmd) in place. ``phys`` = [mass, g, motor_tau, omega_max, dx, dy, dz]."""
    n = cmd.shape[0]
    m = phys[0]
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    wx, wy, wz = x[10], x[11], x[12]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotation(qw, qx, qy, qz)
    thrust = 0.0
    tx = 0.0
    ty = 0.0
    tz = 0.0
    for k in range(n):
        wk = x[N_RIGID + k]
        s = wk * wk
        thrust += alloc[0, k] * s
        tx += alloc[1, k] * s
        ty += alloc[2, k] * s
        tz += alloc[3, k] * s
        c = min(max(cmd[k], 0.0), phys[3])
        dx[N_RIGID + k] = (c - wk) / phys[2]
    # Drag in the body frame: F_b = −D Rᵀ (v − wind); world force = R F_b.
    ax = x[3] - wind[0]
    ay = x[4] - wind[1]
    az = x[5] - wind[2]
    bx = -phys[4] * (r00 * ax + r10 * ay + r20 * az)
    by = -phys[5] * (r01 * ax + r11 * ay + r21 * az)
    bz = -phys[6] * (r02 * ax + r12 * ay + r22 * az) + thrust
    dx[0] = x[3]
    dx[1] = x[4]
    dx[2] = x[5]
    dx[3] = (r00 * bx + r01 * by + r02 * bz) / m
    dx[4] = (r10 * bx + r11 * by + r12 * bz) / m
    dx[5] = (r20 * bx + r21 * by + r22 * bz) / m - phys[1]
    dx[6] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    dx[7] = 0.5 * (qw * wx + qy * wz - qz * wy)
    dx[8] = 0.5 * (qw * wy + qz * wx - qx * wz)
    dx[9] = 0.5 * (qw * wz + qx * wy - qy * wx)
    jw0 = inertia[0, 0] * wx + inertia[0, 1] * wy + inertia[0, 2] * wz
    jw1 = inertia[1, 0] * wx + inertia[1, 1] * wy + inertia[1, 2] * wz
    jw2 = inertia[2, 0] * wx + inertia[2, 1] * wy + inertia[2, 2] * wz
    mx = tx - (wy * jw2 - wz * jw1)
    my = ty - (wz * jw0 - wx * jw2)
    mz = tz - (wx * jw1 - wy * jw0)
    dx[10] = inertia_inv[0, 0] * mx + inertia_inv[0, 1] * my + inertia_inv[0, 2] * mz
    dx[11] = inertia_inv[1, 0] * mx + inertia_inv[1, 1] * my + inertia_inv[1, 2] * mz
    dx[12] = inertia_inv[2, 0] * mx + inertia_inv[2, 1] * my + inertia_inv[2, 2] * mz


@numba.njit(cache=True)
def _ground(x, alloc, phys):
    """Inelastic flat-ground contact at z = 0; returns True when the vehicle rests on it."""
    if x[2] > 0.0:
        return False
    x[2] = 0.0
    if x[5] < 0.0:
        x[5] = 0.0
    thrust = 0.0
    for k in range(alloc.shape[1]):
        thrust += alloc[0, k] * x[N_RIGID + k] * x[N_RIGID + k]
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
    if thrust * r22 >= phys[0] * phys[1]:
        return False  # lifting off
    yaw = math.atan2(2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qy * qy + qz * qz))
    x[3] = 0.0
    x[4] = 0.0
    x[5] = 0.0
    x[6] = math.cos(0.5 * yaw)
    x[7] = 0.0
    x[8] = 0.0
    x[9] = math.sin(0.5 * yaw)
    x[10] = 0.0
    x[11] = 0.0
    x[12] = 0.0
    return True


@numba.njit(cache=True)
def run_substeps(
    x, ctrl, landed, n_sub, dt, direct, motor_cmd, qd, thrust_n, ff, wind,
    phys, inertia, inertia_inv, alloc, gains, mix_inv, lo, hi,
):
    """Advance ``x`` (and the attitude loop's state ``ctrl``) by ``n_sub`` substeps of ``dt``.

    ``direct``: use ``motor_cmd`` as the rotor commands instead of the attitude loop.
    ``landed`` (1,) carries the contact flag between calls. Everything is updated in place.
    """
    n = x.shape[0]
    cmd = motor_cmd.copy()
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    xt = np.empty(n)
    for _ in range(n_sub):
        if not direct:
            attitude_kernel(
                x[6:10], x[10:13], qd, thrust_n, ff, ctrl, gains, inertia, mix_inv, lo, hi, dt,
                landed[0] != 0.0, cmd,
            )
        _rhs(x, cmd, phys, inertia, inertia_inv, alloc, wind, k1)
        for i in range(n):
            xt[i] = x[i] + 0.5 * dt * k1[i]
        _rhs(xt, cmd, phys, inertia, inertia_inv, alloc, wind, k2)
        for i in range(n):
            xt[i] = x[i] + 0.5 * dt * k2[i]
        _rhs(xt, cmd, phys, inertia, inertia_inv, alloc, wind, k3)
        for i in range(n):
            xt[i] = x[i] + dt * k3[i]
        _rhs(xt, cmd, phys, inertia, inertia_inv, alloc, wind, k4)
        for i in range(n):
            x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        qn = math.sqrt(x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9])
        for i in range(6, 10):
            x[i] /= qn
        landed[0] = 1.0 if _ground(x, alloc, phys) else 0.0


@numba.njit(cache=True, error_model="numpy")
def se3_kernel(
    p, v, q, p_d, v_d, a_d, psi, psi_rate, dt, gains, thrust_min, thrust_max, iw, ib, q_out,
    ff_out,
):
    """Compiled :meth:`uavmpc.control.se3.Se3Controller.update` (the numpy backend is the
    readable reference; a test proves both agree to 1e-12).

    ``p``, ``v``, ``q``: the state's position, velocity and attitude (w, x, y, z); ``p_d``,
    ``v_d``, ``a_d``, ``psi``, ``psi_rate``: the command. ``gains`` is
    :func:`uavmpc.control.se3.pack_gains`' (7, 3) table. ``iw``, ``ib`` (3,): the world- and
    body-frame integrals, updated in place (integrated only when neither saturated nor tilt
    limited). Writes the desired quaternion into ``q_out`` (4,) and the body-rate feedforward
    into ``ff_out`` (3,); returns (clipped thrust, saturated, tilt limited).
    ``error_model="numpy"``: a degenerate (zero) force gives NaN as numpy does, not an exception.
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotation(q[0], q[1], q[2], q[3])
    ep0 = p[0] - p_d[0]
    ep1 = p[1] - p_d[1]
    ep2 = p[2] - p_d[2]
    m = gains[6, 0]
    g = gains[6, 1]
    # R (K_ib ∫_body)
    b0 = gains[3, 0] * ib[0]
    b1 = gains[3, 1] * ib[1]
    b2 = gains[3, 2] * ib[2]
    f0 = (m * a_d[0] - gains[0, 0] * ep0 - gains[1, 0] * (v[0] - v_d[0])
          - (r00 * b0 + r01 * b1 + r02 * b2) - gains[2, 0] * iw[0])
    f1 = (m * a_d[1] - gains[0, 1] * ep1 - gains[1, 1] * (v[1] - v_d[1])
          - (r10 * b0 + r11 * b1 + r12 * b2) - gains[2, 1] * iw[1])
    f2 = (m * (a_d[2] + g) - gains[0, 2] * ep2 - gains[1, 2] * (v[2] - v_d[2])
          - (r20 * b0 + r21 * b1 + r22 * b2) - gains[2, 2] * iw[2])
    # Tilt limit: keep the vertical part (at least thrust_min), scale the horizontal one.
    fz = max(f2, thrust_min)
    h = math.hypot(f0, f1)
    h_max = fz * gains[6, 2]
    tilt_limited = h > h_max or f2 < thrust_min
    if h > h_max:
        f0 = f0 * h_max / h
        f1 = f1 * h_max / h
    f2 = fz
    nf = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    z0 = f0 / nf
    z1 = f1 / nf
    z2 = f2 / nf
    c = math.cos(psi)
    s = math.sin(psi)
    # b2 = b3 × b1c (b1c = [cos ψ, sin ψ, 0]), normalized; b1 = b2 × b3
    y0 = z1 * 0.0 - z2 * s
    y1 = z2 * c - z0 * 0.0
    y2 = z0 * s - z1 * c
    ny = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    y0 /= ny
    y1 /= ny
    y2 /= ny
    x0 = y1 * z2 - y2 * z1
    x1 = y2 * z0 - y0 * z2
    x2 = y0 * z1 - y1 * z0
    thrust = f0 * r02 + f1 * r12 + f2 * r22
    clipped = min(max(thrust, thrust_min), thrust_max)
    saturated = clipped != thrust
    if not (saturated or tilt_limited):
        e = (ep0, ep1, ep2)
        for i in range(3):
            lim = gains[4, i]
            iw[i] = min(max(iw[i] + e[i] * dt, -lim), lim)
        rte = (r00 * ep0 + r10 * ep1 + r20 * ep2,
               r01 * ep0 + r11 * ep1 + r21 * ep2,
               r02 * ep0 + r12 * ep1 + r22 * ep2)
        for i in range(3):
            lim = gains[5, i]
            ib[i] = min(max(ib[i] + rte[i] * dt, -lim), lim)
    ff_out[0] = psi_rate * x2
    ff_out[1] = psi_rate * y2
    ff_out[2] = psi_rate * z2
    # Quaternion of R_d = [b1, b2, b3] (columns), Shepperd's method as rot_to_quat.
    tr = x0 + y1 + z2
    if tr > max(x0, y1, z2):
        t = 2.0 * math.sqrt(1.0 + tr)
        qw, qx, qy, qz = 0.25 * t, (y2 - z1) / t, (z0 - x2) / t, (x1 - y0) / t
    elif x0 >= y1 and x0 >= z2:
        t = 2.0 * math.sqrt(1.0 + x0 - y1 - z2)
        qw, qx, qy, qz = (y2 - z1) / t, 0.25 * t, (y0 + x1) / t, (z0 + x2) / t
    elif y1 >= z2:
        t = 2.0 * math.sqrt(1.0 + y1 - x0 - z2)
        qw, qx, qy, qz = (z0 - x2) / t, (y0 + x1) / t, 0.25 * t, (z1 + y2) / t
    else:
        t = 2.0 * math.sqrt(1.0 + z2 - x0 - y1)
        qw, qx, qy, qz = (x1 - y0) / t, (z0 + x2) / t, (z1 + y2) / t, 0.25 * t
    nq = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if qw < 0.0:
        nq = -nq
    q_out[0] = qw / nq
    q_out[1] = qx / nq
    q_out[2] = qy / nq
    q_out[3] = qz / nq
    return clipped, saturated, tilt_limited
