"""One UAV's onboard stack (SPEC §1): avoidance → MPC tracker → SE(3) controller.

The stack is what would run on the UAV's own computer. It takes the state estimate and the
predictions other UAVs broadcast, and returns an :class:`~uavmpc.plant.AttitudeTarget` for
whatever stands behind the :class:`~uavmpc.plant.Plant` contract (our simulator, another
simulator, an autopilot), plus its own prediction message to broadcast.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from uavmpc.control import Se3Controller
from uavmpc.plant import Airframe, AttitudeTarget, VehicleState
from uavmpc.reference import Reference
from uavmpc.tracker import (
    DynamicLimits,
    MpcTracker,
    Prediction,
    TrackerConfig,
    TrackerOutput,
)

#: How often the avoidance re-plans (the tracker ticks at 100 Hz, predictions arrive at 2 Hz).
AVOIDANCE_PERIOD_S = 0.1


@dataclass(frozen=True, eq=False)
class OnboardOutput:
    """What one 10 ms tick of the stack produced.

    Attributes:
        tracker: the tracker's command (virtual-UAV state) and prediction.
        target: attitude and collective thrust for the plant side.
    """

    tracker: TrackerOutput
    target: AttitudeTarget


class OnboardStack:
    """Avoidance, tracker and SE(3) controller of one UAV, ticked at the tracker's rate (100 Hz).

    Args:
        airframe: the aircraft (mass, thrust range, SE(3) gains).
        tracker_config: MPC set-up and nominal limits (default: packaged data/tracker.toml).
        position_m, heading_rad, t0_s: the initial virtual-UAV state (usually the UAV's own).
        uav_id, priority: identity on the link (lower priority number = higher priority).
        avoidance: a resolution strategy (see :mod:`uavmpc.avoidance`), or None to fly without
            avoidance (the broadcast flag is then down: others treat this UAV as
            non-cooperative and yield to it).
    """

    def __init__(
        self,
        airframe: Airframe,
        tracker_config: TrackerConfig | None = None,
        *,
        position_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        heading_rad: float = 0.0,
        t0_s: float = 0.0,
        uav_id: str = "uav",
        priority: int = 0,
        avoidance: object | None = None,
    ) -> None:
        self.airframe = airframe
        self.uav_id = uav_id
        self.priority = priority
        self.tracker = MpcTracker(tracker_config, position_m=position_m, heading_rad=heading_rad,
                                  t0_s=t0_s)
        self.period_s = self.tracker.config.first_step_s
        self.controller = Se3Controller(airframe, period_s=self.period_s)
        self.avoidance = avoidance
        self.nominal_limits = self.tracker.limits
        self.decision: object | None = None
        self._last: TrackerOutput | None = None
        self._next_avoidance_s = t0_s
        self._limits_key: tuple[float, float | None, float | None] = (1.0, None, None)

    def set_mission(self, reference: Reference) -> None:
        """Fly a new desired trajectory (validated when the Reference was built)."""
        self.tracker.set_reference(reference)

    @property
    def last_output(self) -> TrackerOutput | None:
        return self._last

    def tick(self, estimate: VehicleState,
             others: Mapping[str, object] | None = None) -> OnboardOutput:
        """One control period: reshape the reference if needed, advance the virtual UAV, then
        steer the real UAV towards it. ``others``: the newest prediction message per sender."""
        self.reshape(others)
        return self.control(self.tracker.step(), estimate)

    # The two halves of :meth:`tick`, for a world that steps the trackers of many UAVs at once
    # (:func:`uavmpc.tracker.tracker.step_trackers`) in between.
    def reshape(self, others: Mapping[str, object] | None,
                prediction: Prediction | None = None) -> None:
        """Avoidance (every AVOIDANCE_PERIOD_S): z offset and limits for the next tracker step.

        ``prediction``: our own current plan, if not the last output's (a world that steps the
        trackers elsewhere, :mod:`uavmpc.world_kernel`, hands it in when due).
        """
        if prediction is None and self._last is not None:
            prediction = self._last.prediction
        if others is None or prediction is None:
            return
        now = float(prediction.times_s[0])
        if self.avoidance_due(now):
            self._next_avoidance_s = now + AVOIDANCE_PERIOD_S
            self._avoid(now, prediction, others)

    def avoidance_due(self, now_s: float) -> bool:
        """Whether :meth:`reshape` would re-plan at time ``now_s`` (the plan's first stamp)."""
        return self.avoidance is not None and now_s >= self._next_avoidance_s - 1e-9

    def control(self, out: TrackerOutput, estimate: VehicleState) -> OnboardOutput:
        """SE(3) control towards the tracker's new command."""
        self._last = out
        target = self.controller.update(out.command, estimate, self.period_s)
        return OnboardOutput(out, target)

    def _avoid(self, now: float, pred: Prediction, others: Mapping[str, object]) -> None:
        # The strategy shifts our plan by candidate offsets; hand it the plan without the part
        # of the current offset the virtual UAV has already climbed at each predicted point
        # (plan minus mission reference, clipped to [0, offset]). Subtracting the whole offset
        # would put the early, still-climbing points below the mission and make the strategy
        # climb again and again for a conflict the climb in progress already resolves.
        own = pred.position_m.copy()
        offset = self.tracker.z_offset_m
        mission = self.tracker.reference
        if offset and mission is not None:
            nominal_z = mission.sample(pred.times_s)[:, 2]
            own[:, 2] -= np.clip(own[:, 2] - nominal_z, 0.0, offset)
        elif offset:
            own[:, 2] -= offset
        decision = self.avoidance.update(  # type: ignore[attr-defined]
            now, self.uav_id, self.priority, pred.times_s, own, others)
        self.decision = decision
        if decision.z_offset_m != self.tracker.z_offset_m:
            self.tracker.set_z_offset(decision.z_offset_m)
        key = (decision.horizontal_scale, decision.climb_speed_mps, decision.climb_accel_mps2)
        if key != self._limits_key:
            self._limits_key = key
            self.tracker.set_limits(avoidance_limits(self.nominal_limits, *key))


def avoidance_limits(nominal: DynamicLimits, horizontal_scale: float,
                     climb_speed_mps: float | None, climb_accel_mps2: float | None
                     ) -> DynamicLimits:
    """Nominal limits, horizontally tightened and with the climb lifted while avoiding."""
    limits = nominal.scaled(horizontal=horizontal_scale)
    if climb_speed_mps is None and climb_accel_mps2 is None:
        return limits
    return DynamicLimits(
        limits.horizontal_speed_mps, limits.horizontal_accel_mps2,
        max(limits.ascend_speed_mps, climb_speed_mps or 0.0),
        max(limits.ascend_accel_mps2, climb_accel_mps2 or 0.0),
        limits.descend_speed_mps, limits.descend_accel_mps2,
        limits.heading_rate_radps, limits.heading_accel_radps2,
    )

