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


@pytest.fixture
def hover_pair(tmp_path):
    """A scenario file: uav1 (priority 1) and uav2 hover 2 m apart at 5 m, in conflict."""
    path = tmp_path / "pair.toml"
    path.write_text("""
name = "pair"
duration_s = 14.0
[[uavs]]
id = "uav1"
priority = 1
start = [0.0, 0.0, 5.0]
goto = [0.0, 0.0, 5.0, 0.0]
[[uavs]]
id = "uav2"
priority = 2
start = [2.0, 0.0, 5.0]
goto = [2.0, 0.0, 5.0, 0.0]
""")
    return path
