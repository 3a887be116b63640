"""The tracker's per-tick QP data, for all four axes at once (``m`` steps, ``r = m + 1`` rows):

    f       = s0 F_sᵀ + r_ref F_rᵀ + u_prev F_u + clip(r_ref D, v_lo, v_hi) F_vrᵀ      (4, m)
    lower', upper' = the bounds on [U; C U] shifted by the free response s0 C_freeᵀ     (4, m + r)
    u_free  = −f H⁻¹ (the unconstrained optimum)                                       (4, m)
    excess  = the largest bound violation of u_free per axis                           (4,)

Measured: ≈ 22 µs per tick in numpy; a numba twin of it took ≈ 18 µs (its call overhead eats the
gain), so it was not kept. The tick's cost is in the QP solves, not here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class QpData:
    """Constant matrices of the per-tick build, laid out for row-vector products.

    Attributes:
        f_state_t: (3, m); f_ref_t, vref_of_ref, f_vref_t: (m, m); f_uprev: (m,);
        cfree_t: (3, r); neg_hinv: (m, m); c_t: (m, r) with r = m + 1 constraint rows.
    """

    f_state_t: np.ndarray
    f_ref_t: np.ndarray
    vref_of_ref: np.ndarray
    f_vref_t: np.ndarray
    f_uprev: np.ndarray
    cfree_t: np.ndarray
    neg_hinv: np.ndarray
    c_t: np.ndarray
    use_vref: bool


def build_qp(
    d: QpData, rel: np.ndarray, r_ref: np.ndarray, u_prev: np.ndarray,
    v_lo: np.ndarray, v_hi: np.ndarray, lower: np.ndarray, upper: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(f, lower', upper', u_free, excess); see the module docstring."""
    m = d.f_uprev.shape[0]
    f = rel @ d.f_state_t + r_ref @ d.f_ref_t + u_prev[:, None] * d.f_uprev
    if d.use_vref:
        # The reference's own velocity, clipped: a jump in it is not a speed to match.
        vref = np.clip(r_ref @ d.vref_of_ref, v_lo[:, None], v_hi[:, None])
        f += vref @ d.f_vref_t
    rows_free = rel @ d.cfree_t
    lower_qp = lower.copy()
    upper_qp = upper.copy()
    lower_qp[:, m:] -= rows_free
    upper_qp[:, m:] -= rows_free
    u_free = f @ d.neg_hinv
    rows = np.concatenate([u_free, u_free @ d.c_t], axis=1)
    excess = np.maximum(lower_qp - rows, rows - upper_qp).max(axis=1)
    return f, lower_qp, upper_qp, u_free, excess
