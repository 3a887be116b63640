"""Invariants of the virtual UAV over wild references, states and limit changes (hypothesis)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from uavmpc import DynamicLimits, MpcTracker, Reference

TOL = 1e-6

limits_st = st.builds(
    DynamicLimits,
    horizontal_speed_mps=st.floats(0.2, 15.0),
    horizontal_accel_mps2=st.floats(0.2, 6.0),
    ascend_speed_mps=st.floats(0.2, 6.0),
    ascend_accel_mps2=st.floats(0.2, 4.0),
    descend_speed_mps=st.floats(0.2, 4.0),
    descend_accel_mps2=st.floats(0.2, 4.0),
    heading_rate_radps=st.floats(0.1, 3.0),
    heading_accel_radps2=st.floats(0.1, 4.0),
)


@st.composite
def references(draw: st.DrawFn, t_now: float) -> Reference:
    kind = draw(st.sampled_from(["step", "trajectory"]))
    if kind == "step":
        size = draw(st.floats(0.1, 10_000.0))
        direction = np.array(draw(st.lists(st.floats(-1, 1), min_size=3, max_size=3)))
        direction = direction / max(np.linalg.norm(direction), 1e-9)
        heading = draw(st.floats(-50.0, 50.0))
        return Reference.goto(*(size * direction), heading, start_s=t_now)
    n = draw(st.integers(1, 60))
    scale = draw(st.sampled_from([1.0, 100.0, 5000.0]))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-scale, scale, size=(n, 4))
    pts[:, 3] = rng.uniform(-20, 20, size=n)
    period = draw(st.floats(0.01, 2.0))
    start = t_now + draw(st.floats(-5.0, 10.0))
    return Reference.sampled(pts, period, start, loop=n > 1 and draw(st.booleans()))


def _bounds(tracker: MpcTracker) -> tuple[np.ndarray, np.ndarray]:
    """Box (4, 3) of [v, a, w = v + τa] in force."""
    v_lo, v_hi = tracker.limits.velocity_bounds()
    a_lo, a_hi = tracker.limits.acceleration_bounds()
    return np.stack([v_lo, a_lo, v_lo], 1), np.stack([v_hi, a_hi, v_hi], 1)


def _vaw(s: np.ndarray, tau: float) -> np.ndarray:
    return np.stack([s[:, 1], s[:, 2], s[:, 1] + tau * s[:, 2]], 1)


@pytest.mark.slow
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), limits=limits_st)
def test_virtual_uav_never_leaves_its_limits(data: st.DataObject, limits: DynamicLimits) -> None:
    tracker = MpcTracker(position_m=data.draw(st.tuples(*[st.floats(-1e4, 1e4)] * 3)))
    tracker.set_limits(limits)
    tau = tracker.config.tau_s
    lo, hi = _bounds(tracker)
    # a random initial state inside the limits (including w = v + τa)
    frac = np.array(data.draw(st.lists(st.floats(0.0, 1.0), min_size=8, max_size=8))).reshape(4, 2)
    state = tracker.state
    state[:, 1] = lo[:, 0] + frac[:, 0] * (hi[:, 0] - lo[:, 0])
    a_room_lo = np.maximum(lo[:, 1], (lo[:, 0] - state[:, 1]) / tau)
    a_room_hi = np.minimum(hi[:, 1], (hi[:, 0] - state[:, 1]) / tau)
    state[:, 2] = a_room_lo + frac[:, 1] * (a_room_hi - a_room_lo)
    tracker.set_state(state)

    events = data.draw(st.lists(st.tuples(st.integers(0, 300), st.sampled_from(["ref", "lim"])),
                                max_size=6))
    deadline = None  # when the state must be back inside after a tightening
    for tick in range(300):
        for when, what in events:
            if when != tick:
                continue
            if what == "ref":
                tracker.set_reference(data.draw(references(tracker.time_s)))
            else:
                tracker.set_limits(data.draw(limits_st))
                deadline = None
        lo, hi = _bounds(tracker)
        before = _vaw(tracker.state, tau)
        out = tracker.step()
        after = _vaw(tracker.state, tau)
        assert np.all(np.isfinite(tracker.state))
        assert np.all(np.isfinite(out.prediction.position_m))
        assert out.fallback_axes == ()
        inside_before = np.all(before >= lo - 1e-9) and np.all(before <= hi + 1e-9)
        if inside_before:
            assert np.all(after >= lo - TOL) and np.all(after <= hi + TOL)
        else:
            # Only the deceleration envelope: w = v + τa moves towards the box every tick,
            # v stays between where it was and where w was, a decays towards the box.
            excess_w_before = np.maximum(before[:, 2] - hi[:, 2], lo[:, 2] - before[:, 2])
            excess_w_after = np.maximum(after[:, 2] - hi[:, 2], lo[:, 2] - after[:, 2])
            assert np.all(np.maximum(excess_w_after, 0) <= np.maximum(excess_w_before, 0) + TOL)
            v_top = np.maximum.reduce([hi[:, 0], before[:, 0], before[:, 2]])
            v_bot = np.minimum.reduce([lo[:, 0], before[:, 0], before[:, 2]])
            assert np.all(after[:, 0] <= v_top + TOL) and np.all(after[:, 0] >= v_bot - TOL)
            assert np.all(np.abs(after[:, 1]) <= np.maximum(np.abs(before[:, 1]),
                                                             np.maximum(-lo[:, 1], hi[:, 1])) + TOL)
            if deadline is None:
                # braking at the weaker of the two accel limits, plus the lag's settling
                a_min = np.minimum(-lo[:, 1], hi[:, 1])
                deadline = tracker.time_s + np.max(np.abs(before).max(axis=1) / a_min) + 1.5
        # after a tightening, the state is back inside within the time the limits allow
        if deadline is not None and tracker.time_s > deadline:
            assert np.all(after >= lo - TOL) and np.all(after <= hi + TOL)
