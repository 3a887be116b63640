"""A batched dual active-set QP solver for many tracker axes in one compiled call.

Every axis of every UAV solves the same kind of QP (:mod:`uavmpc.solvers.contract`)::

    min ½ Uᵀ H U + fᵀ U   s.t.  lower ≤ G U ≤ upper,   G = [I; C]   (n = m + rows of C)

with H and G shared; only ``f`` and the bounds differ. With ``H = RᵀR`` and
``v = R U + R⁻ᵀ f`` the problem is the least-distance problem (LDP, as in DAQP)::

    min ½ ‖v‖²   s.t.  lower − G U_free ≤ M v ≤ upper − G U_free,   M = G R⁻¹,  U_free = −H⁻¹ f

whose dual only involves the Gram matrix ``M Mᵀ = G H⁻¹ Gᵀ`` (n, n), computed once. For a
working set W (rows held at one of their two bounds, ``b_W``) the multipliers are
``λ = −(M_W M_Wᵀ)⁻¹ b_W`` and the primal solution is ``U = U_free − (G H⁻¹)_Wᵀ λ``, so an
iteration costs O(|W|²) with a Cholesky factor of ``M_W M_Wᵀ`` that is updated, never rebuilt,
when a row enters or leaves. Sign convention: an upper bound has ``λ ≥ 0``, a lower one ``λ ≤ 0``.

The iteration is DAQP's (Arnström, Bemporad, Axehill 2022): from a dual-feasible λ, compute the
equality-constrained multipliers λ* of W; if some have the wrong sign, step from λ towards λ*
until the first one reaches zero and drop that row; otherwise λ = λ* is optimal for W, and the
most violated row (the side it violates) is added. A row that depends linearly on W (e.g. the
first input, first velocity and ``w_1`` rows are parallel) is added Goldfarb–Idnani style: its
multiplier grows while the others keep the primal point fixed until one of them reaches zero
and leaves; if none ever does, the bounds are infeasible.

Warm start: the previous working set is factorised row by row; rows that are dependent on the
ones already taken (or whose bound is not finite) are dropped, and λ starts at 0, which is
always dual feasible, so a stale warm set only costs iterations, never correctness.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from uavmpc.jit import FASTMATH, kernel
from uavmpc.solvers.contract import QpMatrices, QpResult

#: Status codes (the same numbers as DAQP's exit flags where the meaning is the same).
OPTIMAL = 1
INFEASIBLE = -1
ITERATION_LIMIT = -4
#: Non-finite data, or a final solution that fails the bound check (round-off gone wrong).
NUMERICAL = -7

STATUS_NAMES = {OPTIMAL: "optimal", INFEASIBLE: "infeasible",
                ITERATION_LIMIT: "iteration limit", NUMERICAL: "numerical failure"}

#: Largest bound violation (in the units of the bounds) left by the active-set iteration.
PRIMAL_TOL = 1e-10
#: A multiplier with the wrong sign by less than this counts as zero (round-off on a weakly
#: active row); avoids dropping and re-adding the same row forever.
DUAL_TOL = 1e-12
#: A row is linearly dependent on W when its squared distance to span(M_W) is below this
#: fraction of its squared norm.
PIVOT_TOL = 1e-11
#: A violated row that cannot enter W (it depends on W and no row can leave) means the bounds
#: are infeasible, unless it is violated by less than this (round-off at a degenerate vertex).
NEAR_TOL = 1e-9
#: Internal status: a row was left out as violated by round-off only.
SKIPPED = 2
#: The solution is re-checked against the bounds; beyond this it is reported NUMERICAL.
CHECK_TOL = 1e-8
#: A problem's cached factor is rebuilt from scratch after this many solves.
REFRESH_AGE = 50
#: Relative relaxations of the bounds for the retries of a failed solve (see solve_warm):
#: 1e-10, then 1e-9 (≤ 2e-7 absolute on the tracker's bounds of ≤ 100 m/s or m/s²).
RELAX = 1e-10
RELAX_MAX = 1e-9
#: An attempt taking more than this many iterations per constraint row is cycling (a normal
#: cold solve of the tracker's QPs takes about one per input, 40–100 in all).
CYCLE_ROWS = 4



# --------------------------------------------------------------------------- the kernel
@kernel(fastmath=FASTMATH)
def _forward(lf: np.ndarray, n: int, rhs: np.ndarray, out: np.ndarray) -> None:
    """Solve L out = rhs for the leading n×n lower-triangular block of lf."""
    for i in range(n):
        s = rhs[i]
        for k in range(i):
            s -= lf[i, k] * out[k]
        out[i] = s / lf[i, i]


@kernel(fastmath=FASTMATH)
def _backward(lf: np.ndarray, n: int, rhs: np.ndarray, out: np.ndarray) -> None:
    """Solve Lᵀ out = rhs for the leading n×n lower-triangular block of lf."""
    # Column by column of Lᵀ, i.e. along the rows of L: contiguous memory, vectorised (the
    # dot-product form would walk down the columns of L).
    for k in range(n):
        out[k] = rhs[k]
    for i in range(n - 1, -1, -1):
        x = out[i] / lf[i, i]
        out[i] = x
        row = lf[i]
        for k in range(i):
            out[k] -= row[k] * x


@kernel(fastmath=FASTMATH)
def _try_append(lf: np.ndarray, n: int, gram: np.ndarray, widx: np.ndarray, j: int,
                col: np.ndarray, ell: np.ndarray) -> bool:
    """Append row j to the factor of Gram[W, W] (size n) if it is independent of W.

    On return ``ell`` holds L⁻¹ Gram[W, j] either way (the caller needs it when j is dependent).
    """
    for i in range(n):
        col[i] = gram[widx[i], j]
    _forward(lf, n, col, ell)
    d2 = gram[j, j]
    for i in range(n):
        d2 -= ell[i] * ell[i]
    if not d2 > PIVOT_TOL * gram[j, j]:
        return False
    for i in range(n):
        lf[n, i] = ell[i]
    lf[n, n] = math.sqrt(d2)
    return True


@kernel(fastmath=FASTMATH)
def _remove(lf: np.ndarray, n: int, k: int, widx: np.ndarray, wside: np.ndarray,
            lam: np.ndarray, x: np.ndarray) -> None:
    """Remove position k (of n) from W: a rank-1 Cholesky update of the trailing block."""
    # Deleting row/column k of A = L Lᵀ leaves L₂₂ L₂₂ᵀ + l lᵀ for the trailing block,
    # l = L[k+1:, k]: re-triangularise it with the classic rank-1 update (stable, O(n²)).
    for i in range(k + 1, n):
        x[i] = lf[i, k]
    for c in range(k + 1, n):
        diag = lf[c, c]
        r = math.hypot(diag, x[c])
        cs = r / diag
        sn = x[c] / diag
        lf[c, c] = r
        for i in range(c + 1, n):
            lf[i, c] = (lf[i, c] + sn * x[i]) / cs
            x[i] = cs * x[i] - sn * lf[i, c]
    for i in range(k + 1, n):
        for j in range(k):
            lf[i - 1, j] = lf[i, j]
        for j in range(k + 1, i + 1):
            lf[i - 1, j - 1] = lf[i, j]
        widx[i - 1] = widx[i]
        wside[i - 1] = wside[i]
        lam[i - 1] = lam[i]


@kernel(fastmath=FASTMATH)
def _refine(
    f: np.ndarray, lower: np.ndarray, upper: np.ndarray, hess: np.ndarray, hinv: np.ndarray,
    cmat: np.ndarray, q: np.ndarray, gram: np.ndarray, lf: np.ndarray, widx: np.ndarray,
    wside: np.ndarray, nw: int, u: np.ndarray, lam: np.ndarray,
    r: np.ndarray, delta: np.ndarray, e: np.ndarray, t: np.ndarray, mu: np.ndarray,
) -> None:
    """One step of iterative refinement of the KKT system of W, in place on u and λ.

    With a large ``f`` (far references), ``U_free = −H⁻¹ f`` carries an error of about
    eps·κ(H)·|U_free| (≈ 1e-8) that the active set cannot remove in the free directions. The
    KKT residual, computed directly from H and f, and one solve with the same factor remove it.
    """
    m = u.shape[0]
    # Stationarity residual r = H U + f + G_Wᵀ λ and the equality residual e = b_W − G_W U.
    for i in range(m):
        acc = f[i]
        for k in range(m):
            acc += hess[i, k] * u[k]
        r[i] = acc
    for k in range(nw):
        j = widx[k]
        if j < m:
            r[j] += lam[k]
            gu = u[j]
        else:
            gu = 0.0
            for i in range(m):
                r[i] += cmat[j - m, i] * lam[k]
                gu += cmat[j - m, i] * u[i]
        e[k] = (upper[j] if wside[k] > 0 else lower[j]) - gu
    # δ = δ_free − (G H⁻¹)_Wᵀ μ with δ_free = −H⁻¹ r and Gram_W μ = G_W δ_free − e.
    for i in range(m):
        acc = 0.0
        for k in range(m):
            acc -= hinv[i, k] * r[k]
        delta[i] = acc
    for k in range(nw):
        j = widx[k]
        acc = 0.0
        if j < m:
            acc = delta[j]
        else:
            for i in range(m):
                acc += cmat[j - m, i] * delta[i]
        e[k] = acc - e[k]
    _forward(lf, nw, e, t)
    _backward(lf, nw, t, mu)
    for k in range(nw):
        j = widx[k]
        for i in range(m):
            delta[i] -= q[j, i] * mu[k]
        lam[k] += mu[k]
    for i in range(m):
        u[i] += delta[i]


@kernel(fastmath=FASTMATH)
def unconstrained(f: np.ndarray, hinv: np.ndarray, cmat: np.ndarray, u: np.ndarray,
                  rows: np.ndarray) -> None:
    """The unconstrained optimum U_free = −H⁻¹ f into ``u`` (m,) and its rows G U_free =
    [U_free; C U_free] into ``rows`` (n,): what :func:`solve_one` starts from."""
    m = f.shape[0]
    for i in range(m):
        s = 0.0
        for k in range(m):
            s -= hinv[i, k] * f[k]
        u[i] = s
    for i in range(m):
        rows[i] = u[i]
    for r in range(rows.shape[0] - m):
        s = 0.0
        for k in range(m):
            s += cmat[r, k] * u[k]
        rows[m + r] = s


@kernel(fastmath=FASTMATH)
def solve_one(
    f: np.ndarray, lower: np.ndarray, upper: np.ndarray, warm: np.ndarray,
    hess: np.ndarray, hinv: np.ndarray, cmat: np.ndarray, q: np.ndarray, gram: np.ndarray,
    inv_norm: np.ndarray, iter_limit: int, u: np.ndarray, ws: np.ndarray,
    lf: np.ndarray, widx: np.ndarray, wside: np.ndarray, nw_cached: int,
    lam: np.ndarray, lam_star: np.ndarray, blo: np.ndarray, bhi: np.ndarray, y: np.ndarray,
    col: np.ndarray, ell: np.ndarray, z: np.ndarray, rows: np.ndarray, skip: np.ndarray,
) -> tuple[int, int, int]:
    """One QP; writes u (m,) and ws (n,); returns (status, iterations, |W|). See module doc.

    On entry ``u`` holds the unconstrained optimum U_free = −H⁻¹ f and ``rows`` (n,) its rows
    G U_free (:func:`unconstrained`; a caller that has them already, as the tracker does,
    passes its own). ``lf`` (m+1, m+1), ``widx``/``wside`` (m+1,) are this problem's own
    factor of Gram[W, W] and its ordered working set, kept from the previous call;
    ``nw_cached`` is their size then (−1: unknown). They are reused when ``warm`` is exactly
    that set, else rebuilt.
    """
    m = f.shape[0]
    n = lower.shape[0]
    # Non-finite data (NaN in a bound, anything in f) before crossed bounds. Flags or-ed
    # without branches: every problem passes here, and these loops vectorise.
    non_finite = False
    for i in range(m):
        non_finite |= not math.isfinite(f[i])
    crossed = False
    for i in range(n):
        non_finite |= math.isnan(lower[i]) | math.isnan(upper[i])
        crossed |= lower[i] > upper[i]
    bad = NUMERICAL if non_finite else (INFEASIBLE if crossed else 0)
    if bad != 0:
        for i in range(n):
            ws[i] = 0
        for i in range(m):
            u[i] = 0.0
        return bad, 0, 0

    # The iteration works with these shifted bounds, whose round-off grows with the shift (a
    # far reference: |G U_free| ≈ 1e4): a row's "violation" below NEAR_TOL at that scale is
    # round-off, not infeasibility.
    scale = 1.0
    for i in range(n):
        blo[i] = lower[i] - rows[i]
        bhi[i] = upper[i] - rows[i]
        scale = max(scale, abs(rows[i]))
    near_tol = NEAR_TOL * scale

    # Warm start. The factor depends on W only (not on f or the bounds), so when the warm set is
    # the one factorised last time it is reused as is: no refactorisation on a quiet tick.
    reuse = 0 <= nw_cached <= m
    if reuse:
        count = 0
        for j in range(n):
            if warm[j] != 0:
                count += 1
        reuse = count == nw_cached
        for i in range(nw_cached if reuse else 0):
            j = widx[i]
            bound = bhi[j] if wside[i] > 0 else blo[j]
            if warm[j] != wside[i] or not math.isfinite(bound):
                reuse = False
    nw = nw_cached if reuse else 0
    for i in range(nw):
        lam[i] = 0.0
    # Otherwise take the previous rows one by one, dropping any that no longer fit.
    for j in range(0 if reuse else n):
        side = warm[j]
        if side == 0 or nw >= m:
            continue
        bound = bhi[j] if side > 0 else blo[j]
        if not math.isfinite(bound):
            continue
        if _try_append(lf, nw, gram, widx, j, col, ell):
            widx[nw] = j
            wside[nw] = 1 if side > 0 else -1
            lam[nw] = 0.0
            nw += 1
    # Only now: ws may be the same array as warm (the drop-in adapter updates in place).
    for i in range(n):
        ws[i] = 0
        skip[i] = 0

    iterations = 0
    status = 0
    while True:
        # λ* of the current working set: Gram_W λ* = −b_W.
        for i in range(nw):
            j = widx[i]
            col[i] = -(bhi[j] if wside[i] > 0 else blo[j])
        _forward(lf, nw, col, ell)
        _backward(lf, nw, ell, lam_star)
        # Blocking row on the way from λ to λ*: the first wrong-signed multiplier to reach 0.
        block = -1
        t_min = 2.0
        for i in range(nw):
            if wside[i] * lam_star[i] < -DUAL_TOL:
                gap = lam[i] - lam_star[i]
                t = max(lam[i] / gap, 0.0) if wside[i] * gap > 0.0 else 0.0
                if t < t_min:
                    t_min, block = t, i
        if block >= 0:
            if iterations >= iter_limit:
                status = ITERATION_LIMIT
                break
            for i in range(nw):
                lam[i] += t_min * (lam_star[i] - lam[i])
            _remove(lf, nw, block, widx, wside, lam, z)
            nw -= 1
            iterations += 1
            continue
        for i in range(nw):
            lam[i] = lam_star[i]

        # Primal point of W: rows of G(U − U_free) = −Gram[:, W] λ; find the worst violation.
        for i in range(n):
            y[i] = 0.0
        for k in range(nw):
            lk = lam[k]
            jk = widx[k]
            for i in range(n):
                y[i] -= gram[jk, i] * lk  # gram is symmetric: read it row-wise
        for k in range(nw):
            y[widx[k]] = np.nan  # rows in W are satisfied by construction; skip them
        for i in range(n):
            if skip[i]:
                y[i] = np.nan
        # Rows violated beyond the tolerance compete by their distance in the LDP space
        # (violation / ‖M_i‖), as DAQP's normalised rows do: far fewer iterations than by the
        # raw violation, which favours the rows with large norms.
        worst = 0.0
        add = -1
        add_side = 0
        add_violation = 0.0
        for i in range(n):
            yi = y[i]
            if math.isnan(yi):
                continue
            if blo[i] - yi > PRIMAL_TOL:
                dist = (blo[i] - yi) * inv_norm[i]
                if dist > worst:
                    worst, add, add_side, add_violation = dist, i, -1, blo[i] - yi
            elif yi - bhi[i] > PRIMAL_TOL:
                dist = (yi - bhi[i]) * inv_norm[i]
                if dist > worst:
                    worst, add, add_side, add_violation = dist, i, 1, yi - bhi[i]
        if add < 0:
            status = OPTIMAL
            break
        if iterations >= iter_limit:
            status = ITERATION_LIMIT
            break
        iterations += 1

        # Add the violated row; if it depends on W, first free a row Goldfarb–Idnani style.
        lam_add = 0.0
        while not _try_append(lf, nw, gram, widx, add, col, ell):
            # Gram[W, add] = Gram_W z: the row is M_Wᵀ z, so raising its multiplier by
            # add_side·t while λ_W falls by add_side·t·z keeps the primal point fixed.
            _backward(lf, nw, ell, z)
            block = -1
            t_min = np.inf
            for i in range(nw):
                rate = wside[i] * add_side * z[i]
                if rate > 0.0:
                    t = max(wside[i] * lam[i] / rate, 0.0)
                    if t < t_min:
                        t_min, block = t, i
            if block < 0:
                if add_violation <= near_tol:
                    # A degenerate vertex (e.g. the braking plan, on every bound at once) can
                    # look infeasible by round-off: leave this row out instead. The final
                    # check still bounds its violation.
                    skip[add] = 1
                    status = SKIPPED
                else:
                    status = INFEASIBLE
                break
            for i in range(nw):
                lam[i] -= add_side * t_min * z[i]
            lam_add += add_side * t_min
            _remove(lf, nw, block, widx, wside, lam, col)
            nw -= 1
            if iterations >= iter_limit:
                status = ITERATION_LIMIT
                break
            iterations += 1
        if status == SKIPPED:
            status = 0
            continue
        if status != 0:
            break
        widx[nw] = add
        wside[nw] = add_side
        lam[nw] = lam_add
        nw += 1

    if status != OPTIMAL:
        # A failed working set is not a good warm start: report the unconstrained optimum
        # (finite) and an empty set.
        return status, iterations, 0

    # U = U_free − (G H⁻¹)_Wᵀ λ.
    for k in range(nw):
        lk = lam[k]
        jk = widx[k]
        for i in range(m):
            u[i] -= q[jk, i] * lk
        ws[jk] = wside[k]
    _refine(f, lower, upper, hess, hinv, cmat, q, gram, lf, widx, wside, nw, u, lam,
            rows, y, col, ell, z)
    # Never trust the iteration alone: check the actual rows G U against the bounds.
    worst = 0.0
    for i in range(n):
        if i < m:
            s = u[i]
        else:
            s = 0.0
            for k in range(m):
                s += cmat[i - m, k] * u[k]
        worst = max(worst, lower[i] - s, s - upper[i])
        if not math.isfinite(s):
            worst = np.inf
    if not worst <= CHECK_TOL:
        for i in range(n):
            ws[i] = 0
        return NUMERICAL, iterations, 0
    return OPTIMAL, iterations, nw


@kernel(fastmath=FASTMATH, allocates=True)
def _solve_relaxed(
    relax: float, f: np.ndarray, lower: np.ndarray, upper: np.ndarray, hess: np.ndarray,
    hinv: np.ndarray, cmat: np.ndarray, q: np.ndarray, gram: np.ndarray, inv_norm: np.ndarray,
    budget: int, u: np.ndarray, ws: np.ndarray, lf: np.ndarray, widx: np.ndarray,
    wside: np.ndarray, lam: np.ndarray, lam_star: np.ndarray, blo: np.ndarray, bhi: np.ndarray,
    y: np.ndarray, col: np.ndarray, ell: np.ndarray, z: np.ndarray, rows: np.ndarray,
    skip: np.ndarray,
) -> tuple[int, int, int]:
    """:func:`solve_warm`'s retry from an empty working set with every bound relaxed by
    ``relax`` (0: as they are); returns :func:`solve_one`'s (status, iterations, |W|). A kernel
    of its own so that :func:`solve_warm` allocates nothing (retries are rare)."""
    n = lower.shape[0]
    lo = np.empty(n)
    hi = np.empty(n)
    for j in range(n):
        # Row-dependent amounts: a uniform shift keeps parallel rows coincident.
        r = relax * (1.0 + j / n)
        lo[j] = lower[j] - r * max(1.0, abs(lower[j]))
        hi[j] = upper[j] + r * max(1.0, abs(upper[j]))
    ws[:] = 0
    unconstrained(f, hinv, cmat, u, rows)
    return solve_one(f, lo, hi, ws, hess, hinv, cmat, q, gram, inv_norm, budget, u, ws, lf, widx,
                     wside, -1, lam, lam_star, blo, bhi, y, col, ell, z, rows, skip)


@kernel(fastmath=FASTMATH)
def solve_warm(
    f: np.ndarray, lower: np.ndarray, upper: np.ndarray, warm: np.ndarray,
    hess: np.ndarray, hinv: np.ndarray, cmat: np.ndarray, q: np.ndarray, gram: np.ndarray,
    inv_norm: np.ndarray, iter_limit: int, u: np.ndarray, ws: np.ndarray,
    lf: np.ndarray, widx: np.ndarray, wside: np.ndarray, c_nw: np.ndarray, c_age: np.ndarray,
    p: int, lam: np.ndarray, lam_star: np.ndarray, blo: np.ndarray, bhi: np.ndarray,
    y: np.ndarray, col: np.ndarray, ell: np.ndarray, z: np.ndarray, rows: np.ndarray,
    skip: np.ndarray,
) -> tuple[int, int]:
    """:func:`solve_one` for problem slot ``p`` with its factor cache (``c_nw[p]``,
    ``c_age[p]``, ``lf``, ``widx``, ``wside``), and retries; returns (status, iterations).
    ``u`` and ``rows`` hold the unconstrained start on entry, as for :func:`solve_one`.

    At a degenerate vertex (the braking plan sits on dozens of bounds at once: 46 active rows
    for 40 inputs) the iteration can end on a row that no multiplier makes room for, which
    reads as infeasible although the problem is not, or cycle from a warm set until the
    iteration limit (both found by the tracker's property test; DAQP solved the same
    problems). So a failed solve is solved again from an empty working set, then with every
    bound relaxed by :data:`RELAX` (relative, by a slightly different amount per row), then
    by :data:`RELAX_MAX`: that splits the degenerate vertex (the perturbation remedy against
    cycling), and the solution violates the original bounds by no more than the relaxation,
    which the caller checks against its own tolerance (the tracker's is 1e-6). Each attempt
    stops after ``iter_limit`` iterations or :data:`CYCLE_ROWS` per row, whichever is fewer;
    the iterations returned are those of all attempts.
    """
    nw_cached = c_nw[p]
    if c_age[p] >= REFRESH_AGE:
        # Rank-1 updates accumulate round-off: refactorise from the Gram matrix now and then.
        nw_cached = -1
        c_age[p] = 0
    warm_start = nw_cached >= 0
    for j in range(0 if warm_start else warm.shape[0]):
        if warm[j] != 0:
            warm_start = True
            break
    # An attempt cycling at a degenerate vertex stops early, leaving room for the retries.
    budget = min(iter_limit, CYCLE_ROWS * lower.shape[0])
    st, it, nw = solve_one(f, lower, upper, warm, hess, hinv, cmat, q, gram, inv_norm, budget,
                           u, ws, lf, widx, wside, nw_cached, lam, lam_star, blo, bhi, y, col,
                           ell, z, rows, skip)
    # Without a success, the verdict is the cold attempt's (a relaxed attempt may cycle on a
    # problem that is infeasible indeed).
    verdict = st
    for relax in (0.0, RELAX, RELAX_MAX):
        if st == OPTIMAL:
            break
        if st == ITERATION_LIMIT and budget == iter_limit and (relax > 0.0 or not warm_start):
            break  # a cold attempt used the caller's whole budget
        if relax == 0.0 and not warm_start:  # the first attempt was the cold one
            continue
        st, it2, nw = _solve_relaxed(relax, f, lower, upper, hess, hinv, cmat, q, gram,
                                     inv_norm, budget, u, ws, lf, widx, wside, lam, lam_star,
                                     blo, bhi, y, col, ell, z, rows, skip)
        it += it2
        c_age[p] = 0
        if relax == 0.0:
            verdict = st
    if st != OPTIMAL:
        st = verdict
    c_nw[p] = nw
    c_age[p] += 1
    return st, it


@kernel(fastmath=FASTMATH, allocates=True)
def solve_batch(
    f: np.ndarray, lower: np.ndarray, upper: np.ndarray, warm: np.ndarray,
    hess: np.ndarray, hinv: np.ndarray, cmat: np.ndarray, q: np.ndarray, gram: np.ndarray,
    inv_norm: np.ndarray, iter_limit: int,
    u: np.ndarray, status: np.ndarray, iterations: np.ndarray, ws: np.ndarray,
    c_lf: np.ndarray, c_widx: np.ndarray, c_wside: np.ndarray, c_nw: np.ndarray,
    c_age: np.ndarray,
) -> None:
    """Solve K QPs sharing H and G, in place.

    Args:
        f: (K, m) linear terms; lower, upper: (K, n) bounds on G U; warm: (K, n) int8 working
            sets (−1 lower active, +1 upper active, 0 inactive).
        hess: (m, m) H; hinv: (m, m) H⁻¹; cmat: (n − m, m) C; q: (n, m) G H⁻¹;
            gram: (n, n) G H⁻¹ Gᵀ;
            inv_norm: (n,) 1 / √diag(gram), the inverse norms of the LDP rows.
        iter_limit: active-set changes allowed per problem.
        u: (K, m), status: (K,), iterations: (K,), ws: (K, n) int8 outputs (ws may be warm).
        c_lf: (K, m+1, m+1), c_widx, c_wside: (K, m+1) int64, c_nw, c_age: (K,) int64: each
            problem's factor cache (see :func:`solve_one`), updated in place; c_nw = −1
            marks an empty cache.
    """
    n_prob, m = f.shape
    n = lower.shape[1]
    # Scratch shared by all problems (one allocation per call, not per problem).
    lam = np.zeros(m + 1)
    lam_star = np.zeros(m + 1)
    blo = np.empty(n)
    bhi = np.empty(n)
    y = np.empty(n)
    col = np.empty(max(n, m + 1))
    ell = np.empty(m + 1)
    z = np.empty(m + 1)
    rows = np.empty(n)
    skip = np.zeros(n, dtype=np.int8)
    for p in range(n_prob):
        unconstrained(f[p], hinv, cmat, u[p], rows)
        st, it = solve_warm(f[p], lower[p], upper[p], warm[p], hess, hinv, cmat, q, gram,
                            inv_norm, iter_limit, u[p], ws[p], c_lf[p], c_widx[p], c_wside[p],
                            c_nw, c_age, p, lam, lam_star, blo, bhi, y, col, ell, z, rows, skip)
        status[p] = st
        iterations[p] = it


# --------------------------------------------------------------------------- Python API
class LdpData(NamedTuple):
    """The constant data of the solver for one (H, C), in the least-distance form (module doc).

    Attributes:
        hess: (m, m) H.
        hinv: (m, m) H⁻¹.
        cmat: (r, m) C (n = m + r rows in G = [I; C]).
        q: (n, m) G H⁻¹.
        gram: (n, n) G H⁻¹ Gᵀ.
        inv_norm: (n,) 1 / √diag(gram), the inverse norms of the LDP rows.
    """

    hess: np.ndarray
    hinv: np.ndarray
    cmat: np.ndarray
    q: np.ndarray
    gram: np.ndarray
    inv_norm: np.ndarray

    @classmethod
    def build(cls, hessian: np.ndarray, constraint_matrix: np.ndarray) -> LdpData:
        h = np.ascontiguousarray(hessian, dtype=float)
        c = np.ascontiguousarray(constraint_matrix, dtype=float)
        m = h.shape[0]
        g = np.vstack([np.eye(m), c])
        # H = RᵀR; the Gram matrix is formed from M = G R⁻¹ (κ(R) = √κ(H)) rather than from
        # H⁻¹ directly, which halves the digits lost to the conditioning of H.
        r_upper = np.linalg.cholesky(h).T
        r_inv = np.triu(np.linalg.solve(r_upper, np.eye(m)))
        mm = g @ r_inv
        gram = mm @ mm.T
        gram = np.ascontiguousarray(0.5 * (gram + gram.T))
        return cls(h, np.ascontiguousarray(r_inv @ r_inv.T), c,
                   np.ascontiguousarray(mm @ r_inv.T), gram, 1.0 / np.sqrt(np.diag(gram)))


class BatchQpSolver:
    """Solves K tracker QPs (any mix of axes and UAVs) sharing H and G in one compiled call.

    Besides the warm working sets (which the caller passes), the solver keeps for each of the K
    slots the Cholesky factor of its last working set: when a slot's warm set is exactly that
    set, the factor is reused (no refactorisation), otherwise it is rebuilt, so slots may hold
    other problems between calls at no risk. Not thread-safe (the cache is shared state).

    Example:
        >>> solver = BatchQpSolver(model)                               # doctest: +SKIP
        >>> u, status, iters, ws = solver.solve(f, lower, upper, ws)    # doctest: +SKIP
    """

    def __init__(self, model: QpMatrices, iter_limit: int = 200) -> None:
        self.data = LdpData.build(model.hessian, model.constraint_matrix)
        self.m = self.data.hess.shape[0]
        self.n_rows = self.m + self.data.cmat.shape[0]
        self.iter_limit = int(iter_limit)
        self._cache_arrays: tuple[np.ndarray, ...] = ()
        self.reset(0)

    def reset(self, k: int) -> None:
        """Forget the cached factorisations and size the cache for ``k`` problems."""
        m1 = self.m + 1
        self._cache_arrays = (
            np.zeros((k, m1, m1)), np.zeros((k, m1), dtype=np.int64),
            np.zeros((k, m1), dtype=np.int64), np.full(k, -1, dtype=np.int64),
            np.zeros(k, dtype=np.int64),
        )

    def _cache(self, k: int) -> tuple[np.ndarray, ...]:
        """The per-problem factor cache for K = k (a new, empty one when K changes)."""
        if self._cache_arrays[0].shape[0] != k:
            self.reset(k)
        return self._cache_arrays

    def solve(
        self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray, warm: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Solve K QPs.

        Args:
            f: (K, m) linear terms.
            lower, upper: (K, n) bounds on ``[U; C U]`` (n = m + rows of C).
            warm: (K, n) int8 working sets from the previous call (None: cold start).

        Returns:
            u (K, m), status (K,) int64 (1 optimal, see the module constants), iterations (K,)
            int64 and the working sets (K, n) int8 to pass as ``warm`` next time. A failed
            problem returns the unconstrained optimum in ``u`` and an empty working set.
        """
        f = np.ascontiguousarray(f, dtype=float)
        lower = np.ascontiguousarray(lower, dtype=float)
        upper = np.ascontiguousarray(upper, dtype=float)
        k = f.shape[0]
        if f.shape != (k, self.m) or lower.shape != (k, self.n_rows) or upper.shape != lower.shape:
            raise ValueError(f"expected f (K, {self.m}) and bounds (K, {self.n_rows}); got "
                             f"{f.shape}, {lower.shape}, {upper.shape}")
        if warm is None:
            warm = np.zeros((k, self.n_rows), dtype=np.int8)
        else:
            warm = np.ascontiguousarray(warm, dtype=np.int8)
            if warm.shape != lower.shape:
                raise ValueError(f"warm must have shape {lower.shape}, got {warm.shape}")
        u = np.empty((k, self.m))
        status = np.empty(k, dtype=np.int64)
        iterations = np.empty(k, dtype=np.int64)
        ws = np.empty((k, self.n_rows), dtype=np.int8)
        solve_batch(f, lower, upper, warm, *self.data, self.iter_limit, u, status, iterations, ws,
                    *self._cache(f.shape[0]))
        return u, status, iterations, ws

    def solve_into(
        self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray, warm: np.ndarray,
        u: np.ndarray, status: np.ndarray, iterations: np.ndarray, ws: np.ndarray,
    ) -> None:
        """:meth:`solve` without checks or allocations: all arrays C-contiguous, right dtypes.

        ``warm`` and ``ws`` may be the same array (each problem reads its warm set first).
        """
        solve_batch(f, lower, upper, warm, *self.data, self.iter_limit, u, status, iterations, ws,
                    *self._cache(f.shape[0]))


class BatchAxisSolver:
    """The batched kernel with K = 1, as a drop-in :class:`~uavmpc.solvers.contract.AxisQpSolver`.

    Keeps its own working set between calls (the warm start), reset after a failure.
    """

    name = "batchqp"

    def __init__(self, model: QpMatrices, iter_limit: int = 200) -> None:
        self._solver = BatchQpSolver(model, iter_limit)
        n, m = self._solver.n_rows, self._solver.m
        self._f = np.zeros((1, m))
        self._lower = np.zeros((1, n))
        self._upper = np.zeros((1, n))
        self._ws = np.zeros((1, n), dtype=np.int8)
        self._u = np.zeros((1, m))
        self._status = np.zeros(1, dtype=np.int64)
        self._iterations = np.zeros(1, dtype=np.int64)

    def solve(self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QpResult:
        """Solve with f (m,) and bounds (n,); see :class:`~uavmpc.solvers.contract.AxisQpSolver`."""
        self._f[0] = f
        self._lower[0] = lower
        self._upper[0] = upper
        # In place: the kernel reads the warm set of a problem before it writes the new one.
        self._solver.solve_into(self._f, self._lower, self._upper, self._ws, self._u,
                                self._status, self._iterations, self._ws)
        status = int(self._status[0])
        iterations = int(self._iterations[0])
        if status != OPTIMAL:
            return QpResult(None, f"batchqp {STATUS_NAMES.get(status, status)} ({status})",
                            iterations)
        return QpResult(self._u[0].copy(), "optimal", iterations)
