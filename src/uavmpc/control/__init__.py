"""Onboard control below the tracker: the SE(3) position/attitude controller (SPEC §3).

The autopilot-like attitude loop that flies its targets belongs to the plant
(:mod:`uavmpc.plant.attitude`); this package builds on the plant's contract, never the other way
round.
"""

from __future__ import annotations

from uavmpc.control.se3 import ControlRows, Se3Controller, se3_law, se3_row

__all__ = ["ControlRows", "Se3Controller", "se3_law", "se3_row"]
