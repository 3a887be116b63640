"""The plant's laws, compiled: rigid body (RK4), motors, drag, ground contact, and the step of
one row of a :class:`~uavmpc.plant.rows.PlantRows` record (attitude loop + RK4 + ground).

These are the only implementation of the plant: :class:`~uavmpc.plant.multirotor.Multirotor`
is a view on one row and calls :func:`plant_step`, a batched driver (the world) calls the same
kernel on every row of a shared record. ``tests/oracles.py`` holds a plain-numpy rendering that
the tests compare them with. The model and its equations are described in
:mod:`uavmpc.plant.multirotor`.

Every kernel takes the row's rotor count and touches only that many rotor columns, so rows of
different airframes share one record (sized for the most rotors) and each flies exactly as in a
record of its own width.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import types

from uavmpc.jit import intrinsic_returning, kernel
from uavmpc.plant.attitude import attitude_kernel

if TYPE_CHECKING:  # rows.py sizes its records with this module's constants
    from uavmpc.plant.rows import PlantRows

N_RIGID = 13
"""Rigid-body part of the state vector: p (3), v (3), q (4), Ω (3)."""

__all__ = ["N_RIGID", "attitude_target_ok", "contact", "deck_contact", "fly_target", "ground",
           "normalize_quat", "plant_step",
           "plant_step_motors", "quat_norm", "quat_rotation", "rhs", "settle", "work_floats"]


def work_floats(max_rotors: int) -> int:
    """The width of a :class:`~uavmpc.plant.rows.PlantRows` row's work area for vehicles of
    up to ``max_rotors`` rotors: for a row of nr rotors, the four RK4 stages and the stage
    state (13 + nr each), the attitude loop's angular acceleration (3), then the rotor
    commands (nr, from :func:`work_command_column`)."""
    return work_command_column(max_rotors) + max_rotors


@kernel(inline="always")
def work_command_column(n_rotors: int) -> int:
    """Where a row of ``n_rotors`` rotors keeps its rotor commands in its work area."""
    return 5 * (N_RIGID + n_rotors) + 3


@intrinsic_returning(float)
def _fma(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    """a · b + c with one rounding (LLVM's fma: the hardware instruction where there is one,
    an exact software fallback elsewhere)."""
    if not all(isinstance(t, types.Float) for t in (a, b, c)):
        return None
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.fma(*args)

    return sig, codegen


@kernel
def quat_norm(q: np.ndarray) -> float:
    """‖q‖ of a (4,) array.

    Rounded as numpy's ``math.sqrt(q @ q)``, with which :class:`~uavmpc.plant.Multirotor` used
    to normalise its targets, is on x86-64 (OpenBLAS's ``ddot`` accumulates with fused
    multiply-adds): moving the check into the kernel changed no flight. Each ``_fma`` rounds
    once on any machine, so the kernel itself is portable.
    """
    s = q[0] * q[0]
    s = _fma(q[1], q[1], s)
    s = _fma(q[2], q[2], s)
    s = _fma(q[3], q[3], s)
    return math.sqrt(s)


@kernel
def attitude_target_ok(qd: np.ndarray, thrust_n: float, ff: np.ndarray) -> bool:
    """Whether an attitude target can be flown: quaternion ``qd`` (4,) of norm in (0.9, 1.1),
    finite thrust [N] and body-rate feedforward ``ff`` (3,). A plant refuses anything else
    instead of integrating NaN."""
    nq = quat_norm(qd)
    return (0.9 < nq < 1.1 and math.isfinite(thrust_n) and math.isfinite(ff[0])
            and math.isfinite(ff[1]) and math.isfinite(ff[2]))


@kernel
def normalize_quat(q: np.ndarray) -> None:
    """Scale the (4,) quaternion ``q`` to unit length in place (by :func:`quat_norm`)."""
    nq = quat_norm(q)
    for j in range(4):
        q[j] /= nq


@kernel(inline="always")
def quat_rotation(w: float, x: float, y: float, z: float) -> tuple[float, ...]:
    """Row-major entries (9) of the rotation matrix of the unit quaternion (w, x, y, z)."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))


@kernel
def rhs(
    x: np.ndarray,
    cmd: np.ndarray,
    n: int,
    phys: np.ndarray,
    inertia: np.ndarray,
    inertia_inv: np.ndarray,
    alloc: np.ndarray,
    wind: np.ndarray,
    dx: np.ndarray,
) -> None:
    """dx = f(x, cmd) in place, for a vehicle with ``n`` rotors (the first 13 + n entries).

    ``cmd`` (≥ n,) rotor-speed commands [rad/s]; ``phys`` = [mass, g, motor_tau, omega_max,
    drag x, y, z]; ``alloc`` (4, ≥ n) the allocation matrix; ``wind`` (3,) [m/s].
    """
    m = phys[0]
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    wx, wy, wz = x[10], x[11], x[12]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_rotation(qw, qx, qy, qz)
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


#: Deck record columns (:class:`~uavmpc.plant.rows.PlantRows` ``deck``).
DECK_ACTIVE, DECK_X, DECK_Y, DECK_Z, DECK_HEADING, DECK_VX, DECK_VY, DECK_YAW_RATE, DECK_HALF = \
    range(9)
#: Touch record columns (``touch``): touchdowns, then the first one's time, relative velocity
#: (3) and offset from the deck centre (along, across the deck's heading), edge strikes, the
#: contact now (:data:`FREE`, :data:`ON_TOP`, :data:`STRIKING`), and while resting on the deck
#: 1.0 and where on it (along, across).
(TOUCH_COUNT, TOUCH_T, TOUCH_VX, TOUCH_VY, TOUCH_VZ, TOUCH_ALONG, TOUCH_ACROSS, TOUCH_STRIKES,
 TOUCH_STATE, TOUCH_RESTING, TOUCH_REST_ALONG, TOUCH_REST_ACROSS) = range(12)
FREE, ON_TOP, STRIKING = 0.0, 1.0, 2.0
#: How far below the deck's top a vehicle over it may be found after a substep and still be on
#: top (it came from above; deeper, it came through the side: a strike).
DECK_TOP_TOLERANCE_M = 0.1


@kernel
def _rest(x: np.ndarray, vx: float, vy: float, yaw_rate: float) -> None:
    """At rest on a surface moving at (vx, vy) and turning at ``yaw_rate``: roll and pitch
    levelled, the heading kept, carried along."""
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    yaw = math.atan2(2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qy * qy + qz * qz))
    x[3] = vx
    x[4] = vy
    x[5] = 0.0
    x[6] = math.cos(0.5 * yaw)
    x[7] = 0.0
    x[8] = 0.0
    x[9] = math.sin(0.5 * yaw)
    x[10] = 0.0
    x[11] = 0.0
    x[12] = yaw_rate


@kernel
def _lifting(x: np.ndarray, n: int, alloc: np.ndarray, phys: np.ndarray) -> bool:
    """The vertical component of the thrust carries the weight."""
    thrust = 0.0
    for k in range(n):
        thrust += alloc[0, k] * x[N_RIGID + k] * x[N_RIGID + k]
    r22 = 1.0 - 2.0 * (x[7] * x[7] + x[8] * x[8])
    return thrust * r22 >= phys[0] * phys[1]


@kernel
def ground(x: np.ndarray, n: int, alloc: np.ndarray, phys: np.ndarray) -> bool:
    """Inelastic flat-ground contact at z = 0 for a vehicle with ``n`` rotors, in place; returns
    True when the vehicle rests on the ground (its thrust cannot lift it)."""
    if x[2] > 0.0:
        return False
    x[2] = 0.0
    if x[5] < 0.0:
        x[5] = 0.0
    if _lifting(x, n, alloc, phys):
        return False
    _rest(x, 0.0, 0.0, 0.0)  # no motion, roll and pitch levelled, the heading kept
    return True


@kernel
def deck_contact(x: np.ndarray, n: int, alloc: np.ndarray, phys: np.ndarray, deck: np.ndarray,
                 elapsed_s: float, t_s: float, touch: np.ndarray) -> bool:
    """Contact with a moving deck, in place: a horizontal square (``deck`` row as it was
    ``elapsed_s`` ago, its centre moving at constant velocity and yaw rate since) on top of a
    vehicle whose body fills the square down to the ground. Returns True when the vehicle rests
    on the deck.

    A vehicle whose centre is over the square and at most :data:`DECK_TOP_TOLERANCE_M` below
    its top is on top: inelastic contact, carried along once its thrust cannot lift it (the
    touchdown's time ``t_s``, relative velocity and offset are recorded in ``touch`` the first
    time). A vehicle whose rotor disc (radius ``phys[7]``) overlaps the deck's footprint below
    its top otherwise hits the deck's edge or the vehicle's side: counted as a strike in
    ``touch``, not simulated as an impact (a strike is a failed landing)."""
    if deck[DECK_ACTIVE] == 0.0:
        touch[TOUCH_STATE] = FREE
        return False
    psi = deck[DECK_HEADING] + deck[DECK_YAW_RATE] * elapsed_s
    rx = x[0] - (deck[DECK_X] + deck[DECK_VX] * elapsed_s)
    ry = x[1] - (deck[DECK_Y] + deck[DECK_VY] * elapsed_s)
    top = deck[DECK_Z]
    half = deck[DECK_HALF]
    c = math.cos(psi)
    s = math.sin(psi)
    along = c * rx + s * ry
    across = -s * rx + c * ry
    reach = half + phys[7]
    state = FREE
    if x[2] <= top and abs(along) <= reach and abs(across) <= reach:
        over = abs(along) <= half and abs(across) <= half
        state = ON_TOP if over and x[2] >= top - DECK_TOP_TOLERANCE_M else STRIKING
    before = touch[TOUCH_STATE]
    touch[TOUCH_STATE] = state
    if state != ON_TOP:
        touch[TOUCH_RESTING] = 0.0
    if state == STRIKING:
        if before != STRIKING:
            touch[TOUCH_STRIKES] += 1.0
        return False
    if state == FREE:
        return False
    # On top: the deck's point under the vehicle moves at v + ω × r.
    wz = deck[DECK_YAW_RATE]
    vx = deck[DECK_VX] - wz * ry
    vy = deck[DECK_VY] + wz * rx
    if before != ON_TOP:
        touch[TOUCH_COUNT] += 1.0
        if touch[TOUCH_COUNT] == 1.0:
            touch[TOUCH_T] = t_s
            touch[TOUCH_VX] = x[3] - vx
            touch[TOUCH_VY] = x[4] - vy
            touch[TOUCH_VZ] = x[5]
            touch[TOUCH_ALONG] = along
            touch[TOUCH_ACROSS] = across
    x[2] = top
    if x[5] < 0.0:
        x[5] = 0.0
    if _lifting(x, n, alloc, phys):
        touch[TOUCH_RESTING] = 0.0
        return False
    # Resting: it stays where it came to rest on the deck (integrating the carried motion
    # would let it drift outwards in a turn, by the deck's acceleration within a step).
    if touch[TOUCH_RESTING] == 0.0:
        touch[TOUCH_RESTING] = 1.0
        touch[TOUCH_REST_ALONG] = along
        touch[TOUCH_REST_ACROSS] = across
    a0 = touch[TOUCH_REST_ALONG]
    a1 = touch[TOUCH_REST_ACROSS]
    x[0] += (c * a0 - s * a1) - rx
    x[1] += (s * a0 + c * a1) - ry
    _rest(x, vx, vy, wz)
    return True


@kernel
def contact(i: int, rows: PlantRows, elapsed_s: float) -> None:
    """Row ``i``'s contacts after a substep ending ``elapsed_s`` after the row's time: the deck
    (when there is one), then the flat ground; sets the row's ``landed`` flag."""
    x = rows.x[i]
    nr = rows.n_rotors[i]
    on_deck = deck_contact(x, nr, rows.alloc[i], rows.phys[i], rows.deck[i], elapsed_s,
                           rows.t_s[i] + elapsed_s, rows.touch[i])
    rests = on_deck or ground(x, nr, rows.alloc[i], rows.phys[i])
    rows.landed[i] = 1.0 if rests else 0.0


@kernel
def settle(i: int, rows: PlantRows) -> None:
    """Apply the contacts to row ``i`` as it stands (after its state was written, e.g. at
    start-up on the ground or on the deck); sets its ``landed`` flag when it rests."""
    contact(i, rows, 0.0)


@kernel
def _integrate(
    i: int, rows: PlantRows, n_sub: int, direct: bool, qd: np.ndarray, thrust_n: float,
    ff: np.ndarray,
) -> None:
    """``n_sub`` substeps of row ``i``: (attitude loop unless ``direct``) → RK4 → ground. The
    rotor commands are those in the row's work area (``direct``) or the attitude loop's."""
    nr = rows.n_rotors[i]
    n = N_RIGID + nr
    x = rows.x[i]
    ctrl = rows.ctrl[i]
    wind = rows.wind_mps[i]
    phys = rows.phys[i]
    inertia = rows.inertia[i]
    inertia_inv = rows.inertia_inv[i]
    alloc = rows.alloc[i]
    gains = rows.att_gains[i]
    mix_inv = rows.mix_inv[i]
    lo = rows.lo[i]
    hi = rows.hi[i]
    dt = rows.substep_s[i]
    # The stages, the attitude loop's work and the commands: the row's own work area (a row
    # is stepped by one thread at a time), laid out as :func:`work_floats` counts it.
    work = rows.work[i]
    k1 = work[0:n]
    k2 = work[n:2 * n]
    k3 = work[2 * n:3 * n]
    k4 = work[3 * n:4 * n]
    xt = work[4 * n:5 * n]
    alpha = work[5 * n:5 * n + 3]  # the attitude loop's angular acceleration
    cmd = work[work_command_column(nr):work_command_column(nr) + nr]
    for sub in range(n_sub):
        if not direct:
            # Zero-order hold of the rotor commands over the substep.
            attitude_kernel(
                x[6:10], x[10:13], qd, thrust_n, ff, ctrl, gains, inertia, mix_inv, nr, lo, hi,
                dt, rows.landed[i] != 0.0, cmd, alpha,
            )
        if rows.armed[i] == 0.0:  # motors cut: the rotors spin down
            for k in range(nr):
                cmd[k] = 0.0
        rhs(x, cmd, nr, phys, inertia, inertia_inv, alloc, wind, k1)
        for j in range(n):
            xt[j] = x[j] + 0.5 * dt * k1[j]
        rhs(xt, cmd, nr, phys, inertia, inertia_inv, alloc, wind, k2)
        for j in range(n):
            xt[j] = x[j] + 0.5 * dt * k2[j]
        rhs(xt, cmd, nr, phys, inertia, inertia_inv, alloc, wind, k3)
        for j in range(n):
            xt[j] = x[j] + dt * k3[j]
        rhs(xt, cmd, nr, phys, inertia, inertia_inv, alloc, wind, k4)
        for j in range(n):
            x[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        qn = math.sqrt(x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9])
        for j in range(6, 10):
            x[j] /= qn
        contact(i, rows, (sub + 1) * dt)
    rows.t_s[i] += n_sub * dt


@kernel
def plant_step(
    i: int, rows: PlantRows, n_sub: int, qd: np.ndarray, thrust_n: float, ff: np.ndarray
) -> None:
    """Fly row ``i`` of ``rows`` (a :class:`~uavmpc.plant.rows.PlantRows`) for ``n_sub``
    substeps towards the attitude target: unit quaternion ``qd`` (4,) (check it with
    :func:`attitude_target_ok`, then :func:`normalize_quat`), collective thrust ``thrust_n`` [N]
    and body-rate feedforward ``ff`` (3,) [rad/s]. Runs the attitude loop at every substep,
    holds the row's ``wind_mps``, and advances its ``t_s`` by ``n_sub`` substeps."""
    _integrate(i, rows, n_sub, False, qd, thrust_n, ff)


@kernel(allocates=True)
def plant_step_motors(i: int, rows: PlantRows, n_sub: int, omega_cmd: np.ndarray) -> None:
    """:func:`plant_step` with the rotor-speed commands ``omega_cmd`` (≥ n,) [rad/s] held
    instead of the attitude loop's (the loop and its state are left alone)."""
    nr = rows.n_rotors[i]
    first = work_command_column(nr)
    for k in range(nr):
        rows.work[i, first + k] = omega_cmd[k]
    _integrate(i, rows, n_sub, True, np.array([1.0, 0.0, 0.0, 0.0]), 0.0, np.zeros(3))


@kernel
def fly_target(i: int, rows: PlantRows, n_sub: int, qd: np.ndarray, thrust_n: float,
               ff: np.ndarray) -> bool:
    """What a plant does with an attitude target: refuse it (False) unless
    :func:`attitude_target_ok`, else normalise ``qd`` in place and :func:`plant_step`."""
    if not attitude_target_ok(qd, thrust_n, ff):
        return False
    normalize_quat(qd)
    plant_step(i, rows, n_sub, qd, thrust_n, ff)
    return True
