"""One UAV's onboard stack (SPEC §1): reference → MPC tracker → SE(3) controller.

The stack is what would run on the UAV's own computer. It takes the state estimate and returns
an :class:`~uavmpc.plant.AttitudeTarget` for whatever stands behind the
:class:`~uavmpc.plant.Plant` contract (our simulator, another simulator, an autopilot).
"""

from __future__ import annotations

from dataclasses import dataclass

from uavmpc.control import Se3Controller
from uavmpc.plant import Airframe, AttitudeTarget, VehicleState
from uavmpc.reference import Reference
from uavmpc.tracker import MpcTracker, TrackerConfig, TrackerOutput


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
    """Tracker and SE(3) controller of one UAV, ticked at the tracker's rate (100 Hz).

    Args:
        airframe: the aircraft (mass, thrust range, SE(3) gains).
        tracker_config: MPC set-up and nominal limits (default: packaged data/tracker.toml).
        position_m, heading_rad, t0_s: the initial virtual-UAV state (usually the UAV's own).
    """

    def __init__(
        self,
        airframe: Airframe,
        tracker_config: TrackerConfig | None = None,
        *,
        position_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        heading_rad: float = 0.0,
        t0_s: float = 0.0,
    ) -> None:
        self.airframe = airframe
        self.tracker = MpcTracker(tracker_config, position_m=position_m, heading_rad=heading_rad,
                                  t0_s=t0_s)
        self.period_s = self.tracker.config.first_step_s
        self.controller = Se3Controller(airframe, period_s=self.period_s)

    def set_mission(self, reference: Reference) -> None:
        """Fly a new desired trajectory (validated when the Reference was built)."""
        self.tracker.set_reference(reference)

    def tick(self, estimate: VehicleState) -> OnboardOutput:
        """One control period: advance the virtual UAV, then steer the real one towards it."""
        out = self.tracker.step()
        target = self.controller.update(out.command, estimate, self.period_s)
        return OnboardOutput(out, target)
