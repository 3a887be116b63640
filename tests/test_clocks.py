"""Unsynchronised clocks: the scenario's ``time_reference`` reaches every UAV's inbox and its
avoidance, end to end (the setting is one thing: ``[avoidance] time_reference``)."""

import pytest

from uavmpc import scenarios
from uavmpc.drivers.world import World
from uavmpc.scenarios.faults import Faults
from uavmpc.scenarios.run import RunSpec

HEAD_ON = """
name = "head_on"
duration_s = 25.0
[avoidance]
time_reference = "{reference}"
{extra}
[[uavs]]
id = "uav1"
priority = 1
start = [-20.0, 0.0, 5.0]
goto = [20.0, 0.0, 5.0, 0.0]
[[uavs]]
id = "uav2"
priority = 2
start = [20.0, 0.0, 5.0]
goto = [-20.0, 0.0, 5.0, 0.0]
"""
#: uav1's clock runs 0.7 s ahead of uav2's: more than the 0.5 s a stamp may lie in the future.
OFFSETS_S = (0.7, 0.0)


def _fly(tmp_path, reference: str, extra: str = ""):
    path = tmp_path / f"{reference}{len(extra)}.toml"
    path.write_text(HEAD_ON.format(reference=reference, extra=extra))
    world = World(RunSpec(scenarios.load(path), seed=1,
                          drawn=Faults.given(clock_offsets_s=OFFSETS_S)))
    return world, world.run()


@pytest.mark.parametrize("reference", ["stamp", "receive"])
def test_the_setting_reaches_the_inbox(tmp_path, reference: str) -> None:
    world, _ = _fly(tmp_path, reference)
    for u in world.uavs:
        assert u.stack.inbox.time_reference == reference
        assert u.stack.avoidance.params.time_reference == reference


def test_a_clock_ahead_is_measured_with_stamps_and_ignored_with_receive_times(tmp_path) -> None:
    """uav1's clock runs 0.7 s ahead: its stamps look future-stamped to uav2, which must
    yield. Refused, uav2 never saw it coming (they collided without the acknowledgement).
    Now uav2's inbox measures the offset and puts uav1's messages on its own clock: uav2
    yields one layer, as with the receive-time reference, even without the acknowledgement."""
    for extra in ("ack_grace_s = 0.0", ""):
        stamp_world, stamp = _fly(tmp_path, "stamp", extra)
        uav2 = stamp_world.uavs[1].stack.inbox
        assert uav2.rejected_total <= 1 and uav2.accepted > 40  # its first, before measured
        assert uav2.latest["uav1"].received_s is not None  # put on uav2's clock
        assert stamp.collisions == []
        assert stamp.per_uav["uav2"].max_z_offset_m == 3.0
        assert stamp.per_uav["uav1"].max_z_offset_m == 0.0
        assert min(stamp.min_distance_m) > 2.5

    receive_world, receive = _fly(tmp_path, "receive")
    assert receive_world.uavs[1].stack.inbox.rejected_total == 0
    assert receive.collisions == []
    assert receive.per_uav["uav2"].max_z_offset_m == 3.0  # it yielded one Δz
    assert receive.per_uav["uav1"].max_z_offset_m == 0.0
    assert min(receive.min_distance_m) > 2.5
    assert all(u.reached_goal for u in receive.per_uav.values())
