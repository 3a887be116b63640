"""Missions that feed the tracker a *predicted* trajectory (SPEC §6): they turn observations
into a :class:`~uavmpc.reference.Reference`, and live outside the onboard stack."""
