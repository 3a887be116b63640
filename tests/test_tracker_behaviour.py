"""What the virtual UAV does with steps, moving references, far stops, headings and limits."""

import dataclasses

import numpy as np
import pytest
from conftest import fly

from uavmpc import DynamicLimits, MpcTracker, Reference, TrackerConfig
from uavmpc.tracker import ClarabelSolver, DaqpSolver, QpResult


def test_50m_step_at_max_speed_settles_without_overshoot(tracker: MpcTracker) -> None:
    tracker.set_reference(Reference.goto(50.0, 0.0, 10.0))
    states = fly(tracker, 2000)
    x, vx, ax = states[:, 0, 0], states[:, 0, 1], states[:, 0, 2]
    lim = tracker.limits
    assert vx.max() == pytest.approx(lim.horizontal_speed_mps, abs=1e-3)  # flown at max speed
    assert np.abs(vx).max() <= lim.horizontal_speed_mps + 1e-6
    assert np.abs(ax).max() <= lim.horizontal_accel_mps2 + 1e-6
    assert x.max() - 50.0 <= 0.05  # overshoot ≤ 5 cm
    outside = np.flatnonzero(np.abs(x - 50.0) >= 0.01)
    settle_s = (outside[-1] + 1) * 0.01
    assert settle_s < 12.0  # and stays within 1 cm afterwards (to the end of 20 s)
    # the other axes did not move
    np.testing.assert_allclose(states[:, 1:3, 0], [[0.0, 10.0]] * 2000, atol=1e-9)
    assert tracker.fallback_count == 0


def _line(speed: float, stop_s: float, duration_s: float = 40.0) -> Reference:
    t = np.arange(0.0, duration_s, 0.2)
    x = speed * np.minimum(t, stop_s)
    return Reference(t, np.stack([x, 0 * t, 0 * t + 10.0, 0 * t], axis=1))


def test_feasible_moving_reference_is_tracked_with_small_lag(tracker: MpcTracker) -> None:
    ref = _line(3.0, 25.0)
    tracker.set_reference(ref)
    states = fly(tracker, 2000)
    t = 0.01 * np.arange(1, 2001)
    err = states[:, 0, 0] - ref.sample(t)[:, 0]
    cruise = (t > 6.0) & (t < 14.0)
    assert np.abs(err[cruise]).max() < 0.01
    assert np.abs(states[cruise, 0, 1] - 3.0).max() < 0.01


def test_stop_beyond_the_horizon_is_anticipated(tracker: MpcTracker) -> None:
    # At t = 0 the stop at t = 20 s lies beyond the 7.8 s horizon; the tracker must start braking
    # before the reference stops, as soon as the stop enters its horizon.
    ref = _line(6.0, 20.0)
    tracker.set_reference(ref)
    states = fly(tracker, 2500)
    t = 0.01 * np.arange(1, 2501)
    vx = states[:, 0, 1]
    braking_start = t[np.argmax((t > 8.0) & (vx < 5.99))]
    assert 20.0 - 7.81 < braking_start < 20.0
    assert states[-1, 0, 0] == pytest.approx(120.0, abs=0.01)
    # the instantaneous stop is infeasible; the virtual UAV stops smoothly just past it
    assert states[:, 0, 0].max() - 120.0 < 0.5


def test_heading_across_pi_takes_the_short_way() -> None:
    tracker = MpcTracker(position_m=(0.0, 0.0, 5.0), heading_rad=3.0)
    tracker.goto(0.0, 0.0, 5.0, heading=-3.0)  # 0.283 rad ahead, not 6 rad back
    headings = []
    for _ in range(400):
        headings.append(tracker.step().command.heading_rad)
    headings = np.array(headings)
    assert np.abs(headings).min() > 2.99  # never swung through 0
    assert np.all((headings >= -np.pi) & (headings < np.pi))
    assert headings[-1] == pytest.approx(-3.0, abs=1e-3)
    assert tracker.state[3, 1] == pytest.approx(0.0, abs=1e-3)


def test_new_trajectory_replaces_the_old_one_from_its_start_time(tracker: MpcTracker) -> None:
    tracker.set_reference(Reference.goto(10.0, 0.0, 10.0))
    tracker.set_reference(Reference.goto(-10.0, 0.0, 10.0, start_s=3.0))
    states = fly(tracker, 1200)
    t = 0.01 * np.arange(1, 1201)
    # heads for +10 first, turns back before 3 s (it sees the switch coming), ends at -10
    assert states[t < 0.5, 0, 1].min() > 0.0
    assert np.argmax(states[:, 0, 1] < 0.0) * 0.01 < 3.0
    assert states[-1, 0, 0] == pytest.approx(-10.0, abs=0.05)


def test_looping_reference_repeats() -> None:
    pts = np.array([[0, 0, 5, 0], [4, 0, 5, 0], [4, 4, 5, 0], [0, 4, 5, 0]], dtype=float)
    ref = Reference.sampled(pts, 2.0, loop=True)
    np.testing.assert_allclose(ref.sample(np.array([0.0, 8.0, 16.0, 7.0])),
                               [pts[0], pts[0], pts[0], [0, 2, 5, 0]])


def test_limits_halved_mid_flight_decelerate_at_the_limit(tracker: MpcTracker) -> None:
    tracker.set_reference(Reference.goto(500.0, 0.0, 10.0))
    fly(tracker, 800)
    assert tracker.state[0, 1] == pytest.approx(8.3, abs=1e-3)
    nominal = tracker.limits
    half = nominal.scaled(0.5, 0.5)
    tracker.set_limits(half)
    states = fly(tracker, 600)
    v = states[:, 0, 1]
    a = states[:, 0, 2]
    above = np.flatnonzero(v > half.horizontal_speed_mps + 1e-6)
    assert np.all(np.diff(v[: above[-1] + 2]) <= 1e-9)  # monotonic deceleration to the limit
    assert np.all(v[above[-1] + 1 :] <= half.horizontal_speed_mps + 1e-6)  # then stays below
    assert v.min() > 0.97 * half.horizontal_speed_mps  # the acceleration lag undershoots little
    assert np.abs(a).max() <= half.horizontal_accel_mps2 + 1e-6  # at the *new* accel limit
    # it takes at least the time the limit allows, and not much more
    reached = (above[-1] + 1) * 0.01
    min_time = (8.3 - 4.15) / half.horizontal_accel_mps2
    assert min_time <= reached <= min_time + 0.6
    assert tracker.fallback_count == 0
    tracker.set_limits(nominal)
    states = fly(tracker, 600)
    assert states[-1, 0, 1] == pytest.approx(8.3, abs=1e-3)


def test_unconstrained_shortcut_equals_the_qp_solution() -> None:
    tracker = MpcTracker(position_m=(0.0, 0.0, 10.0))
    model = tracker.model
    solver = DaqpSolver(model)
    rng = np.random.default_rng(3)
    m = model.config.steps
    lim = tracker.limits
    lower = np.concatenate([np.full(m, -lim.horizontal_accel_mps2),
                            np.full(m + 1, -lim.horizontal_speed_mps)])
    for _ in range(20):
        r = rng.uniform(-0.05, 0.05)  # small error: no bound active
        f = model.f_ref @ np.full(m, r)
        u_free = -model.hessian_inv @ f
        assert np.abs(u_free).max() < lim.horizontal_accel_mps2
        res = solver.solve(f, lower, -lower)
        assert res.ok
        np.testing.assert_allclose(res.inputs, u_free, atol=1e-7)


def test_daqp_agrees_with_clarabel_on_constrained_qps() -> None:
    tracker = MpcTracker(position_m=(0.0, 0.0, 10.0))
    model = tracker.model
    daqp_solver, ref_solver = DaqpSolver(model), ClarabelSolver(model)
    m = model.config.steps
    rng = np.random.default_rng(4)
    for _ in range(20):
        s0 = np.array([0.0, rng.uniform(-4, 4), rng.uniform(-1, 1)])
        f = model.f_state @ s0 + model.f_ref @ np.full(m, rng.uniform(-100, 100))
        free = model.constraint_free @ s0
        lower = np.concatenate([np.full(m, -2.5), np.full(m + 1, -8.3) - free])
        upper = np.concatenate([np.full(m, 2.5), np.full(m + 1, 8.3) - free])
        a, b = daqp_solver.solve(f, lower, upper), ref_solver.solve(f, lower, upper)
        assert a.ok and b.ok
        np.testing.assert_allclose(a.inputs, b.inputs, atol=1e-4)


class _Failing:
    name = "failing"

    def solve(self, f, lower, upper):
        return QpResult(None, "forced failure", 0)


class _Raising:
    name = "raising"

    def solve(self, f, lower, upper):
        raise RuntimeError("boom")


@pytest.mark.parametrize("how", ["iter_limit", "status", "exception"])
def test_solver_failure_falls_back_to_braking(how: str) -> None:
    if how == "iter_limit":  # a real DAQP failure: one iteration is never enough here
        config = dataclasses.replace(TrackerConfig(), iter_limit=1)
        tracker = MpcTracker(config, position_m=(0.0, 0.0, 10.0))
    else:
        cls = _Failing if how == "status" else _Raising
        tracker = MpcTracker(position_m=(0.0, 0.0, 10.0), solvers=[cls() for _ in range(4)])
    tracker.set_state(np.array([[0, 8.0, 0.0], [0, 0, 0], [10, 0, 0], [0, 0, 0]], dtype=float))
    tracker.set_reference(Reference.goto(-100.0, 0.0, 10.0))  # needs the solver at once
    speeds = []
    for _ in range(500):
        out = tracker.step()
        assert 0 in out.fallback_axes
        assert np.all(np.isfinite(out.prediction.position_m))
        speeds.append(out.command.velocity_mps[0])
    assert tracker.fallback_count == 500
    assert tracker.last_solver_status[0] != "optimal"
    speeds = np.array(speeds)
    assert np.all(np.diff(speeds) <= 1e-12) and speeds[-1] == pytest.approx(0.0, abs=1e-6)
    assert np.abs(tracker.state[0, 2]) <= 2.5 + 1e-9  # braked within the accel limit


def test_tightened_vertical_limits_apply_to_climb_and_descent() -> None:
    lim = DynamicLimits(ascend_speed_mps=1.0, descend_speed_mps=0.5)
    config = dataclasses.replace(TrackerConfig(), limits=lim)
    tracker = MpcTracker(config, position_m=(0.0, 0.0, 10.0))
    tracker.goto(0.0, 0.0, 30.0)
    up = fly(tracker, 1000)
    tracker.goto(0.0, 0.0, 0.0)
    down = fly(tracker, 1000)
    assert up[:, 2, 1].max() == pytest.approx(1.0, abs=1e-6)
    assert down[:, 2, 1].min() == pytest.approx(-0.5, abs=1e-6)


def test_stepping_trackers_together_equals_stepping_them_alone() -> None:
    """Rows of one batch and standalone trackers run the same kernels: bit for bit equal."""
    from uavmpc.tracker import TrackerBatch

    goals = [(50.0, 0.0, 10.0, 3.0), (-20.0, 30.0, 2.0, -3.0), (0.0, 0.0, 10.0, 0.0)]
    batch = TrackerBatch(n=len(goals))

    def make(where) -> list[MpcTracker]:
        out = []
        for i, goal in enumerate(goals):
            t = MpcTracker(position_m=(0.0, 0.0, 10.0), **where(i))
            t.set_reference(Reference.goto(*goal))
            if i == 1:
                t.set_z_offset(3.0)
            out.append(t)
        return out

    together = make(lambda i: {"batch": batch, "row": i})
    alone = make(lambda i: {})
    braked = False
    for k in range(400):
        if k == 200:  # one of them tightens its limits mid-flight (braking envelope)
            together[0].set_limits(together[0].limits.scaled(0.5))
            alone[0].set_limits(alone[0].limits.scaled(0.5))
        batch.step()
        for i, t in enumerate(alone):
            ref = t.step()
            out = batch.output(i)
            assert np.array_equal(out.prediction.position_m, ref.prediction.position_m)
            assert out.braking == ref.braking and out.qp_solves == ref.qp_solves
            braked |= out.braking
    assert braked, "the tightening must make one of them brake"
    for a, b in zip(together, alone, strict=True):
        assert np.array_equal(a.state, b.state)


def test_a_held_height_stops_the_references_climb_and_keeps_the_offset(
        tracker: MpcTracker) -> None:
    """A hold short stops vertically too: with a held height the reference's own climb no
    longer moves the virtual UAV, the avoidance's offset still does; released, it climbs on."""
    climb = Reference(np.array([0.0, 20.0]), np.array([[0.0, 0.0, 0.0, 0.0],
                                                       [0.0, 0.0, 30.0, 0.0]]))
    tracker.set_reference(climb)
    fly(tracker, 200)  # 2 s into a 1.5 m/s climb
    assert tracker.hold_z_m is None
    tracker.hold_height(3.0)
    held = fly(tracker, 800)
    assert held[-1, 2, 0] == pytest.approx(3.0, abs=0.01)  # the climb went on to 24 m
    tracker.set_z_offset(3.0)
    raised = fly(tracker, 800)
    assert raised[-1, 2, 0] == pytest.approx(6.0, abs=0.01)
    tracker.hold_height(None)
    freed = fly(tracker, 500)
    assert freed[-1, 2, 0] > 10.0 and freed[-1, 2, 1] > 1.0
    with pytest.raises(ValueError, match="hold z_m"):
        tracker.hold_height(float("nan"))
