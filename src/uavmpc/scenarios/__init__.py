"""Scenarios: who flies where, over which link, with which avoidance (SPEC §6).

A scenario is a TOML file (the built-ins live in this package as such files) validated on load
with errors that name the field, e.g. ``uavs[2].priority: duplicate of uavs[0]``.

    name = "swap_through_static"
    duration_s = 60.0
    [link]       latency_s, jitter_s, loss, range_m (0 = unlimited),
                 burst_len (mean burst of losses in messages; 0 = independent losses)
    [avoidance]  any AvoidanceParams field (defaults: the reference design)
    [limits]     any DynamicLimits field: every UAV's nominal limits (default: data/tracker.toml)
    [[uavs]]     id, priority, airframe, start = [x, y, z], heading_rad,
                 at most one of goto, trajectory or path: the UAV's mission, in the one
                   mission format (uavmpc.missions.format; none: hold at the start)
                 avoidance = true/false (default true; false: a non-cooperative UAV, flying
                   its mission without avoidance, its flag down: the others yield to it)

Field applications (SPEC §6) add their tables:

    [ground_vehicle]  a car on a figure-eight track carrying a landing deck: speed_kmh,
                      track_length_m, track_width_m, track_centre = [x, y], start_arc_m,
                      deck_size_m, deck_height_m
    [target_sensor]   the lander's fixes of the car: rate_hz, sigma_m, dropout
    [landing]         uav = id, and any LandingParams field (uavmpc.missions.landing)
    [formation]       leader, followers, spacing_m, shape, changes = [{ t_s, shape }, ...],
                      transition_s, member_radius_m, heading_rad (uavmpc.missions.formation)
    [geofence]        polygon = [[x, y], ...] or box = [x0, y0, x1, y1], min_altitude_m,
                      max_altitude_m, margin_m, inset_m (uavmpc.geofence)
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from uavmpc.avoidance import AvoidanceParams
from uavmpc.config import ConfigError, from_table, positive, read_toml, reject_unknown, take
from uavmpc.geofence import Geofence, GeofenceError
from uavmpc.missions.format import FORMS, mission_from_table
from uavmpc.missions.formation import FormationSpec
from uavmpc.missions.landing import LandingParams
from uavmpc.plant.ground_vehicle import KMH, FigureEightTrack, GroundVehicle
from uavmpc.reference import InvalidReferenceError, Reference
from uavmpc.tracker.params import DynamicLimits, TrackerConfig

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

#: The built-in conflicts: UAVs whose paths collide without avoidance, which the avoidance
#: resolves, every UAV but the highest priority climbing over another (SPEC §6). The last is
#: adversarial: a non-cooperative UAV through a hovering group (benchmarks/sweep_dense.py).
CONFLICTS = ("swap_through_static", "converge_center", "noncooperative_crossing")
#: Dense conflicts: N UAVs meeting above one point at once (uavmpc.scenarios.dense,
#: benchmarks/sweep_dense.py). Not everyone need climb (two neighbours may pass just outside
#: the cylinder); and 12 are beyond the layers: they need 12, dz_m = 3 m under the ceiling
#: max_offset_m = 30 m gives 11, so the lowest priority holds short until the way is clear
#: (antipodal_8 is not among CONFLICTS for the first reason, antipodal_12 for the second).
DENSE = ("antipodal_8", "antipodal_12")
#: The built-in field applications (uavmpc.missions).
APPLICATIONS = ("moving_target_landing", "moving_target_landing_30kmh", "formation")
BUILTIN = CONFLICTS + DENSE + APPLICATIONS
_ID = re.compile(r"[A-Za-z0-9_-]{1,32}")  # with fullmatch: "$" would let a final "\n" in


@dataclass(frozen=True)
class LinkSettings:
    """The simulated broadcast link: latency = latency_s + U(0, jitter_s), loss probability,
    optional range limit (0 = unlimited), mean burst of losses ``burst_len`` in messages (0 =
    independent losses; see :class:`~uavmpc.comms.link.SimulatedLink`)."""

    latency_s: float = 0.05
    jitter_s: float = 0.02
    loss: float = 0.0
    range_m: float = 0.0
    burst_len: float = 0.0

    @classmethod
    def from_dict(cls, t: dict[str, Any], prefix: str = "link") -> LinkSettings:
        reject_unknown(t, {"latency_s", "jitter_s", "loss", "range_m", "burst_len"}, prefix)
        d = cls()
        loss = positive(t.get("loss", d.loss), f"{prefix}.loss", upper=1.0, allow_zero=True)
        if loss >= 1.0:
            raise ConfigError(f"{prefix}.loss: must be < 1, got {loss}")
        burst = positive(t.get("burst_len", d.burst_len), f"{prefix}.burst_len", upper=1e6,
                         allow_zero=True)
        if 0.0 < burst < 1.0:
            raise ConfigError(f"{prefix}.burst_len: must be 0 (independent losses) or a mean "
                              f"burst length ≥ 1 (messages), got {burst}")
        # The Gilbert channel needs P(good→bad) = loss / ((1 − loss) burst_len) ≤ 1.
        if burst > 0.0 and loss > burst * (1.0 - loss) * (1.0 + 1e-12):
            raise ConfigError(f"{prefix}.burst_len: {burst:g} with loss={loss:g} needs "
                              f"P(good→bad) = {loss / ((1.0 - loss) * burst):.3g} > 1 (need "
                              f"burst_len ≥ loss / (1 − loss) = {loss / (1.0 - loss):.3g})")
        return cls(
            latency_s=positive(t.get("latency_s", d.latency_s), f"{prefix}.latency_s",
                               upper=10.0, allow_zero=True),
            jitter_s=positive(t.get("jitter_s", d.jitter_s), f"{prefix}.jitter_s", upper=10.0,
                              allow_zero=True),
            loss=loss,
            range_m=positive(t.get("range_m", d.range_m), f"{prefix}.range_m", allow_zero=True),
            burst_len=burst,
        )


@dataclass(frozen=True)
class LimitOverrides:
    """The ``[limits]`` of a scenario: the :class:`~uavmpc.tracker.params.DynamicLimits`
    fields it sets for every UAV, validated; the others stay the tracker set-up's (so it is an
    override, not a whole set: a tracker set-up with other limits keeps those it does not set).
    False when it sets none."""

    #: (field, value) pairs, sorted by field; each value valid for its field.
    values: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        table = dict(self.values)
        reject_unknown(table, {f.name for f in dataclasses.fields(DynamicLimits)}, "limits")
        full = DynamicLimits(**{**dataclasses.asdict(DynamicLimits()), **table})  # validates
        object.__setattr__(self, "values",
                           tuple(sorted((k, getattr(full, k)) for k in table)))

    @classmethod
    def from_dict(cls, t: object, prefix: str = "limits") -> LimitOverrides:
        if not isinstance(t, dict):
            raise ConfigError(f"{prefix}: must be a table")
        return cls(tuple(t.items()))  # DynamicLimits names a bad field as limits.<field>

    def __bool__(self) -> bool:
        return bool(self.values)

    def as_dict(self) -> dict[str, float]:
        return dict(self.values)

    def apply(self, base: DynamicLimits) -> DynamicLimits:
        """``base`` with these fields replaced."""
        return DynamicLimits(**{**dataclasses.asdict(base), **dict(self.values)})

    def over(self, config: TrackerConfig | None) -> TrackerConfig | None:
        """``config`` (None: the packaged one) with these limits over its own; ``config`` as
        given when they set none. Every driver takes a scenario's limits through this."""
        if not self.values:
            return config
        base = config if config is not None else TrackerConfig.from_toml()
        return dataclasses.replace(base, limits=self.apply(base.limits))


@dataclass(frozen=True)
class TargetSensorSettings:
    """Fixes of an observed target: rate [Hz], white noise per horizontal axis [m], dropout
    probability."""

    rate_hz: float = 20.0
    sigma_m: float = 0.3
    dropout: float = 0.1

    def __post_init__(self) -> None:
        p = "target_sensor"
        object.__setattr__(self, "rate_hz", positive(self.rate_hz, f"{p}.rate_hz", upper=1000.0))
        object.__setattr__(self, "sigma_m", positive(self.sigma_m, f"{p}.sigma_m", upper=100.0,
                                                     allow_zero=True))
        dropout = positive(self.dropout, f"{p}.dropout", upper=1.0, allow_zero=True)
        if dropout >= 1.0:
            raise ConfigError(f"{p}.dropout: must be < 1, got {dropout}")
        object.__setattr__(self, "dropout", dropout)

    @classmethod
    def from_dict(cls, t: dict[str, Any], prefix: str = "target_sensor") -> TargetSensorSettings:
        return from_table(cls, t, prefix)


def _ground_vehicle(t: dict[str, Any], prefix: str = "ground_vehicle") -> GroundVehicle:
    if not isinstance(t, dict):
        raise ConfigError(f"{prefix}: must be a table")
    reject_unknown(t, {"speed_kmh", "track_length_m", "track_width_m", "track_centre",
                       "start_arc_m", "deck_size_m", "deck_height_m"}, prefix)
    centre = _vec(t.get("track_centre", [0.0, 0.0]), 2, f"{prefix}.track_centre")
    track = FigureEightTrack(
        positive(t.get("track_length_m", 90.0), f"{prefix}.track_length_m", upper=1e4),
        positive(t.get("track_width_m", 60.0), f"{prefix}.track_width_m", upper=1e4),
        (centre[0], centre[1]))
    start_arc = t.get("start_arc_m", 0.0)
    _vec([start_arc], 1, f"{prefix}.start_arc_m")
    return GroundVehicle(
        track, speed_mps=positive(t.get("speed_kmh", 15.0), f"{prefix}.speed_kmh", upper=200.0,
                                  allow_zero=True) * KMH,
        start_arc_m=float(start_arc),
        deck_size_m=positive(t.get("deck_size_m", 1.5), f"{prefix}.deck_size_m", upper=100.0),
        deck_height_m=positive(t.get("deck_height_m", 1.5), f"{prefix}.deck_height_m",
                               upper=100.0, allow_zero=True))


@dataclass(frozen=True, eq=False)
class UavSpec:
    """One UAV of a scenario. ``mission`` is the desired trajectory (absolute times)."""

    uav_id: str
    priority: int
    airframe: str
    start_m: tuple[float, float, float]
    heading_rad: float
    mission: Reference
    goal_m: tuple[float, float, float]
    #: False: it flies without avoidance, broadcasting its flag down (non-cooperative: the
    #: others yield to it).
    avoidance: bool = True


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario."""

    name: str
    duration_s: float
    uavs: tuple[UavSpec, ...]
    link: LinkSettings = field(default_factory=LinkSettings)
    #: The avoidance parameters every UAV flies (``[avoidance]`` over the defaults), validated.
    avoidance: AvoidanceParams = field(default_factory=AvoidanceParams)
    #: The DynamicLimits fields the scenario sets for every UAV (the others: the tracker
    #: set-up's).
    limits: LimitOverrides = field(default_factory=LimitOverrides)
    ground_vehicle: GroundVehicle | None = None
    target_sensor: TargetSensorSettings = field(default_factory=TargetSensorSettings)
    #: (the lander's id, its manoeuvre), when a UAV lands on the ground vehicle.
    landing: tuple[str, LandingParams] | None = None
    formation: FormationSpec | None = None
    #: The operational volume (``[geofence]``, :mod:`uavmpc.geofence`): every mission is
    #: inside it; a UAV found outside flies back in and holds; offsets stay below its ceiling.
    geofence: Geofence | None = None

    def points_m(self) -> np.ndarray:
        """(n, 3) every start and mission point of every UAV (e.g. the area a view shows)."""
        return np.array([p for u in self.uavs
                         for p in (u.start_m, *u.mission.points[:, :3])], dtype=float)


def _vec(value: object, n: int, name: str) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise ConfigError(f"{name}: must be a list of {n} numbers, got {value!r}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int | float) or (
                isinstance(v, int) and abs(v) > 1e5) or not math.isfinite(v):
            # (a huge TOML integer would overflow math.isfinite; it is out of bounds anyway)
            if isinstance(v, int) and not isinstance(v, bool):
                raise ConfigError(f"{name}[{i}]: an integer beyond the sane bound 1e5")
            raise ConfigError(f"{name}[{i}]: must be a finite number, got {v!r}")
        if abs(v) > 1e5:
            raise ConfigError(f"{name}[{i}]: {v} is beyond the sane bound 1e5")
        out.append(float(v))
    return tuple(out)


def _uav(t: dict[str, Any], i: int) -> UavSpec:
    p = f"uavs[{i}]"
    reject_unknown(t, {"id", "priority", "airframe", "start", "heading_rad", "goto",
                       "trajectory", "path", "avoidance"}, p)
    uav_id = take(t, "id", p)
    if not isinstance(uav_id, str) or not _ID.fullmatch(uav_id):
        raise ConfigError(f"{p}.id: must be 1–32 characters of [A-Za-z0-9_-], got {uav_id!r}")
    priority = take(t, "priority", p)
    if isinstance(priority, bool) or not isinstance(priority, int) or not 0 <= priority < 2**31:
        raise ConfigError(f"{p}.priority: must be a non-negative integer, got {priority!r}")
    airframe = t.get("airframe", "f550")
    if not isinstance(airframe, str):
        raise ConfigError(f"{p}.airframe: must be a name or a TOML path, got {airframe!r}")
    start = _vec(take(t, "start", p), 3, f"{p}.start")
    if start[2] < 0.0:
        raise ConfigError(f"{p}.start[2]: must be ≥ 0 (ground), got {start[2]}")
    heading = t.get("heading_rad", 0.0)
    _vec([heading], 1, f"{p}.heading_rad")
    avoidance = t.get("avoidance", True)
    if not isinstance(avoidance, bool):
        raise ConfigError(f"{p}.avoidance: must be true or false, got {avoidance!r}")
    given = {k: t[k] for k in FORMS if k in t}
    try:
        # None given: hold at the start (e.g. until a mission says where to go).
        mission = (mission_from_table(given, p) if given
                   else Reference.goto(start[0], start[1], start[2], float(heading)))
    except InvalidReferenceError as exc:
        raise ConfigError(str(exc)) from None
    goal = mission.points[-1]
    return UavSpec(uav_id, priority, airframe, (start[0], start[1], start[2]), float(heading),
                   mission, (float(goal[0]), float(goal[1]), float(goal[2])), avoidance)


def from_dict(data: dict[str, Any], source: str = "scenario") -> Scenario:
    """Validate a parsed scenario table."""
    reject_unknown(data, {"name", "duration_s", "link", "avoidance", "uavs", "limits",
                          "ground_vehicle", "target_sensor", "landing", "formation",
                          "geofence"}, source)
    name = data.get("name", source)
    duration = positive(take(data, "duration_s", source), "duration_s", upper=7 * 24 * 3600.0)
    uavs_raw = take(data, "uavs", source)
    if not isinstance(uavs_raw, list) or not uavs_raw:
        raise ConfigError("uavs: must be a non-empty list of [[uavs]] tables")
    if len(uavs_raw) > 1000:
        raise ConfigError(f"uavs: {len(uavs_raw)} UAVs, more than the limit 1000")
    uavs = tuple(_uav(t, i) for i, t in enumerate(uavs_raw))
    seen_id: dict[str, int] = {}
    seen_prio: dict[int, int] = {}
    for i, u in enumerate(uavs):
        if u.uav_id in seen_id:
            raise ConfigError(f"uavs[{i}].id: duplicate of uavs[{seen_id[u.uav_id]}]")
        if u.priority in seen_prio:
            raise ConfigError(f"uavs[{i}].priority: duplicate of uavs[{seen_prio[u.priority]}]")
        seen_id[u.uav_id], seen_prio[u.priority] = i, i
    link = LinkSettings.from_dict(data.get("link", {}))
    avoidance = avoidance_params(data.get("avoidance", {}))
    limits = LimitOverrides.from_dict(data.get("limits", {}))
    car = _ground_vehicle(data["ground_vehicle"]) if "ground_vehicle" in data else None
    sensor = TargetSensorSettings.from_dict(data.get("target_sensor", {}))
    landing = None
    if "landing" in data:
        table = data["landing"]
        if not isinstance(table, dict):
            raise ConfigError("landing: must be a table")
        table = dict(table)
        lander = take(table, "uav", "landing")
        if not isinstance(lander, str) or lander not in seen_id:
            raise ConfigError(f"landing.uav: {lander!r} is not a UAV of the scenario")
        if car is None:
            raise ConfigError("landing: needs a [ground_vehicle] to land on")
        del table["uav"]
        table.setdefault("deck_height_m", car.deck_height_m)
        landing = (str(lander), LandingParams.from_dict(table))
    formation = None
    if "formation" in data:
        formation = FormationSpec.from_dict(data["formation"], set(seen_id))
        if landing is not None and landing[0] in formation.members:
            raise ConfigError(f"formation: {landing[0]!r} cannot land and keep a slot")
    fence = None
    if "geofence" in data:
        fence = Geofence.from_dict(data["geofence"], "geofence")
        for i, u in enumerate(uavs):
            try:
                fence.check_reference(u.mission)
            except GeofenceError as exc:
                raise ConfigError(f"uavs[{i}] ({u.uav_id}): {exc}") from None
    return Scenario(str(name), duration, uavs, link, avoidance, limits, car, sensor,
                    landing, formation, fence)


def avoidance_params(table: object, prefix: str = "avoidance") -> AvoidanceParams:
    """An ``[avoidance]`` table (any :class:`~uavmpc.avoidance.AvoidanceParams` field) as the
    parameters, validated: a bad field fails on load, not in flight."""
    if not isinstance(table, dict):
        raise ConfigError(f"{prefix}: must be a table")
    try:
        return AvoidanceParams.from_dict(dict(table), prefix)
    except TypeError as exc:
        raise ConfigError(f"{prefix}: {exc}") from None


def changed_fields(params: DataclassInstance) -> dict[str, Any]:
    """The fields of a dataclass ``params`` that differ from its defaults (what a file needs to
    give to build it again)."""
    default = type(params)()
    return {f.name: getattr(params, f.name) for f in dataclasses.fields(params)
            if getattr(params, f.name) != getattr(default, f.name)}


def load(name_or_path: str | Path) -> Scenario:
    """A built-in scenario by name, or a scenario TOML file."""
    if str(name_or_path) in BUILTIN:
        text = resources.files("uavmpc.scenarios").joinpath(f"{name_or_path}.toml").read_bytes()
        import tomllib

        return from_dict(tomllib.loads(text.decode()), str(name_or_path))
    path = Path(name_or_path)
    if not path.exists():
        raise ConfigError(
            f"{name_or_path}: neither a built-in scenario ({', '.join(BUILTIN)}) nor a file")
    return from_dict(read_toml(path), path.stem)
