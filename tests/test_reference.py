"""Reference sampling against numpy's own interpolation (uniform fast path and general path)."""

import numpy as np
import pytest

from uavmpc import Reference


@pytest.mark.parametrize("uniform", [True, False])
def test_sampling_matches_np_interp(uniform: bool) -> None:
    rng = np.random.default_rng(5)
    n = 50
    times = 3.0 + (0.2 * np.arange(n) if uniform else np.cumsum(rng.uniform(0.01, 1.0, n)))
    pts = rng.normal(scale=10.0, size=(n, 4))
    pts[:, 3] = np.cumsum(rng.uniform(-1.0, 1.0, n))  # already continuous headings
    ref = Reference(times, pts)
    assert (ref.uniform_period_s > 0.0) == uniform
    t = rng.uniform(times[0] - 5.0, times[-1] + 5.0, 500)
    expected = np.column_stack([np.interp(t, times, pts[:, i]) for i in range(4)])
    np.testing.assert_allclose(ref.sample(t), expected, atol=1e-9)


def test_loop_closes_the_short_way_round_in_heading() -> None:
    pts = np.array([[0, 0, 5, 3.0], [4, 0, 5, 3.1]], dtype=float)
    ref = Reference.sampled(pts, 1.0, loop=True)
    # from heading 3.1 back to 3.0 over the closing segment, and the period is 2 s
    np.testing.assert_allclose(ref.sample(np.array([1.5, 2.0, 3.0, 4.5])),
                               [[2, 0, 5, 3.05], [0, 0, 5, 3.0], [4, 0, 5, 3.1], [2, 0, 5, 3.05]])


def test_headings_are_unwrapped_for_interpolation() -> None:
    ref = Reference(np.array([0.0, 1.0]), np.array([[0, 0, 0, 3.0], [0, 0, 0, -3.0]]))
    mid = ref.sample(np.array([0.5]))[0, 3]
    assert mid == pytest.approx(np.pi, abs=0.01)  # through π, not through 0


# ------------------------------------------------------------------ refused by name
def test_integers_beyond_the_float_range_are_refused_by_name() -> None:
    from uavmpc.reference import InvalidReferenceError

    # float() of them raises OverflowError: the field and the number's size are named instead.
    with pytest.raises(InvalidReferenceError,
                       match=r"^sample_period_s must be finite, got an integer of about 401 "
                             r"digits \(beyond the float range\)$"):
        Reference.sampled(np.zeros((2, 4)), 10**400)
    with pytest.raises(InvalidReferenceError, match=r"^start_s must be finite, got an integer"):
        Reference.goto(0.0, 0.0, 5.0, start_s=-(10**400))
    with pytest.raises(InvalidReferenceError, match=r"^goto holds a number beyond the float"):
        Reference.goto(10**400, 0.0, 5.0)
    with pytest.raises(InvalidReferenceError, match=r"^points holds a number beyond the float"):
        Reference(np.array([0.0]), [[0, 0, 10**400, 0]])


@pytest.mark.parametrize("speed", [1e-320, 5e-324, 1e-9])
def test_a_path_too_slow_to_sample_is_refused_naming_the_speed(speed: float) -> None:
    from uavmpc.reference import MAX_POINTS, InvalidReferenceError

    # A subnormal speed once made int(length / (speed * period)) an int(inf): OverflowError.
    with pytest.raises(InvalidReferenceError,
                       match=rf"^speed_mps=.* is too small: .* more than the limit of "
                             rf"{MAX_POINTS} points$"):
        Reference.along_path(np.array([[0, 0, 1], [10, 0, 1]]), speed)
    # A slow speed whose samples stay within the limit still flies.
    ref = Reference.along_path(np.array([[0, 0, 1], [10, 0, 1]]), 10.0 / (0.2 * 1000))
    assert 1000 <= ref.points.shape[0] <= 1002


def test_waypoints_beyond_the_position_bound_are_refused_before_the_curve() -> None:
    from uavmpc.reference import InvalidReferenceError

    # The Catmull–Rom end extensions of 1e308 overflow to inf and the arc length to NaN.
    with pytest.raises(InvalidReferenceError, match=r"^waypoints\[1\] lies 1e\+308 m"):
        Reference.along_path(np.array([[0, 0, 1], [1e308, 0, 1]]), 2.0)


def test_stamps_and_the_closing_knot_stay_finite() -> None:
    from uavmpc.reference import MAX_ABS_TIME_S, InvalidReferenceError

    two = np.array([[0, 0, 1, 0], [1, 0, 1, 0]], dtype=float)
    # The reproducer: every stamp finite, the closing knot 1e308 + 2·5e307 = inf.
    with pytest.raises(InvalidReferenceError, match=r"^start_s=1e\+308 is beyond the sane "
                                                    r"bound of ±1e\+11 s$"):
        Reference.sampled(two, 5e307, 1e308, loop=True)
    with pytest.raises(InvalidReferenceError,
                       match=r"^sample_period_s=5e\+307 from start_s=0.0 puts the last "
                             r"\(closing\) knot at 1e\+308 s, beyond"):
        Reference.sampled(two, 5e307, 0.0, loop=True)
    with pytest.raises(InvalidReferenceError, match=r"^times_s\[1\]=1e\+308 is beyond"):
        Reference(np.array([0.0, 1e308]), two, loop=True)
    # Unix time (a swarm's missions) and the bound itself are fine; the knots are finite.
    ref = Reference.sampled(two, 0.2, 1.7e9, loop=True)
    assert np.all(np.isfinite(ref.knots_s)) and ref.knots_s[-1] == pytest.approx(1.7e9 + 0.4)
    assert Reference.goto(0.0, 0.0, 1.0, start_s=-MAX_ABS_TIME_S).start_s == -MAX_ABS_TIME_S


def test_headings_beyond_the_bound_are_refused_before_they_are_unwrapped() -> None:
    from uavmpc.reference import MAX_ABS_HEADING_RAD, InvalidReferenceError

    # np.unwrap of ±1e308 overflows: the stored heading was NaN.
    with pytest.raises(InvalidReferenceError,
                       match=r"^points\[0\] heading is 1e\+308 rad, beyond the sane bound of "
                             r"±1e\+06 rad$"):
        Reference(np.array([0.0, 1.0]), np.array([[0, 0, 5, 1e308], [0, 0, 5, -1e308]]))
    with pytest.raises(InvalidReferenceError, match=r"^points\[1\] heading"):
        Reference.sampled(np.array([[0, 0, 5, 0.0], [0, 0, 5, -2e6]]), 0.2)
    ref = Reference(np.array([0.0, 1.0]),
                    np.array([[0, 0, 5, MAX_ABS_HEADING_RAD], [0, 0, 5, -MAX_ABS_HEADING_RAD]]))
    assert np.all(np.isfinite(ref.points))
