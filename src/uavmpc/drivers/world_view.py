"""What a :class:`~uavmpc.drivers.world.World` shows and logs of its UAVs: the 3-D scene
(Foxglove ``SceneUpdate``), the plot-ready metrics, and the poses and status of the flight
log — all read from the world's UAVs (their stacks and plants), none written back."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from uavmpc.plant.interface import heading_of
from uavmpc.view.scene import (
    ObjectView,
    UavView,
    detail_of,
    ground_around,
    metrics_update,
    scene_update,
    state_of,
)

if TYPE_CHECKING:
    from uavmpc.drivers.world import World

#: Period of the 3-D scene and the metrics in logs and live views [s].
SCENE_PERIOD_S = 0.1
#: The ground vehicle's name in logs (``/ground_vehicle/state``: its deck's centre).
GROUND_VEHICLE_ID = "ground_vehicle"


class WorldScene:
    """The scene, the metrics and the pose log of ``world`` at its current time."""

    def __init__(self, world: World) -> None:
        self.world = world
        self._ground: dict[str, Any] | None = None  # the scene's ground, made once
        #: When the scene is next due [s, world time].
        self.next_scene_s = -math.inf

    def show(self, min_distance_m: float | None,
              on_scene: Callable[[float, dict[str, Any], dict[str, Any]], None] | None) -> None:
        """The 3-D scene and the metrics now, to the log and to ``on_scene``."""
        w = self.world
        self.next_scene_s = w.t_s + SCENE_PERIOD_S
        views = self.views()
        scene = self.scene(views)
        metrics = self.metrics(min_distance_m, views)
        if w.recorder is not None:
            w.recorder.scene(w.t_s, scene)
            w.recorder.metrics(w.t_s, metrics)
        if on_scene is not None:
            on_scene(w.t_s, scene, metrics)

    def views(self) -> list[UavView]:
        """Every flying UAV as the 3-D scene shows it now (:mod:`uavmpc.view.scene`)."""
        w = self.world
        out = []
        for u in w.uavs:
            stack = u.stack
            if stack.last_output is None:
                continue
            s = u.plant.state()
            d = stack.steering.decision
            plan = stack.last_broadcast
            desired = np.zeros((0, 3))
            ref = stack.tracker.reference
            if plan is not None and ref is not None:
                desired = ref.sample(plan.times_s)[:, :3]
            silent = w.t_s >= w.silent_from_s.get(u.uav_id, math.inf)
            state = state_of(silent=silent, waiting_for=d.waiting_for if d else (),
                             yielding_to=d.yielding_to if d else (),
                             z_offset_m=stack.tracker.z_offset_m,
                             avoiding=bool(d is not None and d.avoiding))
            detail = detail_of(yielding_to=d.yielding_to if d else (),
                               waiting_for=d.waiting_for if d else ())
            out.append(UavView(
                u.uav_id, s.position_m, float(heading_of(s.attitude_wxyz)),
                plan.position_m if plan is not None else np.zeros((0, 3)), desired,
                stack.tracker.z_offset_m, state, stack.params.radius_m, stack.params.height_m,
                detail))
        return out

    def scene(self, views: Sequence[UavView] | None = None) -> dict[str, Any]:
        """The ``foxglove.SceneUpdate`` of now: the UAVs (``views``, default :meth:`views`),
        the ground, the geofence, the car and its deck."""
        w = self.world
        if self._ground is None:
            self._ground = ground_around(w.scenario.points_m())
        objects = []
        if w.ground_vehicle is not None:
            car = w.ground_vehicle.state(w.t_s)
            deck = w.ground_vehicle.deck_size_m
            x, y, deck_z = (float(v) for v in car.position_m)
            objects = [  # the car's body under its deck
                ObjectView("car", np.array([x, y, 0.5 * deck_z]), car.heading_rad,
                           (2.0 * deck, deck, deck_z), (0.2, 0.2, 0.25, 1.0)),
                ObjectView("deck", car.position_m, car.heading_rad, (deck, deck, 0.05),
                           (0.95, 0.85, 0.2, 1.0))]
        fence = None
        if w.geofence is not None:
            g = w.geofence
            fence = (g.polygon_xy_m, g.min_altitude_m, g.max_altitude_m)
        return scene_update(w.t_s, self.views() if views is None else views, fence=fence,
                            objects=objects,
                            ground=self._ground)

    def metrics(self, min_distance_m: float | None,
                views: Sequence[UavView] | None = None) -> dict[str, Any]:
        """The plot-ready numbers of now: the closest pair's distance and, per UAV, its
        cylinder state and whom it yields to or waits for (``views``, default
        :meth:`views`), its z offset, how far its virtual UAV is outside the limits, its
        tracker fallbacks."""
        w = self.world
        rows = {u.uav_id: {"z_offset_m": u.stack.tracker.z_offset_m,
                           "limit_excess": u.stack.tracker.limit_excess(),
                           "tracker_fallbacks": u.stack.tracker.fallback_count,
                           "avoiding": bool(u.stack.steering.decision is not None
                                            and u.stack.steering.decision.avoiding)}
                for u in w.uavs}
        return metrics_update(w.t_s, min_distance_m, self.views() if views is None else views,
                              rows)

    def log(self) -> None:
        """The poses (state, command, reference) and status of every flying UAV, and the
        ground vehicle's pose, into the world's recorder."""
        w = self.world
        rec = w.recorder
        assert rec is not None
        if w.ground_vehicle is not None:
            car = w.ground_vehicle.state(w.t_s)
            rec.pose(GROUND_VEHICLE_ID, "state", w.t_s, car.position_m, car.heading_rad)
        for u in w.uavs:
            last = u.stack.last_output
            if last is None:
                continue
            s = u.plant.state()
            rec.pose(u.uav_id, "state", w.t_s, s.position_m, float(heading_of(s.attitude_wxyz)))
            c = last.command
            rec.pose(u.uav_id, "command", w.t_s, c.position_m, c.heading_rad)
            ref = u.stack.tracker.reference
            if ref is not None:
                r = ref.sample(np.array([w.t_s]))[0]
                rec.pose(u.uav_id, "reference", w.t_s, r[:3], float(r[3]))
            decision = u.stack.steering.decision
            sigma_h, sigma_v = u.stack.position_sigma_m
            rec.status(u.uav_id, w.t_s,
                       velocity_mps=s.velocity_mps.tolist(),
                       command_velocity_mps=c.velocity_mps.tolist(),
                       z_offset_m=u.stack.tracker.z_offset_m,
                       avoiding=bool(decision is not None and decision.avoiding),
                       conflicts=list(decision.conflicts) if decision is not None else [],
                       yielding_to=list(decision.yielding_to) if decision is not None else [],
                       holding=bool(decision is not None and decision.holding),
                       deaf=list(decision.deaf) if decision is not None else [],
                       heard=list(u.stack.heard), position_sigma_horizontal_m=sigma_h,
                       position_sigma_vertical_m=sigma_v,
                       limit_excess=u.stack.tracker.limit_excess(),
                       braking=bool(last.braking))
