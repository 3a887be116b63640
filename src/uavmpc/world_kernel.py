"""The compiled world step: every UAV's tracker, SE(3) controller and plant in one numba call.

A 5-UAV world spends most of a 10 ms tick in Python overhead around small numpy calls (see
docs/campaign.md). This module runs the per-tick numerical work of all UAVs — reference
sampling, the tracker's QP build, the batched QP solver, the virtual UAV's step, the SE(3)
controller, the attitude loop and RK4 plant, the bookkeeping and the distances between UAVs —
in one compiled function over packed arrays, and leaves to Python only what happens at a lower
rate and is decentralised by nature: messages on the link, avoidance (10 Hz), broadcasts (2 Hz).

It is the same computation as the plain per-UAV path (:class:`uavmpc.onboard.OnboardStack`,
:class:`uavmpc.tracker.MpcTracker`, :class:`uavmpc.plant.Multirotor`), which stays the
readable reference: ``World(..., backend="plain")``. ``tests/test_world_kernel.py`` flies both
and compares. Two differences, both below 1e-6 m in flight: the QPs are solved by our batched
dual active-set solver (:mod:`uavmpc.tracker.batchqp`, equal to DAQP to 1e-9), and sums are
taken in a different order than numpy's.

Not cached on disk (``cache=False``): numba's cache only notices edits to a kernel's own file,
and this kernel calls kernels from three others. Compiling takes about 10 s once per process.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numba
import numpy as np

from uavmpc.plant.kernels import run_substeps, se3_kernel
from uavmpc.tracker.batchqp import OPTIMAL, REFRESH_AGE, BatchQpSolver, _solve_one
from uavmpc.tracker.qp import FEASIBILITY_TOL
from uavmpc.tracker.tracker import (
    HEADING_RECENTER_RAD,
    INSIDE_TOL,
    N_AXES,
    Prediction,
    TrackerCommand,
    TrackerOutput,
)

if TYPE_CHECKING:
    from uavmpc.world import World

_TWO_PI = 2.0 * math.pi
_FAST = {"reassoc", "contract", "nsz", "arcp"}


# ------------------------------------------------------------------------------ tracker parts
@numba.njit(cache=False)
def _sample_reference(knots, values, n, period, loop, times, out):
    """:meth:`uavmpc.reference.Reference.sample` of one reference (its sampling tables
    ``knots`` (n,), ``values`` (n, 4)) at increasing ``times`` (m,), into ``out`` (m, 4)."""
    m = times.shape[0]
    if n == 1:
        for k in range(m):
            for j in range(4):
                out[k, j] = values[0, j]
        return
    t0 = knots[0]
    cycle = knots[n - 1] - t0
    idx = 0
    for k in range(m):
        t = times[k]
        if loop:
            t = t0 + (0.0 if t < t0 else np.mod(t - t0, cycle))
        if period > 0.0:
            pos = min(max((t - t0) / period, 0.0), n - 1.0)
            i = min(int(pos), n - 2)
            frac = pos - i
        else:
            # searchsorted(knots, t, "right") − 1, clipped to [0, n − 2]; times only increase
            # within a horizon unless a loop wraps, so walk from the last index when we can.
            if loop or k == 0 or knots[idx] > t:
                lo, hi = 0, n
                while lo < hi:
                    mid = (lo + hi) // 2
                    if knots[mid] <= t:
                        lo = mid + 1
                    else:
                        hi = mid
                idx = lo - 1
            else:
                while idx + 1 < n and knots[idx + 1] <= t:
                    idx += 1
            i = min(max(idx, 0), n - 2)
            k0 = knots[i]
            frac = min(max((t - k0) / (knots[i + 1] - k0), 0.0), 1.0)
        for j in range(4):
            lo_v = values[i, j]
            out[k, j] = lo_v + (values[i + 1, j] - lo_v) * frac


@numba.njit(cache=False)
def _excess(s, v_lo, v_hi, a_lo, a_hi, tau):
    """:meth:`uavmpc.tracker.MpcTracker.limit_excess` of state s (4, 3)."""
    worst = 0.0
    for ax in range(4):
        v = s[ax, 1]
        a = s[ax, 2]
        w = v + tau * a
        worst = max(worst, v - v_hi[ax], v_lo[ax] - v, a - a_hi[ax], a_lo[ax] - a,
                    w - v_hi[ax], v_lo[ax] - w)
    return worst


@numba.njit(cache=False)
def _braking(rel, a_lo, a_hi, tau, t_grid, step_len, free_t, forced_t, u_out, s_out):
    """:func:`uavmpc.tracker.model.braking_plan`: inputs u_out (4, m) and states s_out
    (4, m, 3) of braking at the acceleration limits from ``rel`` (4, 3)."""
    m = step_len.shape[0]
    for ax in range(4):
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
        for c in range(3 * m):
            acc = rel[ax, 0] * free_t[0, c] + rel[ax, 1] * free_t[1, c] + rel[ax, 2] * free_t[2, c]
            for k in range(m):
                acc += u_out[ax, k] * forced_t[k, c]
            s_out[ax, c // 3, c % 3] = acc


@numba.njit(cache=False, fastmath=_FAST, inline="always")
def _axpy(a, x, y):
    """y += a x."""
    for c in range(y.shape[0]):
        y[c] += a * x[c]


@numba.njit(cache=False, fastmath=_FAST)
def _bound_excess(u, c_t, lower, upper, rows):
    """The largest violation of lower ≤ [u; u C_tᵀ] ≤ upper (−inf if none; NaN propagates as
    a violation: the caller tests ``not worst <= tol``). ``rows``: scratch of C_t's width."""
    m = u.shape[0]
    nr = c_t.shape[1]
    worst = -math.inf
    for c in range(m):
        worst = max(worst, lower[c] - u[c], u[c] - upper[c])
        if math.isnan(u[c]):
            return math.nan
    rows[:nr] = 0.0
    for k in range(m):
        _axpy(u[k], c_t[k], rows[:nr])
    for c in range(nr):
        worst = max(worst, lower[m + c] - rows[c], rows[c] - upper[m + c])
    return worst


@numba.njit(cache=False, fastmath=_FAST)
def _tracker_tick(i, trk, ref, tc, qp, qc, scratch):
    """One :meth:`uavmpc.tracker.MpcTracker.step` of UAV ``i`` (see ``_begin``/``_finish``
    there); returns (braking, fell back). Writes the new state, the inputs and ``rel``/``p0``
    of the plan (the plan itself is formed only when someone needs it)."""
    s_all, t_all, u_prev, v_lo_all, v_hi_all, a_lo_all, a_hi_all, z_off, u_out, p0_out, \
        rel_out = trk
    knots_all, values_all, r_start, r_len, r_period, r_loop = ref
    (horizon, step_len, t_grid, tau, f_state_t, f_ref_t, vref_of_ref, f_vref_t, f_uprev,
     cfree_t, neg_hinv, c_t, use_vref, free_t, forced_t) = tc
    hess, hinv, cmat, q, gram, inv_norm, iter_limit = qp
    ws_all, c_lf, c_widx, c_wside, c_nw, c_age = qc
    (times, rr, r_rel, rel, f, lower, upper, u, brake_u, brake_s, vref, rows_free,
     lam, lam_star, blo, bhi, y, col, ell, z, rows, skip) = scratch
    m = horizon.shape[0]
    nr = c_t.shape[1]
    s0 = s_all[i]
    v_lo, v_hi, a_lo, a_hi = v_lo_all[i], v_hi_all[i], a_lo_all[i], a_hi_all[i]

    if abs(s0[3, 0]) > HEADING_RECENTER_RAD:
        s0[3, 0] -= _TWO_PI * np.round(s0[3, 0] / _TWO_PI)
    t_now = t_all[i]
    for k in range(m):
        times[k] = t_now + horizon[k]
    n_ref = r_len[i]
    if n_ref == 0:  # no reference yet: hold the current position
        for k in range(m):
            for ax in range(4):
                rr[k, ax] = s0[ax, 0]
    else:
        a0 = r_start[i]
        _sample_reference(knots_all[a0:a0 + n_ref], values_all[a0:a0 + n_ref], n_ref,
                          r_period[i], r_loop[i], times, rr)
    if z_off[i] != 0.0:
        for k in range(m):
            rr[k, 2] += z_off[i]
    shift = _TWO_PI * np.round((s0[3, 0] - rr[0, 3]) / _TWO_PI)
    for k in range(m):
        rr[k, 3] += shift

    for ax in range(4):
        p0_out[i, ax] = s0[ax, 0]
        rel[ax, 0] = 0.0
        rel[ax, 1] = s0[ax, 1]
        rel[ax, 2] = s0[ax, 2]
        for k in range(m):
            r_rel[ax, k] = rr[k, ax] - s0[ax, 0]
        for k in range(m):
            lower[ax, k] = a_lo[ax]
            upper[ax, k] = a_hi[ax]
        for k in range(m, m + nr):
            lower[ax, k] = v_lo[ax]
            upper[ax, k] = v_hi[ax]

    braking = _excess(s0, v_lo, v_hi, a_lo, a_hi, tau) > INSIDE_TOL
    if braking:
        _braking(rel, a_lo, a_hi, tau, t_grid, step_len, free_t, forced_t, brake_u, brake_s)
        for ax in range(4):
            for k in range(m):
                lower[ax, k] = min(lower[ax, k], brake_u[ax, k])
                upper[ax, k] = max(upper[ax, k], brake_u[ax, k])
                lower[ax, m + k] = min(lower[ax, m + k], brake_s[ax, k, 1])
                upper[ax, m + k] = max(upper[ax, m + k], brake_s[ax, k, 1])
            w1 = brake_s[ax, 0, 1] + tau * brake_s[ax, 0, 2]
            lower[ax, 2 * m] = min(lower[ax, 2 * m], w1)
            upper[ax, 2 * m] = max(upper[ax, 2 * m], w1)

    # The QP data (:func:`uavmpc.tracker.qpdata.build_qp`) and the unconstrained optimum.
    fell_back = False
    # Row-vector products are written as sums of scaled rows (axpy over contiguous memory),
    # which LLVM vectorises; the column-wise dot products it cannot.
    for ax in range(4):
        fa = f[ax]
        r1, r2, up = rel[ax, 1], rel[ax, 2], u_prev[i, ax]
        for c in range(m):
            fa[c] = r1 * f_state_t[1, c] + r2 * f_state_t[2, c] + up * f_uprev[c]
        for k in range(m):
            _axpy(r_rel[ax, k], f_ref_t[k], fa)
        if use_vref:
            vref[:] = 0.0
            for k in range(m):
                _axpy(r_rel[ax, k], vref_of_ref[k], vref)
            for c in range(m):
                vref[c] = min(max(vref[c], v_lo[ax]), v_hi[ax])
            for k in range(m):
                _axpy(vref[k], f_vref_t[k], fa)
        for c in range(nr):
            rows_free[c] = r1 * cfree_t[1, c] + r2 * cfree_t[2, c]
            lower[ax, m + c] -= rows_free[c]
            upper[ax, m + c] -= rows_free[c]
        ua = u[ax]
        ua[:] = 0.0
        for k in range(m):
            _axpy(fa[k], neg_hinv[k], ua)
        worst = _bound_excess(ua, c_t, lower[ax], upper[ax], rows)
        if not worst <= 0.0:  # a bound is active (or NaN): solve the QP
            p = N_AXES * i + ax
            nw_cached = c_nw[p]
            if c_age[p] >= REFRESH_AGE:
                nw_cached = -1
                c_age[p] = 0
            st, _, nw = _solve_one(
                f[ax], lower[ax], upper[ax], ws_all[p], hess, hinv, cmat, q, gram, inv_norm,
                iter_limit, u[ax], ws_all[p], c_lf[p], c_widx[p], c_wside[p], nw_cached, lam,
                lam_star, blo, bhi, y, col, ell, z, rows, skip)
            c_nw[p] = nw
            c_age[p] += 1
            ok = st == OPTIMAL
            if ok:  # never trust a solver's word alone (as MpcTracker._finish)
                ok = _bound_excess(ua, c_t, lower[ax], upper[ax], rows) <= FEASIBILITY_TOL
            if not ok:
                if not fell_back and not braking:
                    _braking(rel, a_lo, a_hi, tau, t_grid, step_len, free_t, forced_t,
                             brake_u, brake_s)
                fell_back = True
                for k in range(m):
                    u[ax, k] = brake_u[ax, k]

    # Advance by one step of the same model: the first predicted state.
    for ax in range(4):
        for j in range(3):
            acc = rel[ax, 1] * free_t[1, j] + rel[ax, 2] * free_t[2, j]
            for k in range(m):
                acc += u[ax, k] * forced_t[k, j]
            s0[ax, j] = acc
        s0[ax, 0] += p0_out[i, ax]
        u_prev[i, ax] = u[ax, 0]
        for k in range(m):
            u_out[i, ax, k] = u[ax, k]
        for j in range(3):
            rel_out[i, ax, j] = rel[ax, j]
    t_all[i] = times[0]
    return braking, fell_back


@numba.njit(cache=False)
def world_tick(k, trk, ref, tc, qp, qc, ctl, plant, book, trace):
    """One 10 ms tick of every UAV: tracker → SE(3) → attitude loop + plant, then the
    bookkeeping of :class:`uavmpc.world.World` and row ``k`` of its traces. Returns −1, or the
    index of a UAV whose attitude target was not finite (the tick stops there)."""
    s_all, _, _, v_lo_all, v_hi_all, a_lo_all, a_hi_all, z_off, _, _, _ = trk
    tau = tc[3]
    m = tc[0].shape[0]
    n_rows = qp[4].shape[0]
    se3_gains, thrust_min, thrust_max, iw, ib, sat, tilt, period = ctl
    (x_all, ctrl, landed, n_sub, substep, wind, phys, inertia, inertia_inv, alloc, att_gains,
     mix_inv, lo, hi, plant_t) = plant
    err_sq, max_zoff, avoiding, avoiding_ticks, max_excess, violations, fallbacks, \
        braking_out, limit_tol = book
    pos_out, zoff_out, dmin_out, pair_d = trace
    n_uav = s_all.shape[0]
    scratch = (
        np.empty(m), np.empty((m, 4)), np.empty((4, m)), np.empty((4, 3)), np.empty((4, m)),
        np.empty((4, n_rows)), np.empty((4, n_rows)), np.empty((4, m)), np.empty((4, m)),
        np.empty((4, m, 3)), np.empty(m), np.empty(n_rows - m),
        np.zeros(m + 1), np.zeros(m + 1), np.empty(n_rows), np.empty(n_rows), np.empty(n_rows),
        np.empty(max(n_rows, m + 1)), np.empty(m + 1), np.empty(m + 1), np.empty(n_rows),
        np.zeros(n_rows, dtype=np.int8),
    )
    qd = np.empty(4)
    ff = np.empty(3)
    no_cmd = np.zeros(x_all.shape[1] - 13)
    for i in range(n_uav):
        braking, fell_back = _tracker_tick(i, trk, ref, tc, qp, qc, scratch)
        braking_out[i] = braking
        if fell_back:
            fallbacks[i] += 1
        s = s_all[i]
        x = x_all[i]
        cmd_p = s[:3, 0].copy()
        heading = (s[3, 0] + math.pi) % _TWO_PI - math.pi
        thrust, saturated, limited = se3_kernel(
            x[0:3], x[3:6], x[6:10], cmd_p, s[:3, 1].copy(), s[:3, 2].copy(), heading, s[3, 1],
            period, se3_gains, thrust_min, thrust_max, iw[i], ib[i], qd, ff)
        sat[i] = saturated
        tilt[i] = limited
        # Multirotor.step: refuse a non-finite target, normalise the quaternion.
        nq = math.sqrt(qd[0] * qd[0] + qd[1] * qd[1] + qd[2] * qd[2] + qd[3] * qd[3])
        if not (0.9 < nq < 1.1 and math.isfinite(thrust) and math.isfinite(ff[0])
                and math.isfinite(ff[1]) and math.isfinite(ff[2])):
            return i
        for j in range(4):
            qd[j] /= nq
        run_substeps(x, ctrl[i], landed[i], n_sub, substep, False, no_cmd, qd, thrust, ff,
                     wind[i], phys, inertia, inertia_inv, alloc, att_gains, mix_inv, lo, hi)
        plant_t[i] += n_sub * substep
        # World._bookkeeping
        e0 = x[0] - cmd_p[0]
        e1 = x[1] - cmd_p[1]
        e2 = x[2] - cmd_p[2]
        err_sq[i] += e0 * e0 + e1 * e1 + e2 * e2
        max_zoff[i] = max(max_zoff[i], z_off[i])
        if avoiding[i]:
            avoiding_ticks[i] += 1
        if not braking:
            ex = _excess(s, v_lo_all[i], v_hi_all[i], a_lo_all[i], a_hi_all[i], tau)
            max_excess[i] = max(max_excess[i], ex)
            if ex > limit_tol:
                violations[i] += 1
        for j in range(3):
            pos_out[k, i, j] = x[j]
        zoff_out[k, i] = z_off[i]
    best = math.inf
    p = 0
    for a in range(n_uav):
        for b in range(a + 1, n_uav):
            d0 = pos_out[k, a, 0] - pos_out[k, b, 0]
            d1 = pos_out[k, a, 1] - pos_out[k, b, 1]
            d2 = pos_out[k, a, 2] - pos_out[k, b, 2]
            d = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            pair_d[p] = d
            best = min(best, d)
            p += 1
    dmin_out[k] = best
    return -1


# ------------------------------------------------------------------------------ Python side
@dataclass
class _Packed:
    """The world's per-UAV state as arrays (the kernel's view of it)."""

    trk: tuple[np.ndarray, ...]
    ref: tuple[Any, ...]
    ctl: tuple[Any, ...]
    plant: tuple[Any, ...]
    book: tuple[Any, ...]


def compiled_supported(world: World) -> str | None:
    """Why ``world`` cannot take the compiled step (None when it can)."""
    uavs = world.uavs
    first = uavs[0]
    if world.recorder is not None:
        return "a recorder is attached (logging goes through the per-UAV objects)"
    for u in uavs:
        if u.stack.tracker.config != first.stack.tracker.config:
            return "the UAVs' tracker configurations differ"
        if u.stack.airframe is not first.stack.airframe:
            return "the UAVs fly different airframes"
        if u.plant.substep_s != first.plant.substep_s or u.plant.backend != "numba":
            return "the plants' substeps or backends differ"
        if u.stack.controller.backend != "numba":
            return "a controller uses the numpy backend"
        if u.stack.tracker._previous_reference is not None:
            return "a reference switch is pending"
    return None


class CompiledStep:
    """Packs a :class:`~uavmpc.world.World`'s UAVs into arrays, ticks them with
    :func:`world_tick`, and writes the state back into the per-UAV objects (:meth:`unpack`)
    so that the plain path, logging and summaries see the same world afterwards."""

    def __init__(self, world: World, limit_tol: float) -> None:
        self.world = world
        #: A state outside its limits by more than this (when not braking) is a violation.
        self.limit_tol = float(limit_tol)
        first = world.uavs[0]
        tracker = first.stack.tracker
        cfg = tracker.config
        model = tracker.model
        d = tracker._qp_data
        self.m = cfg.steps
        self.tc = (
            np.ascontiguousarray(cfg.horizon_times_s), np.ascontiguousarray(cfg.step_lengths_s),
            np.concatenate([[0.0], cfg.horizon_times_s]), float(cfg.tau_s),
            d.f_state_t, d.f_ref_t, d.vref_of_ref, d.f_vref_t, d.f_uprev, d.cfree_t, d.neg_hinv,
            d.c_t, bool(d.use_vref), np.ascontiguousarray(model.free.T),
            np.ascontiguousarray(model.forced.T),
        )
        solver = BatchQpSolver(model, cfg.iter_limit)
        self.qp = (solver._hess, solver._hinv, solver._cmat, solver._q, solver._gram,
                   solver._inv_norm, solver.iter_limit)
        n = len(world.uavs)
        k = N_AXES * n
        m1 = self.m + 1
        self.qc = (np.zeros((k, solver.n_rows), dtype=np.int8), np.zeros((k, m1, m1)),
                   np.zeros((k, m1), dtype=np.int64), np.zeros((k, m1), dtype=np.int64),
                   np.full(k, -1, dtype=np.int64), np.zeros(k, dtype=np.int64))
        self.u_plan = np.zeros((n, N_AXES, self.m))
        self.p0 = np.zeros((n, N_AXES))
        self.rel = np.zeros((n, N_AXES, 3))
        self.has_plan = np.zeros(n, dtype=bool)
        plant = first.plant
        self._plant_consts = (plant._phys, plant._inertia, plant._inertia_inv, plant._alloc,
                              plant._gains, plant._mix_inv, plant._lo, plant._hi)
        self.n_sub = plant._substeps(first.stack.period_s)
        self.packed: _Packed | None = None

    # -- packing ---------------------------------------------------------------------------
    def pack(self) -> None:
        """Copy the objects' state into fresh arrays (call before ticking)."""
        uavs = self.world.uavs
        n = len(uavs)
        trackers = [u.stack.tracker for u in uavs]
        trk = (
            np.array([t._state for t in trackers]), np.array([t._t for t in trackers]),
            np.array([t._u_prev for t in trackers]),
            np.zeros((n, N_AXES)), np.zeros((n, N_AXES)), np.zeros((n, N_AXES)),
            np.zeros((n, N_AXES)), np.zeros(n), self.u_plan, self.p0, self.rel,
        )
        self.trk = trk
        for i in range(n):
            self.refresh_limits(i)
        self.ref = self._pack_references(trackers)
        ctls = [u.stack.controller for u in uavs]
        c0 = ctls[0]
        self.ctl = (c0._packed, c0.thrust_min_n, c0.thrust_max_n,
                    np.array([c.integral_world_ms for c in ctls]),
                    np.array([c.integral_body_ms for c in ctls]),
                    np.array([c.saturated for c in ctls]), np.array([c.tilt_limited for c in ctls]),
                    float(uavs[0].stack.period_s))
        plants = [u.plant for u in uavs]
        self.wind = np.zeros((n, 3))
        self.plant = (np.array([p._x for p in plants]), np.array([p._ctrl for p in plants]),
                      np.array([p._landed for p in plants]), self.n_sub, plants[0].substep_s,
                      self.wind, *self._plant_consts, np.array([p.t_s for p in plants]))
        self.book = (
            np.array([u.err_sq_sum for u in uavs]), np.array([u.max_z_offset_m for u in uavs]),
            np.zeros(n, dtype=np.bool_), np.array([u.avoiding_ticks for u in uavs]),
            np.array([u.max_limit_excess for u in uavs]),
            np.array([u.limit_violations for u in uavs]),
            np.array([t.fallback_count for t in trackers]), np.zeros(n, dtype=np.bool_),
            self.limit_tol,
        )
        for i, u in enumerate(uavs):
            self.refresh_avoiding(i)
            self.has_plan[i] = u.stack.last_output is not None

    def _pack_references(self, trackers: list[Any]) -> tuple[Any, ...]:
        n = len(trackers)
        knots, values = [], []
        start = np.zeros(n, dtype=np.int64)
        length = np.zeros(n, dtype=np.int64)
        period = np.zeros(n)
        loop = np.zeros(n, dtype=np.bool_)
        offset = 0
        for i, t in enumerate(trackers):
            r = t.reference
            if r is None:
                continue
            kn, va = r._knots, r._values
            knots.append(kn)
            values.append(va)
            start[i], length[i] = offset, kn.shape[0]
            period[i], loop[i] = r._uniform_period, r.loop
            offset += kn.shape[0]
        all_knots = np.concatenate(knots) if knots else np.zeros(1)
        all_values = np.ascontiguousarray(np.vstack(values)) if values else np.zeros((1, 4))
        return (all_knots, all_values, start, length, period, loop)

    def refresh_limits(self, i: int) -> None:
        """Re-read UAV i's limits and z offset (after its avoidance changed them)."""
        t = self.world.uavs[i].stack.tracker
        trk = self.trk
        trk[3][i], trk[4][i], trk[5][i], trk[6][i] = t._v_lo, t._v_hi, t._a_lo, t._a_hi
        trk[7][i] = t.z_offset_m

    def refresh_avoiding(self, i: int) -> None:
        decision = self.world.uavs[i].stack.decision
        self.book[2][i] = bool(decision is not None and decision.avoiding)

    # -- ticking ---------------------------------------------------------------------------
    def tick(self, k: int, pos: np.ndarray, zoff: np.ndarray, dmin: np.ndarray,
             pair_d: np.ndarray) -> None:
        bad = world_tick(k, self.trk, self.ref, self.tc, self.qp, self.qc, self.ctl, self.plant,
                         self.book, (pos, zoff, dmin, pair_d))
        self.has_plan[:] = True
        if bad >= 0:
            raise ValueError(f"invalid attitude target for {self.world.uavs[bad].uav_id} "
                             "(not finite): the controller got a degenerate state")

    def time_s(self, i: int) -> float:
        return float(self.trk[1][i])

    def prediction(self, i: int) -> Prediction:
        """UAV i's plan of its last tick, as :class:`~uavmpc.tracker.Prediction`."""
        m = self.m
        tc = self.tc
        trk_t = self.trk[1][i]
        times = (trk_t - tc[0][0]) + tc[0]
        plan = (self.rel[i] @ tc[13] + self.u_plan[i] @ tc[14]).reshape(N_AXES, m, 3)
        plan[:, :, 0] += self.p0[i][:, None]
        xyz = plan[:3]
        return Prediction(times_s=times, position_m=xyz[:, :, 0].T.copy(),
                          velocity_mps=xyz[:, :, 1].T.copy(),
                          acceleration_mps2=xyz[:, :, 2].T.copy(),
                          heading_rad=plan[3, :, 0].copy(), heading_rate_radps=plan[3, :, 1].copy())

    def output(self, i: int) -> TrackerOutput:
        """UAV i's last tick as the :class:`~uavmpc.tracker.TrackerOutput` the objects keep."""
        s = self.trk[0][i]
        pred = self.prediction(i)
        command = TrackerCommand(
            t_s=float(self.trk[1][i]), position_m=s[:3, 0].copy(), velocity_mps=s[:3, 1].copy(),
            acceleration_mps2=s[:3, 2].copy(),
            heading_rad=float((s[3, 0] + np.pi) % (2.0 * np.pi) - np.pi),
            heading_rate_radps=float(s[3, 1]), heading_accel_radps2=float(s[3, 2]))
        return TrackerOutput(command, pred, (), bool(self.book[7][i]), 0, 0)

    # -- unpacking -------------------------------------------------------------------------
    def unpack(self) -> None:
        """Write the arrays back into the per-UAV objects."""
        trk, ctl, plant, book = self.trk, self.ctl, self.plant, self.book
        for i, u in enumerate(self.world.uavs):
            t = u.stack.tracker
            t._state = trk[0][i].copy()
            t._t = float(trk[1][i])
            t._u_prev = trk[2][i].copy()
            t.fallback_count = int(book[6][i])
            c = u.stack.controller
            c.integral_world_ms[:] = ctl[3][i]
            c.integral_body_ms[:] = ctl[4][i]
            c.saturated, c.tilt_limited = bool(ctl[5][i]), bool(ctl[6][i])
            p = u.plant
            p._x[:] = plant[0][i]
            p._ctrl[:] = plant[1][i]
            p._landed[:] = plant[2][i]
            p.t_s = float(plant[-1][i])
            u.err_sq_sum = float(book[0][i])
            u.max_z_offset_m = float(book[1][i])
            u.avoiding_ticks = int(book[3][i])
            u.max_limit_excess = float(book[4][i])
            u.limit_violations = int(book[5][i])
            if self.has_plan[i]:
                u.stack._last = self.output(i)
