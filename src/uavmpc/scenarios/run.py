"""One flight, specified: a scenario and how it is flown (:class:`RunSpec`).

Every driver takes a flight as one :class:`RunSpec`: the world
(:meth:`uavmpc.drivers.world.World.from_spec`), the swarm of node processes
(:func:`uavmpc.drivers.swarm.run_swarm`, which hands each node its part as a
:class:`~uavmpc.drivers.launch.NodeLaunch`) and every campaign (one spec per trial, from the
campaign's own spec in ``campaign.json``). It is frozen and validated when made: a bad value is a
:class:`~uavmpc.config.ConfigError` naming the field, before anything flies.

The faults act in one place, :attr:`RunSpec.flown` (:func:`~uavmpc.scenarios.faults.
apply_faults`): the scenario with its avoidance's time reference, the link with its burst
length, and one draw of offsets, non-cooperative and silent UAVs from the run's seed.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Any

from uavmpc.config import ConfigError
from uavmpc.scenarios import LinkSettings, Scenario
from uavmpc.scenarios.faults import Faults, FaultSpec, apply_faults


@dataclass(frozen=True)
class FlownRun:
    """What a :class:`RunSpec` flies once its faults have acted: the scenario (its
    avoidance's time reference set), the link (its burst length set) and the faults drawn."""

    scenario: Scenario
    link: LinkSettings
    faults: Faults


@dataclass(frozen=True, eq=False)
class RunSpec:
    """One flight: ``scenario`` flown with or without ``avoidance``, over ``link`` (None: the
    scenario's), with ``faults``, seeded by ``seed`` (the link's losses, the wind's gusts and the
    fault draws), in a mean wind of ``wind_mps`` along x [m/s], held at the start by a launch
    check of at most ``launch_check_s`` [s] (None: every UAV sets off at once), for
    ``duration_s`` [s] (None: the scenario's)."""

    scenario: Scenario
    avoidance: bool = True
    seed: int = 0
    link: LinkSettings | None = None
    faults: FaultSpec = field(default_factory=FaultSpec)
    wind_mps: float = 0.0
    launch_check_s: float | None = None
    duration_s: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.scenario, Scenario):
            raise ConfigError(f"scenario: must be a Scenario, got {type(self.scenario).__name__}")
        if not isinstance(self.avoidance, bool):
            raise ConfigError(f"avoidance: must be true or false, got {self.avoidance!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed: must be an integer ≥ 0, got {self.seed!r}")
        if not isinstance(self.faults, FaultSpec):
            raise ConfigError(f"faults: must be a FaultSpec, got {type(self.faults).__name__}")
        if self.link is not None:  # a replaced field is not checked by LinkSettings itself
            object.__setattr__(self, "link",
                               LinkSettings.from_dict(dataclasses.asdict(self.link)))
        w = self.wind_mps
        if isinstance(w, bool) or not isinstance(w, int | float) or not (
                math.isfinite(w) and 0.0 <= w <= 30.0):
            raise ConfigError(f"wind_mps: must be in [0, 30] m/s, got {w!r}")
        d = self.duration_s
        if d is not None and (isinstance(d, bool) or not isinstance(d, int | float)
                              or not (math.isfinite(d) and d > 0.0)):
            raise ConfigError(f"duration_s: must be > 0 s, got {d!r}")
        lc = self.launch_check_s
        if lc is not None and (isinstance(lc, bool) or not isinstance(lc, int | float)
                               or not (math.isfinite(lc) and 0.0 <= lc <= self.flight_s)):
            raise ConfigError(f"launch_check_s: must be a time in [0, the flight's "
                              f"{self.flight_s:g} s], got {lc!r}")
        self.faults.check(len(self.scenario.uavs), self.run_link.loss)

    @property
    def flight_s(self) -> float:
        """How long it flies [s]."""
        return self.scenario.duration_s if self.duration_s is None else float(self.duration_s)

    @property
    def run_link(self) -> LinkSettings:
        """The link it is flown over, before the faults' burst length."""
        return self.scenario.link if self.link is None else self.link

    @functools.cached_property
    def flown(self) -> FlownRun:
        """The scenario, link and fault draw it flies (the faults applied, once)."""
        scenario, link, drawn = apply_faults(self.faults, self.scenario, self.run_link,
                                             duration_s=self.flight_s, seed=self.seed)
        return FlownRun(scenario, link, drawn)

    def replace(self, **changes: Any) -> RunSpec:
        """A copy with ``changes`` (validated again)."""
        return dataclasses.replace(self, **changes)

    def describe(self) -> dict[str, Any]:
        """JSON-ready: the settings it flies (a summary's or a flight log's parameters)."""
        out: dict[str, Any] = {"scenario": self.scenario.name, "avoidance": self.avoidance,
                               "seed": self.seed, "duration_s": self.flight_s,
                               "link": dataclasses.asdict(self.flown.link)}
        if self.wind_mps:
            out["wind_mps"] = float(self.wind_mps)
        if self.launch_check_s is not None:
            out["launch_check_s"] = float(self.launch_check_s)
        if self.faults.active():
            out["faults"] = self.flown.faults.summary()
        return out
