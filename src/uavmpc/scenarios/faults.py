"""Faults a field team meets, as seeded draws over a scenario's UAVs (SPEC §7).

A :class:`FaultSpec` says what goes wrong and how badly (the flags of ``uavmpc run`` and
``uavmpc campaign``); :func:`draw_faults` turns it into one realisation for one flight, from a
seed, so a trial is replayed exactly from its seeds:

- **clock offsets**: every UAV's clock is ahead of the world's by an offset drawn uniformly in
  ±``clock_offset_s`` (its stamps, its judgement of ages and its schedule run on it). Drift is
  not drawn: a 50 ppm crystal drifts 30 ms over a 10-minute trial, against offsets of 0.5 s;
- **the time reference** the receivers judge ages by (``stamp`` or ``receive``, see
  :class:`~uavmpc.avoidance.AvoidanceParams`), to compare them under offsets;
- **GNSS**: the controllers fly on the output of a state observer fed with GNSS-like
  positions (``single``: a single-band receiver, ``rtk``; :mod:`uavmpc.estimation`);
- **burst loss**: a mean burst length for the link's losses (the Gilbert channel of
  :class:`~uavmpc.comms.link.SimulatedLink`), with the link's own loss rate;
- **non-cooperative UAVs**: ``non_cooperative`` of the UAVs, drawn, fly without avoidance and
  broadcast their flag down (everyone yields to them);
- **silent radios**: ``silent`` of the UAVs, drawn, stop broadcasting at a time drawn
  uniformly over the flight, and keep flying their missions.

The draws come from ``SeedSequence(seed, spawn_key=(FAULT_STREAM,))``: they do not touch the
scenario's or the link's random streams, so a fault changes nothing else of a trial.

A spec acts in three places: the link (its burst length), the scenario (the time reference
its avoidance judges ages by) and the world (offsets, GNSS, non-cooperative and silent UAVs:
the draw, which :class:`uavmpc.drivers.world.World` reads from its run spec).
:func:`apply_faults` is the one place that splits it, for ``uavmpc run`` and every campaign;
:meth:`Faults.given` states a draw by hand (a test's, a replay's).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, Literal, cast

import numpy as np

from uavmpc.config import ConfigError

if TYPE_CHECKING:
    from uavmpc.scenarios import LinkSettings, Scenario

#: The spawn key of the fault draws (any value other streams of a trial do not use).
FAULT_STREAM = 0xFA17
GNSS_CHOICES = ("none", "single", "rtk")
TIME_REFERENCES = ("stamp", "receive")


@dataclass(frozen=True)
class FaultSpec:
    """What goes wrong in a flight (all off by default). See the module docstring."""

    clock_offset_s: float = 0.0
    time_reference: str | None = None
    gnss: str = "none"
    burst_len: float = 0.0
    non_cooperative: int = 0
    silent: int = 0

    def __post_init__(self) -> None:
        v = self.clock_offset_s
        if isinstance(v, bool) or not isinstance(v, int | float) or not (
                math.isfinite(v) and 0.0 <= v <= 10.0):
            raise ConfigError(f"clock_offset_s: must be in [0, 10] s, got {v!r}")
        if self.time_reference is not None and self.time_reference not in TIME_REFERENCES:
            raise ConfigError(f"time_reference: must be one of {TIME_REFERENCES}, got "
                              f"{self.time_reference!r}")
        if self.gnss not in GNSS_CHOICES:
            raise ConfigError(f"gnss: must be one of {GNSS_CHOICES}, got {self.gnss!r}")
        b = self.burst_len
        if isinstance(b, bool) or not isinstance(b, int | float) or not (
                b == 0.0 or (math.isfinite(b) and b >= 1.0)):
            raise ConfigError(f"burst_len: must be 0 or a mean burst length ≥ 1, got {b!r}")
        for name in ("non_cooperative", "silent"):
            k = getattr(self, name)
            if isinstance(k, bool) or not isinstance(k, int) or k < 0:
                raise ConfigError(f"{name}: must be an integer ≥ 0, got {k!r}")

    def active(self) -> dict[str, Any]:
        """The fields not at their defaults (what a run's parameters record)."""
        return {f.name: getattr(self, f.name) for f in fields(self)
                if getattr(self, f.name) != f.default}

    def check(self, n_uavs: int, link_loss: float) -> None:
        """Raise :class:`ConfigError` unless it can act on ``n_uavs`` UAVs over a link losing
        ``link_loss`` of its messages."""
        self.check_uavs(n_uavs)
        self.check_link(link_loss)

    def check_link(self, link_loss: float) -> None:
        """Raise :class:`ConfigError` unless it can act on a link losing ``link_loss``."""
        if self.burst_len and not link_loss:
            raise ConfigError("--burst-loss needs a loss rate: give --loss P with it")

    def check_uavs(self, n: int) -> None:
        """Raise :class:`ConfigError` unless ``n`` UAVs leave room for the drawn ones."""
        if self.non_cooperative + self.silent > n:
            raise ConfigError(f"non_cooperative ({self.non_cooperative}) + silent "
                              f"({self.silent}) exceed the {n} UAVs")
        if self.non_cooperative >= n > 0:
            raise ConfigError(f"non_cooperative: {self.non_cooperative} of {n} UAVs leaves "
                              "none cooperative")


@dataclass(frozen=True)
class Faults:
    """One realisation of a :class:`FaultSpec` for the UAVs of one flight."""

    spec: FaultSpec
    #: Per UAV (scenario order) [s], or None without offsets.
    clock_offsets_s: tuple[float, ...] | None = None
    non_cooperative: tuple[str, ...] = ()
    #: UAV id → when its radio goes silent [s, world time].
    silent_from_s: dict[str, float] = field(default_factory=dict)

    @classmethod
    def given(cls, *, clock_offsets_s: Sequence[float] | None = None,
              non_cooperative: Sequence[str] = (),
              silent_from_s: Mapping[str, float] | None = None, gnss: str = "none",
              time_reference: str | None = None, burst_len: float = 0.0) -> Faults:
        """Faults as given, not drawn (a test's, a replay's): per-UAV clock offsets [s] in
        the scenario's order, the ids of the non-cooperative UAVs, UAV id → when its radio
        goes silent [s, world time]; the rest as in :class:`FaultSpec`. Checked against a
        scenario by :meth:`check_against` (the run spec does)."""
        if isinstance(non_cooperative, str):  # its characters would be taken for ids
            raise ConfigError(f"non_cooperative: a list of UAV ids, not the string "
                              f"{non_cooperative!r}")
        offsets = None
        if clock_offsets_s is not None:
            offsets = tuple(float(v) for v in clock_offsets_s)
            if not all(math.isfinite(v) for v in offsets):
                raise ConfigError(f"clock_offsets_s: must be finite [s], got {offsets!r}")
        silent = {str(k): float(v) for k, v in (silent_from_s or {}).items()}
        if not all(math.isfinite(t) for t in silent.values()):
            raise ConfigError(f"silent_from_s: times must be finite, got {silent!r}")
        spec = FaultSpec(clock_offset_s=max(map(abs, offsets or (0.0,))),
                         time_reference=time_reference, gnss=gnss, burst_len=burst_len,
                         non_cooperative=len(set(non_cooperative)), silent=len(silent))
        return cls(spec, offsets, tuple(dict.fromkeys(non_cooperative)), silent)

    def check_against(self, uav_ids: Sequence[str], scenario_name: str) -> None:
        """Raise :class:`ConfigError` unless every UAV it names is one of ``uav_ids`` and
        its clock offsets are one per UAV."""
        known = set(uav_ids)
        for name, ids in (("non_cooperative", self.non_cooperative),
                          ("silent_from_s", tuple(self.silent_from_s))):
            unknown = sorted(set(ids) - known)
            if unknown:
                raise ConfigError(f"{name}: {', '.join(map(repr, unknown))} not UAVs of the "
                                  f"scenario {scenario_name!r}")
        offsets = self.clock_offsets_s
        if offsets is not None and len(offsets) != len(uav_ids):
            raise ConfigError(f"clock_offsets_s: need {len(uav_ids)} offsets [s], one per "
                              f"UAV, got {len(offsets)}")

    def summary(self) -> dict[str, Any]:
        """JSON-ready: what was drawn."""
        out: dict[str, Any] = dict(self.spec.active())
        if self.clock_offsets_s is not None:
            out["clock_offsets_s"] = [round(v, 6) for v in self.clock_offsets_s]
        if self.non_cooperative:
            out["non_cooperative_uavs"] = list(self.non_cooperative)
        if self.silent_from_s:
            out["silent_from_s"] = {k: round(v, 3) for k, v in self.silent_from_s.items()}
        return out


def draw_faults(spec: FaultSpec, uav_ids: list[str], duration_s: float, start_s: float,
                seed: int) -> Faults:
    """The faults of one flight of ``uav_ids`` over [start_s, start_s + duration_s]."""
    spec.check_uavs(len(uav_ids))
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(FAULT_STREAM,)))
    offsets = None
    if spec.clock_offset_s > 0.0:
        offsets = tuple(float(v) for v in rng.uniform(-spec.clock_offset_s,
                                                      spec.clock_offset_s, len(uav_ids)))
    order = rng.permutation(len(uav_ids))
    non_coop = tuple(uav_ids[i] for i in sorted(order[:spec.non_cooperative]))
    silent_idx = sorted(order[spec.non_cooperative:spec.non_cooperative + spec.silent])
    times = rng.uniform(start_s, start_s + duration_s, len(silent_idx))
    silent = {uav_ids[i]: float(t) for i, t in zip(silent_idx, times, strict=True)}
    return Faults(spec, offsets, non_coop, silent)


def check_faults(spec: FaultSpec, given: Faults | None, uav_ids: Sequence[str],
                 scenario_name: str, link_loss: float) -> None:
    """Raise :class:`ConfigError` unless ``spec`` can act on the UAVs ``uav_ids`` of the
    scenario ``scenario_name`` over a link losing ``link_loss``: drawn, it needs room among
    them; ``given`` (:meth:`Faults.given`), any of them may be named, none other."""
    if given is None:
        spec.check(len(uav_ids), link_loss)
    else:
        spec.check_link(link_loss)
        given.check_against(uav_ids, scenario_name)


def apply_faults(spec: FaultSpec, scenario: Scenario, link: LinkSettings, *, duration_s: float,
                 seed: int, given: Faults | None = None
                 ) -> tuple[Scenario, LinkSettings, Faults]:
    """The one place a :class:`FaultSpec` acts: ``scenario`` with its avoidance's time
    reference, ``link`` with its burst length, and the faults drawn for a flight of
    ``duration_s`` from 0 with ``seed`` (or ``given``, :meth:`Faults.given`, whose spec
    ``spec`` is)."""
    ids = [u.uav_id for u in scenario.uavs]
    check_faults(spec, given, ids, scenario.name, link.loss)
    if spec.burst_len:
        link = dataclasses.replace(link, burst_len=spec.burst_len)
    if spec.time_reference is not None:
        # one of TIME_REFERENCES: FaultSpec.__post_init__ checked it
        time_reference = cast(Literal["stamp", "receive"], spec.time_reference)
        scenario = dataclasses.replace(scenario, avoidance=dataclasses.replace(
            scenario.avoidance, time_reference=time_reference))
    if given is not None:
        return scenario, link, given
    return scenario, link, draw_faults(spec, ids, duration_s, 0.0, seed)
