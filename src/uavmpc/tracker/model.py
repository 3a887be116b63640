"""The virtual UAV's per-axis model and the condensed MPC matrices (SPEC §2.1–2.3).

Each axis is a chain ``s = [p, v, a]`` with ``ṗ = v``, ``v̇ = a``, ``ȧ = (u − a) / τ``, discretised
exactly (zero-order hold on ``u``) for every step length of the non-uniform horizon. The 100 Hz
simulation of the virtual UAV uses the first step's matrices, so the next command *is* the first
predicted state and obeys every constraint of the QP.

Feasibility (SPEC §2.3) rests on one observation: ``w = v + τ·a`` obeys ``ẇ = u`` exactly (also in
the discrete model, ``w⁺ = w + Δt·u``), and ``v`` is a first-order lag of ``w``. Hence the set

    S = { v_lo ≤ v ≤ v_hi,  a_lo ≤ a ≤ a_hi,  v_lo ≤ w ≤ v_hi }

is invariant under ``u = 0`` (w freezes inside the box, v and a relax towards it). So the QP
only needs ``|u_k| ≤ a_max`` and ``|v_k| ≤ v_max`` along the horizon, plus ``w`` within the velocity
box at the *first* step: the next state is then in S, where "u ≡ 0" is a feasible plan, and the
QP is recursively feasible. The acceleration needs no rows of its own: ``a⁺ = α a + (1 − α) u`` is
a convex combination, so ``|u| ≤ a_max`` keeps ``|a| ≤ a_max``. When limits tighten and the state
lies outside the new S, the bounds are widened to a braking trajectory (:func:`braking_plan`),
which keeps the QP feasible and bounds the virtual UAV by the deceleration envelope.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavmpc.tracker.kernels import braking_plan as law
from uavmpc.tracker.params import TrackerConfig


def discretize(dt_s: float, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation of one axis over ``dt_s``: ``s⁺ = A s + B u``; A (3, 3), B (3,)."""
    alpha = np.exp(-dt_s / tau_s)
    lag = tau_s * (1.0 - alpha)  # ∫₀^Δt e^{-t/τ} dt
    a_mat = np.array([
        [1.0, dt_s, tau_s * (dt_s - lag)],
        [0.0, 1.0, lag],
        [0.0, 0.0, alpha],
    ])
    b_vec = np.array([0.5 * dt_s**2 - tau_s * (dt_s - lag), dt_s - lag, 1.0 - alpha])
    return a_mat, b_vec


@dataclass(frozen=True, eq=False)
class CondensedModel:
    """Prediction and QP matrices for one axis, shared by all four axes.

    With ``m`` steps and the input sequence ``U`` (m,), the predicted states are
    ``X = s0 @ free.T + U @ forced.T`` reshaped to (m, 3): row k is the state after step k.

    Attributes:
        config: the tracker set-up these matrices were built for.
        a_steps, b_steps: (m, 3, 3) and (m, 3) per-step model.
        free: (3m, 3) free response; forced: (3m, m) forced response.
        hessian: (m, m) QP Hessian H of ``½ Uᵀ H U + fᵀ U``.
        hessian_inv: (m, m) H⁻¹ (for the unconstrained shortcut).
        f_state: (m, 3), f_ref, f_vref: (m, m), f_uprev: (m,):
            ``f = F_s s0 + F_r r + F_vr ṙ + F_u u_prev`` (r, ṙ: reference position, velocity).
        constraint_matrix: (m + 1, m) rows ``[v_1..v_m, w_1]`` as functions of U.
        constraint_free: (m + 1, 3) the same rows as functions of s0.
    """

    config: TrackerConfig
    a_steps: np.ndarray
    b_steps: np.ndarray
    free: np.ndarray
    forced: np.ndarray
    hessian: np.ndarray
    hessian_inv: np.ndarray
    f_state: np.ndarray
    f_ref: np.ndarray
    f_vref: np.ndarray
    f_uprev: np.ndarray
    constraint_matrix: np.ndarray
    constraint_free: np.ndarray

    @classmethod
    def build(cls, config: TrackerConfig) -> CondensedModel:
        m, tau = config.steps, config.tau_s
        a_steps = np.empty((m, 3, 3))
        b_steps = np.empty((m, 3))
        for k, dt in enumerate(config.step_lengths_s):
            a_steps[k], b_steps[k] = discretize(float(dt), tau)
        phi = np.empty((m, 3, 3))
        gam = np.zeros((m, 3, m))
        a_prev, g_prev = np.eye(3), np.zeros((3, m))
        for k in range(m):
            a_prev = a_steps[k] @ a_prev
            g_prev = a_steps[k] @ g_prev
            g_prev[:, k] += b_steps[k]
            phi[k], gam[k] = a_prev, g_prev
        free = phi.reshape(3 * m, 3)
        forced = gam.reshape(3 * m, m)

        g_p, g_v, g_a = gam[:, 0, :], gam[:, 1, :], gam[:, 2, :]
        p_p, p_v, p_a = phi[:, 0, :], phi[:, 1, :], phi[:, 2, :]
        diff = np.eye(m) - np.eye(m, k=-1)  # (u_k − u_{k−1}); row 0 uses u_prev via f
        hessian = 2.0 * (
            config.q_position * g_p.T @ g_p
            + config.q_velocity * g_v.T @ g_v
            + config.q_acceleration * g_a.T @ g_a
            + config.q_input * np.eye(m)
            + config.q_input_rate * diff.T @ diff
        )
        hessian = 0.5 * (hessian + hessian.T)
        f_state = 2.0 * (
            config.q_position * g_p.T @ p_p
            + config.q_velocity * g_v.T @ p_v
            + config.q_acceleration * g_a.T @ p_a
        )
        f_ref = -2.0 * config.q_position * g_p.T
        f_vref = -2.0 * config.q_velocity * g_v.T
        f_uprev = np.zeros(m)
        f_uprev[0] = -2.0 * config.q_input_rate
        g_w1 = g_v[:1] + tau * g_a[:1]
        p_w1 = p_v[:1] + tau * p_a[:1]
        return cls(
            config=config,
            a_steps=a_steps,
            b_steps=b_steps,
            free=free,
            forced=forced,
            hessian=hessian,
            hessian_inv=np.linalg.inv(hessian),
            f_state=f_state,
            f_ref=f_ref,
            f_vref=f_vref,
            f_uprev=f_uprev,
            constraint_matrix=np.vstack([g_v, g_w1]),
            constraint_free=np.vstack([p_v, p_w1]),
        )


def braking_plan(
    model: CondensedModel,
    state: np.ndarray,
    a_lo: np.ndarray,
    a_hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Brake to a stop at the acceleration limits, every axis at once (the law is
    :func:`uavmpc.tracker.kernels.braking_plan`; this is its array-in, array-out face).

    Args:
        state: (n_axes, 3) current ``[p, v, a]`` per axis.
        a_lo, a_hi: (n_axes,) acceleration (and input) bounds, a_lo < 0 < a_hi.

    Returns:
        inputs (n_axes, m) and states (n_axes, m, 3) after each step.
    """
    cfg = model.config
    m = cfg.steps
    s = np.ascontiguousarray(state, dtype=float)
    inputs = np.empty((s.shape[0], m))
    states = np.empty((s.shape[0], m, 3))
    law(s, np.ascontiguousarray(a_lo, dtype=float), np.ascontiguousarray(a_hi, dtype=float),
        float(cfg.tau_s), np.concatenate([[0.0], cfg.horizon_times_s]), cfg.step_lengths_s,
        np.ascontiguousarray(model.free.T), np.ascontiguousarray(model.forced.T), inputs, states)
    return inputs, states
