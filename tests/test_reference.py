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
