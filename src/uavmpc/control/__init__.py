"""Onboard control below the tracker: the SE(3) position/attitude controller (SPEC §3) and the
autopilot-like attitude controller that the simulated plant runs (SPEC §4)."""

from __future__ import annotations

from uavmpc.control.attitude import AttitudeController, Mixer
from uavmpc.control.se3 import Se3Controller

__all__ = ["AttitudeController", "Mixer", "Se3Controller"]
