"""The simulated world on a ROS 2 graph (``uavmpc run SCENARIO --ros2 ROUTER``).

:class:`WorldOnRos2` is called by :meth:`World.run <uavmpc.drivers.world.World.run>` at its log
rate (20 Hz): it publishes every UAV's topics as a node would (:class:`~uavmpc.comms.ros2.
UavTopics`), its plan each time the UAV broadcasts one, and hands the goals and trajectories
that arrived from ROS 2 to the UAV's stack through the same validation as every mission.
Stamps are wall-clock: the world's time plus the epoch at which it started, so that ROS 2 tools
see a live system; a trajectory's stamps are read back on the world's clock.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from uavmpc.comms.ros2 import Ros2Graph, UavTopics
from uavmpc.drivers.node import ros2_mission
from uavmpc.drivers.world import World

__all__ = ["WorldOnRos2"]


class WorldOnRos2:
    """Mirror ``uav_ids`` of a world on ``graph``; ``commands``: take ROS 2 missions."""

    def __init__(self, graph: Ros2Graph, uav_ids: Sequence[str], *, commands: bool = True,
                 epoch_s: float | None = None) -> None:
        self.topics = {u: UavTopics(graph, u, commands=commands) for u in uav_ids}
        self.epoch_s = time.time() if epoch_s is None else float(epoch_s)
        self._sent = dict.fromkeys(uav_ids, 0)
        self._calls = 0
        self.missions_taken = 0
        self.missions_rejected: list[str] = []

    def __call__(self, world: World) -> None:
        now = world.t_s
        stamp = self.epoch_s + now
        self._calls += 1
        for u in world.uavs:
            topics = self.topics[u.uav_id]
            s = u.plant.state()
            topics.publish_state(stamp, s.position_m, s.velocity_mps, s.attitude_wxyz,
                                 s.body_rates_radps)
            if self._calls % 2 == 0:  # 10 Hz, the avoidance's rate
                d = u.stack.decision
                topics.publish_avoidance(stamp, bool(d is not None and d.avoiding),
                                         u.stack.tracker.z_offset_m,
                                         list(d.yielding_to) if d is not None else [])
            if u.stack.predictions_sent != self._sent[u.uav_id] \
                    and u.stack.last_broadcast is not None:
                self._sent[u.uav_id] = u.stack.predictions_sent
                b = u.stack.last_broadcast
                topics.publish_prediction(stamp, b.times_s + self.epoch_s, b.position_m,
                                          b.heading_rad)
            refs, rejected = topics.missions(now, self._mission(now))
            self.missions_rejected += rejected
            for ref in refs:
                u.stack.set_mission(ref)
                self.missions_taken += 1

    def _mission(self, now: float) -> Any:
        def build(times: np.ndarray | None, points: np.ndarray) -> Any:
            return ros2_mission(None if times is None else times - self.epoch_s, points, now)
        return build
