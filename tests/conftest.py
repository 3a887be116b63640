import numpy as np
import pytest

from uavmpc.tracker import MpcTracker


def fly(tracker: MpcTracker, ticks: int) -> np.ndarray:
    """Step the tracker; returns (ticks, 4, 3) states after each step."""
    out = np.empty((ticks, 4, 3))
    for i in range(ticks):
        tracker.step()
        out[i] = tracker.state
    return out


@pytest.fixture
def tracker() -> MpcTracker:
    return MpcTracker(position_m=(0.0, 0.0, 10.0))
