"""The virtual UAV's discrete model and condensed matrices, against independent computations."""

import numpy as np
import pytest
from scipy.linalg import expm

from uavmpc.tracker import CondensedModel, TrackerConfig, braking_plan, discretize


@pytest.mark.parametrize("dt", [0.01, 0.2, 1.0])
@pytest.mark.parametrize("tau", [0.05, 0.1, 0.5])
def test_discretize_matches_matrix_exponential(dt: float, tau: float) -> None:
    cont = np.zeros((4, 4))  # augmented [p, v, a, u] with u held constant
    cont[0, 1] = 1.0
    cont[1, 2] = 1.0
    cont[2, 2] = -1.0 / tau
    cont[2, 3] = 1.0 / tau
    exact = expm(cont * dt)
    a_mat, b_vec = discretize(dt, tau)
    np.testing.assert_allclose(a_mat, exact[:3, :3], atol=1e-12)
    np.testing.assert_allclose(b_vec, exact[:3, 3], atol=1e-12)
    # unit-gain lag: α + β = 1
    assert a_mat[2, 2] + b_vec[2] == pytest.approx(1.0)


def test_w_integrates_input_exactly() -> None:
    tau, dt = 0.1, 0.2
    a_mat, b_vec = discretize(dt, tau)
    rng = np.random.default_rng(0)
    for _ in range(20):
        s, u = rng.normal(size=3), rng.normal()
        s1 = a_mat @ s + b_vec * u
        assert s1[1] + tau * s1[2] == pytest.approx(s[1] + tau * s[2] + dt * u, abs=1e-12)


def test_condensed_prediction_equals_step_by_step_simulation() -> None:
    config = TrackerConfig()
    model = CondensedModel.build(config)
    rng = np.random.default_rng(1)
    s0, u = rng.normal(size=3), rng.normal(size=config.steps)
    states = (s0 @ model.free.T + u @ model.forced.T).reshape(config.steps, 3)
    s = s0.copy()
    for k, dt in enumerate(config.step_lengths_s):
        a_mat, b_vec = discretize(float(dt), config.tau_s)
        s = a_mat @ s + b_vec * u[k]
        np.testing.assert_allclose(states[k], s, atol=1e-9)
    np.testing.assert_allclose(config.horizon_times_s[[0, -1]], [0.01, 7.81])


def _braking_plain(model, state, a_lo, a_hi):
    """The braking policy simulated step by step (the plain path)."""
    cfg = model.config
    s = state.copy()
    us, ss = [], []
    for k, dt in enumerate(cfg.step_lengths_s):
        w = s[:, 1] + cfg.tau_s * s[:, 2]
        u = np.clip(-w / dt, a_lo, a_hi)
        s = s @ model.a_steps[k].T + u[:, None] * model.b_steps[k]
        us.append(u)
        ss.append(s.copy())
    return np.stack(us, 1), np.stack(ss, 1)


def test_braking_plan_closed_form_equals_plain_simulation() -> None:
    model = CondensedModel.build(TrackerConfig())
    rng = np.random.default_rng(2)
    a_lo, a_hi = np.array([-2.5, -2.5, -1.0, -2.0]), np.array([2.5, 2.5, 1.5, 2.0])
    for _ in range(50):
        state = rng.normal(scale=[5.0, 8.0, 3.0], size=(4, 3))
        u_fast, s_fast = braking_plan(model, state, a_lo, a_hi)
        u_plain, s_plain = _braking_plain(model, state, a_lo, a_hi)
        np.testing.assert_allclose(u_fast, u_plain, atol=1e-9)
        np.testing.assert_allclose(s_fast, s_plain, atol=1e-9)
        w_end = s_fast[:, -1, 1] + model.config.tau_s * s_fast[:, -1, 2]
        # |w| shrinks monotonically and the inputs respect the bounds
        assert np.all(u_fast >= a_lo[:, None] - 1e-12) and np.all(u_fast <= a_hi[:, None] + 1e-12)
        assert np.all(np.abs(w_end) <= np.abs(state[:, 1] + 0.1 * state[:, 2]) + 1e-12)


def test_hessian_is_positive_definite_and_symmetric() -> None:
    model = CondensedModel.build(TrackerConfig())
    np.testing.assert_allclose(model.hessian, model.hessian.T)
    assert np.linalg.eigvalsh(model.hessian).min() > 0.0


def test_bound_check_is_the_largest_violation_and_nan_for_a_nan_input() -> None:
    from uavmpc.tracker.kernels import excess4

    model = CondensedModel.build(TrackerConfig())
    c_t = np.ascontiguousarray(model.constraint_matrix.T)
    m, r = c_t.shape
    rng = np.random.default_rng(5)
    for trial in range(20):
        u = rng.normal(scale=2.0, size=(4, m))
        lower = rng.normal(scale=3.0, size=(4, m + r)) - 2.0
        upper = lower + rng.uniform(0.0, 6.0, size=(4, m + r))
        if trial % 4 == 0:
            u[trial % 3 + 1, rng.integers(m)] = np.nan
        worst = np.empty(4)
        excess4(u, c_t, lower, upper, np.empty((4, r)), worst)
        rows = np.concatenate([u, u @ c_t], axis=1)
        for ax in range(4):
            if np.isnan(u[ax]).any():
                assert np.isnan(worst[ax])
            else:
                expected = max(np.max(lower[ax] - rows[ax]), np.max(rows[ax] - upper[ax]))
                assert worst[ax] == pytest.approx(expected, abs=1e-12)
