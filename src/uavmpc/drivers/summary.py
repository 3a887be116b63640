"""A run's summary: how it ended and what it measured, one schema (``summary.json``) for the
simulated world (``uavmpc run``/``demo``) and for a swarm of node processes (``uavmpc swarm``).

The summary is typed: the CLI, plots and campaigns read its fields, never string keys of a
dictionary. It is written with its schema version and read back only at that version, so an old
file is refused by name rather than misread.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import types
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from uavmpc.typed_json import decode, plain

if TYPE_CHECKING:
    from uavmpc.missions.formation import FormationSpec

__all__ = ["SUMMARY_VERSION", "CalmError", "Contact", "ErrorStats", "Formation", "Landing",
           "LinkCounts", "RunStatus", "RunSummary", "SummaryError", "Touchdown", "UavSummary",
           "run_status"]

#: The schema version of ``summary.json`` (raised on any change a reader must know of).
SUMMARY_VERSION = 1


class SummaryError(ValueError):
    """A summary file that cannot be read as this version's (the text says why)."""


class RunStatus(enum.Enum):
    """How a run ended, worst first (:func:`run_status` picks the worst that applies)."""

    #: Two UAVs came closer than the collision distance.
    COLLISION = "collision"
    #: A vehicle stopped flying before the end: its node died or was killed, its autopilot
    #: refused or failed safe, or its motors were cut in the air.
    VEHICLE_STOPPED = "vehicle_stopped"
    #: Stopped before its time (SIGINT/SIGTERM).
    INTERRUPTED = "interrupted"
    #: Flown to its end, but a UAV was not at its goal (or a lander had not landed) by then.
    GOAL_MISSED = "goal_missed"
    #: Flown to its end: no collision, every goal reached, every landing made.
    COMPLETE = "complete"


def run_status(*, collisions: int, reached_goal: Iterable[bool | None],
               stopped: Iterable[str] = (), interrupted: bool = False,
               landed: bool | None = None) -> RunStatus:
    """The one rule for a run's status: the worst of what happened.

    Args:
        collisions: how many contacts closer than the collision distance.
        reached_goal: per UAV, whether it ended at its goal (None: its mission sets its way).
        stopped: the UAVs whose vehicle stopped flying before the end.
        interrupted: the run was stopped before its time.
        landed: a landing's outcome (None: no landing in this run).
    """
    if collisions:
        return RunStatus.COLLISION
    if any(True for _ in stopped):
        return RunStatus.VEHICLE_STOPPED
    if interrupted:
        return RunStatus.INTERRUPTED
    if landed is False or any(r is False for r in reached_goal):
        return RunStatus.GOAL_MISSED
    return RunStatus.COMPLETE


@dataclass(frozen=True)
class Contact:
    """One contact of two UAVs closer than the collision distance.

    Attributes:
        t_s: when it began, on the run's clock (0 = its start) [s].
        a, b: the two UAVs.
        distance_m: the world: its closest approach; a swarm: the distance when it began [m].
    """

    t_s: float
    a: str
    b: str
    distance_m: float


@dataclass(frozen=True)
class LinkCounts:
    """Predictions over the link.

    Attributes:
        sent: predictions sent, one per receiver.
        delivered: predictions a receiver took.
        dropped: predictions lost on the way.
    """

    sent: int
    delivered: int
    dropped: int


@dataclass(frozen=True)
class UavSummary:
    """How one UAV's flight went.

    Attributes:
        max_z_offset_m: the highest offset its avoidance took [m].
        avoidance_active_s: how long its avoidance was active [s] (None: not reported, e.g. a
            node that died).
        tracking_rmse_m: its tracking error [m] (None: not reported).
        reached_goal: it ended within the goal tolerance (None: its mission sets its way, e.g.
            a lander or a formation's follower).
        final_position_m: where it ended, ENU [m] (None: never heard of).
        details: what only its driver knows (the world: limit violations, rejected messages,
            whom it yielded to; a node: its report, its vehicle's, its last state), as JSON.
    """

    max_z_offset_m: float
    avoidance_active_s: float | None
    tracking_rmse_m: float | None
    reached_goal: bool | None
    final_position_m: tuple[float, float, float] | None
    details: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "details", plain(self.details))


@dataclass(frozen=True)
class Touchdown:
    """The first touchdown of a landing.

    Attributes:
        t_s: when [s].
        relative_speed_mps, vertical_speed_mps, horizontal_speed_mps: its speed relative to
            the deck, down, across [m/s].
        offset_m: where on the deck, from its centre, deck frame [m].
        offset_from_centre_m: how far from the deck's centre [m].
        hard: faster down than the airframe's touchdown limit.
    """

    t_s: float
    relative_speed_mps: float
    vertical_speed_mps: float
    horizontal_speed_mps: float
    offset_m: tuple[float, float]
    offset_from_centre_m: float
    hard: bool


@dataclass(frozen=True)
class Landing:
    """How a landing on the moving deck went (``uavmpc.missions.landing.landing_outcome`` and
    its mission's own summary), for the UAV ``uav`` that landed.

    Attributes:
        uav: the UAV that landed (or tried).
        landed: resting on the deck at the end after a soft touchdown.
        time_to_land_s: from the approach's start to the touchdown [s] (None: not landed).
        touchdown: the first touchdown (None: none).
        landed_elsewhere: its motors were cut resting somewhere else than the deck.
        touchdowns, edge_strikes: how many touchdowns, and rotor strikes on the deck's edge.
        on_deck_at_end: on the deck at the end.
        max_touchdown_speed_mps: the airframe's touchdown speed limit [m/s].
        approach_started_s: when the approach began [s] (None: never).
        phases_s: time spent in each phase [s].
        phase: the phase at the end.
        aborts: aborts by reason.
        transitions: (time [s], phase entered), in order.
        fixes_accepted, fixes_rejected, track_restarts: the target filter's fixes taken and
            refused, and how often it restarted its track.
    """

    uav: str
    landed: bool
    time_to_land_s: float | None
    touchdown: Touchdown | None
    landed_elsewhere: bool
    touchdowns: int
    edge_strikes: int
    on_deck_at_end: bool
    max_touchdown_speed_mps: float
    approach_started_s: float | None
    phases_s: Mapping[str, float]
    phase: str
    aborts: Mapping[str, int]
    transitions: tuple[tuple[float, str], ...]
    fixes_accepted: int
    fixes_rejected: int
    track_restarts: int

    @classmethod
    def of(cls, uav: str, outcome: Mapping[str, Any]) -> Landing:
        """The landing of ``uav`` from its outcome's dictionary (every field checked)."""
        return decode(cls, {"uav": uav, **outcome}, "landing", SummaryError)


@dataclass(frozen=True)
class ErrorStats:
    """A distance error.

    Attributes:
        rms_m, max_m: its RMS and its maximum [m].
    """

    rms_m: float
    max_m: float


@dataclass(frozen=True)
class CalmError:
    """The formation error while no member avoids.

    Attributes:
        rms_m, max_m: its RMS and its maximum [m].
        share_of_time: the share of the measured time no member avoided.
    """

    rms_m: float
    max_m: float
    share_of_time: float


@dataclass(frozen=True)
class Formation:
    """How a formation kept its shape, measured from ``measured_from_s`` [s] on.

    Attributes:
        error: every follower's distance from its slot (None: a member was never heard).
        per_follower: the same per follower id.
        while_no_member_avoids: the error while no member avoided (None: never, or unknown).
        outsiders: the UAVs of the scenario that are not members.
    """

    leader: str
    followers: tuple[str, ...]
    measured_from_s: float
    outsiders: tuple[str, ...]
    error: ErrorStats | None
    per_follower: Mapping[str, ErrorStats]
    while_no_member_avoids: CalmError | None

    @classmethod
    def of(cls, spec: FormationSpec, measured_from_s: float, error: Mapping[str, Any] | None,
           outsiders: Iterable[str] = ()) -> Formation:
        """The formation ``spec`` (a ``FormationSpec``) and its error's dictionary
        (``uavmpc.missions.formation.formation_error`` without the series, or None)."""
        calm = None if error is None else error.get("while_no_member_avoids")
        return cls(
            leader=spec.leader, followers=tuple(spec.followers),
            measured_from_s=float(measured_from_s), outsiders=tuple(outsiders),
            error=None if error is None else ErrorStats(error["rms"], error["max"]),
            per_follower={} if error is None else {
                k: ErrorStats(v["rms"], v["max"]) for k, v in error["per_follower"].items()},
            while_no_member_avoids=None if calm is None else CalmError(
                calm["rms"], calm["max"], calm["share_of_time"]))


@dataclass(frozen=True)
class RunSummary:
    """A run's summary (``summary.json``).

    Attributes:
        driver: ``world`` (the simulated world) or ``swarm`` (node processes).
        status: how the run ended (:func:`run_status`).
        scenario, avoidance, duration_s: what was flown, with avoidance or not, for how
            long [s].
        seed: the run's seed (None for a swarm: real time has none).
        collisions: every contact, in time order.
        min_distance_m: the closest any two UAVs came [m] (None with one UAV).
        uavs: per UAV id.
        messages: the link's predictions.
        wall_s, realtime_factor: the run's wall time and simulated seconds per wall second
            (None for a swarm, which runs in real time).
        landing: a landing's outcome, or None.
        formation: a formation's error and members, or None.
        sections: the reports of the parts a run had (see :data:`SECTIONS`), each the JSON of
            its own report.
    """

    driver: str
    status: RunStatus
    scenario: str
    seed: int | None
    avoidance: bool
    duration_s: float
    collisions: tuple[Contact, ...]
    min_distance_m: float | None
    uavs: Mapping[str, UavSummary]
    messages: LinkCounts
    wall_s: float | None = None
    realtime_factor: float | None = None
    landing: Landing | None = None
    formation: Formation | None = None
    sections: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.driver not in DRIVERS:
            raise ValueError(f"driver: one of {', '.join(DRIVERS)}, not {self.driver!r}")
        object.__setattr__(self, "sections", plain(self.sections))

    def with_sections(self, **sections: object) -> RunSummary:
        """This summary with ``sections`` added (or replaced)."""
        return dataclasses.replace(self, sections={**self.sections, **sections})

    def to_json(self) -> dict[str, Any]:
        """The ``summary.json`` object (JSON has no infinity or NaN: those are refused)."""
        return {"version": SUMMARY_VERSION, **plain(dataclasses.asdict(self))}

    def write(self, path: str | Path) -> None:
        """Write ``summary.json`` to ``path``."""
        Path(path).write_text(json.dumps(self.to_json(), indent=2, allow_nan=False) + "\n")

    @classmethod
    def from_json(cls, data: object, source: str = "summary") -> RunSummary:
        """A summary from its JSON object.

        Raises:
            SummaryError: another version, or a field missing, unknown or of the wrong kind
                (named).
        """
        if not isinstance(data, dict):
            raise SummaryError(f"{source}: not a JSON object")
        version = data.get("version")
        if version != SUMMARY_VERSION:
            raise SummaryError(f"{source}: summary version {version!r}, this uavmpc reads "
                               f"version {SUMMARY_VERSION} (re-run to write it anew)")
        body = {k: v for k, v in data.items() if k != "version"}
        try:
            return decode(cls, body, source, SummaryError)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, SummaryError):
                raise
            raise SummaryError(f"{source}: {exc}") from None

    @classmethod
    def read(cls, path: str | Path) -> RunSummary:
        """Read ``summary.json`` at ``path`` (errors name the file)."""
        p = Path(path)
        try:
            data = json.loads(p.read_text())
        except (OSError, ValueError) as exc:
            raise SummaryError(f"{p}: cannot read: {exc}") from None
        return cls.from_json(data, str(p))


#: The drivers that write a summary.
DRIVERS = ("world", "swarm")

#: The sections a summary may have: name → what it holds.
SECTIONS = {
    "link": "the simulated link's loss and latency (world)",
    "faults": "the faults drawn for the run (world, --faults)",
    "geofence": "per fenced UAV, its geofence watch's report (world)",
    "launch": "the launch check: the longest wait and when each UAV launched (world)",
    "non_cooperative": "the UAVs that flew without avoidance while the others avoided (world)",
    "traffic": "the generated traffic's outcome (world, scenario traffic)",
    "timing": "where a batched run's wall time went (world)",
    "flight_log": "the flight log's file name, or null (world)",
    "transport": "the transport between the nodes (swarm)",
    "vehicles": "what the nodes flew (swarm)",
    "closest_by_pair_m": "each pair's closest approach [m] (swarm)",
    "px4_sitl": "the PX4 SITL build and the geographic origin (swarm, --px4-sitl)",
}


def summary_fields() -> list[tuple[str, str, type, str]]:
    """Every field of ``summary.json`` as (dotted name, JSON type, the dataclass that holds
    it, its name there), from the dataclasses: the file reference cannot drift from the code.
    ``version`` is the schema's (held by none: its class is :class:`RunSummary`)."""
    rows: list[tuple[str, str, type, str]] = [("version", "int", RunSummary, "version")]

    def walk(cls: type, prefix: str) -> None:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            tp = hints[f.name]
            rows.append((prefix + f.name, _type_name(tp), cls, f.name))
            for inner in _dataclasses_in(tp):
                sep = "{}." if _is_mapping(tp) else "[]." if _is_tuple(tp) else "."
                walk(inner, prefix + f.name + sep)

    walk(RunSummary, "")
    return rows


def _is_mapping(tp: object) -> bool:
    return typing.get_origin(_strip_none(tp)) in (Mapping, dict)


def _is_tuple(tp: object) -> bool:
    return typing.get_origin(_strip_none(tp)) is tuple


def _strip_none(tp: object) -> object:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        rest = [a for a in typing.get_args(tp) if a is not type(None)]
        return rest[0] if len(rest) == 1 else tp
    return tp


def _dataclasses_in(tp: object) -> list[type]:
    tp = _strip_none(tp)
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return [tp]
    if typing.get_origin(tp) in (Mapping, dict):
        return _dataclasses_in(typing.get_args(tp)[1])
    if typing.get_origin(tp) is tuple:
        return _dataclasses_in(typing.get_args(tp)[0])
    return []


def _type_name(tp: object) -> str:
    if tp is Any:
        return "any JSON"
    if isinstance(tp, type):
        if issubclass(tp, enum.Enum):
            return " | ".join(repr(m.value) for m in tp)
        return {"float": "number", "int": "int", "bool": "bool", "str": "string"}.get(
            tp.__name__, "object")
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join("null" if a is type(None) else _type_name(a) for a in args)
    if origin in (Mapping, dict):
        return f"object of {_type_name(args[1])}"
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_name(args[0])}"
        return f"[{', '.join(_type_name(a) for a in args)}]"
    return str(tp)
