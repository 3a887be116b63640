"""The simulated world on a ROS 2 graph (``uavmpc run SCENARIO --ros2 ROUTER`` or
``--ros2-dds [DOMAIN]``).

Where a world, a swarm or a node appears is one string (:func:`open_graph`): a Zenoh router's
endpoint for rmw_zenoh, or ``dds/<domain>`` for ROS 2's DDS middlewares.

:class:`WorldOnRos2` is called by :meth:`World.run <uavmpc.drivers.world.World.run>` at its log
rate (20 Hz): it publishes every UAV's topics as a node would (:class:`~uavmpc.comms.ros2.
UavTopics`), its plan each time the UAV broadcasts one, and hands the goals and trajectories
that arrived from ROS 2 to the UAV's stack through the same validation as every mission.
Stamps are wall-clock: the world's time plus the epoch at which it started, so that ROS 2 tools
see a live system; a trajectory's stamps are read back on the world's clock.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from uavmpc.comms.ros2 import Ros2Graph, RosGraph, UavTopics
from uavmpc.geofence import GeofenceError
from uavmpc.missions.format import mission_from_table
from uavmpc.onboard import OnboardStack
from uavmpc.reference import Reference

if TYPE_CHECKING:
    from uavmpc.drivers.world import World

__all__ = ["DDS_PREFIX", "WorldOnRos2", "dds_where", "open_graph", "publish_plan",
           "publish_status", "require_graph", "ros2_mission"]

#: ``dds/<domain>``: the graph is a DDS domain (``--ros2-dds``), not a Zenoh router.
DDS_PREFIX = "dds/"


def dds_where(domain_id: int | None) -> str:
    """``--ros2-dds [DOMAIN]`` as a graph's place: ``dds/<domain>``; no domain given:
    ``ROS_DOMAIN_ID``, else 0 (as ROS 2 picks it)."""
    if domain_id is None:
        domain_id = int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    if not 0 <= int(domain_id) <= 232:
        raise ValueError(f"--ros2-dds: a ROS domain id is in 0..232, got {domain_id!r}")
    return f"{DDS_PREFIX}{int(domain_id)}"


def require_graph(where: str) -> None:
    """Raise ImportError, naming the extra to install, unless the graph ``where`` can open."""
    from uavmpc.comms.ros2 import Ros2Codec

    Ros2Codec()
    if where.startswith(DDS_PREFIX):
        from uavmpc.comms.dds import require

        require()


def open_graph(where: str, node_name: str) -> RosGraph:
    """The ROS 2 node ``node_name`` on the graph ``where``: a Zenoh router's endpoint
    (rmw_zenoh, :class:`~uavmpc.comms.ros2.Ros2Graph`) or ``dds/<domain>``
    (:class:`~uavmpc.comms.dds.DdsGraph`). Raises ValueError / OSError naming the problem, and
    ImportError with the extra to install."""
    if where.startswith(DDS_PREFIX):
        from uavmpc.comms.dds import DdsGraph

        domain = where[len(DDS_PREFIX):]
        if not domain.isdigit():
            raise ValueError(f"{where!r}: expected dds/<domain id>")
        return DdsGraph(int(domain), node_name=node_name)
    return Ros2Graph(where, node_name=node_name)


def ros2_mission(times: np.ndarray | None, points: np.ndarray, now_s: float) -> Reference:
    """A mission from ROS 2, in the one mission format (:mod:`uavmpc.missions.format`): one
    pose is a go-to from now; a path has its stamps, or (all zero) is sampled every 0.2 s from
    now."""
    table: dict[str, Any]
    if len(points) == 1:
        table = {"goto": points[0]}
    elif times is None:
        table = {"trajectory": {"points": points}}
    else:
        table = {"trajectory": {"times_s": times, "points": points}}
    return mission_from_table(table, "ros2 mission", now_s)


def publish_status(topics: UavTopics, stamp_s: float, stack: OnboardStack,
                   broken: Sequence[str] = ()) -> None:
    """The avoidance's state of ``stack`` on ``/<id>/avoidance``: its decision's, what its
    prediction messages carry (the ids heard, the stated position uncertainty), and the
    assumptions its driver finds ``broken`` now (:mod:`uavmpc.assumptions`)."""
    d = stack.steering.decision
    sigma_h, sigma_v = stack.position_sigma_m
    topics.publish_avoidance(stamp_s, bool(d is not None and d.avoiding),
                             stack.tracker.z_offset_m,
                             list(d.yielding_to) if d is not None else [],
                             heard=list(stack.heard), position_sigma_horizontal_m=sigma_h,
                             position_sigma_vertical_m=sigma_v,
                             holding=bool(d is not None and d.holding),
                             deaf=list(d.deaf) if d is not None else [], broken=list(broken))


def publish_plan(topics: UavTopics, stamp_s: float, stack: OnboardStack,
                 epoch_s: float = 0.0) -> None:
    """The plan ``stack`` broadcast last on ``/<id>/prediction`` (its times + ``epoch_s``)."""
    b = stack.last_broadcast
    if b is not None:
        topics.publish_prediction(stamp_s, b.times_s + epoch_s, b.position_m, b.heading_rad)


class WorldOnRos2:
    """Mirror ``uav_ids`` of a world on ``graph``; ``commands``: take ROS 2 missions."""

    def __init__(self, graph: RosGraph, uav_ids: Sequence[str], *, commands: bool = True,
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
                publish_status(topics, stamp, u.stack)
            if u.stack.predictions_sent != self._sent[u.uav_id]:
                self._sent[u.uav_id] = u.stack.predictions_sent
                publish_plan(topics, stamp, u.stack, self.epoch_s)
            refs, rejected = topics.missions(now, self._mission(now))
            self.missions_rejected += rejected
            for ref in refs:  # as a node takes them: checked against the geofence, flown
                fence = u.supervisor.fence  # under its ceiling by the supervisor
                if fence is not None:
                    try:
                        fence.check_mission(ref)
                    except GeofenceError as e:
                        fence.refused += 1
                        self.missions_rejected.append(f"{u.uav_id}: {e}")
                        continue
                u.supervisor.fly(ref)
                self.missions_taken += 1

    def _mission(self, now: float) -> Callable[[np.ndarray | None, np.ndarray], Reference]:
        def build(times: np.ndarray | None, points: np.ndarray) -> Reference:
            return ros2_mission(None if times is None else times - self.epoch_s, points, now)
        return build
