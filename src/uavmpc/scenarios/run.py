"""One flight, specified: a scenario and how it is flown (:class:`RunSpec`).

Every driver takes a flight as one :class:`RunSpec`: the world
(:class:`uavmpc.drivers.world.World`), the swarm of node processes
(:func:`uavmpc.drivers.swarm.run_swarm`, which hands each node its part as a
:class:`~uavmpc.drivers.launch.NodeLaunch`) and every campaign (one spec per trial, from the
campaign's own spec in ``campaign.json``). It is frozen and validated when made: a bad value is a
:class:`~uavmpc.config.ConfigError` naming the field, before anything flies.

A spec is its scenario plus :class:`RunSettings`, how any scenario is flown: a campaign holds
one as the template of its trials and makes each trial's spec with
:meth:`RunSettings.for_scenario`, so a field and its check are written once.

The faults act in one place, :attr:`RunSpec.flown` (:func:`~uavmpc.scenarios.faults.
apply_faults`): the scenario with its avoidance's time reference, the link with its burst
length, and one draw of offsets, non-cooperative and silent UAVs from the run's seed.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, Self, TypedDict, Unpack

import numpy as np

from uavmpc.config import ConfigError
from uavmpc.scenarios import LinkSettings, Scenario
from uavmpc.scenarios.faults import Faults, FaultSpec, apply_faults, check_faults


@dataclass(frozen=True)
class FlownRun:
    """What a :class:`RunSpec` flies once its faults have acted: the scenario (its
    avoidance's time reference set), the link (its burst length set) and the faults drawn."""

    scenario: Scenario
    link: LinkSettings
    faults: Faults


class RunSettingsChanges(TypedDict, total=False):
    """The fields :meth:`RunSettings.replace` may change (a :class:`RunSettings` field each)."""

    avoidance: bool
    seed: int
    link: LinkSettings | None
    faults: FaultSpec
    drawn: Faults | None
    wind_mps: float
    launch_check_s: float | None
    duration_s: float | None


class RunChanges(RunSettingsChanges, total=False):
    """The fields :meth:`RunSpec.replace` may change (a :class:`RunSpec` field each)."""

    scenario: Scenario


@dataclass(frozen=True, kw_only=True)
class RunSettings:
    """How a flight is flown, whatever its scenario: with or without ``avoidance``, over
    ``link`` (None: the scenario's), with ``faults``, seeded by ``seed`` (the link's losses,
    the wind's gusts and the fault draws), in a mean wind of ``wind_mps`` along x [m/s], held
    at the start by a launch check of at most ``launch_check_s`` [s] (None: every UAV sets off
    at once), for ``duration_s`` [s] (None: the scenario's). ``drawn``: the faults as given
    instead of drawn from ``faults`` and the seed (:meth:`~uavmpc.scenarios.faults.Faults.
    given`: a test's or a replay's clock offsets, non-cooperative and silent UAVs); ``faults``
    is then its spec.

    A template: a campaign's trials fly it over scenarios of their own
    (:meth:`for_scenario`). Checked when made as far as it can be without a scenario; the
    rest (the faults against the UAVs, the launch check within the flight, the given faults'
    UAVs) when it meets one (:meth:`check_flight`, :class:`RunSpec`)."""

    avoidance: bool = True
    seed: int = 0
    link: LinkSettings | None = None
    faults: FaultSpec = field(default_factory=FaultSpec)
    drawn: Faults | None = None
    wind_mps: float = 0.0
    launch_check_s: float | None = None
    duration_s: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.avoidance, bool):
            raise ConfigError(f"avoidance: must be true or false, got {self.avoidance!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed: must be an integer ≥ 0, got {self.seed!r}")
        if not isinstance(self.faults, FaultSpec):
            raise ConfigError(f"faults: must be a FaultSpec, got {type(self.faults).__name__}")
        if self.drawn is not None:
            if not isinstance(self.drawn, Faults):
                raise ConfigError(f"drawn: must be Faults, got {type(self.drawn).__name__}")
            if self.faults == FaultSpec():
                object.__setattr__(self, "faults", self.drawn.spec)
            elif self.faults != self.drawn.spec:
                raise ConfigError("faults: given with drawn faults, must be their spec "
                                  f"({self.drawn.spec}), got {self.faults}")
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
                               or not (math.isfinite(lc) and lc >= 0.0)):
            raise ConfigError(f"launch_check_s: the launch check's longest wait must be a "
                              f"time ≥ 0 s, got {lc!r}")
        if d is not None:  # the flight's length is known without its scenario
            self._check_launch_within(float(d))

    def _check_launch_within(self, flight_s: float) -> None:
        lc = self.launch_check_s
        if lc is not None and lc > flight_s:
            raise ConfigError(f"launch_check_s: the launch check's longest wait must be a "
                              f"time in [0, the flight's {flight_s:g} s], got {lc!r}")

    def check_flight(self, uav_ids: Sequence[str], scenario_name: str, link: LinkSettings,
                     flight_s: float) -> None:
        """Raise :class:`ConfigError` unless it can fly the UAVs ``uav_ids`` of the scenario
        ``scenario_name`` over ``link`` (before the faults' burst length) for ``flight_s``
        [s]: what a scenario adds to the checks."""
        self._check_launch_within(flight_s)
        check_faults(self.faults, self.drawn, uav_ids, scenario_name, link.loss)

    def replace(self, **changes: Unpack[RunSettingsChanges]) -> Self:
        """A copy with ``changes`` (validated again)."""
        return dataclasses.replace(self, **changes)

    def for_scenario(self, scenario: Scenario) -> RunSpec:
        """The flight of ``scenario`` flown with these settings (checked against it)."""
        return RunSpec(scenario, **{f.name: getattr(self, f.name)
                                    for f in dataclasses.fields(RunSettings)})


@dataclass(frozen=True, eq=False)
class RunSpec(RunSettings):
    """One flight: ``scenario`` flown with the :class:`RunSettings` (``RunSpec(scenario,
    seed=1, ...)``, or a template's :meth:`~RunSettings.for_scenario`). Equal to itself
    only: a scenario holds arrays."""

    scenario: Scenario

    __eq__ = object.__eq__
    __hash__ = object.__hash__

    def __post_init__(self) -> None:
        if not isinstance(self.scenario, Scenario):
            raise ConfigError(f"scenario: must be a Scenario, got {type(self.scenario).__name__}")
        super().__post_init__()
        self.check_flight([u.uav_id for u in self.scenario.uavs], self.scenario.name,
                          self.run_link, self.flight_s)

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
                                             duration_s=self.flight_s, seed=self.seed,
                                             given=self.drawn)
        return FlownRun(scenario, link, drawn)

    def replace(self, **changes: Unpack[RunChanges]) -> Self:
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


class Outcome(Protocol):
    """What a flown UAV's outcome tells the scenarios' own measures."""

    @property
    def reached_goal(self) -> bool | None: ...


class Contact(Protocol):
    """A collision of a flown run: the two UAVs."""

    @property
    def a(self) -> str: ...

    @property
    def b(self) -> str: ...


class Flight(Protocol):
    """A flown run as the scenarios measure it (a driver's result, e.g. the world's
    ``WorldResult``): its times (K,) [s], positions (K, N, 3) [m] and closest distances (K,)
    [m], its UAVs' ids and outcomes, its collisions."""

    @property
    def t_s(self) -> np.ndarray: ...

    @property
    def positions_m(self) -> np.ndarray: ...

    @property
    def min_distance_m(self) -> np.ndarray: ...

    @property
    def uav_ids(self) -> list[str]: ...

    @property
    def per_uav(self) -> Mapping[str, Outcome]: ...

    @property
    def collisions(self) -> Sequence[Contact]: ...

