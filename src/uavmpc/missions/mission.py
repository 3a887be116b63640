"""The contract between a mission and the driver that runs it.

A mission runs beside a UAV's onboard stack, at its own period, on what that UAV has: its own
state estimate, its land detector, the newest prediction of every other UAV its inbox accepted
(the same messages the avoidance uses), and the fixes of any target it observes. It answers
with a new desired trajectory for the tracker, or none (keep flying the current one), and may
cut the motors once landed. It never touches the stack itself, so the same mission runs in the
simulated world (:class:`~uavmpc.drivers.world.World`) and on a node
(:class:`~uavmpc.drivers.node.Node`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from uavmpc.comms.message import PredictionMessage
from uavmpc.plant.interface import VehicleState
from uavmpc.plant.sensors import TargetFix
from uavmpc.reference import Reference

__all__ = ["CommandedMission", "Mission", "MissionInput", "MissionOutput"]


@dataclass(frozen=True, eq=False)
class MissionInput:
    """What a mission sees at one step.

    Attributes:
        t_s: the UAV's clock [s].
        estimate: its state estimate (ENU, SI).
        landed: its land detector: resting on a surface (the ground, a deck), or touching
            one (a contact switch on the landing gear).
        neighbours: the newest prediction per other UAV its inbox accepted (may be stale).
        fixes: target fixes received since the last step, oldest first.
    """

    t_s: float
    estimate: VehicleState
    landed: bool
    neighbours: Mapping[str, PredictionMessage]
    fixes: Sequence[TargetFix] = ()


@dataclass(frozen=True, eq=False)
class MissionOutput:
    """What a mission asks for.

    Attributes:
        reference: the tracker's new desired trajectory, or None to keep the current one.
        cut_motors: stop the motors (landed: the driver cuts them and from then on broadcasts
            the UAV where it rests, flag down).
    """

    reference: Reference | None = None
    cut_motors: bool = False


@runtime_checkable
class Mission(Protocol):
    """A mission: stepped every :attr:`period_s` by its driver."""

    @property
    def period_s(self) -> float:  # read-only: a mission may compute it (LandingMission)
        ...

    def step(self, inp: MissionInput) -> MissionOutput:
        """One step at ``inp.t_s`` (non-decreasing between calls)."""
        ...

    def summary(self) -> dict[str, Any]:
        """What it did, for the run's summary (JSON-serialisable)."""
        ...


@runtime_checkable
class CommandedMission(Mission, Protocol):
    """A mission that also takes commands while it flies (a formation follower's shape
    changes): a node hands it each payload that arrives on ``uavmpc/<swarm>/<sender>/formation``
    (checked with ``isinstance``; a plain :class:`Mission` hears none)."""

    def command(self, payload: bytes, now_s: float) -> bool:
        """Take the command ``payload`` (its raw bytes) at ``now_s`` [s, the UAV's clock]:
        True if it changed the mission, False for a repeat of one already taken; a bad one
        raises ValueError naming the problem (the node counts it rejected)."""
        ...
