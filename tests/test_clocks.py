"""Unsynchronised clocks: the scenario's ``time_reference`` reaches every UAV's inbox and its
avoidance, end to end (the setting is one thing: ``[avoidance] time_reference``)."""

import pytest

from uavmpc import scenarios
from uavmpc.drivers.world import World

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
    world = World(scenarios.load(path), clock_offsets_s=OFFSETS_S, seed=1)
    return world, world.run()


@pytest.mark.parametrize("reference", ["stamp", "receive"])
def test_the_setting_reaches_the_inbox(tmp_path, reference: str) -> None:
    world, _ = _fly(tmp_path, reference)
    for u in world.uavs:
        assert u.stack.inbox.time_reference == reference
        assert u.stack.avoidance.params.time_reference == reference


def test_receive_time_avoids_where_stamps_from_a_clock_ahead_are_refused(tmp_path) -> None:
    stamp_world, stamp = _fly(tmp_path, "stamp", "ack_grace_s = 0.0")
    uav2 = stamp_world.uavs[1].stack.inbox
    # With stamps, every message of the UAV whose clock is ahead looks future-stamped to the
    # one that must yield: it never sees it coming, and without the acknowledgement they
    # collide.
    assert uav2.accepted == 0 and uav2.rejected_total > 40
    assert stamp.collisions
    assert stamp.per_uav["uav2"].max_z_offset_m == 0.0
    # The acknowledgement (on by default, docs/safety.md, A2) saves them: uav2 never lists
    # uav1 as heard, so uav1, the higher priority, climbs over it instead.
    _, acked = _fly(tmp_path, "stamp")
    assert acked.collisions == []
    assert acked.per_uav["uav1"].max_z_offset_m == 3.0
    assert acked.per_uav["uav2"].max_z_offset_m == 0.0

    receive_world, receive = _fly(tmp_path, "receive")
    assert receive_world.uavs[1].stack.inbox.rejected_total == 0
    assert receive.collisions == []
    assert receive.per_uav["uav2"].max_z_offset_m == 3.0  # it yielded one Δz
    assert receive.per_uav["uav1"].max_z_offset_m == 0.0
    assert min(receive.min_distance_m) > 2.5
    assert all(u.reached_goal for u in receive.per_uav.values())
