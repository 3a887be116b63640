"""One UAV's supervision beside its onboard stack: what decides *which* trajectory it flies.

:class:`~uavmpc.onboard.OnboardStack` flies a desired trajectory (and avoids the others); a
:class:`Supervisor` chooses that trajectory, the same way under every driver (the simulated
world, a network node, a node flying a PX4):

- the **launch hold** (docs/safety.md, A1 at the start): a UAV holds where it is, its mission
  waiting, until its driver launches it (the world: once its inbox holds a prediction from
  every other UAV, :meth:`heard_from`, or a deadline passed; a node: once the vehicle is its
  to fly);
- the **mission** stepped beside the stack (:mod:`uavmpc.missions`) at its period: a new
  trajectory, or a **motor cut**, after which the stack only follows where the UAV rests
  (:meth:`~uavmpc.onboard.OnboardStack.follow`: broadcast it, flag down);
- the **geofence** (:class:`FenceGuard`): missions checked against the volume, the
  avoidance's ceiling over the mission flown, and the failsafe: a UAV found outside flies back
  to a point inside and holds there, its mission stopped.

A supervisor holds no numbers of the flight: its decisions are calls on its stack. The world
keeps one per UAV and steps them together (it computes the fence margins of all UAVs in one
call and hands each its own).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from uavmpc.avoidance.encounters import heard_from_all
from uavmpc.geofence import FenceWatch, Geofence
from uavmpc.missions.mission import Mission, MissionInput
from uavmpc.onboard import OnboardStack
from uavmpc.plant import VehicleState
from uavmpc.reference import Reference

#: Tolerance of the mission's schedule against round-off in the tick times [s].
_SCHEDULE_TOL_S = 1e-9
#: A change of the highest height a trajectory may ask for [m] (:meth:`FenceGuard.top_m`)
#: smaller than this does not set the trajectory again: an estimator's σ wanders each cycle.
_TOP_TOL_M = 0.25
#: The geofence failsafe looks every this many control ticks (10 Hz at 100 Hz, the
#: avoidance's rate), in every driver (:meth:`Supervisor.fence_due`).
FENCE_CHECK_TICKS = 10


class FenceGuard:
    """One UAV's geofence duty: its failsafe (:class:`~uavmpc.geofence.FenceWatch`), the
    missions it refused for leaving the volume, the avoidance's ceiling over a mission."""

    def __init__(self, geofence: Geofence) -> None:
        self.geofence = geofence
        self.watch = FenceWatch(geofence)
        #: Missions from the network refused for leaving the volume (counted by the driver
        #: that took them).
        self.refused = 0
        #: The most a trajectory was lowered to stay under the ceiling (:meth:`capped`) [m].
        self.capped_m = 0.0

    def check_mission(self, reference: Reference) -> None:
        """Accept ``reference`` as the next mission (it replaces a failsafe's hold).

        Raises:
            GeofenceError: it leaves the volume (the message says where).
        """
        self.geofence.check_reference(reference)
        self.watch.mission_accepted()

    def needs_look(self, margin_m: float) -> bool:
        """A UAV at ``margin_m`` [m] from the walls needs :meth:`recovery` (outside, or not
        yet inside once); else nothing can change."""
        return not (margin_m >= 0.0) or not self.watch.entered

    def recovery(self, own_s: float, position_m: np.ndarray, heading_rad: float,
                 margin_m: float | None = None, *, offset_m: float = 0.0,
                 sigma_above_m: float = 0.0) -> Reference | None:
        """The failsafe's trajectory when ``position_m`` (3,) is a new exit: back to a point
        inside from ``own_s`` (the UAV's clock) on, holding ``heading_rad``; else None.
        ``margin_m``: the position's margin, if the caller computed it in a batch.

        The point is where the UAV is to be, avoidance offset ``offset_m`` [m] included: the
        trajectory (the mission's frame, under the offset) is that far below it, and no
        higher than the inset below the ceiling less ``sigma_above_m`` (how far above its
        estimate it may truly be). Found under every fault at once: the way back put the
        offset on top of a point at the ceiling, and UAVs held 30 m above it."""
        back = self.watch.check(position_m, margin_m)
        if back is None:
            return None
        fence = self.geofence
        low = fence.min_altitude_m + fence.inset_m
        total = max(low, min(float(back[2]), fence.max_altitude_m - fence.inset_m
                             - sigma_above_m))
        return Reference.goto(back[0], back[1], max(low, total - offset_m), heading_rad,
                              start_s=own_s)

    def ceiling_m(self, z_m: np.ndarray) -> float:
        """The avoidance's ceiling [m] over a mission at heights ``z_m`` (K,)."""
        return self.geofence.offset_ceiling_m(z_m)

    def top_m(self, sigma_above_m: float) -> float:
        """The highest estimated height [m] a trajectory may ask for: ``margin_m`` under the
        ceiling, less ``sigma_above_m`` (how far above its estimate the UAV may truly be),
        and never under the floor's margin."""
        fence = self.geofence
        return max(fence.min_altitude_m + fence.margin_m,
                   fence.max_altitude_m - fence.margin_m - sigma_above_m)

    def capped(self, reference: Reference, sigma_above_m: float) -> Reference:
        """``reference`` with no point above :meth:`top_m` (those points lowered to it, their
        times kept); itself when none is. A mission checked against the volume by its
        estimate may still take the truth over the ceiling: found by the falsifier with
        single-band GNSS (σ_v 2.5 m), walks to 29 m under a 30 m ceiling flew to 34.7 m."""
        top = self.top_m(sigma_above_m)
        z = reference.points[:, 2]
        if not (z > top).any():
            return reference
        self.capped_m = max(self.capped_m, float(z.max()) - top)
        points = reference.points.copy()
        points[:, 2] = np.minimum(z, top)
        return Reference(reference.times_s, points, reference.loop)

    def report(self) -> dict[str, Any]:
        """The failsafe's report, the missions refused and the most a trajectory was lowered
        under the ceiling (:meth:`capped`) [m]."""
        return {**self.watch.report(), "missions_refused": self.refused,
                "capped_m": self.capped_m}


class Supervisor:
    """The supervision of one :class:`~uavmpc.onboard.OnboardStack` (see the module).

    Args:
        stack: the program it steers.
        mission: a mission stepped beside the stack (then the source of its trajectory).
        fence: the geofence duty, or None without a geofence.
        launched: False holds the UAV until :meth:`launch` (:meth:`hold` gives the mission
            that waits).
    """

    def __init__(self, stack: OnboardStack, *, mission: Mission | None = None,
                 fence: FenceGuard | None = None, launched: bool = True) -> None:
        self.stack = stack
        self.mission = mission
        self.fence = fence
        self.launched = launched
        #: The mission waiting for the launch, if any.
        self.held: Reference | None = None
        #: When the mission is next stepped, on the driver's clock [s].
        self.next_mission_s = 0.0
        #: The mission cut the motors (the UAV rests; its stack follows it).
        self.motors_cut = False
        #: Paused (:meth:`pause`): the trajectory that waits for :meth:`resume`.
        self.paused: Reference | None = None
        #: The fence's room for an offset over the mission flown [m], before the UAV's
        #: uncertainty is taken off (None before the first trajectory, or without a fence).
        self._fence_room_m: float | None = None
        #: Its estimator's vertical 1σ [m] as a driver states it (:meth:`state_sigma`).
        self._estimate_sigma_v_m: float | None = None
        #: The last trajectory given to :meth:`_steer`, before the ceiling lowered it, and the
        #: highest height it was given under then [m] (:meth:`FenceGuard.capped`).
        self._commanded: Reference | None = None
        self._top_m = math.inf
        #: What :meth:`_steer` gave the stack last (the commanded trajectory, lowered).
        self._flown: Reference | None = None

    # ------------------------------------------------------------------ launch hold
    def hold(self, mission: Reference, hover: Reference) -> None:
        """Hold: fly ``hover`` (where it starts) while ``mission`` waits for :meth:`launch`."""
        self.launched = False
        self.held = mission
        self._steer(hover)

    def heard_from(self, own_s: float, peers: Sequence[int] | np.ndarray) -> bool:
        """Its inbox holds a prediction from every column of ``peers`` of its table that its
        encounters count (fresh, or silent at most ``silent_hold_s`` old) at ``own_s``."""
        prm = self.stack.params
        return bool(heard_from_all(self.stack.inbox.table.rows, self.stack.row,
                                   np.asarray(peers, dtype=np.int64), own_s,
                                   prm.time_reference == "receive", prm.timeout_s,
                                   prm.silent_hold_s))

    def unheard(self, own_s: float, peers: Sequence[int] | np.ndarray) -> list[int]:
        """The columns of ``peers`` it has not heard from (:meth:`heard_from`)."""
        return [int(c) for c in np.asarray(peers).tolist()
                if not self.heard_from(own_s, np.array([c]))]

    def launch(self, reference: Reference | None = None) -> None:
        """Set off: fly the mission held (else ``reference``, if any)."""
        self.launched = True
        ref, self.held = (self.held if self.held is not None else reference), None
        if ref is not None:
            self._steer(ref)

    # ------------------------------------------------------------------ mission
    def mission_due(self, now_s: float) -> bool:
        """A mission steps beside the stack, its period has passed (driver's clock) and no
        pause holds it (:meth:`pause`)."""
        return (self.mission is not None and self.paused is None
                and now_s >= self.next_mission_s - _SCHEDULE_TOL_S)

    def step_mission(self, now_s: float, own_s: float, estimate: VehicleState,
                     touching: bool = False, fixes: Sequence[Any] = ()) -> bool:
        """Step the mission (due: :meth:`mission_due`) at ``now_s`` (driver's clock) with what
        the UAV knows at ``own_s`` (its clock): its estimate, its land detector, its inbox's
        plans, the target fixes. A new trajectory is flown; a motor cut makes the stack
        follow the UAV where it rests. Returns True when the motors are cut now, the first
        time (the driver cuts them)."""
        assert self.mission is not None
        self.next_mission_s = now_s + self.mission.period_s
        out = self.mission.step(MissionInput(own_s, estimate, touching, self.stack.inbox.latest,
                                             fixes))
        if out.cut_motors:
            first = not self.motors_cut
            self.motors_cut = True
            # Where it rests is what it will do: broadcast that, flag down (others avoid it).
            self.stack.follow(own_s, estimate)
            return first
        if out.reference is not None:
            self._steer(out.reference)
        return False

    # ------------------------------------------------------------------ an assumption broke
    def pause(self, hover: Reference) -> None:
        """Hold at ``hover`` (an assumption of the safety argument broke,
        :mod:`uavmpc.assumptions`); the trajectory flown until now waits for :meth:`resume`,
        and so does any mission commanded meanwhile."""
        if self.paused is None:
            self.paused = self.stack.tracker.reference
        self._steer(hover)

    def resume(self) -> None:
        """Fly the trajectory that waited since :meth:`pause` (on its own clock: a path
        resumes where it would be now)."""
        ref, self.paused = self.paused, None
        if ref is not None:
            self._steer(ref)

    # ------------------------------------------------------------------ geofence
    def fly(self, reference: Reference) -> None:
        """Fly a commanded mission (checked against the geofence already), or, paused, keep
        it for :meth:`resume`."""
        if self.paused is not None:
            self.paused = reference
            return
        self._steer(reference)

    def _steer(self, reference: Reference) -> None:
        """Every trajectory the stack is given passes here (the launch hold, the mission and
        its steps, a pause and its end, the fence's way back): the avoidance's ceiling over
        it, then the trajectory. A mission step that climbs lowers the room left above it
        (found: a walk's waypoint higher than the first kept the first's ceiling)."""
        self._commanded = reference
        if self.fence is not None:
            sigma_above = self._sigma_above_m()
            self._top_m = self.fence.top_m(sigma_above)
            reference = self.fence.capped(reference, sigma_above)
        self._flown = reference
        self.limit_ceiling(reference.points[:, 2])
        self.stack.set_mission(reference)

    def limit_ceiling(self, z_m: np.ndarray) -> None:
        """With a geofence, the avoidance climbs no higher than its ceiling over a mission at
        heights ``z_m`` (K,) [m], lowered by ``uncertainty_k`` of the vertical σ the UAV states
        (A3: where its estimate is at the ceiling, its truth may lie that far above; found
        with single-band GNSS, a UAV raised to the ceiling was outside by its truth)."""
        if self.fence is not None:
            self._fence_room_m = self.fence.ceiling_m(z_m)
            self._limit_offset()

    def state_sigma(self, sigma_m: tuple[float, float], estimate_sigma_v_m: float) -> None:
        """The (horizontal, vertical) 1σ [m] the UAV states from now on
        (:attr:`~uavmpc.onboard.OnboardStack.position_sigma_m`), and its estimator's own
        vertical 1σ [m], which the avoidance's ceiling follows from now on (what is stated
        may add the tracking error, which the fence's margin covers: the world states its
        estimator's σ alone). Found on real PX4: EKF2's σ arrives after the mission is set,
        and a ceiling taken with none let a vehicle sit at the top layer while its truth
        drifted 1.2 m above its estimate, past the fence's 1 m margin."""
        if not (math.isfinite(estimate_sigma_v_m) and estimate_sigma_v_m >= 0.0):
            raise ValueError(f"estimate_sigma_v_m: must be finite and ≥ 0, got "
                             f"{estimate_sigma_v_m}")
        self.stack.position_sigma_m = sigma_m
        self._estimate_sigma_v_m = float(estimate_sigma_v_m)
        if self.fence is None or self._commanded is None:
            return
        top = self.fence.top_m(self._sigma_above_m())
        # Only the trajectory it set is set again: a driver may have given the stack its own
        # since (a node's landing).
        if (abs(top - self._top_m) > _TOP_TOL_M
                and self.stack.tracker.reference is self._flown
                and float(self._commanded.points[:, 2].max()) > min(top, self._top_m)):
            self._steer(self._commanded)  # the trajectory flown is lowered (or raised) to it
        elif self._fence_room_m is not None:
            self._limit_offset()

    def _limit_offset(self) -> None:
        assert self._fence_room_m is not None
        room_m = self._fence_room_m - self._sigma_above_m()
        self.stack.steering.limit_offset(max(0.0, room_m))

    def _sigma_above_m(self) -> float:
        """How far above its estimate the UAV may truly be [m]: ``uncertainty_k`` σ_v of its
        estimator (:meth:`state_sigma`; until a driver states it, the σ its stack states)."""
        sigma_v = (self.stack.position_sigma_m[1] if self._estimate_sigma_v_m is None
                   else self._estimate_sigma_v_m)
        return float(self.stack.params.uncertainty_k) * sigma_v

    def fence_due(self, tick: int) -> bool:
        """With a geofence, whether control tick ``tick`` (counted by the driver) is one the
        failsafe looks at (:data:`FENCE_CHECK_TICKS`)."""
        return self.fence is not None and tick % FENCE_CHECK_TICKS == 0

    def watch_fence(self, own_s: float, position_m: np.ndarray, heading_rad: float,
                    margin_m: float | None = None) -> bool:
        """The failsafe (with a geofence): a UAV found outside at ``position_m`` flies back in
        from ``own_s`` on and holds; its mission, if one steps beside it, stops. Returns True
        when it engaged."""
        if self.fence is None:
            return False
        ref = self.fence.recovery(own_s, position_m, heading_rad, margin_m,
                                  offset_m=self.stack.tracker.z_offset_m,
                                  sigma_above_m=self._sigma_above_m())
        if ref is None:
            return False
        self.failsafe(ref)
        return True

    def failsafe(self, recovery: Reference) -> None:
        """Fly ``recovery`` (back inside the geofence, :meth:`FenceGuard.recovery`) and hold:
        its mission, if one steps beside it, stops; a pause ends (the way back in comes
        first)."""
        self.mission = None
        self.paused = None
        self.fly(recovery)
