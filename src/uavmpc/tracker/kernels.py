"""The tracker's law, once: compiled functions over rows of virtual UAVs, state in and out.

One tick of row ``i`` (SPEC §2), split along its natural seam:

- :func:`prepare_row`: sample the reference over the horizon (holding, looping or switching
  references), shift it by the avoidance's z offset, unwrap the heading the short way round,
  lay out the bounds in force (widened to the braking envelope when a tightening left the state
  outside the limits), build the four axis QPs (only the linear term and the bounds change) and
  their unconstrained optima; mark the axes whose optimum breaks a bound (``need``).
- the solve of the marked axes: inline with our dual active-set solver
  (:func:`uavmpc.solvers.batchqp.solve_warm`, in :func:`tick_row`) or, between the two compiled
  halves, by any Python solver behind the solver contract (DAQP, Clarabel).
- :func:`advance_row`: never trust a solver's word alone (every solution is checked against its
  bounds), brake on the axes that failed, and advance the virtual UAV by one step of the *same*
  model: the first predicted state is the next command.

:class:`uavmpc.tracker.MpcTracker` runs these on its own row; the world's batched tick runs
:func:`tick_row` for every UAV inside one compiled call. There is no other copy of this law.

Records (``NamedTuple`` of arrays, so that numba takes them as arguments): :class:`TrackerConsts`
(the fixed matrices of one :class:`~uavmpc.tracker.params.TrackerConfig`), :class:`TrackerRows`
(the state of N virtual UAVs, owned by whoever drives them) and :class:`ReferenceTable` (their
desired trajectories, packed).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba.core import types
from numba.experimental import structref

from uavmpc.jit import FASTMATH, FASTMATH_ORDERED, cycle_count, kernel
from uavmpc.reference import sample_reference
from uavmpc.solvers.batchqp import OPTIMAL, LdpData, solve_warm
from uavmpc.solvers.contract import FEASIBILITY_TOL

N_AXES = 4
#: State components outside the limit box by less than this count as inside (solver round-off).
INSIDE_TOL = 1e-9
#: Headings are kept continuous; re-centred by whole turns past this magnitude.
HEADING_RECENTER_RAD = 64.0 * np.pi
_TWO_PI = 2.0 * math.pi


class TrackerConsts(NamedTuple):
    """The fixed data of one tracker set-up (m steps, r = m + 1 constraint rows, n = m + r).

    Attributes:
        horizon_s: (m,) time of each predicted state after now [s].
        step_len_s: (m,) length of each step [s]; t_grid_s: (m + 1,) [0, horizon_s].
        tau_s: lag of the acceleration behind the input [s].
        f_state_t: (3, m), f_ref_t, vref_of_ref, f_vref_t: (m, m), f_uprev: (m,): the linear
            term ``f = s0 F_sᵀ + r F_rᵀ + u_prev F_u + clip(r D, v_lo, v_hi) F_vrᵀ``.
        cfree_t: (3, r) the constraint rows' free response; c_t: (m, r) their forced one.
        neg_hinv: (m, m) −H⁻¹ (the unconstrained optimum is ``f @ neg_hinv``).
        use_vref: the velocity weight is on (the reference's velocity enters f).
        free_t: (3, 3m), forced_t: (m, 3m): the plan ``X = s0 free_t + U forced_t``.
        ldp_*: the QP solver's data for (H, C) (the fields of
            :class:`~uavmpc.solvers.batchqp.LdpData`, flat: numba's parallel loops take
            records of arrays, not records of records); iter_limit: its iteration limit.
    """

    horizon_s: np.ndarray
    step_len_s: np.ndarray
    t_grid_s: np.ndarray
    tau_s: float
    f_state_t: np.ndarray
    f_ref_t: np.ndarray
    vref_of_ref: np.ndarray
    f_vref_t: np.ndarray
    f_uprev: np.ndarray
    cfree_t: np.ndarray
    c_t: np.ndarray
    neg_hinv: np.ndarray
    use_vref: bool
    free_t: np.ndarray
    forced_t: np.ndarray
    ldp_hess: np.ndarray
    ldp_hinv: np.ndarray
    ldp_cmat: np.ndarray
    ldp_q: np.ndarray
    ldp_gram: np.ndarray
    ldp_inv_norm: np.ndarray
    iter_limit: int


class TrackerRows(NamedTuple):
    """The state of N virtual UAVs (row i = one UAV; axes x, y, z, heading; ENU, SI).

    State (carried from tick to tick):
        state: (N, 4, 3) per axis [p, v, a] (m, m/s, m/s²; heading rad, rad/s, rad/s²).
        t_s: (N,) absolute time of ``state``.
        u_prev: (N, 4) the last applied input (for the input-rate weight).
        v_lo, v_hi, a_lo, a_hi: (N, 4) the limits in force (velocity, acceleration/input).
        z_offset_m: (N,) the avoidance's shift of the reference (≥ 0 in practice).
        hold_z_m: (N,) while the avoidance holds short, the reference's height (before the
            offset) in place of its own; NaN: none. A hold stops the mission's climb or
            descent as well as its horizontal motion; the offset still moves it.
        has_previous: (N,) a reference switch is pending: before the current reference's start
            the previous one is flown.
        fallback_count: (N,) ticks on which an axis fell back to braking.
    The last tick's plan and diagnostics:
        u_plan: (N, 4, m) inputs; p0: (N, 4) positions it is relative to; rel: (N, 4, 3) the
            start state relative to p0 (the plan is ``rel free_t + u_plan forced_t`` + p0).
        braking: (N,) the state was outside the limits in force; fallback: (N, 4) axes that
            braked because their QP failed; qp_solves, iterations: (N,) solver work.
    The QPs between :func:`prepare_row` and :func:`advance_row`:
        f: (N, 4, m); lower, upper: (N, 4, n); need: (N, 4) the axis needs the solver;
        solved: (N, 4) int8 what its solver reported (written by the solver step): 0 no
            solution, 1 a solution (that :func:`advance_row` checks against the bounds), 2 a
            solution the solver checked itself against the actual rows (our compiled one);
        brake_u: (N, 4, m) the braking plan's inputs (valid when braking or fallen back).
    The dual active-set solver's warm start per axis:
        ws: (N, 4, n) int8 working sets; lf: (N, 4, m + 1, m + 1) Cholesky factors;
        widx, wside: (N, 4, m + 1) int64; nw, age: (N, 4) int64 (see ``solve_batch``).
    """

    state: np.ndarray
    t_s: np.ndarray
    u_prev: np.ndarray
    v_lo: np.ndarray
    v_hi: np.ndarray
    a_lo: np.ndarray
    a_hi: np.ndarray
    z_offset_m: np.ndarray
    hold_z_m: np.ndarray
    has_previous: np.ndarray
    fallback_count: np.ndarray
    u_plan: np.ndarray
    p0: np.ndarray
    rel: np.ndarray
    braking: np.ndarray
    fallback: np.ndarray
    qp_solves: np.ndarray
    iterations: np.ndarray
    f: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    need: np.ndarray
    solved: np.ndarray
    brake_u: np.ndarray
    ws: np.ndarray
    lf: np.ndarray
    widx: np.ndarray
    wside: np.ndarray
    nw: np.ndarray
    age: np.ndarray

    @classmethod
    def empty(cls, n: int, m: int) -> TrackerRows:
        """N rows at rest at the origin, no limits set (the owner sets them)."""
        nr = 2 * m + 1
        m1 = m + 1
        return cls(
            np.zeros((n, N_AXES, 3)), np.zeros(n), np.zeros((n, N_AXES)),
            np.zeros((n, N_AXES)), np.zeros((n, N_AXES)), np.zeros((n, N_AXES)),
            np.zeros((n, N_AXES)), np.zeros(n), np.full(n, np.nan),
            np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.int64),
            np.zeros((n, N_AXES, m)), np.zeros((n, N_AXES)), np.zeros((n, N_AXES, 3)),
            np.zeros(n, dtype=np.bool_), np.zeros((n, N_AXES), dtype=np.bool_),
            np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
            np.zeros((n, N_AXES, m)), np.zeros((n, N_AXES, nr)), np.zeros((n, N_AXES, nr)),
            np.zeros((n, N_AXES), dtype=np.bool_), np.zeros((n, N_AXES), dtype=np.int8),
            np.zeros((n, N_AXES, m)),
            np.zeros((n, N_AXES, nr), dtype=np.int8), np.zeros((n, N_AXES, m1, m1)),
            np.zeros((n, N_AXES, m1), dtype=np.int64), np.zeros((n, N_AXES, m1), dtype=np.int64),
            np.full((n, N_AXES), -1, dtype=np.int64), np.zeros((n, N_AXES), dtype=np.int64),
        )


class ReferenceTable(NamedTuple):
    """The desired trajectories of N rows, packed (slot 0: current, slot 1: previous).

    Attributes:
        knots_s: (K,) all sampling knots, each reference's a contiguous run.
        values: (K, 4) ``[x, y, z, heading]`` at the knots (headings unwrapped).
        start: (N, 2) int64 first knot of each slot; length: (N, 2) its knot count (0: none).
        period_s: (N, 2) the knot spacing when uniform (O(1) sampling), else 0.
        loop: (N, 2) the reference repeats (its closing segment is among the knots).
    """

    knots_s: np.ndarray
    values: np.ndarray
    start: np.ndarray
    length: np.ndarray
    period_s: np.ndarray
    loop: np.ndarray


# ------------------------------------------------------------------------------ laws
@kernel
def limit_excess(s: np.ndarray, v_lo: np.ndarray, v_hi: np.ndarray, a_lo: np.ndarray,
                 a_hi: np.ndarray, tau: float) -> float:
    """How far state s (4, 3) lies outside the box of v, a and w = v + τa (0 inside)."""
    worst = 0.0
    for ax in range(4):
        v = s[ax, 1]
        a = s[ax, 2]
        w = v + tau * a
        worst = max(worst, v - v_hi[ax], v_lo[ax] - v, a - a_hi[ax], a_lo[ax] - a,
                    w - v_hi[ax], v_lo[ax] - w)
    return worst


@kernel
def braking_plan(rel: np.ndarray, a_lo: np.ndarray, a_hi: np.ndarray, tau: float,
                 t_grid: np.ndarray, step_len: np.ndarray, free_t: np.ndarray,
                 forced_t: np.ndarray, u_out: np.ndarray, s_out: np.ndarray) -> None:
    """Brake to a stop at the acceleration limits, every axis of state ``rel`` (4, 3).

    The policy ``u_k = clip(−w_k / Δt_k, a_lo, a_hi)`` drives ``w = v + τa`` to zero as fast as
    the input bound allows, so velocity and acceleration only shrink towards the box of the
    limits in force; ``w`` integrates ``u`` exactly, so it is a ramp at the limit down to zero,
    known in closed form. Writes the inputs ``u_out`` (4, m) and the states ``s_out``
    (4, m, 3); it is the safe fallback plan and the envelope that keeps the QP feasible after
    a tightening (:mod:`uavmpc.tracker.model`).
    """
    m = step_len.shape[0]
    for ax in range(rel.shape[0]):
        w0 = rel[ax, 1] + tau * rel[ax, 2]
        prev = w0
        for k in range(m):
            t = t_grid[k + 1]
            if w0 > 0.0:
                w = max(w0 + a_lo[ax] * t, 0.0)
            else:
                w = min(w0 + a_hi[ax] * t, 0.0)
            u_out[ax, k] = (w - prev) / step_len[k]
            prev = w
        # Row by row of forced_t (contiguous), each element's sum in the order of k.
        s = s_out[ax].reshape(3 * m)
        for c in range(3 * m):
            s[c] = rel[ax, 0] * free_t[0, c] + rel[ax, 1] * free_t[1, c] \
                + rel[ax, 2] * free_t[2, c]
        for k in range(m):
            uk = u_out[ax, k]
            fk = forced_t[k]
            for c in range(3 * m):
                s[c] += uk * fk[c]


@kernel(fastmath=FASTMATH)
def _axpy2(a: np.ndarray, x: np.ndarray, y: np.ndarray, i0: int, i1: int) -> None:
    """y[i] += Σ_k a[i, k] x[k] for the rows i = i0, i1 of a (4, K) and y (4, W), x (K, W):
    rows of x scaled and summed, k in order, each read once for both."""
    y0, y1 = y[i0], y[i1]
    for k in range(x.shape[0]):
        a0, a1 = a[i0, k], a[i1, k]
        xk = x[k]
        for j in range(x.shape[1]):
            xj = xk[j]
            y0[j] += a0 * xj
            y1[j] += a1 * xj


@kernel(fastmath=FASTMATH)
def _axpy1(a: np.ndarray, x: np.ndarray, y: np.ndarray, i0: int) -> None:
    """:func:`_axpy2` for the one row i0."""
    y0 = y[i0]
    for k in range(x.shape[0]):
        a0 = a[i0, k]
        xk = x[k]
        for j in range(x.shape[1]):
            y0[j] += a0 * xk[j]


@kernel(fastmath=FASTMATH)
def _axpy_axes(a: np.ndarray, x: np.ndarray, y: np.ndarray, n: int,
               i0: int, i1: int, i2: int, i3: int) -> None:
    """:func:`_axpy2` for the first ``n`` of the rows ``i0, i1, i2, i3`` of a and y (the
    others left as they are), two at a time: more rows per pass leave LLVM too many
    possibly overlapping stores to vectorise."""
    if n >= 2:
        _axpy2(a, x, y, i0, i1)
    elif n == 1:
        _axpy1(a, x, y, i0)
    if n == 4:
        _axpy2(a, x, y, i2, i3)
    elif n == 3:
        _axpy1(a, x, y, i2)


@kernel(fastmath=FASTMATH)
def excess4(u: np.ndarray, c_t: np.ndarray, lower: np.ndarray,
            upper: np.ndarray, cu: np.ndarray, worst: np.ndarray) -> None:
    """The largest violation of lower ≤ [u; u C_tᵀ] ≤ upper for each of the four axes (inputs
    ``u`` (4, m), bounds (4, m + r)) into ``worst`` (4,): −inf if none, NaN for an axis with
    a NaN input (callers test ``not worst <= tol``). ``cu`` (4, r): scratch for the rows."""
    _excess_axes(u, c_t, lower, upper, cu, worst, 4, 0, 1, 2, 3)


@kernel(fastmath=FASTMATH)
def _excess_axes(u: np.ndarray, c_t: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray, cu: np.ndarray, worst: np.ndarray, n: int, i0: int,
                 i1: int, i2: int, i3: int) -> None:
    """:func:`excess4` forming the rows C u of the first ``n`` of the axes ``i0, i1, i2, i3``
    only (for the others, whose u is +0, they are the +0 they start from)."""
    m = u.shape[1]
    nr = c_t.shape[1]
    cu[:] = 0.0
    _axpy_axes(u, c_t, cu, n, i0, i1, i2, i3)
    # The four axes' maxima side by side (a maximum is exact in any order): one chain of
    # 2 (m + r) dependent maxima per axis would wait on each comparison's latency.
    w0 = w1 = w2 = w3 = -math.inf
    bad0 = bad1 = bad2 = bad3 = False
    for k in range(m):
        x0, x1, x2, x3 = u[0, k], u[1, k], u[2, k], u[3, k]
        w0 = max(w0, lower[0, k] - x0, x0 - upper[0, k])
        w1 = max(w1, lower[1, k] - x1, x1 - upper[1, k])
        w2 = max(w2, lower[2, k] - x2, x2 - upper[2, k])
        w3 = max(w3, lower[3, k] - x3, x3 - upper[3, k])
        bad0 |= math.isnan(x0)
        bad1 |= math.isnan(x1)
        bad2 |= math.isnan(x2)
        bad3 |= math.isnan(x3)
    for k in range(nr):
        j = m + k
        x0, x1, x2, x3 = cu[0, k], cu[1, k], cu[2, k], cu[3, k]
        w0 = max(w0, lower[0, j] - x0, x0 - upper[0, j])
        w1 = max(w1, lower[1, j] - x1, x1 - upper[1, j])
        w2 = max(w2, lower[2, j] - x2, x2 - upper[2, j])
        w3 = max(w3, lower[3, j] - x3, x3 - upper[3, j])
    # An axis with a NaN input: NaN.
    worst[0] = math.nan if bad0 else w0
    worst[1] = math.nan if bad1 else w1
    worst[2] = math.nan if bad2 else w2
    worst[3] = math.nan if bad3 else w3


class Scratch(NamedTuple):
    """Work arrays of one row's tick, shared by the rows of a call (:func:`make_scratch`)."""


    times: np.ndarray
    rr: np.ndarray
    r_rel: np.ndarray
    brake_s: np.ndarray
    vref: np.ndarray
    rows_free: np.ndarray
    rows: np.ndarray
    h_orig: np.ndarray
    cu: np.ndarray
    lam: np.ndarray
    lam_star: np.ndarray
    blo: np.ndarray
    bhi: np.ndarray
    y: np.ndarray
    col: np.ndarray
    ell: np.ndarray
    z: np.ndarray
    skip: np.ndarray
    worst: np.ndarray


@kernel
def scratch_floats(m: int) -> int:
    """Length of the float buffer :func:`scratch_views` cuts a :class:`Scratch` from."""
    return 45 * m + 18


@kernel(allocates=True)
def scratch_views(buf: np.ndarray, skip: np.ndarray, m: int) -> Scratch:
    """The work arrays of a tick as views of one float buffer (:func:`scratch_floats` long)
    and one int8 buffer (2m + 1): a driver passes two arrays to a kernel, not nineteen."""
    n = 2 * m + 1
    o = 0
    times = buf[o:o + m]
    o += m
    rr = buf[o:o + 4 * m].reshape((m, 4))
    o += 4 * m
    r_rel = buf[o:o + 4 * m].reshape((4, m))
    o += 4 * m
    brake_s = buf[o:o + 12 * m].reshape((4, m, 3))
    o += 12 * m
    vref = buf[o:o + 4 * m].reshape((4, m))
    o += 4 * m
    rows_free = buf[o:o + m + 1]
    o += m + 1
    rows = buf[o:o + n]
    o += n
    h_orig = buf[o:o + m]
    o += m
    cu = buf[o:o + 4 * (m + 1)].reshape((4, m + 1))
    o += 4 * (m + 1)
    lam = buf[o:o + m + 1]
    o += m + 1
    lam_star = buf[o:o + m + 1]
    o += m + 1
    blo = buf[o:o + n]
    o += n
    bhi = buf[o:o + n]
    o += n
    y = buf[o:o + n]
    o += n
    col = buf[o:o + n]
    o += n
    ell = buf[o:o + m + 1]
    o += m + 1
    z = buf[o:o + m + 1]
    o += m + 1
    worst = buf[o:o + 4]
    return Scratch(times, rr, r_rel, brake_s, vref, rows_free, rows, h_orig, cu, lam, lam_star,
                   blo, bhi, y, col, ell, z, skip[:n], worst)


@kernel(allocates=True)
def make_scratch(m: int) -> Scratch:
    """Fresh work arrays of one row's tick (shared by the rows of one call)."""
    return scratch_views(np.empty(scratch_floats(m)), np.zeros(2 * m + 1, dtype=np.int8), m)


@kernel(fastmath=FASTMATH)
def prepare_row(i: int, rows: TrackerRows, refs: ReferenceTable, c: TrackerConsts,
                sc: Scratch) -> None:
    """First half of row i's tick: the reference over the horizon, the bounds in force, the
    QP data and the unconstrained optima (in ``rows.u_plan[i]``); sets ``rows.need[i]``."""
    horizon, step_len, t_grid, tau = c.horizon_s, c.step_len_s, c.t_grid_s, c.tau_s
    m = horizon.shape[0]
    nr = c.c_t.shape[1]
    s0 = rows.state[i]
    v_lo, v_hi, a_lo, a_hi = rows.v_lo[i], rows.v_hi[i], rows.a_lo[i], rows.a_hi[i]
    times, rr, r_rel = sc.times, sc.rr, sc.r_rel
    rel, f, lower, upper, u = rows.rel[i], rows.f[i], rows.lower[i], rows.upper[i], rows.u_plan[i]

    if abs(s0[3, 0]) > HEADING_RECENTER_RAD:
        s0[3, 0] -= _TWO_PI * np.round(s0[3, 0] / _TWO_PI)
    t_now = rows.t_s[i]
    for k in range(m):
        times[k] = t_now + horizon[k]
    n_ref = refs.length[i, 0]
    if n_ref == 0:  # no reference yet: hold the current state (no offset: it would ratchet)
        for k in range(m):
            for ax in range(4):
                rr[k, ax] = s0[ax, 0]
    else:
        a0 = refs.start[i, 0]
        sample_reference(refs.knots_s[a0:a0 + n_ref], refs.values[a0:a0 + n_ref],
                         refs.period_s[i, 0], refs.loop[i, 0], times, rr)
        if rows.has_previous[i]:
            if t_now >= refs.knots_s[a0]:
                rows.has_previous[i] = False  # the switch is done
            else:  # before the new reference starts, the previous one applies
                early = 0
                while early < m and times[early] < refs.knots_s[a0]:
                    early += 1
                b0, nb = refs.start[i, 1], refs.length[i, 1]
                sample_reference(refs.knots_s[b0:b0 + nb], refs.values[b0:b0 + nb],
                                 refs.period_s[i, 1], refs.loop[i, 1], times[:early],
                                 rr[:early])
        if not math.isnan(rows.hold_z_m[i]):
            for k in range(m):
                rr[k, 2] = rows.hold_z_m[i]
        if rows.z_offset_m[i] != 0.0:
            for k in range(m):
                rr[k, 2] += rows.z_offset_m[i]
    # Heading: the short way round from the current heading. A reference stores its headings
    # unwrapped, so one whole-turn shift suffices unless two references meet in the horizon.
    if rows.has_previous[i]:
        for k in range(m):
            sc.h_orig[k] = rr[k, 3]
        acc = 0.0
        for k in range(1, m):
            acc += (sc.h_orig[k] - sc.h_orig[k - 1] + math.pi) % _TWO_PI - math.pi
            rr[k, 3] = sc.h_orig[0] + acc
    shift = _TWO_PI * np.round((s0[3, 0] - rr[0, 3]) / _TWO_PI)
    for k in range(m):
        rr[k, 3] += shift

    # Positions relative to the current one keep the QP data well scaled (10 km steps).
    for ax in range(4):
        rows.p0[i, ax] = s0[ax, 0]
        rel[ax, 0] = 0.0
        rel[ax, 1] = s0[ax, 1]
        rel[ax, 2] = s0[ax, 2]
        for k in range(m):
            r_rel[ax, k] = rr[k, ax] - s0[ax, 0]
        # Row layout of the bounds: [u_1..u_m | v_1..v_m | w_1] (see tracker.model).
        for k in range(m):
            lower[ax, k] = a_lo[ax]
            upper[ax, k] = a_hi[ax]
        for k in range(m, m + nr):
            lower[ax, k] = v_lo[ax]
            upper[ax, k] = v_hi[ax]

    braking = limit_excess(s0, v_lo, v_hi, a_lo, a_hi, tau) > INSIDE_TOL
    rows.braking[i] = braking
    if braking:
        brake_u, brake_s = rows.brake_u[i], sc.brake_s
        braking_plan(rel, a_lo, a_hi, tau, t_grid, step_len, c.free_t, c.forced_t, brake_u,
                     brake_s)
        for ax in range(4):
            for k in range(m):
                lower[ax, k] = min(lower[ax, k], brake_u[ax, k])
                upper[ax, k] = max(upper[ax, k], brake_u[ax, k])
                lower[ax, m + k] = min(lower[ax, m + k], brake_s[ax, k, 1])
                upper[ax, m + k] = max(upper[ax, m + k], brake_s[ax, k, 1])
            w1 = brake_s[ax, 0, 1] + tau * brake_s[ax, 0, 2]
            lower[ax, 2 * m] = min(lower[ax, 2 * m], w1)
            upper[ax, 2 * m] = max(upper[ax, 2 * m], w1)

    # The linear terms, the constraint rows' free response and the unconstrained optima, two
    # axes at a time: each row of a matrix is read once for both, and written as sums of
    # scaled rows (contiguous memory), which LLVM vectorises. Every element sums its terms in
    # the same order as one axis at a time.
    vref, rows_free = sc.vref, sc.rows_free
    for ax in range(4):
        r1, r2 = rel[ax, 1], rel[ax, 2]
        for k in range(nr):
            rows_free[k] = r1 * c.cfree_t[1, k] + r2 * c.cfree_t[2, k]
            lower[ax, m + k] -= rows_free[k]
            upper[ax, m + k] -= rows_free[k]
    # An axis at rest on its reference over the whole horizon (no offset, speed, acceleration
    # or last input: the heading, mostly, and z until a climb) with 0 inside all its bounds
    # has the optimum U = 0 and no active bound; the products below would only add exact
    # zeros to it, so they run for the other axes only (a resting axis keeps u and the rows
    # C u at the +0 they start from, and f at 0, of either sign). Most ticks, half the axes.
    n_act = 0
    i0 = i1 = i2 = i3 = 0
    for ax in range(4):
        rest = rel[ax, 1] == 0.0 and rel[ax, 2] == 0.0 and rows.u_prev[i, ax] == 0.0
        for k in range(m):
            rest = rest and r_rel[ax, k] == 0.0
        for k in range(m + nr):
            rest = rest and lower[ax, k] <= 0.0 <= upper[ax, k]
        if not rest:
            if n_act == 0:
                i0 = ax
            elif n_act == 1:
                i1 = ax
            elif n_act == 2:
                i2 = ax
            else:
                i3 = ax
            n_act += 1
    for ax in range(4):
        r1, r2, up = rel[ax, 1], rel[ax, 2], rows.u_prev[i, ax]
        for k in range(m):
            f[ax, k] = r1 * c.f_state_t[1, k] + r2 * c.f_state_t[2, k] + up * c.f_uprev[k]
    _axpy_axes(r_rel, c.f_ref_t, f, n_act, i0, i1, i2, i3)
    if c.use_vref:
        # The reference's own velocity, clipped: a jump in it is not a speed to match.
        vref[:] = 0.0
        _axpy_axes(r_rel, c.vref_of_ref, vref, n_act, i0, i1, i2, i3)
        for ax in range(4):
            for k in range(m):
                vref[ax, k] = min(max(vref[ax, k], v_lo[ax]), v_hi[ax])
        _axpy_axes(vref, c.f_vref_t, f, n_act, i0, i1, i2, i3)
    u[:] = 0.0
    _axpy_axes(f, c.neg_hinv, u, n_act, i0, i1, i2, i3)
    # Bound check of the unconstrained optima.
    worst4 = sc.worst
    _excess_axes(u, c.c_t, lower, upper, sc.cu, worst4, n_act, i0, i1, i2, i3)
    for ax in range(4):
        worst = worst4[ax]
        rows.need[i, ax] = not worst <= 0.0  # a bound is active (or NaN): solve the QP
        rows.solved[i, ax] = 0


@kernel(fastmath=FASTMATH)
def advance_row(i: int, rows: TrackerRows, c: TrackerConsts, sc: Scratch) -> None:
    """Second half of row i's tick: check the solved axes, brake on failed ones, advance the
    virtual UAV to the first state of the plan."""
    m = c.horizon_s.shape[0]
    s0, rel, u = rows.state[i], rows.rel[i], rows.u_plan[i]
    braking = rows.braking[i]
    fell_back = False
    solves = 0
    need, solved = rows.need[i], rows.solved[i]
    # Never trust a solver's word alone: a solution is checked against the bounds here unless
    # the solver checked it itself (ours: the rows G U of its final solution, within 1e-8).
    check = False
    for ax in range(4):
        check = check or (need[ax] and solved[ax] == 1)
    if check:
        excess4(u, c.c_t, rows.lower[i], rows.upper[i], sc.cu, sc.worst)
    for ax in range(4):
        rows.fallback[i, ax] = False
        if not need[ax]:
            continue
        solves += 1
        ok = solved[ax] == 2 or (solved[ax] == 1 and sc.worst[ax] <= FEASIBILITY_TOL)
        if not ok:
            if not fell_back and not braking:
                braking_plan(rel, rows.a_lo[i], rows.a_hi[i], c.tau_s, c.t_grid_s, c.step_len_s,
                             c.free_t, c.forced_t, rows.brake_u[i], sc.brake_s)
            fell_back = True
            rows.fallback[i, ax] = True
            for k in range(m):
                u[ax, k] = rows.brake_u[i, ax, k]
    rows.qp_solves[i] = solves
    if fell_back:
        rows.fallback_count[i] += 1
    # Advance by one step of the same model: the first predicted state.
    for ax in range(4):
        for j in range(3):
            acc = rel[ax, 1] * c.free_t[1, j] + rel[ax, 2] * c.free_t[2, j]
            for k in range(m):
                acc += u[ax, k] * c.forced_t[k, j]
            s0[ax, j] = acc
        s0[ax, 0] += rows.p0[i, ax]
        rows.u_prev[i, ax] = u[ax, 0]
    rows.t_s[i] = rows.t_s[i] + c.horizon_s[0]


@kernel(fastmath=FASTMATH)
def solve_row(i: int, rows: TrackerRows, c: TrackerConsts, sc: Scratch) -> None:
    """The marked axes of row i, by the dual active-set solver, warm-started from its last
    working set and factor (:func:`~uavmpc.solvers.batchqp.solve_warm`)."""
    ld = LdpData(c.ldp_hess, c.ldp_hinv, c.ldp_cmat, c.ldp_q, c.ldp_gram, c.ldp_inv_norm)
    iterations = 0
    # Each axis of each row is one slot of the solver's factor cache (nw, age: (N·4,)).
    nw_flat = rows.nw.reshape(-1)
    age_flat = rows.age.reshape(-1)
    for ax in range(4):
        if not rows.need[i, ax]:
            continue
        ws = rows.ws[i, ax]
        # Its start, as prepare_row left it: U_free in u_plan, the rows C U_free in sc.cu.
        m = rows.u_plan.shape[2]
        for k in range(m):
            sc.rows[k] = rows.u_plan[i, ax, k]
        for k in range(sc.cu.shape[1]):
            sc.rows[m + k] = sc.cu[ax, k]
        st, it = solve_warm(
            rows.f[i, ax], rows.lower[i, ax], rows.upper[i, ax], ws, ld.hess, ld.hinv, ld.cmat,
            ld.q, ld.gram, ld.inv_norm, c.iter_limit, rows.u_plan[i, ax], ws, rows.lf[i, ax],
            rows.widx[i, ax], rows.wside[i, ax], nw_flat, age_flat, 4 * i + ax, sc.lam,
            sc.lam_star, sc.blo, sc.bhi, sc.y, sc.col, sc.ell, sc.z, sc.rows, sc.skip)
        rows.solved[i, ax] = 2 if st == OPTIMAL else 0
        iterations += it
    rows.iterations[i] = iterations


@kernel
def tick_row(i: int, rows: TrackerRows, refs: ReferenceTable, c: TrackerConsts,
             sc: Scratch, cycles: np.ndarray) -> None:
    """One whole tick of row i with the compiled solver. ``cycles``: (0,) int64, or (3,) or
    longer to add the CPU cycles of its prepare, QP and advance stages to its first three."""
    if cycles.shape[0] == 0:
        prepare_row(i, rows, refs, c, sc)
        solve_row(i, rows, c, sc)
        advance_row(i, rows, c, sc)
        return
    c0 = cycle_count()
    prepare_row(i, rows, refs, c, sc)
    c1 = cycle_count()
    solve_row(i, rows, c, sc)
    c2 = cycle_count()
    advance_row(i, rows, c, sc)
    cycles[0] += c1 - c0
    cycles[1] += c2 - c1
    cycles[2] += cycle_count() - c2


@kernel(allocates=True)
def tick_rows(idx: np.ndarray, rows: TrackerRows, refs: ReferenceTable, c: TrackerConsts,
              buf: np.ndarray, skip: np.ndarray) -> None:
    """:func:`tick_row` for the rows ``idx`` (work arrays: :func:`scratch_views`' buffers)."""
    sc = scratch_views(buf, skip, c.horizon_s.shape[0])
    untimed = np.empty(0, dtype=np.int64)
    for i in idx:
        tick_row(i, rows, refs, c, sc, untimed)


@kernel(allocates=True)
def prepare_rows(idx: np.ndarray, rows: TrackerRows, refs: ReferenceTable, c: TrackerConsts,
                 buf: np.ndarray, skip: np.ndarray) -> None:
    """:func:`prepare_row` for the rows ``idx`` (a Python solver takes the marked axes)."""
    sc = scratch_views(buf, skip, c.horizon_s.shape[0])
    for i in idx:
        prepare_row(i, rows, refs, c, sc)
        rows.iterations[i] = 0


@kernel(allocates=True)
def advance_rows(idx: np.ndarray, rows: TrackerRows, c: TrackerConsts, buf: np.ndarray,
                 skip: np.ndarray) -> None:
    """:func:`advance_row` for the rows ``idx``."""
    sc = scratch_views(buf, skip, c.horizon_s.shape[0])
    for i in idx:
        advance_row(i, rows, c, sc)


@kernel(fastmath=FASTMATH_ORDERED, allocates=True)
def plan(rel: np.ndarray, u: np.ndarray, p0: np.ndarray, free_t: np.ndarray,
         forced_t: np.ndarray, out: np.ndarray) -> None:
    """A tick's plan from its record (``rel`` (4, 3), ``u`` (4, m), ``p0`` (4,); see
    :class:`TrackerRows`): ``out`` (4, m, 3) per axis and step [p, v, a], the same sums as
    :func:`advance_row`, so ``out[:, 0]`` is the state the tick advanced to.

    The sums run along rows of ``forced_t`` (all 3m columns at once, vectorised) instead of
    down its columns: each element still adds its terms in the same order, k ascending, and
    without ``reassoc`` LLVM keeps that order, so the result is bit for bit the column-wise
    one (the kernel runs for every broadcast and every avoidance update)."""
    m = u.shape[1]
    w = 3 * m
    acc = np.empty(w)
    f1, f2 = free_t[1], free_t[2]
    for ax in range(4):
        r1, r2 = rel[ax, 1], rel[ax, 2]
        for j in range(w):
            acc[j] = r1 * f1[j] + r2 * f2[j]
        for k in range(m):
            uk = u[ax, k]
            fk = forced_t[k]
            for j in range(w):
                acc[j] += uk * fk[j]
        for j in range(w):
            out[ax, j // 3, j % 3] = acc[j]
        for k in range(m):
            out[ax, k, 0] += p0[ax]


@kernel
def snapshot_row(i: int, rows: TrackerRows, out: np.ndarray) -> tuple[bool, int, int, int]:
    """Copy row i's result into ``out`` (29 + 4m,): state (12), t_s (1), rel (12), u_plan
    (4m), p0 (4) — one copy of what a tick's output needs; returns (braking, QP solves,
    iterations, the fallback axes as bits)."""
    k = 0
    for ax in range(4):
        for j in range(3):
            out[k] = rows.state[i, ax, j]
            k += 1
    out[k] = rows.t_s[i]
    k += 1
    for ax in range(4):
        for j in range(3):
            out[k] = rows.rel[i, ax, j]
            k += 1
    m = rows.u_plan.shape[2]
    for ax in range(4):
        for j in range(m):
            out[k] = rows.u_plan[i, ax, j]
            k += 1
    bits = 0
    for ax in range(4):
        out[k] = rows.p0[i, ax]
        k += 1
        if rows.fallback[i, ax]:
            bits |= 1 << ax
    return rows.braking[i], rows.qp_solves[i], rows.iterations[i], bits


# ------------------------------------------------------------------------------ one tracker
@structref.register
class _BundleType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class TrackerBundle(structref.StructRefProxy):
    """One reference to the records a tick needs (rows, references, constants, work buffers).

    numba unpacks every array of a record argument on every call (≈ 3 µs for these, a tenth of
    a standalone tick); a bundle crosses into compiled code as one pointer. Built once, and
    again when the references are repacked (:func:`make_bundle`).
    """

    # The fields as compiled code reads them (kernels only: define_proxy gives the Python
    # proxy no accessors); declared for type checkers, no attributes at run time
    rows: TrackerRows
    refs: ReferenceTable
    consts: TrackerConsts
    buf: np.ndarray
    skip: np.ndarray


structref.define_proxy(TrackerBundle, _BundleType, ["rows", "refs", "consts", "buf", "skip"])


@kernel(allocates=True)
def make_bundle(rows: TrackerRows, refs: ReferenceTable, consts: TrackerConsts,
                buf: np.ndarray, skip: np.ndarray) -> TrackerBundle:
    """A :class:`TrackerBundle` of these records (compiled, so that it is cached)."""
    return TrackerBundle(rows, refs, consts, buf, skip)


@kernel(allocates=True)
def tick_bundle(i: int, b: TrackerBundle, out: np.ndarray) -> tuple[bool, int, int, int]:
    """:func:`tick_row` on a bundle's records, then :func:`snapshot_row`: a tracker ticking
    alone, in one call."""
    c = b.consts
    tick_row(i, b.rows, b.refs, c, scratch_views(b.buf, b.skip, c.horizon_s.shape[0]),
             np.empty(0, dtype=np.int64))
    return snapshot_row(i, b.rows, out)
